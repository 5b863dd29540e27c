"""A track as data: a closed centreline sampled about every metre, with widths.

Everything downstream (car, sensors, lines, bots) reads these arrays; how a track was authored
(TOML segments, TORCS XML, the procedural generator) ends here, so the step loop never touches
highway-env lanes or any other object graph.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

SAMPLE_SPACING_M = 1.0
"""Target spacing of centreline samples; ~1 m keeps projection exact to millimetres."""

VERTICAL_CURVATURE_WINDOW_M = 10.0
"""Vertical curvature is the change of the grade over this much track (a centred mean): TORCS
profiles are chains of straight pieces, and a kink between two of them would otherwise be one
sample of huge curvature (a 1 % kink is 0.01 1/m over 1 m, 2.5 g of unloading at 50 m/s)."""

LEVEL_SEPARATION_M = 4.0
"""Two parts of a track whose heights differ by more than this are on different levels (a
bridge over the other): they may cross in plan, and a car on one never projects onto the other."""


@dataclass(frozen=True, eq=False)
class Track:
    """A closed track: centreline samples, start line at ``s = 0``, lateral > 0 to the left.

    Arrays all have length ``n``; sample ``n`` would coincide with sample 0 (the track is closed,
    the last segment runs from ``n-1`` back to 0 with length ``length_m - s_m[-1]``).

    Heights and banking: ``z_m`` (centreline height, m) and ``banking_rad`` (> 0 raises the left
    edge, TORCS' sign), both zero when not given (a flat track). Derived from them:
    ``slope_rad`` (the grade, uphill in the driving direction > 0) and
    ``vertical_curvature_1pm`` (> 0 a crest, < 0 a compression). ``x, y`` stay the horizontal
    plan and ``s`` the horizontal arc length.

    Surfaces (:mod:`~formula_tourney.sim.surfaces`): ``friction_road``/``friction_side`` multiply
    the car's asphalt ``mu`` (a NaN side is the car's own ``mu_grass``), ``rolling_road``/
    ``rolling_side`` add to its rolling resistance; when not given, 1.0, NaN, 0.0, 0.0
    (asphalt with grass beside it).
    """

    name: str
    s_m: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    curvature_1pm: np.ndarray
    width_left_m: np.ndarray
    width_right_m: np.ndarray
    length_m: float
    closure_error_m: float = 0.0
    segments: list[dict] = field(default_factory=list)
    source: str = ""
    z_m: np.ndarray | None = None
    banking_rad: np.ndarray | None = None
    friction_road: np.ndarray | None = None
    friction_side: np.ndarray | None = None
    rolling_road: np.ndarray | None = None
    rolling_side: np.ndarray | None = None
    slope_rad: np.ndarray = field(init=False, repr=False)
    vertical_curvature_1pm: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        n = self.s_m.shape[0]
        z = np.zeros(n) if self.z_m is None else np.asarray(self.z_m, dtype=float)
        bank = np.zeros(n) if self.banking_rad is None else np.asarray(self.banking_rad, float)
        if z.shape != (n,) or bank.shape != (n,):
            raise ValueError("z_m and banking_rad need one value per sample")
        slope, kv = slope_and_vertical_curvature(self.s_m, z, self.length_m)
        object.__setattr__(self, "z_m", z)
        object.__setattr__(self, "banking_rad", bank)
        object.__setattr__(self, "slope_rad", slope)
        object.__setattr__(self, "vertical_curvature_1pm", kv)
        for key, default in (("friction_road", 1.0), ("friction_side", np.nan),
                             ("rolling_road", 0.0), ("rolling_side", 0.0)):
            value = getattr(self, key)
            arr = np.full(n, default) if value is None else np.asarray(value, dtype=float)
            ok = np.isnan(arr) if key == "friction_side" else np.zeros(n, dtype=bool)
            if arr.shape != (n,) or not np.all(ok | (np.isfinite(arr) & (arr >= 0.0))):
                raise ValueError(f"{key} needs one finite value >= 0 per sample")
            object.__setattr__(self, key, arr)

    @property
    def has_surface(self) -> bool:
        """True when any height or banking is non-zero (the physics then reads the surface)."""
        return bool(np.any(self.z_m != 0.0) or np.any(self.banking_rad != 0.0))

    @property
    def n(self) -> int:
        return int(self.s_m.shape[0])

    @property
    def width_m(self) -> np.ndarray:
        return self.width_left_m + self.width_right_m

    @property
    def min_radius_m(self) -> float:
        k = float(np.max(np.abs(self.curvature_1pm)))
        return float("inf") if k == 0.0 else 1.0 / k

    def wrap_s(self, s_m: np.ndarray | float) -> np.ndarray | float:
        return np.mod(s_m, self.length_m)

    def index_at(self, s_m: np.ndarray | float) -> np.ndarray:
        """Index of the sample at or before ``s`` (samples are near-uniform)."""
        s = np.asarray(self.wrap_s(s_m))
        i = np.searchsorted(self.s_m, s, side="right") - 1
        return np.clip(i, 0, self.n - 1)

    def pose_at(self, s_m: np.ndarray | float, lateral_m: np.ndarray | float = 0.0):
        """World ``(x, y, heading)`` of the point at arc length ``s`` and lateral offset."""
        s = np.asarray(self.wrap_s(s_m), dtype=float)
        i = self.index_at(s)
        j = (i + 1) % self.n
        seg_len = np.where(j == 0, self.length_m - self.s_m[i], self.s_m[j] - self.s_m[i])
        t = (s - self.s_m[i]) / np.maximum(seg_len, 1e-12)
        x = self.x_m[i] + t * (self.x_m[j] - self.x_m[i])
        y = self.y_m[i] + t * (self.y_m[j] - self.y_m[i])
        dh = np.angle(np.exp(1j * (self.heading_rad[j] - self.heading_rad[i])))
        h = self.heading_rad[i] + t * dh
        lat = np.asarray(lateral_m, dtype=float)
        return x - lat * np.sin(h), y + lat * np.cos(h), h

    def project(self, x_m: float, y_m: float, hint_index: int = -1, window: int = 30,
                z_m: float | None = None):
        """Arc length, lateral offset and segment index of a world point.

        With a ``hint_index`` (the previous result) only ``window`` samples either side are
        searched: a car moves at most ~20 m per 0.2 s step, so a local search replaces the
        global scan the step loop must never do, and it cannot jump to another level of a track
        that crosses itself on a bridge. Without a hint the whole track is scanned; give
        ``z_m`` there to keep to the samples within :data:`LEVEL_SEPARATION_M` of that height.
        """
        if hint_index < 0:
            idx = np.arange(self.n)
            if z_m is not None:
                near = np.abs(self.z_m - z_m) <= LEVEL_SEPARATION_M
                if near.any():
                    idx = idx[near]
        else:
            idx = np.arange(hint_index - window, hint_index + window + 1) % self.n
        nxt = (idx + 1) % self.n
        ax, ay = self.x_m[idx], self.y_m[idx]
        dx, dy = self.x_m[nxt] - ax, self.y_m[nxt] - ay
        seg2 = np.maximum(dx * dx + dy * dy, 1e-12)
        t = np.clip(((x_m - ax) * dx + (y_m - ay) * dy) / seg2, 0.0, 1.0)
        px, py = ax + t * dx, ay + t * dy
        d2 = (x_m - px) ** 2 + (y_m - py) ** 2
        k = int(np.argmin(d2))
        i = int(idx[k])
        seg_len = float(np.sqrt(seg2[k]))
        s = float(self.wrap_s(self.s_m[i] + t[k] * seg_len))
        cross = dx[k] * (y_m - ay[k]) - dy[k] * (x_m - ax[k])
        lateral = float(np.sign(cross) * np.sqrt(d2[k]))
        return s, lateral, i

    @classmethod
    def from_centreline(
        cls,
        name: str,
        x_m: np.ndarray,
        y_m: np.ndarray,
        width_left_m: np.ndarray | float,
        width_right_m: np.ndarray | float,
        *,
        closure_error_m: float = 0.0,
        segments: list[dict] | None = None,
        source: str = "",
        spacing_m: float = SAMPLE_SPACING_M,
        z_m: np.ndarray | float = 0.0,
        banking_rad: np.ndarray | float = 0.0,
    ) -> Track:
        """Resample a closed polyline (last point != first) to ~``spacing_m`` and derive
        heading and curvature by central differences on the closed loop (heights and banking,
        if given, are resampled the same way)."""
        x = np.asarray(x_m, dtype=float)
        y = np.asarray(y_m, dtype=float)
        wl = np.broadcast_to(np.asarray(width_left_m, dtype=float), x.shape)
        wr = np.broadcast_to(np.asarray(width_right_m, dtype=float), x.shape)
        xc, yc = np.append(x, x[0]), np.append(y, y[0])
        seg = np.hypot(np.diff(xc), np.diff(yc))
        s_in = np.concatenate([[0.0], np.cumsum(seg)])
        length = float(s_in[-1])
        n = max(int(round(length / spacing_m)), 8)
        s = np.linspace(0.0, length, n, endpoint=False)
        xs = np.interp(s, s_in, xc)
        ys = np.interp(s, s_in, yc)
        wls = np.interp(s, s_in, np.append(wl, wl[0]))
        wrs = np.interp(s, s_in, np.append(wr, wr[0]))
        zz = np.broadcast_to(np.asarray(z_m, dtype=float), x.shape)
        bb = np.broadcast_to(np.asarray(banking_rad, dtype=float), x.shape)
        zs = np.interp(s, s_in, np.append(zz, zz[0]))
        bs = np.interp(s, s_in, np.append(bb, bb[0]))
        heading, curvature = closed_heading_curvature(xs, ys)
        return cls(
            name=name, s_m=s, x_m=xs, y_m=ys, heading_rad=heading, curvature_1pm=curvature,
            width_left_m=wls, width_right_m=wrs, length_m=length,
            closure_error_m=float(closure_error_m), segments=list(segments or []), source=source,
            z_m=zs, banking_rad=bs,
        )


def closed_heading_curvature(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heading and signed curvature (left turn > 0) of a closed, evenly spaced polyline."""
    dx = (np.roll(x, -1) - np.roll(x, 1)) / 2.0
    dy = (np.roll(y, -1) - np.roll(y, 1)) / 2.0
    ddx = np.roll(x, -1) - 2 * x + np.roll(x, 1)
    ddy = np.roll(y, -1) - 2 * y + np.roll(y, 1)
    heading = np.arctan2(dy, dx)
    curvature = (dx * ddy - dy * ddx) / np.maximum((dx * dx + dy * dy) ** 1.5, 1e-12)
    return heading, curvature


def slope_and_vertical_curvature(s_m: np.ndarray, z_m: np.ndarray, length_m: float
                                 ) -> tuple[np.ndarray, np.ndarray]:
    """Grade (rad, uphill > 0) and vertical curvature (1/m, crest > 0) of a closed height
    profile: the grade by central differences, the curvature as minus the change of the grade
    over :data:`VERTICAL_CURVATURE_WINDOW_M` per metre of surface. Zeros for a flat profile."""
    n = s_m.shape[0]
    if not np.any(z_m):
        return np.zeros(n), np.zeros(n)
    s_next = np.append(s_m[1:], length_m)
    s_prev = np.insert(s_m[:-1], 0, s_m[-1] - length_m)
    dz = np.roll(z_m, -1) - np.roll(z_m, 1)
    slope = np.arctan(dz / np.maximum(s_next - s_prev, 1e-12))
    spacing = length_m / n
    half = max(int(round(0.5 * VERTICAL_CURVATURE_WINDOW_M / spacing)), 1)
    ahead = np.roll(slope, -half)
    behind = np.roll(slope, half)
    kv = -(ahead - behind) / (2 * half * spacing) * np.cos(slope)
    return slope, kv

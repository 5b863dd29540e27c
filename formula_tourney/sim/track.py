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


@dataclass(frozen=True, eq=False)
class Track:
    """A closed track: centreline samples, start line at ``s = 0``, lateral > 0 to the left.

    Arrays all have length ``n``; sample ``n`` would coincide with sample 0 (the track is closed,
    the last segment runs from ``n-1`` back to 0 with length ``length_m - s_m[-1]``).
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

    def project(self, x_m: float, y_m: float, hint_index: int = -1, window: int = 30):
        """Arc length, lateral offset and segment index of a world point.

        With a ``hint_index`` (the previous result) only ``window`` samples either side are
        searched: a car moves at most ~20 m per 0.2 s step, so a local search replaces the
        global scan the step loop must never do. Without a hint the whole track is scanned.
        """
        if hint_index < 0:
            idx = np.arange(self.n)
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
    ) -> Track:
        """Resample a closed polyline (last point != first) to ~``spacing_m`` and derive
        heading and curvature by central differences on the closed loop."""
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
        heading, curvature = closed_heading_curvature(xs, ys)
        return cls(
            name=name, s_m=s, x_m=xs, y_m=ys, heading_rad=heading, curvature_1pm=curvature,
            width_left_m=wls, width_right_m=wrs, length_m=length,
            closure_error_m=float(closure_error_m), segments=list(segments or []), source=source,
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

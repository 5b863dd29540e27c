"""Telemetry: the observation layout, its normalisation, and the track arrays the sensors read.

The values themselves are computed in the compiled step (:func:`kernels.observe`); this module is
the one place that names them, so agents, docs and tests agree on what index ``i`` means.

Layout (``lac=False``: 29 values; ``lac=True``: 33), all float32, normalised so that typical
values lie in about [-1, 1] (the SCR/gym_torcs conventions, in SI units):

===== ================= ========================= ======== =====================================
index name              raw quantity              unit     normalised value
===== ================= ========================= ======== =====================================
0     angle             car heading - reference   rad      angle / pi, in [-1, 1]
                        line heading
1-19  track_-90..       range finder at -90..+90  m        distance / 200, in [0, 1];
      track_90          deg from the car's axis            -1 for all 19 when off the asphalt
                        every 10 deg (+ = left)
20    trackPos          (lateral - reference      m        0 on the line, +-1 at one half-width
                        offset) / half width               (left > 0), beyond 1 on the grass
21    speedX            body longitudinal speed   m/s      v / 83.33 (300 km/h = 1)
22    speedY            body lateral speed        m/s      v / 83.33 (left > 0)
23    speedZ            vertical speed            m/s      v / 83.33: along-track speed x
                                                           sin(grade) + across-track speed x
                                                           sin(bank); 0 on flat tracks
24-27 wheelSpinVel_FL,  wheel spin speeds         rad/s    omega / 250 (~300 km/h = 1)
      _FR, _RL, _RR
28    rpm               engine speed              rpm      rpm / 10000
29-32 lac_20..lac_80    reference line curvature  1/m      curvature * 10 (a 10 m radius = 1,
                        20/40/60/80 m ahead                left turn > 0); only with ``lac``
===== ================= ========================= ======== =====================================
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from formula_tourney.sim import kernels as K
from formula_tourney.sim.reference_line import ReferenceLine
from formula_tourney.sim.track import Track

RANGE_FINDER_ANGLES_DEG = tuple(range(-90, 91, 10))
"""Range finder directions relative to the car's axis, left > 0 (SCR's 19 default angles)."""
RANGE_FINDER_RANGE_M = K.RAY_RANGE_M
DEFAULT_LAC_DISTANCES_M = (20.0, 40.0, 60.0, 80.0)
N_BASE = K.OBS_LAC
"""Number of values without LAC (29)."""
SPEED_SCALE_MPS = K.SPEED_SCALE_MPS
WHEEL_SCALE_RADPS = K.WHEEL_SCALE_RADPS
RPM_SCALE = K.RPM_SCALE
LAC_SCALE_M = K.LAC_SCALE_M


def observation_names(lac: bool, lac_distances_m: Sequence[float] = DEFAULT_LAC_DISTANCES_M
                      ) -> list[str]:
    """Names of the observation entries in order (see the module table)."""
    names = ["angle"]
    names += [f"track_{a}" for a in RANGE_FINDER_ANGLES_DEG]
    names += ["trackPos", "speedX", "speedY", "speedZ"]
    names += [f"wheelSpinVel_{w}" for w in ("FL", "FR", "RL", "RR")]
    names += ["rpm"]
    if lac:
        names += [f"lac_{float(d):g}" for d in lac_distances_m]
    return names


def observation_bounds(lac: bool, n_lac: int = len(DEFAULT_LAC_DISTANCES_M)
                       ) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` of the normalised observation; unbounded where physics sets no bound."""
    n = N_BASE + (n_lac if lac else 0)
    low = np.full(n, -np.inf, dtype=np.float32)
    high = np.full(n, np.inf, dtype=np.float32)
    low[K.OBS_ANGLE], high[K.OBS_ANGLE] = -1.0, 1.0
    low[K.OBS_TRACK:K.OBS_TRACK + K.N_RAYS] = -1.0
    high[K.OBS_TRACK:K.OBS_TRACK + K.N_RAYS] = 1.0
    low[K.OBS_VZ], high[K.OBS_VZ] = -1.0, 1.0
    low[K.OBS_RPM], high[K.OBS_RPM] = 0.0, np.inf
    return low, high


def denormalise(obs: np.ndarray, lac: bool = False) -> dict[str, np.ndarray]:
    """Physical values (SI units) of an observation or a batch of them, by name.

    For plots and bots that prefer metres and m/s; ``track`` stays -1 where it is off track.
    """
    o = np.asarray(obs, dtype=float)
    tr = o[..., K.OBS_TRACK:K.OBS_TRACK + K.N_RAYS]
    out = {
        "angle_rad": o[..., K.OBS_ANGLE] * np.pi,
        "track_m": np.where(tr < 0, -1.0, tr * RANGE_FINDER_RANGE_M),
        "trackPos": o[..., K.OBS_TRACKPOS],
        "speedX_mps": o[..., K.OBS_VX] * SPEED_SCALE_MPS,
        "speedY_mps": o[..., K.OBS_VY] * SPEED_SCALE_MPS,
        "speedZ_mps": o[..., K.OBS_VZ] * SPEED_SCALE_MPS,
        "wheelSpinVel_radps": o[..., K.OBS_WHEEL:K.OBS_WHEEL + 4] * WHEEL_SCALE_RADPS,
        "rpm": o[..., K.OBS_RPM] * RPM_SCALE,
    }
    if lac:
        out["lac_1pm"] = o[..., K.OBS_LAC:] / LAC_SCALE_M
    return out


def track_geometry(track: Track, reference: ReferenceLine, grip_scale: float = 1.0,
                   mu_over_grass: float = 1.0) -> np.ndarray:
    """Per-sample arrays the kernels read (``G_*`` columns): centreline, widths, asphalt edges,
    the reference line's offset, heading and curvature, straight runs and per-segment constants
    (precomputed so the projection, run 20 times a step, does no division), and the surfaces'
    friction (times ``grip_scale``) and rolling resistance; one block. ``mu_over_grass`` is the
    car's ``mu / mu_grass``: a named side surface's friction is relative to ``mu``, and the
    kernel multiplies ``mu_grass`` on the side."""
    n = track.n
    g = np.zeros((n, K.N_GEOM))
    nx, ny = -np.sin(track.heading_rad), np.cos(track.heading_rad)
    g[:, K.G_X] = track.x_m
    g[:, K.G_Y] = track.y_m
    g[:, K.G_H] = track.heading_rad
    g[:, K.G_WL] = track.width_left_m
    g[:, K.G_WR] = track.width_right_m
    g[:, K.G_S] = track.s_m
    g[:, K.G_LX] = track.x_m + track.width_left_m * nx
    g[:, K.G_LY] = track.y_m + track.width_left_m * ny
    g[:, K.G_RX] = track.x_m - track.width_right_m * nx
    g[:, K.G_RY] = track.y_m - track.width_right_m * ny
    g[:, K.G_REF_OFF] = reference.offset_m
    g[:, K.G_REF_H] = reference.heading_rad
    g[:, K.G_REF_K] = reference.curvature_1pm
    g[:, K.G_RUN] = straight_runs(g)
    g[:, K.G_DX] = np.roll(track.x_m, -1) - track.x_m
    g[:, K.G_DY] = np.roll(track.y_m, -1) - track.y_m
    g[:, K.G_INV2] = 1.0 / np.maximum(g[:, K.G_DX] ** 2 + g[:, K.G_DY] ** 2, 1e-12)
    g[:, K.G_SLEN] = np.diff(np.append(track.s_m, track.length_m))
    block_capsules(g)
    g[:, K.G_MU_ROAD] = track.friction_road * grip_scale
    side = track.friction_side
    g[:, K.G_MU_SIDE] = np.where(np.isnan(side), 1.0, side * mu_over_grass) * grip_scale
    g[:, K.G_RR_ROAD] = track.rolling_road
    g[:, K.G_RR_SIDE] = track.rolling_side
    return np.ascontiguousarray(g)


def surface_block(track: Track) -> np.ndarray:
    """Per-sample surface constants the physics reads on a track with heights or banking
    (``E_*`` columns of :mod:`kernels`): gravity's in-plane part in world axes and its normal
    part, vertical curvature, sin/cos of the banking, sin of the grade, the heading's cos/sin.
    A flat track gives zeros for the gravity terms and is never read (``C_ELEV`` unset)."""
    return surface_rows(track.heading_rad, track.slope_rad, track.banking_rad,
                        track.vertical_curvature_1pm, track.z_m)


def surface_rows(heading_rad, slope_rad, banking_rad, kv_1pm, z_m=0.0) -> np.ndarray:
    """:func:`surface_block` from arrays (or scalars broadcast together)."""
    h, th, b, kv, z = np.broadcast_arrays(*(np.atleast_1d(np.asarray(a, dtype=float))
                                            for a in (heading_rad, slope_rad, banking_rad,
                                                      kv_1pm, z_m)))
    e = np.zeros((h.shape[0], K.N_ELEV))
    g = K.GRAVITY
    along = -g * np.sin(th)
    lat = -g * np.cos(th) * np.sin(b)
    ch, sh = np.cos(h), np.sin(h)
    e[:, K.E_Z] = z
    e[:, K.E_GX] = along * ch - lat * sh
    e[:, K.E_GY] = along * sh + lat * ch
    e[:, K.E_GN] = g * np.cos(th) * np.cos(b)
    e[:, K.E_KV] = kv
    e[:, K.E_SB] = np.sin(b)
    e[:, K.E_ICB] = 1.0 / np.cos(b)
    e[:, K.E_SG] = np.sin(th)
    e[:, K.E_CH] = ch
    e[:, K.E_SH] = sh
    return np.ascontiguousarray(e)


def block_capsules(g: np.ndarray) -> None:
    """Fill ``G_BHL``/``G_BHR``: for each sample ``k``, the largest distance of the left (right)
    edge's vertices ``k .. k + RAY_BLOCK`` (wrapping) from the chord between the first and the
    last, slightly inflated so that rounding in the ray's side test never lets a vertex through.
    The ray caster crosses a block in one step when its line clears both capsules."""
    n = g.shape[0]
    idx = (np.arange(n)[:, None] + np.arange(K.RAY_BLOCK + 1)[None, :]) % n
    for xc, yc, hc in ((K.G_LX, K.G_LY, K.G_BHL), (K.G_RX, K.G_RY, K.G_BHR)):
        x, y = g[idx, xc], g[idx, yc]
        ax, ay = x[:, :1], y[:, :1]
        ex, ey = x[:, -1:] - ax, y[:, -1:] - ay
        len2 = np.maximum(ex * ex + ey * ey, 1e-300)
        t = np.clip(((x - ax) * ex + (y - ay) * ey) / len2, 0.0, 1.0)
        dist = np.hypot(ax + t * ex - x, ay + t * ey - y).max(axis=1)
        g[:, hc] = dist * (1.0 + 1e-9) + 1e-6


STRAIGHT_TOLERANCE_M = 1e-9
"""Largest offset of an edge point from the line through its neighbours that still counts as
straight. Per-point tests chain, so a run could drift by ~(run length)^2 / (8 R) for a radius R
that passes every test: at 1e-9 m per 1 m sample that needs R > 1e8 m, i.e. float noise only."""


def straight_runs(g: np.ndarray) -> np.ndarray:
    """For each sample ``k``, the last sample ``e >= k`` such that both asphalt edges are one
    straight segment from ``k`` to ``e`` (no wrap past the last sample).

    The ray caster crosses such a run in one step: on a 600 m straight the forward range
    finders otherwise walk 200 one-metre quads each, which was most of the telemetry's cost.
    """
    n = g.shape[0]

    def collinear(xc: int, yc: int) -> np.ndarray:
        x, y = g[:, xc], g[:, yc]
        ax, ay = np.roll(x, 1), np.roll(y, 1)
        bx, by = np.roll(x, -1), np.roll(y, -1)
        chord = np.maximum(np.hypot(bx - ax, by - ay), 1e-12)
        dev = np.abs((bx - ax) * (y - ay) - (by - ay) * (x - ax)) / chord
        ahead = (bx - x) * (x - ax) + (by - y) * (y - ay) > 0
        return (dev < STRAIGHT_TOLERANCE_M) & ahead

    interior = collinear(K.G_LX, K.G_LY) & collinear(K.G_RX, K.G_RY)
    interior[0] = interior[-1] = False  # runs do not wrap past the last sample
    run = np.arange(n, dtype=float)
    nxt = n - 1
    for k in range(n - 1, -1, -1):
        # The run from k continues through k+1 while k+1 is an interior straight point.
        if k + 1 < n and interior[k + 1]:
            run[k] = run[k + 1]
        else:
            run[k] = min(k + 1, nxt)
    return run

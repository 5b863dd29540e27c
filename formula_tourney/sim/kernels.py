"""Compiled step of the simulator: physics substeps, projection, lap timing, telemetry, reward.

One call of :func:`step_cars` advances every car of a batch by one control period and writes its
observation, reward and end flags into preallocated arrays. Everything a step needs lives here so
that the Python side of ``env.step`` is one numba call plus a few array reads.

Why numba and this shape (docs/sim.md, "Speed"): NumPy batched over 64
cars managed only ~6-9k car-steps/s because each of the ~100 small array operations per substep
costs microseconds of call overhead; the same step compiled with numba ran 80-140k steps/s for one
car and ~250k car-steps/s for 64 cars on one thread. Range finders dominate the kernel, so each
ray walks the track corridor quad by quad (exact, a few quads per side ray) instead of testing a
window of edges by brute force (3-4x slower). Kernels compile with ``cache=True`` (~15 s cold).

Every kernel is compiled with ``_nrt=False`` and the per-substep helpers with
``inline="always"``: a profile of the first version spent ~24% of the kernel in NRT
reference-count atomics (one incref/decref pair per array argument of each helper call, 20
substeps a step), and numba does not inline one njit function into another by itself. Nothing
here allocates, so the runtime is not needed. ``fastmath`` leaves out ``nnan``/``ninf``: actions
and lap times are checked with ``isnan``.

Data layout (all float64, row per car):

- ``state[c, ST_*]``: pose, body velocities, wheel spins, gear, engine rpm, damage, projection
  (s, lateral, hint index), progress, lap clock; columns named by the ``ST_*`` constants.
- ``params[P_*]``: the car (:func:`pack_params` in ``car.py`` fills it from ``CarParams``).
- ``geom[i, G_*]``: per track sample: centreline, widths, edges, reference line.
- ``elev[i, E_*]``: per track sample: height, gravity on the sloped and banked surface, vertical
  curvature (read only when ``cfg[C_ELEV]`` is set).
- ``cfg[C_*]``: control period, substeps, grass width, termination switches, then the reward
  model's weights from ``C_REWARD`` on, in the order of ``reward.KERNEL_NAMES``.
- ``out[c, O_*]``: truncation, lap time of a lap completed this step, then from ``O_REWARD_IN``
  on what the reward is made of (``reward.INPUT_NAMES``: the reward, the end code, the damage of
  the step, Vx, theta, trackPos, progress), which ``info["rewards"]`` splits into parts.

The reward blocks' indices are derived from ``sim.reward``'s tables, never written by hand: a new
weight or input goes into its table and takes the next slot. numba freezes these indices into the
cached kernels, so :func:`drop_stale_cache` forgets them when those tables change.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit, prange

from formula_tourney.sim import reward as R

# --- state columns -----------------------------------------------------------------------------
ST_X = 0  # world x of the centre of gravity, m
ST_Y = 1
ST_PSI = 2  # yaw (heading of the car's x axis), rad
ST_VX = 3  # body-frame longitudinal speed, m/s
ST_VY = 4  # body-frame lateral speed (left > 0), m/s
ST_R = 5  # yaw rate, rad/s
ST_W_FL = 6  # wheel spin speeds, rad/s: front-left, front-right, rear-left, rear-right
ST_W_FR = 7
ST_W_RL = 8
ST_W_RR = 9
ST_GEAR = 10  # gear index 0..G-1
ST_RPM = 11  # engine speed, rpm
ST_DAMAGE = 12  # cumulative damage points
ST_S = 13  # arc length along the centreline, m
ST_LAT = 14  # lateral offset from the centreline, m (left > 0)
ST_IDX = 15  # projection hint (segment index); < 0 forces a global scan
ST_DIST = 16  # progress along the track since reset, m
ST_TIME = 17  # simulated time since reset, s
ST_LAP_START = 18  # time the running lap started, s; < 0 before the first line crossing
ST_LAP_DEBT = 19  # backward line crossings not yet undone by forward ones
ST_SLOW = 20  # consecutive steps with progress below the slow threshold
ST_AX = 21  # last longitudinal specific force, m/s^2 (load transfer)
ST_AY = 22  # last lateral specific force, m/s^2
ST_STEPS = 23  # control steps since reset
ST_OFF = 24  # 1 when the car's centre is off the asphalt
ST_STEER = 25  # last front wheel angle, rad (rendering)
# This car's episode grip factor minus 1 (per-episode grip, a drying track: docs/sim.md
# "Surfaces"), on top of the geometry block's frictions. Stored as a difference so that a
# zero-filled row (race cars, tests) keeps the track's own grip and the multiply is skipped.
ST_GRIP_DELTA = 26
N_STATE = 27

# --- car parameters ----------------------------------------------------------------------------
P_MASS = 0
P_IZ = 1
P_LF = 2
P_LR = 3
P_H = 4
P_TW = 5
P_LEN = 6
P_WID = 7
P_MU = 8
P_MU_GRASS = 9
P_GRASS_DRAG = 10
P_CF = 11
P_CR = 12
P_CD = 13
P_CL = 14
P_CRR = 15
P_RW = 16
P_IDLE = 17
P_REDLINE = 18
P_FD = 19
P_EFF = 20
P_UP = 21
P_DOWN = 22
P_BRAKE = 23
P_BIAS = 24
P_STEER = 25
P_WALL_DMG = 26
P_WALL_E = 27
P_LAUNCH_RPM = 28
# Derived by :func:`derive_params` (the hot path multiplies by these instead of dividing).
P_INV_M = 29
P_INV_IZ = 30
P_INV_RW = 31
P_MG = 32  # weight, N
P_LR_WB = 33  # cg_to_rear / wheelbase
P_LF_WB = 34
P_H_WB = 35  # cg height / wheelbase
P_H_TW = 36  # cg height / track width
P_CS_F = 37  # cornering stiffness per newton of static axle load, front and rear
P_CS_R = 38
P_TO_RPM = 39  # rpm per (rad/s of wheel x gear ratio)
P_DRIVE_K = 40  # final drive x efficiency / wheel radius
P_BRAKE_F = 41  # front and rear shares of the brake force, N
P_BRAKE_R = 42
P_REACH = 43  # half the body diagonal, m
N_PARAMS = 44

# --- track geometry columns --------------------------------------------------------------------
G_X = 0
G_Y = 1
G_H = 2  # centreline heading
G_WL = 3
G_WR = 4
G_S = 5
G_LX = 6  # left asphalt edge
G_LY = 7
G_RX = 8  # right asphalt edge
G_RY = 9
G_REF_OFF = 10  # reference line: lateral offset, heading, curvature
G_REF_H = 11
G_REF_K = 12
G_RUN = 13  # last sample of the straight run of edges that starts here (== index if none)
G_DX = 14  # segment to the next sample: x and y extent, 1 / length^2, arc length
G_DY = 15
G_INV2 = 16
G_SLEN = 17
# Largest distance of each edge's vertices k .. k + RAY_BLOCK from the chord between the first
# and the last (left, right): a ray whose line clears both capsules crosses those quads at once.
G_BHL = 18
G_BHR = 19
# Surfaces (docs/sim.md "Surfaces"): friction multipliers of the road (on ``P_MU``) and of the
# side beyond each edge (on ``P_MU_GRASS``), already times the env's ``grip_scale``, and extra
# rolling-resistance coefficients (added to ``P_CRR``). 1.0 and 0.0 on a track without surface
# names (x * 1.0 and x + 0.0 are exact: those tracks run bit-identical to before surfaces).
# Road and side columns are adjacent: the column is ``G_MU_ROAD + off`` (``off`` 0 or 1).
G_MU_ROAD = 20
G_MU_SIDE = 21
G_RR_ROAD = 22
G_RR_SIDE = 23
# Beyond the paper: the reference limit's QSS speed (m/s) at each sample, read by the reward's
# overspeed crash term only (0 where no training run filled it: the term's weight is then 0).
G_VLIM = 24
N_GEOM = 25
RAY_BLOCK = 8

# --- surface (elevation and banking) columns, per track sample: ``elev[i, E_*]`` ---------------
# Read only when ``cfg[C_ELEV]`` is set (a track with any height or banking): a flat track never
# enters the code that reads them, so its trajectories are bit-identical to the flat simulator.
E_Z = 0  # centreline height, m
E_GX = 1  # in-plane component of gravity in world x and y, m/s^2 (-g sin(grade) along the
E_GY = 2  # track, -g cos(grade) sin(bank) across it, left > 0)
E_GN = 3  # normal component of gravity, g cos(grade) cos(bank), m/s^2
E_KV = 4  # vertical curvature, 1/m (> 0 a crest)
E_SB = 5  # sin(bank): bank > 0 raises the left edge (TORCS' sign)
E_ICB = 6  # 1 / cos(bank)
E_SG = 7  # sin(grade)
E_CH = 8  # cos and sin of the centreline heading
E_SH = 9
N_ELEV = 10

# --- configuration -----------------------------------------------------------------------------
C_DT = 0  # control period, s
C_NSUB = 1  # physics substeps per control period
C_GRASS_W = 2  # grass width beyond each asphalt edge before the wall, m
C_MAX_STEPS = 3
C_TERM_OFF = 4
C_TERM_BACK = 5
C_TERM_SLOW = 6
C_SLOW_MPS = 7
C_SLOW_PATIENCE = 8
C_LAC = 9
C_LENGTH = 10  # track length, m
C_ELEV = 11  # 1 when the track has heights or banking (the ``elev`` block is read)
C_DRY_M = 12  # drying track: distance (m) over which the grip dries; 0 = no drying
C_DRY_DELTA0 = 13  # drying track: ``ST_GRIP_DELTA`` at distance 0 (rises linearly to 0)
C_REWARD = 14  # the reward model's weights (``reward.pack``), in ``reward.KERNEL_NAMES`` order:
C_TRACKPOS_W = C_REWARD + R.kernel_slot("track_pos_weight")  # of ``-Vx w |trackPos|``
C_PROGRESS = C_REWARD + R.kernel_slot("progress_reward")  # 1: progress replaces the speed term
C_DMG_W = C_REWARD + R.kernel_slot("damage_weight")
C_SLOW_PEN = C_REWARD + R.kernel_slot("slow_penalty")
C_END_REWARD = C_REWARD + R.kernel_slot("early_end_reward")  # an off-track or backwards end
C_WALL_E = C_REWARD + R.kernel_slot("wall_energy_weight")  # off track: less this x Vx^2
C_OVERSPEED = C_REWARD + R.kernel_slot("overspeed_crash_weight")  # off track: less this x
# (Vx^2 - G_VLIM^2) where positive
N_CFG = C_REWARD + len(R.KERNEL_NAMES)

# --- per-step outputs --------------------------------------------------------------------------
O_TRUNC = 0  # 1 when max steps reached (and not terminated)
O_LAP_TIME = 1  # lap completed during this step, s; NaN if none
O_REWARD_IN = 2  # what the reward is made of (``reward.parts`` reads it), in INPUT_NAMES order:
O_REWARD = O_REWARD_IN + R.input_slot("reward")
O_TERM = O_REWARD_IN + R.input_slot("end")  # 0 running, 1 off track, 2 backwards, 3 slow
O_DMG_INC = O_REWARD_IN + R.input_slot("damage")  # damage added during this step
O_VX = O_REWARD_IN + R.input_slot("speed_mps")
O_ANGLE = O_REWARD_IN + R.input_slot("angle_rad")
O_TRACKPOS = O_REWARD_IN + R.input_slot("track_pos")
O_PROGRESS = O_REWARD_IN + R.input_slot("progress_mps")
N_OUT = O_REWARD_IN + len(R.INPUT_NAMES)

TERM_NONE = 0
TERM_OFF_TRACK = 1
TERM_BACKWARDS = 2
TERM_SLOW = 3

# --- observation layout (normalisation documented in sensors.py) -------------------------------
N_RAYS = 19
RAY_RANGE_M = 200.0
OBS_ANGLE = 0
OBS_TRACK = 1
OBS_TRACKPOS = 20
OBS_VX = 21
OBS_VY = 22
OBS_VZ = 23
OBS_WHEEL = 24
OBS_RPM = 28
OBS_LAC = 29
SPEED_SCALE_MPS = 300.0 / 3.6
WHEEL_SCALE_RADPS = 250.0
RPM_SCALE = 10000.0
LAC_SCALE_M = 10.0
# Ray angles relative to the heading (-90..90 deg every 10), as cos/sin tables.
_RAY_COS = np.cos((np.arange(N_RAYS) - 9) * (math.pi / 18.0))
_RAY_SIN = np.sin((np.arange(N_RAYS) - 9) * (math.pi / 18.0))
_RAY_COS[9], _RAY_SIN[9] = 1.0, 0.0

# Slip angles use max(|vx|, this) as denominator: below it the tyre acts as a damper, which keeps
# the explicit integration stable at 100 Hz from standstill (C/(m*v)*dt < 1).
SLIP_MIN_SPEED_MPS = 3.0
# Longitudinal slip stiffness per newton of load (force per unit slip ratio): the slip ratio at
# the grip peak is then mu/20 ~ 8%, typical of racing tyres.
SLIP_STIFFNESS_PER_N = 20.0
# Share of the wall impact impulse that becomes friction along the wall (scrubs speed).
WALL_FRICTION = 0.5
GRAVITY = 9.81
TWO_PI = 2.0 * math.pi
_FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _wrap_angle(a: float) -> float:
    # Float % is a libm fmod call (~2% of the kernel's samples with ~7 calls per car-step):
    # angles here are within one turn of the range, so a subtraction does (same result up to
    # the rounding of +-pi, 4e-16 rad).
    if a >= math.pi:
        a -= TWO_PI
    elif a < -math.pi:
        a += TWO_PI
    if -math.pi <= a < math.pi:
        return a
    return (a + math.pi) % TWO_PI - math.pi


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _clip(v: float, lo: float, hi: float) -> float:
    return lo if v < lo else (hi if v > hi else v)


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _fiala(tan_alpha: float, stiffness: float, fmax: float, inv_fmax: float) -> float:
    """:func:`fiala_lateral_force` for ``fmax > 0`` given ``1 / fmax``: one division fewer.

    With ``q = C tan(alpha) / (3 fmax)`` the cubic is ``fmax (-3q + 3q|q| - q^3)``, sliding
    (``-fmax sign q``) from ``|q| >= 1``.
    """
    q = stiffness * tan_alpha * inv_fmax * (1.0 / 3.0)
    if q >= 1.0:
        return -fmax
    if q <= -1.0:
        return fmax
    return fmax * (q * (3.0 * abs(q) - 3.0 - q * q))


@njit(cache=True, fastmath=_FAST, _nrt=False)
def fiala_lateral_force(tan_alpha: float, stiffness: float, fmax: float) -> float:
    """Fiala brush tyre: cubic in slip up to full sliding at ``3 fmax / C``, then ``-fmax``.

    Cheaper than Pacejka at equal stiffness and peak and saturates exactly at mu*Fz.
    """
    if fmax <= 0.0:
        return 0.0
    return _fiala(tan_alpha, stiffness, fmax, 1.0 / fmax)


@njit(cache=True, fastmath=_FAST, _nrt=False)
def derive_params(p: np.ndarray) -> None:
    """Fill the derived ``P_*`` slots (inverses, ratios) from the car's own parameters."""
    m = p[P_MASS]
    lf = p[P_LF]
    lr = p[P_LR]
    wb = lf + lr
    p[P_INV_M] = 1.0 / m
    p[P_INV_IZ] = 1.0 / p[P_IZ]
    p[P_INV_RW] = 1.0 / p[P_RW]
    p[P_MG] = m * GRAVITY
    p[P_LR_WB] = lr / wb
    p[P_LF_WB] = lf / wb
    p[P_H_WB] = p[P_H] / wb
    p[P_H_TW] = p[P_H] / p[P_TW]
    p[P_CS_F] = p[P_CF] / (m * GRAVITY * lr / wb)
    p[P_CS_R] = p[P_CR] / (m * GRAVITY * lf / wb)
    p[P_TO_RPM] = p[P_FD] * 60.0 / TWO_PI
    p[P_DRIVE_K] = p[P_FD] * p[P_EFF] / p[P_RW]
    p[P_BRAKE_F] = p[P_BRAKE] * p[P_BIAS]
    p[P_BRAKE_R] = p[P_BRAKE] * (1.0 - p[P_BIAS])
    p[P_REACH] = 0.5 * math.sqrt(p[P_LEN] * p[P_LEN] + p[P_WID] * p[P_WID])


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def engine_torque(rpm: float, table: np.ndarray, redline: float) -> float:
    """Torque curve ``table[0]`` (rpm) -> ``table[1]`` (N m), linear, zero above the redline."""
    if rpm > redline:
        return 0.0
    k = table.shape[1]
    if rpm <= table[0, 0]:
        return table[1, 0]
    for j in range(1, k):
        if rpm <= table[0, j]:
            f = (rpm - table[0, j - 1]) / (table[0, j] - table[0, j - 1])
            return table[1, j - 1] + f * (table[1, j] - table[1, j - 1])
    return table[1, k - 1]


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _seg_dist2(geom: np.ndarray, i: int, x: float, y: float):
    """Squared distance from a point to segment ``i`` and the clipped segment parameter."""
    ax = geom[i, G_X]
    ay = geom[i, G_Y]
    dx = geom[i, G_DX]
    dy = geom[i, G_DY]
    t = _clip(((x - ax) * dx + (y - ay) * dy) * geom[i, G_INV2], 0.0, 1.0)
    px = ax + t * dx - x
    py = ay + t * dy - y
    return px * px + py * py, t


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def project(geom: np.ndarray, length: float, x: float, y: float, hint: int):
    """``(s, lateral, index)`` of a point: hill-climb from ``hint`` (global scan if < 0).

    A car moves < 1 m per substep, so the climb takes one or two moves; it never scans.
    """
    n = geom.shape[0]
    if hint < 0:
        best = 1e300
        i = 0
        for k in range(n):
            d2, _ = _seg_dist2(geom, k, x, y)
            if d2 < best:
                best = d2
                i = k
    else:
        i = hint if hint < n else hint % n  # (integer % is a ~40-cycle division)
    d2, t = _seg_dist2(geom, i, x, y)
    moved = False
    for _ in range(n):  # forward first: cars mostly move forward
        ip = i + 1 if i + 1 < n else 0
        dn, tn = _seg_dist2(geom, ip, x, y)
        if dn >= d2:
            break
        i, d2, t = ip, dn, tn
        moved = True
    if not moved:  # (after a forward move the segment behind is known to be farther)
        for _ in range(n):
            im = i - 1 if i > 0 else n - 1
            dp, tp = _seg_dist2(geom, im, x, y)
            if dp >= d2:
                break
            i, d2, t = im, dp, tp
    s = geom[i, G_S] + t * geom[i, G_SLEN]
    if s >= length:
        s -= length
    cross = geom[i, G_DX] * (y - geom[i, G_Y]) - geom[i, G_DY] * (x - geom[i, G_X])
    lat = math.sqrt(d2)
    if cross < 0.0:
        lat = -lat
    return s, lat, i


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _ray_seg(ox, oy, dx, dy, ax, ay, bx, by):
    """Ray parameter where ray ``o + t d`` meets segment ``a-b``; inf if it does not."""
    ex = bx - ax
    ey = by - ay
    den = dx * ey - dy * ex
    if abs(den) < 1e-12:
        return np.inf
    wx = ax - ox
    wy = ay - oy
    # u = nu / den, the position along the segment, is tested without dividing: a ray misses
    # two of the four sides of its first quad, and 19 rays x 4 sides x 2 divisions were a
    # visible share of the ray time.
    nu = wx * dy - wy * dx
    den_a = den
    if den < 0.0:
        nu = -nu
        den_a = -den
    if nu < -1e-9 * den_a or nu > (1.0 + 1e-9) * den_a:
        return np.inf
    return (wx * ey - wy * ex) / den


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _side(ox: float, oy: float, dx: float, dy: float, px: float, py: float) -> float:
    """> 0 when point p lies left of the ray's line, < 0 right of it."""
    return dx * (py - oy) - dy * (px - ox)


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _section_side(geom: np.ndarray, k: int, px: float, py: float) -> float:
    """> 0 when point p lies ahead (in the driving direction) of the cross-section at ``k``."""
    return ((geom[k, G_RX] - geom[k, G_LX]) * (py - geom[k, G_LY])
            - (geom[k, G_RY] - geom[k, G_LY]) * (px - geom[k, G_LX]))


@njit(cache=True, fastmath=_FAST, _nrt=False)
def cast_ray(geom: np.ndarray, idx: int, ox: float, oy: float, ang: float, max_range: float):
    """Distance along a ray at world angle ``ang`` to the asphalt edge (see :func:`_cast`)."""
    return _cast(geom, _origin_quad(geom, idx, ox, oy), ox, oy, math.cos(ang), math.sin(ang),
                 max_range)


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _origin_quad(geom: np.ndarray, idx: int, ox: float, oy: float) -> int:
    """The quad between the two sections the point lies between, searched from ``idx``.

    The nearest segment's quad need not contain the origin (sections are not the projection's
    boundaries on a curve). The same for every ray of a car: computed once per observation.
    """
    n = geom.shape[0]
    i = idx
    for _ in range(4):
        j = i + 1 if i + 1 < n else 0
        if _section_side(geom, i, ox, oy) < 0.0:
            i = i - 1 if i > 0 else n - 1
        elif _section_side(geom, j, ox, oy) > 0.0:
            i = j
        else:
            break
    return i


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _cast(geom: np.ndarray, i: int, ox: float, oy: float, dx: float, dy: float,
          max_range: float) -> float:
    """Distance along the ray ``o + t (dx, dy)`` (unit direction) from quad ``i``, walking the
    corridor quad by quad.

    Quad ``i`` spans samples ``i`` and ``i+1``. In the car's own quad the exit is found by
    intersecting the ray with all four sides. After that the ray enters each quad through a
    cross-section, and (quads being convex) leaves through the next cross-section exactly when
    that section's two ends lie on opposite sides of the ray's line; otherwise through the side
    edge whose ends straddle the line, the only exact intersection computed. Two cross products
    per quad, and a straight run of quads (``G_RUN``) is crossed as one.
    """
    n = geom.shape[0]
    j = i + 1 if i + 1 < n else 0
    best = np.inf
    kind = 0
    t = _ray_seg(ox, oy, dx, dy, geom[i, G_LX], geom[i, G_LY], geom[j, G_LX], geom[j, G_LY])
    if 1e-9 < t < best:
        best, kind = t, 1
    t = _ray_seg(ox, oy, dx, dy, geom[i, G_RX], geom[i, G_RY], geom[j, G_RX], geom[j, G_RY])
    if 1e-9 < t < best:
        best, kind = t, 1
    t = _ray_seg(ox, oy, dx, dy, geom[j, G_LX], geom[j, G_LY], geom[j, G_RX], geom[j, G_RY])
    if 1e-9 < t < best:
        best, kind = t, 2
    t = _ray_seg(ox, oy, dx, dy, geom[i, G_LX], geom[i, G_LY], geom[i, G_RX], geom[i, G_RY])
    if 1e-9 < t < best:
        best, kind = t, 3
    if kind == 0 or best >= max_range:
        return max_range
    if kind == 1:
        return best
    step = 1 if kind == 2 else -1
    k = j if kind == 2 else i  # the section the ray has just passed
    s_l = _side(ox, oy, dx, dy, geom[k, G_LX], geom[k, G_LY])
    for _ in range(n):
        k2 = k + step
        if step == 1 and geom[k, G_RUN] > k2:
            # Both edges run straight to sample G_RUN: treat the run as one (convex) quad, so a
            # ray along a straight costs one test instead of one per metre.
            k2 = int(geom[k, G_RUN])
        else:
            # Block skip: each edge's vertices over the RAY_BLOCK quads ahead lie within
            # G_BH* of the chord between the block's end vertices; if the ray's line keeps that
            # far from both chords' ends on one side, no vertex lies on the other side, so the
            # ray crosses every section up to the block's end (the per-quad walk would find the
            # same exit). In curves rays walked tens of 1 m quads each, and the rays were about
            # half the kernel time.
            b = k if step == 1 else k - RAY_BLOCK
            if b < 0:
                b += n
            e = b + RAY_BLOCK
            if e >= n:
                e -= n
            hl = geom[b, G_BHL]
            hr = geom[b, G_BHR]
            sl_b = _side(ox, oy, dx, dy, geom[b, G_LX], geom[b, G_LY])
            sl_e = _side(ox, oy, dx, dy, geom[e, G_LX], geom[e, G_LY])
            if (sl_b > hl and sl_e > hl) or (sl_b < -hl and sl_e < -hl):
                sr_b = _side(ox, oy, dx, dy, geom[b, G_RX], geom[b, G_RY])
                sr_e = _side(ox, oy, dx, dy, geom[e, G_RX], geom[e, G_RY])
                if (sr_b > hr and sr_e > hr) or (sr_b < -hr and sr_e < -hr):
                    k2 = k + step * RAY_BLOCK
            if k2 >= n:
                k2 -= n
            elif k2 < 0:
                k2 += n
        lx = geom[k2, G_LX]
        ly = geom[k2, G_LY]
        rx = geom[k2, G_RX]
        ry = geom[k2, G_RY]
        s_l2 = _side(ox, oy, dx, dy, lx, ly)
        s_r2 = _side(ox, oy, dx, dy, rx, ry)
        if (s_l2 >= 0.0) != (s_r2 >= 0.0):
            # Through the next section: stop once all of it lies beyond the range.
            if min((lx - ox) * dx + (ly - oy) * dy, (rx - ox) * dx + (ry - oy) * dy) > max_range:
                return max_range
            k = k2
            s_l = s_l2
            continue
        if (s_l >= 0.0) != (s_l2 >= 0.0):
            t = _ray_seg(ox, oy, dx, dy, geom[k, G_LX], geom[k, G_LY], lx, ly)
        else:
            t = _ray_seg(ox, oy, dx, dy, geom[k, G_RX], geom[k, G_RY], rx, ry)
        if t == np.inf or t > max_range:
            return max_range
        return max(t, 0.0)
    return max_range


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _small_rotation(d: float):
    """``(cos d, sin d)`` by Taylor series for |d| <= 0.05 rad (error < 1e-19 there)."""
    d2 = d * d
    c = 1.0 - 0.5 * d2 * (1.0 - d2 * (1.0 / 12.0) * (1.0 - d2 * (1.0 / 30.0)
                                                     * (1.0 - d2 * (1.0 / 56.0))))
    s = d * (1.0 - d2 * (1.0 / 6.0) * (1.0 - d2 * (1.0 / 20.0) * (1.0 - d2 * (1.0 / 42.0))))
    return c, s


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def surface_normal_load(p: np.ndarray, v2: float, vx: float, r: float, gn: float, kv: float,
                        sin_bank: float) -> float:
    """Total tyre normal load (N) on a sloped, banked, curved surface.

    ``m (g cos(grade) cos(bank) - v^2 kv - a_lat sin(bank)) + downforce``: a crest
    (``kv > 0``) unloads the tyres and a compression loads them; on a banked turn the part of
    the path's horizontal acceleration ``a_lat = vx r`` (left > 0) that points into the surface
    adds load (a right turn on a bank that raises the left edge: ``a_lat < 0``). Never below 0
    (the car flies off a sharp crest).
    """
    fz = p[P_MASS] * (gn - v2 * kv - vx * r * sin_bank) + p[P_CL] * v2
    return fz if fz > 0.0 else 0.0


@njit(cache=True, fastmath=_FAST, _nrt=False)
def normal_load(p: np.ndarray, v2: float, vx: float, r: float, gn: float, kv: float,
                sin_bank: float) -> float:
    """:func:`surface_normal_load`, callable from Python (tests)."""
    return surface_normal_load(p, v2, vx, r, gn, kv, sin_bank)


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def physics_substep(st: np.ndarray, steer: float, cd: float, sd: float, throttle: float,
                    brake: float, p: np.ndarray, torque: np.ndarray, gears: np.ndarray,
                    on_grass: bool, dt: float, cp: float, sp: float, elev: np.ndarray,
                    ie: int, surface: bool, grip: float, rolling: float):
    """Advance one car (``st`` = its state row) by ``dt``: dynamic single-track model.

    Tyres: Fiala lateral force per wheel on its own load (static + aero + load transfer from the
    last accelerations); the axle cornering stiffnesses hold at static load and scale with load,
    so the slip angle of peak grip stays put as downforce grows. Longitudinal force = drive/brake
    demand; when demand and Fiala side force together exceed the friction circle
    ``Fx^2 + Fy^2 <= (mu Fz)^2`` both are scaled back onto it. Wheel spins are quasi-static
    (slip ratio from force use): explicit wheel-rotation dynamics would need ~1 kHz to be
    stable, and the observation only needs spins that show slip and lock-up. ``cd``/``sd``
    are cos/sin of the wheel angle, computed once per control step by the caller; ``cp``/``sp``
    are cos/sin of the current yaw, and the function returns those of the new yaw.

    Hot-path shape (kernel ~2.6 us per car-step for 20 substeps before, docs/sim.md "Speed"):
    constants derived from the car once (``P_INV_*``, ``P_*_WB``, ``P_CS_*``: divisions cost
    ~4x a multiply and LLVM cannot hoist loads past the stores to ``st``), one division in the
    Fiala curve, and the yaw's cos/sin rotated by a Taylor series of ``r dt`` instead of two
    libm calls per substep (~25 ns per sin+cos pair measured here).

    With ``surface`` set, the car is on the slope and banking of row ``ie`` of ``elev``
    (``E_*``; :func:`surface_normal_load` gives the normal load): gravity's in-plane component
    joins the accelerations, and the lateral one is the horizontal acceleration of the car's
    path (the in-plane force divided by cos(bank)). Without it, nothing of this is computed.

    ``grip`` multiplies the car's friction (``mu`` on the road, ``mu_grass`` off it) and
    ``rolling`` adds to its rolling-resistance coefficient: the surface under the car
    (``G_MU_*``/``G_RR_*``), 1.0 and 0.0 on asphalt and on the default grass.
    """
    m = p[P_MASS]
    lf = p[P_LF]
    lr = p[P_LR]
    half_tw = 0.5 * p[P_TW]
    inv_rw = p[P_INV_RW]
    mu = p[P_MU_GRASS] if on_grass else p[P_MU]
    if grip != 1.0:  # (a test, not a multiply by 1.0: fastmath would re-contract around it)
        mu *= grip
    vx = st[ST_VX]
    vy = st[ST_VY]
    r = st[ST_R]
    st[ST_STEER] = steer * p[P_STEER]
    v2 = vx * vx + vy * vy

    # Normal loads: weight and downforce split by CG position, then load transfer.
    fz_total = p[P_MG] + p[P_CL] * v2
    if surface:
        fz_total = surface_normal_load(p, v2, vx, r, elev[ie, E_GN], elev[ie, E_KV],
                                       elev[ie, E_SB])
    fz_front = fz_total * p[P_LR_WB] - m * st[ST_AX] * p[P_H_WB]
    fz_rear = fz_total - fz_front
    lat_tr = m * st[ST_AY] * p[P_H_TW]  # left accel (ay > 0) loads the right wheels

    # Engine and automatic gearbox (rear-wheel drive, rpm from the driven wheels).
    g = int(st[ST_GEAR])
    n_gears = gears.shape[0]
    w_drive = 0.5 * (st[ST_W_RL] + st[ST_W_RR])
    to_rpm = p[P_TO_RPM]
    rpm_wheel = abs(w_drive) * gears[g] * to_rpm
    if g < n_gears - 1 and rpm_wheel > p[P_UP]:
        g += 1
    elif g > 0 and rpm_wheel < p[P_DOWN] and rpm_wheel * gears[g - 1] / gears[g] < p[P_UP]:
        g -= 1
    st[ST_GEAR] = g
    rpm = abs(w_drive) * gears[g] * to_rpm
    if g == 0:
        # The clutch slips at launch, holding the engine up to its torque peak.
        rpm = max(rpm, p[P_IDLE] + throttle * (p[P_LAUNCH_RPM] - p[P_IDLE]))
    rpm = max(rpm, p[P_IDLE])
    st[ST_RPM] = rpm
    drive_total = 0.0
    if throttle > 0.0:
        drive_total = (throttle * engine_torque(rpm, torque, p[P_REDLINE]) * gears[g]
                       * p[P_DRIVE_K])

    # Axles. Drive and brake forces are shared between an axle's wheels in proportion to their
    # loads (a limited-slip differential, an ideal left-right brake balance) and each wheel's
    # stiffness and grip scale with its load, so the axle force is exactly the sum of its two
    # wheels' Fiala forces: two tyre evaluations per substep instead of four.
    vy_front = vy + lf * r
    fx_body = 0.0
    fy_body = 0.0
    mz = 0.0
    for a in range(2):
        if a == 0:
            fz_l = max(0.0, 0.5 * fz_front - lat_tr * p[P_LR_WB])
            fz_r = max(0.0, 0.5 * fz_front + lat_tr * p[P_LR_WB])
            vxw = vx * cd + vy_front * sd
            vyw = -vx * sd + vy_front * cd
            fx_dem = -brake * p[P_BRAKE_F] * _clip(vxw * 2.0, -1.0, 1.0)
            c_static = p[P_CS_F]
        else:
            fz_l = max(0.0, 0.5 * fz_rear - lat_tr * p[P_LF_WB])
            fz_r = max(0.0, 0.5 * fz_rear + lat_tr * p[P_LF_WB])
            vxw = vx
            vyw = vy - lr * r
            fx_dem = drive_total - brake * p[P_BRAKE_R] * _clip(vxw * 2.0, -1.0, 1.0)
            c_static = p[P_CS_R]
        fz_ax = fz_l + fz_r
        fmax = mu * fz_ax
        fx = 0.0
        fy = 0.0
        kappa = 0.0
        lr_share = 0.0
        if fmax > 0.0:
            inv_f = 1.0 / fmax
            tan_a = vyw / max(abs(vxw), SLIP_MIN_SPEED_MPS)
            fy0 = _fiala(tan_a, c_static * fz_ax, fmax, inv_f)
            # Friction circle: a demand inside it is met; outside, the demanded (Fx, Fy) is
            # scaled back onto it, so a spinning or locked wheel keeps a share of its side
            # force instead of losing all of it (which made every launch a spin).
            ux = fx_dem * inv_f
            uy = fy0 * inv_f
            u2 = ux * ux + uy * uy
            if u2 > 1.0:
                scale = 1.0 / math.sqrt(u2)
                fx = fx_dem * scale
                fy = fy0 * scale
            else:
                fx = fx_dem
                fy = fy0
            # Quasi-static slip ratio: linear below the peak, growing with excess demand.
            inv_fz = mu * inv_f  # = 1 / fz_ax (fmax = mu fz_ax): one division fewer
            kappa = fx * inv_fz * (1.0 / SLIP_STIFFNESS_PER_N)
            if abs(ux) > 1.0:
                excess = abs(ux) - 1.0
                kappa += excess if fx_dem > 0.0 else -excess
            lr_share = (fz_r - fz_l) * inv_fz
        for side in (-1.0, 1.0):  # left wheel (slower in a left turn), right wheel
            vx_c = vx + side * half_tw * r
            vxw_w = vx_c * cd + vy_front * sd if a == 0 else vx_c
            omega = (vxw_w + kappa * max(abs(vxw_w), 1.0)) * inv_rw
            if fx_dem < 0.0 and vxw_w >= 0.0 and omega < 0.0:
                omega = 0.0  # locked, not spinning backwards
            st[ST_W_FL + 2 * a + (0 if side < 0.0 else 1)] = omega
        # Yaw moment of the unequal left/right longitudinal forces (shared by load).
        if a == 0:
            fxb = fx * cd - fy * sd
            fyb = fx * sd + fy * cd
            mz += lf * fyb + half_tw * lr_share * fxb
        else:
            fxb = fx
            fyb = fy
            mz += -lr * fyb + half_tw * lr_share * fxb
        fx_body += fxb
        fy_body += fyb

    # Aero drag ~ v^2 along the velocity, rolling resistance, grass drag.
    drag = p[P_CD] * math.sqrt(v2)
    fx_body -= drag * vx
    fy_body -= drag * vy
    crr = p[P_CRR]
    if rolling != 0.0:
        crr += rolling
    fx_body -= crr * fz_total * _clip(vx * 2.0, -1.0, 1.0)
    if on_grass:
        fx_body -= p[P_GRASS_DRAG] * vx
        fy_body -= p[P_GRASS_DRAG] * vy

    ax = fx_body * p[P_INV_M]
    ay = fy_body * p[P_INV_M]
    st[ST_AX] = ax  # specific forces of tyres and air: what transfers load
    st[ST_AY] = ay
    vx_old = vx
    if surface:
        gx = elev[ie, E_GX]
        gy = elev[ie, E_GY]
        a_x = ax + gx * cp + gy * sp
        a_y = (ay - gx * sp + gy * cp) * elev[ie, E_ICB]
        vx += (a_x + r * vy) * dt
        vy += (a_y - r * vx_old) * dt
    else:
        vx += (ax + r * vy) * dt
        vy += (ay - r * vx_old) * dt
    r += mz * p[P_INV_IZ] * dt
    st[ST_VX] = vx
    st[ST_VY] = vy
    st[ST_R] = r
    st[ST_X] += (vx * cp - vy * sp) * dt
    st[ST_Y] += (vx * sp + vy * cp) * dt
    dpsi = r * dt
    psi = st[ST_PSI] + dpsi
    if psi > math.pi:
        psi -= TWO_PI
    elif psi < -math.pi:
        psi += TWO_PI
    st[ST_PSI] = psi
    if abs(dpsi) <= 0.05:
        c, s = _small_rotation(dpsi)
        return cp * c - sp * s, sp * c + cp * s
    return math.cos(psi), math.sin(psi)


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def wall_contact(st: np.ndarray, geom: np.ndarray, p: np.ndarray, grass_w: float) -> float:
    """Keep the car inside the walls; return the damage of an impact (0 if none).

    Walls stand ``grass_w`` beyond each asphalt edge. The body corner deepest into the wall
    takes an impulse (restitution ``wall_restitution``, Coulomb friction along the wall) that
    acts on both speed and yaw rate, so a car hitting at an angle is turned along the wall
    instead of grinding into it. Damage is ``wall_damage_per_mps`` per m/s of that corner's
    speed into the wall.
    """
    i = int(st[ST_IDX])
    lat = st[ST_LAT]
    # Far from both walls for any yaw (half diagonal of the body): skip the trigonometry.
    reach = p[P_REACH]
    if lat + reach < geom[i, G_WL] + grass_w and -lat + reach < geom[i, G_WR] + grass_w:
        return 0.0
    th = geom[i, G_H]
    psi = st[ST_PSI]
    cp = math.cos(psi)
    sp = math.sin(psi)
    nx = -math.sin(th)  # wall normal, pointing into the left wall
    ny = math.cos(th)
    # Deepest corner towards each wall: its offset across the track is the body's extent.
    hl = 0.5 * p[P_LEN]
    hw = 0.5 * p[P_WID]
    a_l = cp * nx + sp * ny  # body x axis . normal
    b_l = -sp * nx + cp * ny  # body y axis . normal
    sx = 1.0 if a_l >= 0.0 else -1.0
    sy = 1.0 if b_l >= 0.0 else -1.0
    extent = hl * abs(a_l) + hw * abs(b_l)
    pen_l = lat + extent - (geom[i, G_WL] + grass_w)
    pen_r = -lat + extent - (geom[i, G_WR] + grass_w)
    if pen_l <= 0.0 and pen_r <= 0.0:
        return 0.0
    if pen_r > pen_l:
        nx, ny, pen = -nx, -ny, pen_r
        sx, sy = -sx, -sy
        st[ST_LAT] = lat + pen
    else:
        pen = pen_l
        st[ST_LAT] = lat - pen
    st[ST_X] -= pen * nx
    st[ST_Y] -= pen * ny
    # Contact corner relative to the centre of gravity, world frame.
    cx = sx * hl * cp - sy * hw * sp
    cy = sx * hl * sp + sy * hw * cp
    m = p[P_MASS]
    iz = p[P_IZ]
    r = st[ST_R]
    vwx = st[ST_VX] * cp - st[ST_VY] * sp
    vwy = st[ST_VX] * sp + st[ST_VY] * cp
    vcx = vwx - r * cy
    vcy = vwy + r * cx
    vn = vcx * nx + vcy * ny
    if vn <= 0.0:
        return 0.0
    rn = cx * ny - cy * nx
    jn = (1.0 + p[P_WALL_E]) * vn / (1.0 / m + rn * rn / iz)
    vwx -= jn * nx / m
    vwy -= jn * ny / m
    r -= jn * rn / iz
    # Friction impulse along the wall, at most enough to stop the corner sliding.
    vcx = vwx - r * cy
    vcy = vwy + r * cx
    vn2 = vcx * nx + vcy * ny
    tx = vcx - vn2 * nx
    ty = vcy - vn2 * ny
    vt = math.sqrt(tx * tx + ty * ty)
    if vt > 1e-9:
        tx /= vt
        ty /= vt
        rt = cx * ty - cy * tx
        jt = min(WALL_FRICTION * jn, vt / (1.0 / m + rt * rt / iz))
        vwx -= jt * tx / m
        vwy -= jt * ty / m
        r -= jt * rt / iz
    st[ST_VX] = vwx * cp + vwy * sp
    st[ST_VY] = -vwx * sp + vwy * cp
    st[ST_R] = r
    return p[P_WALL_DMG] * vn


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _interp_heading(geom: np.ndarray, col: int, i: int, s: float, length: float) -> float:
    n = geom.shape[0]
    j = i + 1 if i + 1 < n else 0
    s_next = geom[j, G_S] if j > 0 else length
    t = (s - geom[i, G_S]) / max(s_next - geom[i, G_S], 1e-12)
    return geom[i, col] + _clip(t, 0.0, 1.0) * _wrap_angle(geom[j, col] - geom[i, col])


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _index_ahead(geom: np.ndarray, i: int, s_target: float, length: float) -> int:
    """Sample index at or before ``s_target`` (wrapped), searching forward from ``i``."""
    n = geom.shape[0]
    if 0.0 <= s_target - length < length:
        s_target -= length  # exact (Sterbenz), the same as the fmod below
    elif not 0.0 <= s_target < length:
        s_target = s_target % length
    j = int(s_target / length * n)
    if j >= n:
        j = n - 1
    while j > 0 and geom[j, G_S] > s_target:
        j -= 1
    while j + 1 < n and geom[j + 1, G_S] <= s_target:
        j += 1
    return j


@njit(cache=True, fastmath=_FAST, _nrt=False)
def observe(st: np.ndarray, geom: np.ndarray, elev: np.ndarray, cfg: np.ndarray,
            lac_d: np.ndarray, obs: np.ndarray) -> float:
    """Write one car's telemetry into ``obs``; return its angle to the reference line (rad)."""
    length = cfg[C_LENGTH]
    i = int(st[ST_IDX])
    s = st[ST_S]
    ref_h = _interp_heading(geom, G_REF_H, i, s, length)
    angle = _wrap_angle(st[ST_PSI] - ref_h)
    obs[OBS_ANGLE] = angle / math.pi
    off = st[ST_OFF] > 0.5
    x = st[ST_X]
    y = st[ST_Y]
    if off:
        for k in range(N_RAYS):
            obs[OBS_TRACK + k] = -1.0
    else:
        # One cos/sin pair and one origin quad per car, each ray's direction rotated from the
        # heading by a table: the per-ray libm calls and quad search were ~1/3 of the ray time.
        cp = math.cos(st[ST_PSI])
        sp = math.sin(st[ST_PSI])
        q = _origin_quad(geom, i, x, y)
        for k in range(N_RAYS):
            ca = _RAY_COS[k]
            sa = _RAY_SIN[k]
            obs[OBS_TRACK + k] = _cast(geom, q, x, y, cp * ca - sp * sa, sp * ca + cp * sa,
                                       RAY_RANGE_M) * (1.0 / RAY_RANGE_M)
    half_w = 0.5 * (geom[i, G_WL] + geom[i, G_WR])
    obs[OBS_TRACKPOS] = (st[ST_LAT] - geom[i, G_REF_OFF]) / half_w
    obs[OBS_VX] = st[ST_VX] / SPEED_SCALE_MPS
    obs[OBS_VY] = st[ST_VY] / SPEED_SCALE_MPS
    obs[OBS_VZ] = 0.0
    if cfg[C_ELEV] > 0.5:
        # Vertical speed of a car on the surface: the along-track part of its velocity climbs
        # at sin(grade), the across-track part at sin(bank).
        cpsi = math.cos(st[ST_PSI])
        spsi = math.sin(st[ST_PSI])
        vwx = st[ST_VX] * cpsi - st[ST_VY] * spsi
        vwy = st[ST_VX] * spsi + st[ST_VY] * cpsi
        ch = elev[i, E_CH]
        sh = elev[i, E_SH]
        v_t = vwx * ch + vwy * sh
        v_l = -vwx * sh + vwy * ch
        obs[OBS_VZ] = (v_t * elev[i, E_SG] + v_l * elev[i, E_SB]) / SPEED_SCALE_MPS
    for k in range(4):
        obs[OBS_WHEEL + k] = st[ST_W_FL + k] / WHEEL_SCALE_RADPS
    obs[OBS_RPM] = st[ST_RPM] / RPM_SCALE
    if cfg[C_LAC] > 0.5:
        for k in range(lac_d.shape[0]):
            j = _index_ahead(geom, i, s + lac_d[k], length)
            obs[OBS_LAC + k] = geom[j, G_REF_K] * LAC_SCALE_M
    return angle


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _locate(st: np.ndarray, geom: np.ndarray, length: float) -> None:
    s, lat, i = project(geom, length, st[ST_X], st[ST_Y], int(st[ST_IDX]))
    st[ST_S] = s
    st[ST_LAT] = lat
    st[ST_IDX] = i
    st[ST_OFF] = 1.0 if (lat > geom[i, G_WL] or lat < -geom[i, G_WR]) else 0.0


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def _substeps(st: np.ndarray, steer: float, cd: float, sd: float, throttle: float, brake: float,
              p: np.ndarray, torque: np.ndarray, gears: np.ndarray, geom: np.ndarray,
              elev: np.ndarray, cfg: np.ndarray, out: np.ndarray, length: float, n_sub: int,
              dt: float, cp: float, sp: float, surface: bool) -> None:
    """The physics substeps of :func:`control_step`, with projection, walls and lap timing."""
    for _ in range(n_sub):
        cp, sp = track_substep(st, steer, cd, sd, throttle, brake, p, torque, gears, geom, elev,
                               cfg, out, length, dt, cp, sp, surface)


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def track_substep(st: np.ndarray, steer: float, cd: float, sd: float, throttle: float,
                  brake: float, p: np.ndarray, torque: np.ndarray, gears: np.ndarray,
                  geom: np.ndarray, elev: np.ndarray, cfg: np.ndarray, out: np.ndarray,
                  length: float, dt: float, cp: float, sp: float, surface: bool):
    """One physics substep of one car on the track: dynamics, projection, walls, lap timing.

    Its own function so that the race kernel (``sim/multicar/lockstep_kernels.py``) can advance
    N cars in lockstep, substep by substep, with car-car contact in between, through the same
    per-car arithmetic as :func:`control_step` (inlined: the single-car path compiles as before).
    Returns the carried cos/sin of the yaw.
    """
    s_old = st[ST_S]
    ie = int(st[ST_IDX])
    off = 1 if st[ST_OFF] > 0.5 else 0
    grip = geom[ie, G_MU_ROAD + off]
    d_grip = st[ST_GRIP_DELTA]
    if d_grip != 0.0:  # (a test: a car at the track's grip passes the block's value unchanged)
        grip = grip * (1.0 + d_grip)
    cp, sp = physics_substep(st, steer, cd, sd, throttle, brake, p, torque, gears,
                             off == 1, dt, cp, sp, elev, ie, surface,
                             grip, geom[ie, G_RR_ROAD + off])
    _locate(st, geom, length)
    st[ST_DAMAGE] += wall_contact(st, geom, p, cfg[C_GRASS_W])
    s_new = st[ST_S]
    ds = s_new - s_old
    t0 = st[ST_TIME]
    if ds < -0.5 * length:
        ds += length
        frac = (length - s_old) / max(ds, 1e-12)
        if st[ST_LAP_DEBT] > 0.0:
            st[ST_LAP_DEBT] -= 1.0
        else:
            t_cross = t0 + frac * dt
            if st[ST_LAP_START] >= 0.0:
                out[O_LAP_TIME] = t_cross - st[ST_LAP_START]
            st[ST_LAP_START] = t_cross
    elif ds > 0.5 * length:
        ds -= length
        st[ST_LAP_DEBT] += 1.0
    st[ST_DIST] += ds
    st[ST_TIME] = t0 + dt
    return cp, sp


@njit(cache=True, fastmath=_FAST, _nrt=False)
def control_step(st: np.ndarray, act: np.ndarray, p: np.ndarray, torque: np.ndarray,
                 gears: np.ndarray, geom: np.ndarray, elev: np.ndarray, cfg: np.ndarray,
                 out: np.ndarray) -> None:
    """Integrate one car over one control period; time laps at the start line.

    A lap completes when ``s`` wraps forward past 0; its time is interpolated inside the substep
    from the fraction of the substep's arc length before the line. Backward crossings are owed
    back first, so driving to and fro over the line never completes a lap.
    """
    length = cfg[C_LENGTH]
    n_sub = int(cfg[C_NSUB])
    dt = cfg[C_DT] / n_sub
    steer = _clip(act[0], -1.0, 1.0)
    throttle = _clip(act[1], 0.0, 1.0)
    brake = _clip(act[2], 0.0, 1.0)
    if math.isnan(steer) or math.isnan(throttle) or math.isnan(brake):
        steer, throttle, brake = 0.0, 0.0, 0.0
    dmg0 = st[ST_DAMAGE]
    out[O_LAP_TIME] = np.nan
    cd = math.cos(steer * p[P_STEER])
    sd = math.sin(steer * p[P_STEER])
    cp = math.cos(st[ST_PSI])
    sp = math.sin(st[ST_PSI])
    dry_m = cfg[C_DRY_M]
    if dry_m > 0.0:  # a drying track: the grip rises linearly with the distance driven
        frac = _clip(st[ST_DIST] / dry_m, 0.0, 1.0)
        st[ST_GRIP_DELTA] = cfg[C_DRY_DELTA0] * (1.0 - frac)
    # Two copies of the substep loop, the surface switch a compile-time constant in each: the
    # level copy compiles without any of the surface code or a per-substep test, so flat
    # tracks run the flat simulator's arithmetic (bit-identical trajectories).
    if cfg[C_ELEV] > 0.5:
        _substeps(st, steer, cd, sd, throttle, brake, p, torque, gears, geom, elev, cfg, out,
                  length, n_sub, dt, cp, sp, True)
    else:
        _substeps(st, steer, cd, sd, throttle, brake, p, torque, gears, geom, elev, cfg, out,
                  length, n_sub, dt, cp, sp, False)
    st[ST_STEPS] += 1.0
    out[O_DMG_INC] = st[ST_DAMAGE] - dmg0


@njit(cache=True, fastmath=_FAST, _nrt=False)
def _step_one(c: int, state: np.ndarray, actions: np.ndarray, integrate: np.ndarray,
              p: np.ndarray, torque: np.ndarray, gears: np.ndarray, geom: np.ndarray,
              elev: np.ndarray, cfg: np.ndarray, lac_d: np.ndarray, obs: np.ndarray,
              out: np.ndarray) -> None:
    """One car's env step: physics, telemetry, reward and end flags (see :func:`step_cars`)."""
    length = cfg[C_LENGTH]
    st = state[c]
    o = out[c]
    if integrate[c] == 0:
        _locate(st, geom, length)
        observe(st, geom, elev, cfg, lac_d, obs[c])
        o[O_TRUNC] = 0.0
        o[O_LAP_TIME] = np.nan
        for k in range(O_REWARD_IN, N_OUT):  # reward 0, running (TERM_NONE), nothing paid
            o[k] = 0.0
        return
    dist0 = st[ST_DIST]
    control_step(st, actions[c], p, torque, gears, geom, elev, cfg, o)
    angle = observe(st, geom, elev, cfg, lac_d, obs[c])
    score_step(st, o, obs[c], dist0, angle, geom, cfg)


@njit(cache=True, fastmath=_FAST, _nrt=False, inline="always")
def score_step(st: np.ndarray, o: np.ndarray, obs_row: np.ndarray, dist0: float, angle: float,
               geom: np.ndarray, cfg: np.ndarray) -> None:
    """Reward, slow counter and end flags of one car after its control step and observation.

    Shared by :func:`_step_one` and the race kernel, so both score a step the same way. The
    reward follows ``sim.reward`` (its weights from ``cfg[C_REWARD:]``); what it is made of goes
    to ``o[O_REWARD_IN:]`` for ``info["rewards"]``.
    """
    length = cfg[C_LENGTH]
    vx = st[ST_VX]
    track_pos = obs_row[OBS_TRACKPOS]
    lateral = cfg[C_TRACKPOS_W] * abs(track_pos)
    progress_mps = (st[ST_DIST] - dist0) / cfg[C_DT]
    if cfg[C_PROGRESS] > 0.5:
        # metres of track per second, what a lap time counts: a shorter line through a corner
        # earns more, where the paper's Vx cos(theta) pays only for speed along the line
        reward = progress_mps - vx * lateral
    else:
        reward = vx * (math.cos(angle) - abs(math.sin(angle)) - lateral)
    reward -= cfg[C_DMG_W] * o[O_DMG_INC]
    if progress_mps < cfg[C_SLOW_MPS]:
        st[ST_SLOW] += 1.0
    else:
        st[ST_SLOW] = 0.0
    i = int(st[ST_IDX])
    track_h = _interp_heading(geom, G_H, i, st[ST_S], length)
    term = TERM_NONE
    if cfg[C_TERM_OFF] > 0.5 and st[ST_OFF] > 0.5:
        term = TERM_OFF_TRACK
    elif cfg[C_TERM_BACK] > 0.5 and math.cos(st[ST_PSI] - track_h) < 0.0:
        term = TERM_BACKWARDS
    elif cfg[C_TERM_SLOW] > 0.5 and st[ST_SLOW] >= cfg[C_SLOW_PATIENCE]:
        term = TERM_SLOW
    if term in (TERM_OFF_TRACK, TERM_BACKWARDS):
        reward = cfg[C_END_REWARD]
        if term == TERM_OFF_TRACK and cfg[C_WALL_E] > 0.0:  # the wall's price grows with Vx^2
            reward -= cfg[C_WALL_E] * vx * vx
        if term == TERM_OFF_TRACK and cfg[C_OVERSPEED] > 0.0:  # only speed above the limit's
            v_lim = geom[i, G_VLIM]
            excess = vx * vx - v_lim * v_lim
            if excess > 0.0:
                reward -= cfg[C_OVERSPEED] * excess
    elif term == TERM_SLOW:
        reward = -cfg[C_SLOW_PEN]
    o[O_REWARD] = reward
    o[O_VX] = vx
    o[O_ANGLE] = angle
    o[O_TRACKPOS] = track_pos
    o[O_PROGRESS] = progress_mps
    o[O_TERM] = term
    o[O_TRUNC] = 1.0 if (term == TERM_NONE and st[ST_STEPS] >= cfg[C_MAX_STEPS]) else 0.0


@njit(cache=True, fastmath=_FAST, _nrt=False)
def step_cars(state: np.ndarray, actions: np.ndarray, integrate: np.ndarray, p: np.ndarray,
              torque: np.ndarray, gears: np.ndarray, geom: np.ndarray, elev: np.ndarray,
              cfg: np.ndarray, lac_d: np.ndarray, obs: np.ndarray, out: np.ndarray) -> None:
    """The whole env step for N cars, on the calling thread.

    Cars with ``integrate[c] == 0`` were just reset: they are only located (global scan when
    their hint is < 0) and observed, with reward 0 and no end flags.
    """
    for c in range(state.shape[0]):
        _step_one(c, state, actions, integrate, p, torque, gears, geom, elev, cfg, lac_d, obs,
                  out)


@njit(cache=True, fastmath=_FAST, _nrt=False, parallel=True)
def step_cars_parallel(state: np.ndarray, actions: np.ndarray, integrate: np.ndarray,
                       p: np.ndarray, torque: np.ndarray, gears: np.ndarray, geom: np.ndarray,
                       elev: np.ndarray, cfg: np.ndarray, lac_d: np.ndarray, obs: np.ndarray,
                       out: np.ndarray) -> None:
    """:func:`step_cars` with cars spread over numba's threads (cars are independent).

    For a vector env that owns the machine; training workers keep one thread each (docs/sim.md).
    """
    for c in prange(state.shape[0]):
        _step_one(c, state, actions, integrate, p, torque, gears, geom, elev, cfg, lac_d, obs,
                  out)


@njit(cache=True, fastmath=_FAST, _nrt=False)
def integrate_free(state: np.ndarray, actions: np.ndarray, p: np.ndarray, torque: np.ndarray,
                   gears: np.ndarray, on_grass: np.ndarray, dt: float, n_sub: int,
                   surf: np.ndarray, on_surface: np.ndarray, grip: np.ndarray,
                   rolling: np.ndarray) -> None:
    """Advance N cars ``n_sub`` substeps of ``dt`` on an open plane (no track, no walls).

    The physics tests (top speed, cornering, braking, sliding) drive the car here, so they check
    the vehicle model alone; the env adds the track around the same ``physics_substep``. Car
    ``c`` with ``on_surface[c]`` set drives on the uniform slope, banking and vertical
    curvature of row ``c`` of ``surf`` (``E_*`` columns) instead of the level plane;
    ``grip[c]`` and ``rolling[c]`` are its surface's friction multiplier and extra rolling
    resistance.
    """
    for c in range(state.shape[0]):
        st = state[c]
        steer = _clip(actions[c, 0], -1.0, 1.0)
        throttle = _clip(actions[c, 1], 0.0, 1.0)
        brake = _clip(actions[c, 2], 0.0, 1.0)
        cd = math.cos(steer * p[P_STEER])
        sd = math.sin(steer * p[P_STEER])
        cp = math.cos(st[ST_PSI])
        sp = math.sin(st[ST_PSI])
        if on_surface[c] != 0:
            for _ in range(n_sub):
                cp, sp = physics_substep(st, steer, cd, sd, throttle, brake, p, torque, gears,
                                         on_grass[c] != 0, dt, cp, sp, surf, c, True,
                                         grip[c], rolling[c])
                st[ST_TIME] += dt
        else:  # (a constant switch, as in control_step: the level plane compiles as before)
            for _ in range(n_sub):
                cp, sp = physics_substep(st, steer, cd, sd, throttle, brake, p, torque, gears,
                                         on_grass[c] != 0, dt, cp, sp, surf, c, False,
                                         grip[c], rolling[c])
                st[ST_TIME] += dt


@njit(cache=True, _nrt=False)  # no fastmath: FMA contraction would break bit-identity
def reset_rows(state: np.ndarray, integrate: np.ndarray, cars: np.ndarray, s: np.ndarray,
               start_row: np.ndarray, s_m: np.ndarray, ref_x: np.ndarray, ref_y: np.ndarray,
               ref_h: np.ndarray, length: float) -> None:
    """Put cars ``cars`` at track positions ``s`` on the reference line (the vector autoreset).

    Same arithmetic, in the same order, as ``_Batch.start_pose``, so a vector car starts
    bit-identically to the single env. One call instead of ~20 small NumPy calls: with random
    actions a 64-car env resets ~2.4 cars a step, and the NumPy version cost ~33 us a step
    (~1/8 of the whole 64-car step once the kernel was fast).
    """
    n = s_m.shape[0]
    for k in range(cars.shape[0]):
        c = cars[k]
        sk = s[k] % length
        i = np.searchsorted(s_m, sk, side="right") - 1
        i = min(max(i, 0), n - 1)
        j = i + 1 if i + 1 < n else 0
        s_next = s_m[j] if j > 0 else length
        t = (sk - s_m[i]) / max(s_next - s_m[i], 1e-12)
        d = ref_h[j] - ref_h[i]
        dh = d - np.round(d / TWO_PI) * TWO_PI  # == math.remainder(d, 2 pi) here
        for col in range(start_row.shape[0]):
            state[c, col] = start_row[col]
        state[c, ST_X] = ref_x[i] + t * (ref_x[j] - ref_x[i])
        state[c, ST_Y] = ref_y[i] + t * (ref_y[j] - ref_y[i])
        state[c, ST_PSI] = ref_h[i] + t * dh
        state[c, ST_IDX] = i
        integrate[c] = 0


def drop_stale_cache(kernels: Iterable[Any], inputs: bytes, marker: str) -> None:
    """Forget the cached compiled ``kernels`` when ``inputs`` changed since they were cached.

    numba keys a function's cache on its *own* file's timestamp and freezes the globals it read
    (the reward tables' indices here; ``kernels.py``'s functions, compiled into the race step):
    after an edit elsewhere a cached kernel would run the old arithmetic. ``inputs`` are the
    bytes that edit would change; their digest is kept in ``marker`` beside the cache.
    """
    kernels = list(kernels)
    digest = hashlib.sha1(inputs).hexdigest()
    try:
        folder = Path(kernels[0]._cache.cache_path)
    except AttributeError:  # a numba without the cache API: nothing cached to go stale
        return
    path = folder / marker
    try:
        if path.read_text(encoding="utf-8") == digest:
            return
    except OSError:
        pass
    for fn in kernels:
        fn._cache.flush()
    with contextlib.suppress(OSError):  # a read-only folder: numba does not cache there either
        path.write_text(digest, encoding="utf-8")


REWARD_LAYOUT = repr((R.KERNEL_NAMES, R.INPUT_NAMES)).encode()
"""What this module's kernels take from ``sim.reward``: the order of its two tables."""

drop_stale_cache((v for v in list(globals().values()) if getattr(v, "_cache", None) is not None
                  and getattr(getattr(v, "py_func", None), "__module__", None) == __name__),
                 REWARD_LAYOUT, "kernels.reward-layout-sha1")

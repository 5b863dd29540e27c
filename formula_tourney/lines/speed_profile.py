"""Quasi-steady-state (QSS) speed profile and lap time of a line for our car.

Every lap-time table reads as a gap to the *reference limit*: the QSS lap on the minimum-
curvature line (``lines.limit.reference_limit_s``; docs/lines.md). The car
is the simulator's own ``CarParams`` (grip, downforce, drag, rolling resistance, engine force over
all gears, brake force), so the limit moves when the car does. Three steps, the textbook
"forward/backward" method:

1. corner speed at each point: the largest speed at which the tyres can both hold the line's
   curvature and balance drag + rolling resistance (friction circle with downforce);
2. forward pass: accelerate with the engine (all gears, ideal shifting) within the grip left
   over by cornering and the rear (driven) axle's grip, with load transfer;
3. backward pass: brake with the pedal's force within the grip left over, split by the brake
   bias, with load transfer, up to the point where the first axle saturates;

the speed is the minimum of the three. Both passes run two laps around the closed loop so the
profile is consistent across the start line (the speed leaving the last sample is the speed
entering the first).

On a track with heights, banking or surfaces (``lines.surface.PathSurface``) all three steps
use the simulator's forces: gravity along the slope, the normal load of banking and vertical
curvature, the lateral help of a banked turn, and each sample's friction and rolling
resistance. A level asphalt track at grip 1 runs the flat arithmetic unchanged (its lap times
are pinned by tests).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.lines.surface import (
    N_SURFACE,
    S_GRIP,
    S_ROLLING,
    PathSurface,
    corner_speed_on_surface_mps,
    surface_forces,
)
from formula_tourney.sim.car_params import GRAVITY_MPS2, CarParams
from formula_tourney.sim.reference_line import ReferenceLine
from formula_tourney.sim.track import Track

SPEED_CAP_MPS = 150.0
"""Upper bound for corner speeds where downforce outgrows the curvature (540 km/h: never
binding, since the engine tops out near 300 km/h)."""

_DRIVE_GRID_STEP_MPS = 0.05
"""Engine force is tabulated on this speed grid: ``max_drive_force_n`` loops over gears in
NumPy, too slow to call per sample inside the passes."""


@dataclass(frozen=True)
class CarModel:
    """The scalars of ``CarParams`` the QSS model uses, plus the tabulated engine force."""

    mass_kg: float
    mu: float
    downforce_coef: float
    drag_coef: float
    rolling_resistance: float
    cg_to_front_m: float
    wheelbase_m: float
    cg_height_m: float
    max_brake_force_n: float
    brake_bias_front: float
    cornering_stiffness_front: float
    cornering_stiffness_rear: float
    drive_force_grid_n: np.ndarray
    brake_scale: float = 1.0
    """1 for the physical limit; a driver keeping a braking reserve plans with less."""
    corner_speed_scale: float = 1.0
    """1 for the physical limit; a driver keeping a cornering reserve plans with less (only
    the corner speeds shrink: acceleration and braking between them stay full)."""
    brake_lateral_cutoff: float = 0.0
    """0 for the physical limit. A driver that may brake only while cornering lightly (the
    follower: the simulated car turns unstable when it brakes hard in a corner) sets the share
    of grip used laterally at which its braking fades to zero."""

    @classmethod
    def from_car(cls, car: CarParams) -> CarModel:
        speeds = np.arange(0.0, SPEED_CAP_MPS + 2 * _DRIVE_GRID_STEP_MPS, _DRIVE_GRID_STEP_MPS)
        return cls(
            mass_kg=car.mass_kg,
            mu=car.mu,
            downforce_coef=car.downforce_coef_n_per_mps2,
            drag_coef=car.drag_coef_n_per_mps2,
            rolling_resistance=car.rolling_resistance,
            cg_to_front_m=car.cg_to_front_m,
            wheelbase_m=car.wheelbase_m,
            cg_height_m=car.cg_height_m,
            max_brake_force_n=car.max_brake_force_n,
            brake_bias_front=car.brake_bias_front,
            cornering_stiffness_front=car.cornering_stiffness_front_n_per_rad,
            cornering_stiffness_rear=car.cornering_stiffness_rear_n_per_rad,
            drive_force_grid_n=np.ascontiguousarray(car.max_drive_force_n(speeds), dtype=float),
        )


    def packed(self) -> np.ndarray:
        """The scalars in the order the compiled passes read them (``_M`` ... ``_CR``)."""
        return np.array([
            self.mass_kg, self.mu, self.downforce_coef, self.drag_coef, self.rolling_resistance,
            self.cg_to_front_m, self.wheelbase_m, self.cg_height_m, self.max_brake_force_n,
            self.brake_bias_front, self.brake_lateral_cutoff, self.brake_scale,
            self.cornering_stiffness_front, self.cornering_stiffness_rear,
        ], dtype=float)


@dataclass(frozen=True)
class SpeedProfile:
    """QSS speeds along a closed line, one value per track sample.

    ``ds_m[i]`` is the line length from sample ``i`` to ``i+1`` (the last wraps to 0);
    ``time_s[i]`` is the time at which the car passes sample ``i`` counted from sample 0.
    """

    curvature_1pm: np.ndarray
    ds_m: np.ndarray
    corner_speed_mps: np.ndarray
    speed_mps: np.ndarray
    time_s: np.ndarray
    lap_time_s: float
    line_length_m: float

    @property
    def speed_kmh(self) -> np.ndarray:
        return self.speed_mps * 3.6

    @property
    def mean_speed_kmh(self) -> float:
        return 3.6 * self.line_length_m / self.lap_time_s


def corner_speed_mps(curvature_1pm: np.ndarray | float, car: CarParams,
                     surface: np.ndarray | None = None) -> np.ndarray:
    """Steady-state speed limit at a curvature, in closed form.

    At speed ``v`` (``u = v^2``) the tyres carry a lateral force ``m u |k|`` and a longitudinal
    force ``c_d u + c_rr N`` (to hold the speed against drag and rolling resistance) within the
    friction circle ``mu N`` with ``N = m g + c_l u``. Squaring gives a quadratic in ``u``; its
    positive root is the limit. With no drag and no rolling resistance this reduces to the
    familiar ``v^2 = mu m g R / (m - mu c_l R)``. With ``surface`` (``PathSurface.packed()``
    rows, one per curvature) the sloped, banked, curved form of
    ``lines.surface.corner_speed_on_surface_mps``.
    """
    if surface is not None:
        return corner_speed_on_surface_mps(
            curvature_1pm, surface, car.mass_kg, car.mu, car.downforce_coef_n_per_mps2,
            car.drag_coef_n_per_mps2, car.rolling_resistance, SPEED_CAP_MPS)
    k = np.abs(np.asarray(curvature_1pm, dtype=float))
    m, mu = car.mass_kg, car.mu
    cl, cd, crr = car.downforce_coef_n_per_mps2, car.drag_coef_n_per_mps2, car.rolling_resistance
    a_load, b_load = m * GRAVITY_MPS2, cl
    c_long = cd + crr * b_load
    a2 = (m * k) ** 2 + c_long**2 - (mu * b_load) ** 2
    a1 = 2.0 * c_long * crr * a_load - 2.0 * mu**2 * a_load * b_load
    a0 = (crr**2 - mu**2) * a_load**2
    cap = SPEED_CAP_MPS**2
    with np.errstate(invalid="ignore", divide="ignore"):
        disc = a1 * a1 - 4.0 * a2 * a0
        root = np.where(
            np.abs(a2) > 1e-12,
            (-a1 + np.sqrt(np.maximum(disc, 0.0))) / (2.0 * a2),
            -a0 / a1,
        )
    # a2 <= 0: downforce grows faster than the lateral demand, no limit from this curvature.
    u = np.where((a2 > 0) & (root > 0), np.minimum(root, cap), cap)
    return np.sqrt(u)


# Layout of the packed parameter array the compiled passes read.
_M, _MU, _CL, _CD, _CRR, _LF, _WB, _H, _BRAKE, _BIAS, _CUTOFF, _BSCALE, _CF, _CR = range(14)


@numba.njit(cache=True)
def _axle_drag(force, f_max, stiffness):
    """Drag of an axle carrying lateral ``force``: ``force * tan(alpha)`` at the Fiala slip
    angle that makes it (``F/Fmax = 1 - (1 - u)^3``, ``tan(alpha) = 3 Fmax u / C``)."""
    if f_max <= 0.0 or stiffness <= 0.0:
        return 0.0
    ratio = min(abs(force) / f_max, 1.0)
    u = 1.0 - (1.0 - ratio) ** (1.0 / 3.0)
    return abs(force) * 3.0 * f_max * u / stiffness


@numba.njit(cache=True)
def _net_accel(v, k, sign, p, grid, step, surf, idx, on_surface):
    """Longitudinal acceleration: sign=+1 full throttle, sign=-1 full brake (as a deceleration).

    Resistance is aero drag, rolling resistance and the *cornering drag* of the tyres: a tyre
    makes lateral force at a slip angle, so its force leans back by that angle (``F tan
    alpha``; Fiala curve, load-scaled stiffness, as in ``sim.kernels``). On a 250 m radius at
    64 m/s that is ~1.8 kN, as much as aero drag: without it the profile expected the car to
    accelerate through fast sweepers that it could not even hold speed in (measured).
    Rear-wheel drive: the drive force is also capped by the rear axle's grip, whose load grows
    with the acceleration itself (load transfer ``m a h / wheelbase``, as in ``sim.kernels``):
    ``F = mu (N lf - h R) / (wb - mu h)`` with ``R`` the resistance, solved for ``F``.
    Braking: the pedal splits force ``bias : 1 - bias`` front to rear and the decelerating car
    moves load forward, so the brake force is capped where the first axle reaches its grip
    (the rear, for the default car: braking harder locks it and the car spins, as measured in
    the simulator), scaled down by the share of grip cornering already uses.
    With ``on_surface``, row ``idx`` of ``surf`` gives the normal load, the tyres' lateral
    force and gravity along the slope (``lines.surface.surface_forces``), the friction and
    the rolling resistance. Gravity transfers no load (as in the simulator, whose load
    transfer comes from the tyres' and the air's forces only).
    """
    m, mu, lf, wb, h = p[_M], p[_MU], p[_LF], p[_WB], p[_H]
    lr = wb - lf
    u = v * v
    crr = p[_CRR]
    along = 0.0
    if on_surface:
        normal, lateral, along = surface_forces(surf[idx], m, p[_CL], u, k)
        lateral = abs(lateral)
        mu = mu * surf[idx, S_GRIP]
        crr = crr + surf[idx, S_ROLLING]
    else:
        normal = m * 9.81 + p[_CL] * u
        lateral = m * u * abs(k)
    grip = mu * normal
    rem = grip * grip - lateral * lateral
    rem = math.sqrt(rem) if rem > 0.0 else 0.0
    load = normal / (m * 9.81)
    cornering = (_axle_drag(lateral * lr / wb, grip * lr / wb, p[_CF] * load)
                 + _axle_drag(lateral * lf / wb, grip * lf / wb, p[_CR] * load))
    resist = p[_CD] * u + crr * normal + cornering
    if sign > 0:
        pos = v / step
        i = int(pos)
        if i >= grid.shape[0] - 1:
            drive = grid[grid.shape[0] - 1]
        else:
            t = pos - i
            drive = grid[i] * (1.0 - t) + grid[i + 1] * t
        denom = wb - mu * h
        traction = mu * (normal * lf - h * resist) / denom if denom > 0.0 else grip
        force = min(drive, rem, traction)
        if on_surface:
            return (force - resist - along) / m
        return (force - resist) / m
    bias, brake_max = p[_BIAS], p[_BRAKE]
    ellipse = rem / grip if grip > 0.0 else 0.0
    front_den = bias * wb - mu * h
    front = mu * (normal * lr + resist * h) / front_den if front_den > 0.0 else brake_max
    rear = mu * (normal * lf - resist * h) / ((1.0 - bias) * wb + mu * h)
    force = p[_BSCALE] * min(brake_max, rem, ellipse * min(front, rear))
    cutoff = p[_CUTOFF]
    if cutoff > 0.0 and grip > 0.0:
        force *= max(0.0, 1.0 - lateral / grip / cutoff)
    if on_surface:
        return (force + resist + along) / m
    return (force + resist) / m


@numba.njit(cache=True)
def _pass(ds, kappa, vmax, forward, closed, v_start, p, grid, step, surf, on_surface):
    """One direction of the QSS method; two laps when closed so the start is consistent."""
    n = ds.shape[0]
    out = np.empty(n)
    laps = 2 if closed else 1
    if closed:
        start = 0
        for i in range(n):
            if vmax[i] < vmax[start]:
                start = i
        v = vmax[start]
    else:
        start = 0 if forward else n - 1
        v = min(v_start, vmax[start])
    steps = laps * n
    for j in range(steps):
        if forward:
            i = (start + j) % n
            out[i] = v
            if not closed and i == n - 1:
                break
            nxt = (i + 1) % n
            seg = ds[i]
            sign = 1.0
        else:
            i = (start - j) % n
            out[i] = v
            if not closed and i == 0:
                break
            nxt = (i - 1) % n
            seg = ds[nxt]
            sign = -1.0
        # Heun's method on u = v^2 (du/ds = 2a): exact for constant acceleration and
        # second-order accurate with drag, which the closed-form tests check.
        a0 = _net_accel(v, kappa[i], sign, p, grid, step, surf, i, on_surface)
        u_pred = max(v * v + 2.0 * a0 * seg, 0.0)
        a1 = _net_accel(math.sqrt(u_pred), kappa[nxt], sign, p, grid, step, surf, nxt,
                        on_surface)
        u_new = max(v * v + (a0 + a1) * seg, 0.0)
        v = min(math.sqrt(u_new), vmax[nxt])
    return out


_NO_SURFACE = np.zeros((1, N_SURFACE))


def _run_pass(model: CarModel, ds, kappa, vmax, forward: bool, closed: bool, v_start: float,
              surface: np.ndarray | None = None):
    return _pass(
        np.ascontiguousarray(ds, dtype=float), np.ascontiguousarray(kappa, dtype=float),
        np.ascontiguousarray(vmax, dtype=float), forward, closed, float(v_start),
        model.packed(), model.drive_force_grid_n, _DRIVE_GRID_STEP_MPS,
        _NO_SURFACE if surface is None else surface, surface is not None,
    )


def _segment_times(ds: np.ndarray, v_from: np.ndarray, v_to: np.ndarray) -> np.ndarray:
    """Time over each segment with speed linear in time (exact for constant acceleration)."""
    return 2.0 * ds / np.maximum(v_from + v_to, 1e-9)


def profile_from_geometry(
    ds_m: np.ndarray, curvature_1pm: np.ndarray, car: CarParams | None = None,
    model: CarModel | None = None, surface: PathSurface | None = None,
) -> SpeedProfile:
    """QSS profile of a closed line given segment lengths and curvature per sample (and the
    surface under each sample; None: level asphalt)."""
    car = car or CarParams()
    model = model or CarModel.from_car(car)
    ds = np.asarray(ds_m, dtype=float)
    kappa = np.asarray(curvature_1pm, dtype=float)
    if ds.shape != kappa.shape or ds.ndim != 1 or ds.size < 3:
        raise UserInputError("a speed profile needs matching 1-D arrays of >= 3 samples")
    if not (np.all(np.isfinite(ds)) and np.all(ds > 0) and np.all(np.isfinite(kappa))):
        raise UserInputError("a speed profile needs positive finite spacing and finite curvature")
    if surface is not None and surface.n != ds.size:
        raise UserInputError(f"a speed profile's surface needs {ds.size} samples, "
                             f"got {surface.n}")
    packed = None if surface is None else surface.packed()
    vmax = corner_speed_mps(kappa, car, packed) * model.corner_speed_scale
    v_fwd = _run_pass(model, ds, kappa, vmax, True, True, 0.0, packed)
    v_bwd = _run_pass(model, ds, kappa, vmax, False, True, 0.0, packed)
    speed = np.minimum(np.minimum(v_fwd, v_bwd), vmax)
    seg_t = _segment_times(ds, speed, np.roll(speed, -1))
    time = np.concatenate([[0.0], np.cumsum(seg_t)[:-1]])
    return SpeedProfile(
        curvature_1pm=kappa, ds_m=ds, corner_speed_mps=vmax, speed_mps=speed, time_s=time,
        lap_time_s=float(seg_t.sum()), line_length_m=float(ds.sum()),
    )


def line_profile(line: ReferenceLine, car: CarParams | None = None,
                 model: CarModel | None = None, grip_scale: float = 1.0,
                 surface: PathSurface | None = None) -> SpeedProfile:
    """QSS profile of a reference line (its own arc lengths and curvature, its track's
    surface at ``grip_scale``, or ``surface`` when given)."""
    ds = np.hypot(np.roll(line.x_m, -1) - line.x_m, np.roll(line.y_m, -1) - line.y_m)
    if surface is None:
        surface = PathSurface.of_track(line.track, grip_scale)
    return profile_from_geometry(ds, line.curvature_1pm, car, model, surface)


def speed_profile(track: Track, offsets_m: np.ndarray | float = 0.0,
                  car: CarParams | None = None, model: CarModel | None = None,
                  grip_scale: float = 1.0, surface: PathSurface | None = None) -> SpeedProfile:
    """QSS profile of the line with these lateral offsets on ``track`` (its heights, banking
    and surfaces included, every friction times ``grip_scale``)."""
    offsets = np.asarray(offsets_m, dtype=float)
    if offsets.ndim != 0 and offsets.shape != (track.n,):
        raise UserInputError(
            f"offsets for track {track.name!r} must have {track.n} values, got {offsets.shape}"
        )
    offsets = np.broadcast_to(offsets, (track.n,))
    return line_profile(ReferenceLine.from_offsets(track, offsets), car, model, grip_scale,
                        surface)


def lap_time_s(track: Track, offsets_m: np.ndarray | float = 0.0,
               car: CarParams | None = None, grip_scale: float = 1.0) -> float:
    """QSS lap time of a line (seconds) at ``grip_scale``."""
    return speed_profile(track, offsets_m, car, grip_scale=grip_scale).lap_time_s


def straight_run(length_m: float, car: CarParams | None = None, start_speed_mps: float = 0.0,
                 spacing_m: float = 0.25) -> tuple[float, float]:
    """Time and end speed of a full-throttle run down a straight of ``length_m``.

    The open-ended forward pass of the same kernel the lap uses; it is what the closed-form
    tests check (constant force, grip-limited launch, constant force against drag).
    """
    if not (length_m > 0 and spacing_m > 0 and start_speed_mps >= 0):
        raise UserInputError("a straight run needs length > 0, spacing > 0 and speed >= 0")
    car = car or CarParams()
    model = CarModel.from_car(car)
    n_seg = max(int(math.ceil(length_m / spacing_m)), 1)
    ds = np.full(n_seg + 1, length_m / n_seg)
    kappa = np.zeros(n_seg + 1)
    vmax = np.full(n_seg + 1, SPEED_CAP_MPS)
    speed = _run_pass(model, ds, kappa, vmax, True, False, start_speed_mps)
    seg_t = _segment_times(ds[:-1], speed[:-1], speed[1:])
    return float(seg_t.sum()), float(speed[-1])


def top_speed_mps(car: CarParams | None = None) -> float:
    """Speed at which the best gear's drive force equals drag plus rolling resistance."""
    car = car or CarParams()
    speeds = np.arange(1.0, SPEED_CAP_MPS, 0.01)
    surplus = (car.max_drive_force_n(speeds) - car.drag_force_n(speeds)
               - car.rolling_resistance * car.normal_force_n(speeds))
    negative = np.nonzero(surplus <= 0)[0]
    return float(speeds[negative[0]]) if negative.size else SPEED_CAP_MPS


def cornering_drag_n(car: CarParams, speed_mps: float, lateral_force_n: float,
                     normal_n: float | None = None, grip: float = 1.0) -> float:
    """The tyres' drag while they carry ``lateral_force_n`` (the QSS passes' rule); on a
    surface, its normal load ``normal_n`` and friction multiplier ``grip``."""
    normal = float(car.normal_force_n(speed_mps)) if normal_n is None else float(normal_n)
    load = normal / (car.mass_kg * GRAVITY_MPS2)
    lf, wb = car.cg_to_front_m, car.wheelbase_m
    grip = car.mu * normal if grip == 1.0 else car.mu * grip * normal
    return float(
        _axle_drag(lateral_force_n * (wb - lf) / wb, grip * (wb - lf) / wb,
                   car.cornering_stiffness_front_n_per_rad * load)
        + _axle_drag(lateral_force_n * lf / wb, grip * lf / wb,
                     car.cornering_stiffness_rear_n_per_rad * load))


def brake_force_limit_n(car: CarParams, speed_mps: float, lateral_force_n: float = 0.0,
                        grip_use: float = 1.0, lateral_cutoff: float = 0.0,
                        normal_n: float | None = None, grip: float = 1.0,
                        rolling: float = 0.0) -> float:
    """Largest total brake force before an axle saturates (the QSS backward pass's rule).

    The follower caps its pedal with it: beyond it the simulator's rear axle locks and the car
    spins under braking. On a surface: its normal load ``normal_n``, friction multiplier
    ``grip`` and extra rolling resistance ``rolling``.
    """
    normal = float(car.normal_force_n(speed_mps)) if normal_n is None else float(normal_n)
    crr = car.rolling_resistance if rolling == 0.0 else car.rolling_resistance + rolling
    resist = float(car.drag_force_n(speed_mps)) + crr * normal
    mu = car.mu * grip_use if grip == 1.0 else car.mu * grip * grip_use
    lf, wb, h, bias = car.cg_to_front_m, car.wheelbase_m, car.cg_height_m, car.brake_bias_front
    grip = mu * normal
    ellipse = math.sqrt(max(1.0 - (lateral_force_n / grip) ** 2, 0.0)) if grip > 0 else 0.0
    front_den = bias * wb - mu * h
    front = mu * (normal * (wb - lf) + resist * h) / front_den if front_den > 0 else math.inf
    rear = mu * (normal * lf - resist * h) / ((1.0 - bias) * wb + mu * h)
    force = min(car.max_brake_force_n, ellipse * grip, ellipse * min(front, rear))
    if lateral_cutoff > 0.0 and grip > 0.0:
        force *= max(0.0, 1.0 - lateral_force_n / grip / lateral_cutoff)
    return float(force)

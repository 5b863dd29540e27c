"""Batched vehicle dynamics: the car's parameters as kernel arrays, start states, a free-plane car.

The model itself (dynamic single-track with Fiala tyres on a friction ellipse, aero, engine and
gearbox, brakes, grass and walls) is compiled in :mod:`formula_tourney.sim.kernels`; this module
turns a :class:`~formula_tourney.sim.car_params.CarParams` into the flat arrays the kernels read
and offers :class:`CarBatch`, N cars on an open plane, for tests and for anyone who needs the
vehicle without a track.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.sim import kernels as K
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.sensors import surface_rows


@dataclass(frozen=True)
class CarArrays:
    """A car as the kernels read it: scalar parameters, torque table (2 x k), gear ratios."""

    params: np.ndarray
    torque: np.ndarray
    gears: np.ndarray


def car_from_overrides(overrides: dict | None) -> CarParams:
    """``CarParams`` with a user's overrides; unknown or invalid fields -> ``UserInputError``."""
    try:
        return CarParams(**(overrides or {}))
    except Exception as exc:  # pydantic.ValidationError and TypeError
        raise UserInputError(f"config key 'car': invalid car parameters: {exc}") from None


def pack_params(car: CarParams) -> CarArrays:
    """Flatten ``car`` into the ``P_*`` layout of the kernels."""
    if len(car.engine_rpm_points) != len(car.engine_torque_points_nm):
        raise UserInputError("car: engine_rpm_points and engine_torque_points_nm differ in length")
    rpm_points = car.engine_rpm_points
    if any(b <= a for a, b in zip(rpm_points[:-1], rpm_points[1:], strict=True)):
        raise UserInputError("car: engine_rpm_points must increase")
    if not car.gear_ratios:
        raise UserInputError("car: gear_ratios is empty")
    p = np.zeros(K.N_PARAMS)
    p[K.P_MASS] = car.mass_kg
    p[K.P_IZ] = car.yaw_inertia_kgm2
    p[K.P_LF] = car.cg_to_front_m
    p[K.P_LR] = car.cg_to_rear_m
    p[K.P_H] = car.cg_height_m
    p[K.P_TW] = car.track_width_m
    p[K.P_LEN] = car.car_length_m
    p[K.P_WID] = car.car_width_m
    p[K.P_MU] = car.mu
    p[K.P_MU_GRASS] = car.mu_grass
    p[K.P_GRASS_DRAG] = car.grass_drag_n_per_mps
    p[K.P_CF] = car.cornering_stiffness_front_n_per_rad
    p[K.P_CR] = car.cornering_stiffness_rear_n_per_rad
    p[K.P_CD] = car.drag_coef_n_per_mps2
    p[K.P_CL] = car.downforce_coef_n_per_mps2
    p[K.P_CRR] = car.rolling_resistance
    p[K.P_RW] = car.wheel_radius_m
    p[K.P_IDLE] = car.idle_rpm
    p[K.P_REDLINE] = car.redline_rpm
    p[K.P_FD] = car.final_drive
    p[K.P_EFF] = car.drivetrain_efficiency
    p[K.P_UP] = car.upshift_rpm
    p[K.P_DOWN] = car.downshift_rpm
    p[K.P_BRAKE] = car.max_brake_force_n
    p[K.P_BIAS] = car.brake_bias_front
    p[K.P_STEER] = car.max_steer_rad
    p[K.P_WALL_DMG] = car.wall_damage_per_mps
    p[K.P_WALL_E] = car.wall_restitution
    # Launch: the clutch holds the engine at its torque peak (no extra parameter needed).
    p[K.P_LAUNCH_RPM] = car.engine_rpm_points[int(np.argmax(car.engine_torque_points_nm))]
    K.derive_params(p)  # inverses and ratios the hot path multiplies by
    torque = np.array([car.engine_rpm_points, car.engine_torque_points_nm], dtype=float)
    gears = np.array(car.gear_ratios, dtype=float)
    return CarArrays(p, np.ascontiguousarray(torque), gears)


def gear_for_speed(car: CarParams, speed_mps: float) -> int:
    """Lowest gear whose rpm at ``speed_mps`` is below the upshift point (what the box picks)."""
    for g, ratio in enumerate(car.gear_ratios):
        rpm = abs(speed_mps) / car.wheel_radius_m * ratio * car.final_drive * 60 / (2 * math.pi)
        if rpm <= car.upshift_rpm:
            return g
    return len(car.gear_ratios) - 1


def set_start(row: np.ndarray, car: CarParams, x_m: float, y_m: float, heading_rad: float,
              speed_mps: float) -> None:
    """Put one car (a state row) at a pose, rolling straight at ``speed_mps``, clock cleared."""
    row[:] = 0.0
    row[K.ST_X] = x_m
    row[K.ST_Y] = y_m
    row[K.ST_PSI] = heading_rad
    set_rolling(row, car, speed_mps)
    row[K.ST_IDX] = -1.0
    row[K.ST_LAP_START] = -1.0


def set_rolling(row: np.ndarray, car: CarParams, speed_mps: float) -> None:
    """Make one car (a state row) roll straight at ``speed_mps``: its speed, wheels, gear and
    engine speed agree, as if it had driven up to that speed."""
    row[K.ST_VX] = speed_mps
    row[K.ST_W_FL:K.ST_W_RR + 1] = speed_mps / car.wheel_radius_m
    g = gear_for_speed(car, speed_mps)
    row[K.ST_GEAR] = g
    rpm = speed_mps / car.wheel_radius_m * car.gear_ratios[g] * car.final_drive * 60 / (2 * math.pi)
    row[K.ST_RPM] = max(rpm, car.idle_rpm)


class CarBatch:
    """N cars on an open plane (no track): the vehicle model alone, batched.

    ``step(actions, duration_s)`` integrates at ``physics_hz``; attributes read the state.
    """

    def __init__(self, n: int = 1, car: CarParams | None = None, physics_hz: float = 100.0):
        if n < 1:
            raise UserInputError("CarBatch: n must be >= 1")
        if physics_hz <= 0:
            raise UserInputError("CarBatch: physics_hz must be > 0")
        self.car = car or CarParams()
        self.arrays = pack_params(self.car)
        self.physics_hz = float(physics_hz)
        self.state = np.zeros((n, K.N_STATE))
        self.on_grass = np.zeros(n, dtype=np.uint8)
        self.surface = np.zeros((n, K.N_ELEV))
        self.on_surface = np.zeros(n, dtype=np.uint8)
        self.grip = np.ones(n)
        """Per car: friction multiplier of its surface (1.0 asphalt and the default grass)."""
        self.rolling = np.zeros(n)
        """Per car: extra rolling-resistance coefficient of its surface (0.0 asphalt)."""
        for c in range(n):
            set_start(self.state[c], self.car, 0.0, 0.0, 0.0, 0.0)

    @property
    def n(self) -> int:
        return int(self.state.shape[0])

    def place(self, c: int, x_m: float = 0.0, y_m: float = 0.0, heading_rad: float = 0.0,
              speed_mps: float = 0.0) -> None:
        set_start(self.state[c], self.car, x_m, y_m, heading_rad, speed_mps)

    def set_surface(self, c: int, slope_rad: float = 0.0, banking_rad: float = 0.0,
                    vertical_curvature_1pm: float = 0.0, heading_rad: float = 0.0) -> None:
        """Put car ``c`` on a uniform surface: grade (uphill > 0 along ``heading_rad``),
        banking (> 0 raises the left side) and vertical curvature (> 0 a crest)."""
        self.surface[c] = surface_rows(heading_rad, slope_rad, banking_rad,
                                       vertical_curvature_1pm)[0]
        self.on_surface[c] = 1

    def normal_load_n(self, c: int = 0) -> float:
        """Total tyre normal load of car ``c`` now (N), as the next substep computes it."""
        st = self.state[c]
        v2 = float(st[K.ST_VX] ** 2 + st[K.ST_VY] ** 2)
        if not self.on_surface[c]:
            return float(self.arrays.params[K.P_MG] + self.arrays.params[K.P_CL] * v2)
        e = self.surface[c]
        return float(K.normal_load(self.arrays.params, v2, float(st[K.ST_VX]),
                                   float(st[K.ST_R]), e[K.E_GN], e[K.E_KV], e[K.E_SB]))

    def step(self, actions: np.ndarray, duration_s: float) -> None:
        """Hold ``actions`` (N x 3: steer, throttle, brake) for ``duration_s``."""
        a = np.ascontiguousarray(np.broadcast_to(np.asarray(actions, float), (self.n, 3)))
        n_sub = max(int(round(duration_s * self.physics_hz)), 1)
        K.integrate_free(self.state, a, self.arrays.params, self.arrays.torque,
                         self.arrays.gears, self.on_grass, duration_s / n_sub, n_sub,
                         self.surface, self.on_surface, self.grip, self.rolling)

    @property
    def speed_mps(self) -> np.ndarray:
        return np.hypot(self.state[:, K.ST_VX], self.state[:, K.ST_VY])

    @property
    def vx_mps(self) -> np.ndarray:
        return self.state[:, K.ST_VX].copy()

    @property
    def vy_mps(self) -> np.ndarray:
        return self.state[:, K.ST_VY].copy()

    @property
    def yaw_rate_radps(self) -> np.ndarray:
        return self.state[:, K.ST_R].copy()

    @property
    def lateral_accel_mps2(self) -> np.ndarray:
        return self.state[:, K.ST_AY].copy()

    @property
    def rpm(self) -> np.ndarray:
        return self.state[:, K.ST_RPM].copy()

    @property
    def gear(self) -> np.ndarray:
        return self.state[:, K.ST_GEAR].astype(int)

    @property
    def wheel_spin_radps(self) -> np.ndarray:
        return self.state[:, K.ST_W_FL:K.ST_W_RR + 1].copy()

    @property
    def position_m(self) -> np.ndarray:
        return self.state[:, [K.ST_X, K.ST_Y]].copy()

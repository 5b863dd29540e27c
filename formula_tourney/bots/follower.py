"""The follower bot, our "Tita": drives any line with a speed profile and a steering controller.

Speed: the target at each point is the line's quasi-steady-state (QSS) speed for our car times
``speed_factor``, planned with a braking reserve; the demand is the acceleration that reaches
the target at the place the car will be one control step later (the action is held for
200 ms, 3-16 m of track), turned into throttle or brake through the car's own force model and
capped so the tyres keep grip for cornering (the simulator clips longitudinal force first and
the lateral force shrinks on the friction ellipse, so a full pedal mid-corner spins or
ploughs the car).

Steering: a curvature command ``k_line + e/L^2 + 2 zeta de/ds / L`` (a second-order lateral
error law in distance, preview ``L`` growing with speed) plus yaw damping, on the pose
predicted half a control step ahead, turned into a wheel angle through the tyres' slip angles
(``wheelbase k + alpha_f - alpha_r``, Fiala curve inverted) with counter-steer on the rear's
excess slip. Pure pursuit was the first choice, but on a 15 m hairpin its steady-state corner
cutting (about ``L^2 / 2R``) is metres; docs/lines.md lists what else was tried and why.

On a track with heights, banking or surfaces both the plan (the QSS profile) and the two laws
use the forces of ``lines.surface``: the tyres' lateral force is the path's need less the
banking's help (without that feed-forward the lateral law's steady error on b-speedway's 15 deg
banked straights and turns, ``g sin(bank) L^2 / v^2``, was ~1.6 m, and the car left the
track on the low side at the first apex), the normal load follows slope, banking and crests,
gravity along the slope is paid by the throttle or taken by the brake, and the friction is the
surface's (times the env's ``grip_scale``).

``drive`` runs laps through ``FormulaRacingEnv`` and returns lap times, damage and a per-step
trace (the recorded line is made from it).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.lines.speed_profile import (
    CarModel,
    brake_force_limit_n,
    cornering_drag_n,
    speed_profile,
)
from formula_tourney.lines.surface import S_GRIP, S_ROLLING, PathSurface, surface_forces
from formula_tourney.sim import kernels as K
from formula_tourney.sim.car_params import GRAVITY_MPS2, CarParams
from formula_tourney.sim.env import FormulaRacingEnv
from formula_tourney.sim.reference_line import ReferenceLine
from formula_tourney.sim.track import Track


@dataclass(frozen=True)
class FollowerConfig:
    """Tuning of the follower. Defaults were tuned on 13 test tracks (docs/lines.md): every
    drive clean, 9% mean gap to the reference limit on the min-curvature line."""

    speed_factor: float = 0.97
    """Share of the QSS corner speeds planned for: the margin for what the QSS model leaves
    out (load transfer, the tyre curve's falling side, 200 ms control)."""
    preview_time_s: float = 0.8
    """Preview length of the lateral error law per m/s of speed."""
    min_preview_m: float = 8.0
    """Shortest preview length (low speed): below it the 200 ms step makes the law ring."""
    damping_ratio: float = 0.9
    """Damping of the lateral error law."""
    yaw_damping: float = 0.1
    """Share of the yaw-rate error (commanded minus measured) added to the curvature command:
    damps the heading and catches the rear when it steps out."""
    slip_steering: bool = True
    """Wheel angle from the Fiala slip angles of both axles (else kinematic bicycle plus the
    linear understeer gradient, which spun the car braking into corners)."""
    steer_smoothing: float = 0.3
    """Weight of the previous steering command in the new one: damps the left-right chatter
    that the 200 ms hold excites at 50-60 m/s (0.5 would null it but lags in hairpins)."""
    countersteer_gain: float = 1.0
    """Wheel angle per radian of rear slip beyond the wanted one (catches the rear)."""
    front_force_share: float = 0.9
    """Largest share of an axle's grip the steering law asks for."""
    understeer_gain: float = 1.0
    """Share of the car's linear understeer gradient added as feed-forward wheel angle."""
    curvature_preview_s: float = 0.15
    """Line curvature is read this far ahead (in time) to lead the car into corners."""
    grip_use: float = 1.0
    """Share of the friction ellipse the pedals may use."""
    traction_use: float = 1.0
    """Share of the rear axle's spare grip the throttle may use while cornering: drive force
    takes cornering stiffness from the rear tyre, and the car oversteers before it slides."""
    traction_transfer: float = 0.5
    """Share of the longitudinal load transfer to the rear counted on for traction (1 = the
    QSS forward pass's rule; with 1 the car spun under power at 94% of its cornering grip,
    0.5 was clean on 50 test drives)."""
    brake_plan: float = 0.95
    """Share of the car's braking the speed plan counts on: the reserve catches a car that
    arrives a little fast (which then corners harder and can brake less)."""
    brake_lateral_cutoff: float = 0.0
    """If > 0, braking fades to zero as cornering uses this share of grip (plan and pedal).
    Needed with the kinematic steering law; with slip steering (default) 0 was 4-7% faster
    and as safe."""
    control_period_s: float = 0.2
    """Matches the env's control period (the pose is predicted half of it ahead)."""
    compression_use: float = 0.0
    """Share of a compression's extra normal load (vertical curvature < 0) the speed plan
    counts on. Counting all of it put the car off alpine-2 and dirt-3 (narrow, low-friction
    corners in a dip, entered at 0.97 of a corner speed that holds for a few metres only);
    0 drove all 37 other torcs-data tracks clean at ~0.3 % more lap time (measured)."""

    def validate(self) -> FollowerConfig:
        for name, value in asdict(self).items():
            if isinstance(value, bool):
                continue
            if not (isinstance(value, float | int) and math.isfinite(value) and value >= 0):
                raise UserInputError(f"follower setting {name!r} must be >= 0, got {value!r}")
        if self.speed_factor > 1.5 or self.grip_use > 1.0:
            raise UserInputError("follower: speed_factor must be <= 1.5 and grip_use <= 1")
        return self


@dataclass
class CarState:
    """What the follower reads each step (the true state, not the telemetry)."""

    x_m: float
    y_m: float
    yaw_rad: float
    vx_mps: float
    vy_mps: float
    yaw_rate_radps: float


@dataclass
class Follower:
    """The controller: ``act(state) -> (steer, throttle, brake)``."""

    track: Track
    offsets_m: np.ndarray
    car: CarParams = field(default_factory=CarParams)
    config: FollowerConfig = field(default_factory=FollowerConfig)
    grip_scale: float = 1.0
    """The env's friction multiplier: the plan is made for the grip the car will have."""

    def __post_init__(self) -> None:
        self.config.validate()
        offsets = np.asarray(self.offsets_m, dtype=float)
        if offsets.shape != (self.track.n,) or not np.all(np.isfinite(offsets)):
            raise UserInputError(
                f"line for track {self.track.name!r} must have {self.track.n} finite offsets"
            )
        self.line = ReferenceLine.from_offsets(self.track, offsets)
        surface = PathSurface.of_track(self.track, self.grip_scale)
        self._surf = None if surface is None else surface.packed()
        self.profile = speed_profile(self.track, offsets, self.car, grip_scale=self.grip_scale)
        planned = (None if surface is None
                   else surface.with_compression_share(self.config.compression_use))
        model = replace(CarModel.from_car(self.car),
                        brake_lateral_cutoff=self.config.brake_lateral_cutoff,
                        brake_scale=self.config.brake_plan,
                        corner_speed_scale=self.config.speed_factor)
        # The margin is on corner speeds only: scaling the whole profile also capped the car
        # at 97% of its speed on every straight, where nothing is at risk (measured: 2/3 of the
        # gap to the limit was lost while accelerating).
        self.plan = speed_profile(self.track, offsets, self.car, model, self.grip_scale, planned)
        self.target_mps = self.plan.speed_mps
        self._hint = -1
        self._last_steer = 0.0
        c = self.car
        wb = c.wheelbase_m
        # Linear understeer gradient (rad per m/s^2 of lateral acceleration).
        self._understeer = c.mass_kg / wb * (
            c.cg_to_rear_m / c.cornering_stiffness_front_n_per_rad
            - c.cg_to_front_m / c.cornering_stiffness_rear_n_per_rad
        )
        speeds = np.arange(0.0, 160.0, 0.5)
        self._drive_grid = c.max_drive_force_n(speeds)

    def reset(self) -> None:
        self._hint = -1
        self._last_steer = 0.0

    def _drive_force(self, v: float) -> float:
        return float(np.interp(v, np.arange(0.0, 160.0, 0.5), self._drive_grid))

    def _interp(self, arr: np.ndarray, s: float) -> float:
        t = self.track
        s = s % t.length_m
        i = int(t.index_at(s))
        j = (i + 1) % t.n
        s_j = t.s_m[j] if j else t.length_m
        w = (s - t.s_m[i]) / max(s_j - t.s_m[i], 1e-9)
        return float(arr[i] * (1 - w) + arr[j] * w)

    def target_speed_mps(self, s_m: float) -> float:
        return self._interp(self.target_mps, s_m)

    def _loads(self, i: int, speed: float, curvature_1pm: float) -> tuple[float, float, float]:
        """``(normal load, tyre lateral force, gravity along)`` at sample ``i`` for a path of
        this curvature at this speed; on level asphalt ``m g + c_l v^2``, ``m v^2 k``, 0."""
        c = self.car
        u = speed * speed
        if self._surf is None:
            return (c.mass_kg * GRAVITY_MPS2 + c.downforce_coef_n_per_mps2 * u,
                    c.mass_kg * u * curvature_1pm, 0.0)
        return surface_forces(self._surf[i], c.mass_kg, c.downforce_coef_n_per_mps2, u,
                              curvature_1pm)

    def _slip_wheel_angle(self, st: CarState, v: float, k_total: float, i: int = 0) -> float:
        """Wheel angle from the tyres' slip angles: ``wheelbase k + alpha_f - alpha_r`` for the
        front and rear shares of the wanted lateral force (Fiala curve inverted in closed form,
        load and downforce included), plus counter-steer on the rear's measured excess slip.

        The linear understeer gradient is this law's small-slip limit; near the grip limit the
        Fiala inverse asks for the larger angles the tyres really need. Feeding the measured
        side slip back in full (steering along the front axle's velocity) chattered left-right
        on 55 m/s straights through the 200 ms hold (measured): only the rear's excess slip is
        fed back, with ``countersteer_gain``.
        """
        c, cfg = self.car, self.config
        wb, lf, lr = c.wheelbase_m, c.cg_to_front_m, c.cg_to_rear_m
        if self._surf is None:
            normal = c.mass_kg * GRAVITY_MPS2 + c.downforce_coef_n_per_mps2 * v * v
            lateral = c.mass_kg * v * v * k_total
            mu = c.mu
        else:
            normal, lateral, _ = self._loads(i, v, k_total)
            mu = c.mu * self._surf[i, S_GRIP]
        load = normal / (c.mass_kg * GRAVITY_MPS2)
        alpha_f = _fiala_slip(lateral * lr / wb, mu * normal * lr / wb,
                              c.cornering_stiffness_front_n_per_rad * load,
                              cfg.front_force_share)
        alpha_r = _fiala_slip(lateral * lf / wb, mu * normal * lf / wb,
                              c.cornering_stiffness_rear_n_per_rad * load,
                              cfg.front_force_share)
        wheel = math.atan(wb * k_total) + alpha_f - alpha_r
        rear_slip = -math.atan2(st.vy_mps - lr * st.yaw_rate_radps, max(st.vx_mps, 1.0))
        return wheel + cfg.countersteer_gain * (alpha_r - rear_slip)

    def act(self, st: CarState) -> tuple[float, float, float]:
        cfg, c, t = self.config, self.car, self.track
        speed = math.hypot(st.vx_mps, st.vy_mps)
        v = max(st.vx_mps, 0.0)
        # Pose half a control step ahead: the action is held for the whole step.
        tau = 0.5 * cfg.control_period_s
        cos_y, sin_y = math.cos(st.yaw_rad), math.sin(st.yaw_rad)
        xp = st.x_m + (st.vx_mps * cos_y - st.vy_mps * sin_y) * tau
        yp = st.y_m + (st.vx_mps * sin_y + st.vy_mps * cos_y) * tau
        yaw_p = st.yaw_rad + st.yaw_rate_radps * tau
        s, lateral, self._hint = t.project(xp, yp, self._hint)

        # --- steering -----------------------------------------------------------------------
        line_off = self._interp(self.line.offset_m, s)
        i = int(t.index_at(s))
        line_h = float(self.line.heading_rad[i])
        e_lat = line_off - lateral  # > 0: the line is to the car's left
        # Course angle (velocity direction) rather than yaw: a sliding car's nose lies.
        course = yaw_p + (math.atan2(st.vy_mps, st.vx_mps) if st.vx_mps > 1.0 else 0.0)
        e_head = math.atan2(math.sin(line_h - course), math.cos(line_h - course))
        preview = max(cfg.min_preview_m, cfg.preview_time_s * v)
        k_line = self._interp(self.line.curvature_1pm, s + cfg.curvature_preview_s * v)
        k_cmd = (k_line + e_lat / preview**2 + 2.0 * cfg.damping_ratio * e_head / preview)
        # Yaw damping as a curvature correction: the yaw-rate gain of the car is about
        # v / wheelbase, so a wheel-angle gain would grow with speed and, with one 200 ms step
        # of delay, ring above ~40 m/s; in curvature units the loop gain is speed-independent.
        k_total = k_cmd + cfg.yaw_damping * (v * k_cmd - st.yaw_rate_radps) / max(v, 5.0)
        # Understeer gradient: cornering stiffness grows with load (downforce), so it shrinks.
        load = c.mass_kg * GRAVITY_MPS2 / (c.mass_kg * GRAVITY_MPS2
                                           + c.downforce_coef_n_per_mps2 * v * v)
        if cfg.slip_steering and v > 5.0:
            wheel = self._slip_wheel_angle(st, v, k_total, i)
        else:
            wheel = (math.atan(c.wheelbase_m * k_total)
                     + cfg.understeer_gain * self._understeer * load * v * v * k_cmd)
        steer = max(-1.0, min(1.0, wheel / c.max_steer_rad))
        # Blend with the previous command: at 50-60 m/s the car's side slip answers a wheel
        # angle within one 200 ms hold, and the laws above then over-correct every step (a
        # left-right chatter that grew until the car left the track, measured). An equal
        # blend has zero gain at that period-2 frequency.
        lam = cfg.steer_smoothing
        steer = (1.0 - lam) * steer + lam * self._last_steer
        self._last_steer = steer

        # --- speed --------------------------------------------------------------------------
        dt = cfg.control_period_s
        reach = max(v * dt, 1.0)
        # Slowest target over the next step and a bit: never arrive above any of them.
        probe = np.linspace(s, s + reach + 0.5 * v * dt + 2.0, 6)
        goal = min(self.target_speed_mps(p) for p in probe)
        a_req = (goal * goal - v * v) / (2.0 * reach)
        ahead = [self._interp(self.line.curvature_1pm, p_s)
                 for p_s in (s, s + 0.5 * v * cfg.control_period_s,
                             s + v * cfg.control_period_s)]
        if self._surf is None:
            normal = c.mass_kg * GRAVITY_MPS2 + c.downforce_coef_n_per_mps2 * speed * speed
            resist = c.drag_coef_n_per_mps2 * speed * speed + c.rolling_resistance * normal
            # Lateral force now or asked for before the next decision, whichever is largest:
            # a full pedal held into a turn-in (or an S-bend's switch) snapped the rear.
            k_ahead = max(abs(k) for k in ahead)
            lat_force = c.mass_kg * max(v * v * abs(k_cmd), v * v * k_ahead)
            grip = cfg.grip_use * c.mu * normal
            along = 0.0
            surf_grip, rolling = 1.0, 0.0
            normal_now, lat_now = None, c.mass_kg * v * v * abs(k_line)
        else:
            # The same on the surface: the tyres' share of each curvature after the banking's
            # help, the surface's normal load, friction and rolling, and the slope's pull.
            surf_grip = float(self._surf[i, S_GRIP])
            rolling = float(self._surf[i, S_ROLLING])
            normal, _, along = self._loads(i, speed, k_line)
            resist = (c.drag_coef_n_per_mps2 * speed * speed
                      + (c.rolling_resistance + rolling) * normal)
            lat_force = max(abs(self._loads(i, v, k)[1]) for k in [k_cmd, *ahead])
            grip = cfg.grip_use * c.mu * surf_grip * normal
            normal_now = normal
            lat_now = abs(self._loads(i, v, k_line)[1])
        throttle = brake = 0.0
        if a_req >= 0.0:
            # The rear axle carries the drive and its share of the cornering force. Its static
            # share, not the larger share load transfer gives it: the simulated rear tyre
            # loses cornering stiffness as drive force grows (friction ellipse at equal slip),
            # and using the transferred load spun the car on corner exits (measured).
            rear = c.cg_to_front_m / (c.wheelbase_m - cfg.traction_transfer * c.mu * c.cg_height_m)
            rear_spare = cfg.traction_use * rear * math.sqrt(max(grip**2 - lat_force**2, 0.0))
            # The tyres' cornering drag must be paid too, or the car sags through long corners.
            drag = cornering_drag_n(c, speed, lat_now, normal_now, surf_grip)
            force = min(c.mass_kg * a_req + resist + drag + along, rear_spare)
            full = self._drive_force(speed)
            throttle = max(0.0, min(1.0, force / max(full, 1.0)))
        else:
            # Cap by the cornering happening now, not the one ahead: a car arriving too fast
            # must still brake (it would otherwise give up braking exactly when it must).
            # The line's curvature, not the measured yaw rate: a wobble on a straight read as
            # cornering and held the brakes off until a hairpin was out of reach (measured).
            cap = brake_force_limit_n(c, speed, lat_now, cfg.grip_use, cfg.brake_lateral_cutoff,
                                      normal_now, surf_grip, rolling)
            force = min(c.mass_kg * -a_req - resist - along, cap)
            brake = max(0.0, min(1.0, force / c.max_brake_force_n))
        return steer, throttle, brake


def _fiala_slip(force_n: float, f_max_n: float, stiffness: float, max_share: float) -> float:
    """Slip angle at which a Fiala tyre gives ``force_n``: ``F/Fmax = 1 - (1 - u)^3`` with
    ``u = C tan(alpha) / (3 Fmax)``. The asked share is capped: near the peak the inverse is
    steep (2% more force, twice the slip), which would make the steering loop's gain explode."""
    if f_max_n <= 0.0:
        return 0.0
    ratio = min(abs(force_n) / f_max_n, max_share)
    u = 1.0 - (1.0 - ratio) ** (1.0 / 3.0)
    return math.copysign(math.atan(3.0 * f_max_n * u / stiffness), force_n)


def _car_state(env) -> CarState:
    """The true state of car 0 from the env (the bot is a bot: it may read the simulator)."""
    base = env.unwrapped
    batch = getattr(base, "_b", None)
    state = batch.state if batch is not None else base.state
    row = np.asarray(state)[0] if np.ndim(state) == 2 else np.asarray(state)
    return CarState(float(row[K.ST_X]), float(row[K.ST_Y]), float(row[K.ST_PSI]),
                    float(row[K.ST_VX]), float(row[K.ST_VY]), float(row[K.ST_R]))


def drive(
    track: Track,
    offsets: np.ndarray,
    laps: int = 2,
    car: CarParams | None = None,
    *,
    config: FollowerConfig | None = None,
    start_s_m: float | None = None,
    max_steps: int | None = None,
    env_config: dict | None = None,
) -> dict:
    """Drive ``laps`` timed laps of the line ``offsets`` on ``track`` in the simulator.

    The car starts at rest 50 m before the line (the env's default), so the first timed lap is
    a flying lap. Returns ``lap_times_s``, ``lap_damage``, ``best_lap_s`` (best lap with zero
    damage, NaN if none), ``damage``, ``finished`` (all laps done, no termination),
    ``termination``, ``steps`` and ``trace`` (per step: time_s, distance_m, s_m, lateral_m,
    x_m, y_m, speed_kmh, steer, throttle, brake, lap = start-line crossings so far).
    """
    if laps < 1:
        raise UserInputError(f"laps must be >= 1, got {laps}")
    car = car or CarParams()
    cfg = (config or FollowerConfig()).validate()
    grip_scale = (env_config or {}).get("grip_scale", 1.0)
    bot = Follower(track, np.asarray(offsets, dtype=float), car, cfg,
                   grip_scale=float(grip_scale) if isinstance(grip_scale, int | float) else 1.0)
    if max_steps is None:
        # Generous: twice the QSS time for the laps asked plus the run to the line.
        lap_steps = bot.profile.lap_time_s / cfg.control_period_s
        max_steps = int(2.0 * lap_steps * (laps + 1) / cfg.speed_factor) + 200
    env_cfg = {
        "track": track,
        "reference_line": np.asarray(offsets, dtype=float),
        "control_period_s": cfg.control_period_s,
        "max_steps": max_steps,
        "car": car.model_dump(),
    }
    env_cfg.update(env_config or {})
    env = FormulaRacingEnv(config=env_cfg)
    options = {} if start_s_m is None else {"start_s_m": float(start_s_m)}
    _, info = env.reset(seed=0, options=options)
    bot.reset()
    trace: dict[str, list] = {k: [] for k in (
        "time_s", "distance_m", "s_m", "lateral_m", "x_m", "y_m", "speed_kmh", "steer",
        "throttle", "brake", "lap")}
    crossings = 0
    prev_s = float(info.get("s_m", 0.0))
    termination = None
    steps = 0
    while True:
        st = _car_state(env)
        action = bot.act(st)
        _, _, terminated, truncated, info = env.step(np.asarray(action, dtype=np.float32))
        steps += 1
        s_now = float(info["s_m"])
        if prev_s - s_now > 0.5 * track.length_m:
            crossings += 1
        elif s_now - prev_s > 0.5 * track.length_m:
            crossings -= 1
        prev_s = s_now
        st = _car_state(env)
        trace["time_s"].append(steps * cfg.control_period_s)
        trace["distance_m"].append(float(info["distance_m"]))
        trace["s_m"].append(s_now)
        trace["lateral_m"].append(float(info["lateral_m"]))
        trace["x_m"].append(st.x_m)
        trace["y_m"].append(st.y_m)
        trace["speed_kmh"].append(float(info["speed_mps"]) * 3.6)
        trace["steer"].append(action[0])
        trace["throttle"].append(action[1])
        trace["brake"].append(action[2])
        trace["lap"].append(crossings)
        if terminated or truncated:
            termination = info.get("termination") or ("max_steps" if truncated else "ended")
            break
        if int(info["laps"]) >= laps:
            break
    env.close()
    lap_times = [float(x) for x in info.get("lap_times_s", [])]
    lap_damage = [float(x) for x in info.get("lap_damage", [0.0] * len(lap_times))]
    clean = [t for t, d in zip(lap_times, lap_damage, strict=False) if d == 0.0]
    return {
        "lap_times_s": lap_times,
        "lap_damage": lap_damage,
        "best_lap_s": float(min(clean)) if clean else float("nan"),
        "damage": float(info.get("damage", 0.0)),
        "finished": termination is None and len(lap_times) >= laps,
        "termination": termination,
        "steps": steps,
        "profile_lap_s": bot.profile.lap_time_s,
        "trace": trace,
    }

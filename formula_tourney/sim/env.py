"""The Gymnasium envs: one car (``FormulaRacing-v0``) and N independent cars (its vector entry).

Both wrap the same core, :class:`_Batch`: preallocated state/observation/output arrays and one
compiled call per step (:func:`kernels.step_cars`), so the Python side of a step is a few array
reads. Measured figures and the reasons for this shape are in ``docs/sim.md``.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping
from typing import Any

import gymnasium
import numba
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from formula_tourney.errors import UserInputError
from formula_tourney.sim import kernels as K
from formula_tourney.sim import reward as R
from formula_tourney.sim.car import pack_params, set_rolling, set_start
from formula_tourney.sim.catalog import load_track
from formula_tourney.sim.config import EnvConfig, ResetOptions, default_config
from formula_tourney.sim.draw import TrackRenderer
from formula_tourney.sim.reference_line import ReferenceLine
from formula_tourney.sim.sensors import (
    observation_bounds,
    observation_names,
    surface_block,
    track_geometry,
)

TERMINATIONS = {K.TERM_OFF_TRACK: "off_track", K.TERM_BACKWARDS: "backwards", K.TERM_SLOW: "slow"}
DEFAULT_START_BEFORE_LINE_M = 50.0
"""Default start: this far before the start line, so the first crossing starts a flying lap."""


class _NoLap(float):
    """NaN for "no lap yet" whose equality is reflexive.

    ``info`` reports ``last_lap_s``/``best_lap_s`` as NaN before a lap (docs/CONTRACTS.md), and
    Gymnasium's ``check_env`` compares infos of two identical runs with ``==``, which a plain NaN
    fails. Arithmetic, ``math.isnan`` and ``np.isnan`` see an ordinary NaN.
    """

    def __eq__(self, other: object) -> bool:
        return isinstance(other, float) and math.isnan(other)

    def __ne__(self, other: object) -> bool:
        return not self.__eq__(other)

    __hash__ = float.__hash__


NO_LAP = _NoLap("nan")


class _Batch:
    """N cars on one track: config, compiled-kernel arrays and per-car episode bookkeeping."""

    def __init__(self, n: int, config: Mapping[str, Any] | EnvConfig | None, threads: int = 1):
        most = numba.config.NUMBA_NUM_THREADS
        if not isinstance(threads, (int, np.integer)) or not 1 <= threads <= most:
            raise UserInputError(f"threads: expected 1..{most}, got {threads!r}")
        self.threads = int(threads)
        cfg = EnvConfig.parse(config)
        self.env_config = cfg
        self.config = cfg.as_dict()
        self.track = load_track(cfg.track)
        self.reference = self._reference(cfg.reference_line)
        self.car = cfg.car_params()
        arrays = pack_params(self.car)
        self.params, self.torque, self.gears = arrays.params, arrays.torque, arrays.gears
        self.lac = cfg.lac
        # The one check that needs the track: LAC must look less than a lap ahead.
        too_far = [d for d in cfg.lac_distances_m if not d < self.track.length_m]
        if too_far:
            raise UserInputError(
                f"config key 'lac_distances_m': {too_far} not shorter than the track "
                f"({self.track.length_m:.1f} m); distances must be in (0, track length)")
        self.lac_d = np.array(cfg.lac_distances_m, dtype=float)
        period = cfg.control_period_s
        self.n_sub = max(int(round(period * cfg.physics_hz)), 1)
        self.period_s = period
        self.max_steps = cfg.max_steps
        self.slow_patience = cfg.slow_patience_steps
        self.start_speed = cfg.start_speed_mps
        self.random_start = cfg.random_start
        # beyond the paper: the start curriculum's positions and share (none: no draws at all)
        self.curriculum_starts = np.asarray(cfg.curriculum_starts_m, dtype=float)
        self.curriculum_share = cfg.start_curriculum_share
        self.curriculum_speed = cfg.start_curriculum_speed  # x the limit's speed; 0: start_speed
        self.grass_w = cfg.grass_width_m
        self.cfg = np.zeros(K.N_CFG)
        c = self.cfg
        c[K.C_DT] = period
        c[K.C_NSUB] = self.n_sub
        c[K.C_GRASS_W] = self.grass_w
        c[K.C_MAX_STEPS] = self.max_steps
        c[K.C_TERM_OFF] = cfg.terminate_off_track
        c[K.C_TERM_BACK] = cfg.terminate_backwards
        c[K.C_TERM_SLOW] = cfg.terminate_slow
        c[K.C_SLOW_MPS] = cfg.slow_speed_kmh / 3.6
        c[K.C_SLOW_PATIENCE] = self.slow_patience
        self.reward_weights = c[K.C_REWARD:]  # a view: the kernel and info["rewards"] read it
        R.pack(cfg, self.reward_weights)
        c[K.C_LAC] = 1.0 if self.lac else 0.0
        c[K.C_LENGTH] = self.track.length_m
        self.geom = track_geometry(self.track, self.reference, cfg.grip_scale,
                                   self.car.mu / self.car.mu_grass)
        if cfg.limit_speeds_mps:  # beyond the paper: the overspeed crash term's limit speeds
            if len(cfg.limit_speeds_mps) != self.track.n:
                raise UserInputError(
                    f"config key 'limit_speeds_mps': {len(cfg.limit_speeds_mps)} values for "
                    f"track {self.track.name!r}, which has {self.track.n} samples")
            self.geom[:, K.G_VLIM] = cfg.limit_speeds_mps
        # Per-episode grip (docs/sim.md "Surfaces"): grip_scale lives in the geometry block (1
        # when a range is drawn); a drawn grip or a drying track is each car's ST_GRIP_DELTA.
        self.base_grip = cfg.grip_scale
        self.grip_range = cfg.grip_scale_range
        self.start_grip_delta = 0.0
        if cfg.grip_drying is not None:
            self.start_grip_delta = cfg.grip_drying.start / cfg.grip_scale - 1.0
            c[K.C_DRY_M] = cfg.grip_drying.over_laps * self.track.length_m
            c[K.C_DRY_DELTA0] = self.start_grip_delta
        # Heights and banking: read by the kernels only on a track that has them.
        c[K.C_ELEV] = 1.0 if self.track.has_surface else 0.0
        self.elev = surface_block(self.track)
        self.names = observation_names(self.lac, self.lac_d)
        self.obs_low, self.obs_high = observation_bounds(self.lac, len(self.lac_d))
        n_obs = len(self.names)
        self.n = n
        self.state = np.zeros((n, K.N_STATE))
        self.actions = np.zeros((n, 3))
        self.integrate = np.zeros(n, dtype=np.uint8)
        self.obs = np.zeros((n, n_obs), dtype=np.float32)
        self.out = np.zeros((n, K.N_OUT))
        self.reward_in = self.out[:, K.O_REWARD_IN:]  # what each car's reward is made of
        # Per-car bookkeeping as object/float arrays: the vector env's info copies them whole.
        self.lap_times = np.empty(n, dtype=object)
        self.lap_damage = np.empty(n, dtype=object)
        self.termination = np.full(n, None, dtype=object)
        for c in range(n):
            self.lap_times[c] = []
            self.lap_damage[c] = []
        self.lap_start_damage = np.zeros(n)
        self.best_lap = np.full(n, np.nan)
        self.last_lap = np.full(n, np.nan)
        self.laps = np.zeros(n, dtype=np.int64)
        self._start_row: np.ndarray | None = None
        self._reset_arrays: tuple[np.ndarray, ...] = ()
        self._s_list = self.track.s_m.tolist()
        self._ref_x = self.reference.x_m.tolist()
        self._ref_y = self.reference.y_m.tolist()
        self._ref_h = self.reference.heading_rad.tolist()

    def _reference(self, spec: Any) -> ReferenceLine:
        if isinstance(spec, str):
            if spec != "centre":
                raise UserInputError(
                    f"config key 'reference_line': {spec!r} is not 'centre'; pass an array of "
                    "offsets (bots.line_offsets.reference_offsets) for other lines")
            return ReferenceLine.centre(self.track)
        off = np.asarray(spec, dtype=float)
        tr = self.track
        if off.shape != (tr.n,) or not np.all(np.isfinite(off)):
            raise UserInputError(
                f"config key 'reference_line': expected {tr.n} finite offsets (one per track "
                f"sample), got shape {off.shape}")
        if np.any(off > tr.width_left_m) or np.any(off < -tr.width_right_m):
            raise UserInputError("config key 'reference_line': offsets leave the asphalt")
        return ReferenceLine.from_offsets(tr, off)

    def start_pose(self, s_m: float) -> tuple[float, float, float, int]:
        """Point, heading and sample index of the reference line at track position ``s_m``.

        Plain Python on cached lists: with random actions a vector env resets a few cars every
        step, and NumPy calls on scalars cost microseconds each.
        """
        tr = self.track
        s = float(s_m) % tr.length_m
        s_list = self._s_list
        i = min(max(bisect.bisect_right(s_list, s) - 1, 0), tr.n - 1)
        j = i + 1 if i + 1 < tr.n else 0
        s_next = s_list[j] if j else tr.length_m
        t = (s - s_list[i]) / max(s_next - s_list[i], 1e-12)
        rx, ry, rh = self._ref_x, self._ref_y, self._ref_h
        x = rx[i] + t * (rx[j] - rx[i])
        y = ry[i] + t * (ry[j] - ry[i])
        dh = math.remainder(rh[j] - rh[i], 2 * math.pi)
        return x, y, rh[i] + t * dh, i

    def reset_car(self, c: int, rng: np.random.Generator,
                  options: Mapping[str, Any] | ResetOptions | None) -> None:
        """Place car ``c`` for a new episode; the next kernel call only observes it."""
        opts = ResetOptions.parse(options)  # an instance passes through unchecked
        curriculum = self.curriculum_starts
        placed = False
        if opts.start_s_m is not None:
            s = opts.start_s_m
        elif len(curriculum) and rng.random() < self.curriculum_share:
            s = float(curriculum[rng.integers(len(curriculum))])
            placed = True
        elif self.random_start:
            s = float(rng.uniform(0.0, self.track.length_m))
        else:
            s = self.track.length_m - DEFAULT_START_BEFORE_LINE_M
        x, y, h, i = self.start_pose(s)
        if opts.start_speed_mps is not None:
            speed = opts.start_speed_mps
        elif placed and self.curriculum_speed > 0.0:
            speed = self.curriculum_speed * float(self.geom[i, K.G_VLIM])
        else:
            speed = self.start_speed
        set_start(self.state[c], self.car, x, y, h, speed)
        self.state[c, K.ST_IDX] = i  # projection hint: a local search, not a global scan
        if self.grip_range is not None:  # drawn after the start: no draw moves without a range
            self.state[c, K.ST_GRIP_DELTA] = float(rng.uniform(*self.grip_range)) - 1.0
        else:
            self.state[c, K.ST_GRIP_DELTA] = self.start_grip_delta
        self.integrate[c] = 0
        self._clear_lap_records(np.array([c]))

    def reset_cars(self, cars: np.ndarray, rng: np.random.Generator) -> None:
        """:meth:`reset_car` without options for many cars at once (the vector autoreset).

        Same poses and state as the one-car path, computed with a few array operations: with
        random actions a 64-car env resets two or three cars every step.
        """
        tr = self.track
        k = len(cars)
        if self.random_start:
            s = rng.uniform(0.0, tr.length_m, size=k)
        else:
            s = np.full(k, tr.length_m - DEFAULT_START_BEFORE_LINE_M)
        curriculum = self.curriculum_starts
        if len(curriculum):
            placed = rng.random(k) < self.curriculum_share
            s = np.where(placed, curriculum[rng.integers(len(curriculum), size=k)], s)
        if self._start_row is None:
            self._start_row = np.zeros(K.N_STATE)
            set_start(self._start_row, self.car, 0.0, 0.0, 0.0, self.start_speed)
            self._start_row[K.ST_GRIP_DELTA] = self.start_grip_delta
            ref = self.reference
            self._reset_arrays = tuple(np.ascontiguousarray(a, dtype=float) for a in (
                tr.s_m, ref.x_m, ref.y_m, ref.heading_rad))
        K.reset_rows(self.state, self.integrate, np.asarray(cars, dtype=np.int64), s,
                     self._start_row, *self._reset_arrays, float(tr.length_m))
        if len(curriculum) and self.curriculum_speed > 0.0:  # placed starts roll at speed
            for c in np.asarray(cars)[placed]:
                vlim = float(self.geom[int(self.state[c, K.ST_IDX]), K.G_VLIM])
                set_rolling(self.state[c], self.car, self.curriculum_speed * vlim)
        if self.grip_range is not None:
            self.state[cars, K.ST_GRIP_DELTA] = rng.uniform(*self.grip_range, size=k) - 1.0
        self._clear_lap_records(cars)

    def _clear_lap_records(self, cars: np.ndarray) -> None:
        """Forget the lap book-keeping of ``cars``: the one place a reset clears it."""
        for c in cars:
            self.lap_times[c] = []
            self.lap_damage[c] = []
        self.lap_start_damage[cars] = 0.0
        self.best_lap[cars] = np.nan
        self.last_lap[cars] = np.nan
        self.laps[cars] = 0
        self.termination[cars] = None

    def run(self) -> None:
        """One compiled call: every car with ``integrate`` set advances one control period."""
        if self.threads > 1:
            numba.set_num_threads(self.threads)
            K.step_cars_parallel(self.state, self.actions, self.integrate, self.params,
                                 self.torque, self.gears, self.geom, self.elev, self.cfg,
                                 self.lac_d,
                                 self.obs, self.out)
        else:
            K.step_cars(self.state, self.actions, self.integrate, self.params, self.torque,
                        self.gears, self.geom, self.elev, self.cfg, self.lac_d, self.obs,
                        self.out)

    def record_lap(self, c: int, lap_time_s: float) -> None:
        dmg = float(self.state[c, K.ST_DAMAGE])
        self.last_lap[c] = lap_time_s
        self.laps[c] += 1
        # New list objects, so an info dict handed out earlier keeps its own laps.
        self.lap_times[c] = self.lap_times[c] + [lap_time_s]
        self.lap_damage[c] = self.lap_damage[c] + [dmg - self.lap_start_damage[c]]
        self.lap_start_damage[c] = dmg
        if not lap_time_s >= self.best_lap[c]:  # also true while best is nan
            self.best_lap[c] = lap_time_s

    def info(self, c: int) -> dict[str, Any]:
        st = self.state[c].tolist()
        laps = self.lap_times[c]
        return {
            "lap_times_s": list(laps),
            "lap_damage": list(self.lap_damage[c]),
            "last_lap_s": laps[-1] if laps else NO_LAP,
            "best_lap_s": float(self.best_lap[c]) if laps else NO_LAP,
            "laps": len(laps),
            "damage": st[K.ST_DAMAGE],
            "distance_m": st[K.ST_DIST],
            "s_m": st[K.ST_S],
            "lateral_m": st[K.ST_LAT],
            "speed_mps": math.hypot(st[K.ST_VX], st[K.ST_VY]),
            "off_track": st[K.ST_OFF] > 0.5,
            "termination": self.termination[c],
            "grip_scale": self.base_grip * (1.0 + st[K.ST_GRIP_DELTA]),
            "rewards": R.RewardParts(self.reward_weights, self.reward_in[c].copy()),
        }


class InvalidActionError(gymnasium.error.InvalidAction, ValueError):
    """An action that is not (steer, throttle, brake) as finite numbers, one row per car."""


_ACTION_SHAPE = (3,)
"""One car's action: (steer, throttle, brake). The vector env takes ``(num_envs, 3)``."""
_PEDAL_SHAPE = (2,)
"""One car's action in the ``pedal`` action mode: (steer, pedal)."""


def action_space_of(action_mode: str) -> spaces.Box:
    """One car's action space: ``Box([-1, 0, 0], [1, 1, 1])`` (paper) or ``Box([-1, -1], [1,
    1])`` (``pedal``: steer and one pedal, throttle above 0 and brake below)."""
    if action_mode == "pedal":
        return spaces.Box(np.full(2, -1, np.float32), np.ones(2, np.float32), dtype=np.float32)
    return spaces.Box(np.array([-1, 0, 0], np.float32), np.array([1, 1, 1], np.float32),
                      dtype=np.float32)  # fmt: skip


def pedal_controls(actions: np.ndarray, out: np.ndarray) -> None:
    """(steer, pedal) rows into the (steer, throttle, brake) rows ``out`` the kernel reads:
    throttle = max(pedal, 0), brake = max(-pedal, 0)."""
    out[..., 0] = actions[..., 0]
    np.maximum(actions[..., 1], 0.0, out=out[..., 1])
    np.maximum(np.negative(actions[..., 1]), 0.0, out=out[..., 2])


def as_controls(action: np.ndarray) -> np.ndarray:
    """One car's action of either mode as (steer, throttle, brake): a pedal action mapped by
    :func:`pedal_controls`, a three-axis one as it is."""
    action = np.asarray(action, dtype=np.float64)
    if action.shape != _PEDAL_SHAPE:
        return action
    out = np.empty(3)
    pedal_controls(action, out)
    return out


def pedal_action(controls: np.ndarray) -> np.ndarray:
    """(steer, throttle, brake) rows as (steer, pedal) rows, pedal = throttle - brake: how a
    bot's three-axis action (a demonstration) is written in the ``pedal`` action mode."""
    controls = np.asarray(controls, dtype=np.float32)
    return np.stack([controls[..., 0], controls[..., 1] - controls[..., 2]], axis=-1)


_REAL_KINDS = "fiu"
"""NumPy dtype kinds an action may have: float, int, unsigned. Strings, bools and complex
numbers would be cast (``"0.5"`` parsed, ``True`` made 1, an imaginary part dropped)."""


def _as_array(action: Any, shape: tuple[int, ...]) -> np.ndarray:
    try:
        array = np.asarray(action)
    except (TypeError, ValueError):  # a ragged list
        raise _bad_dtype(action, shape) from None
    if array.dtype.kind == "O" and all(x is None or _is_real(x) for x in array.flat):
        array = array.astype(np.float64)  # None becomes NaN, which the finite check names
    if array.dtype.kind not in _REAL_KINDS:
        raise _bad_dtype(action, shape)
    return array.astype(np.float64, copy=False)


def _is_real(value: Any) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_)


def _bad_dtype(action: Any, shape: tuple[int, ...]) -> InvalidActionError:
    kind = getattr(getattr(action, "dtype", None), "name", None) or type(action).__name__
    return InvalidActionError(
        f"action: expected real numbers (float or int) of shape {shape} (steer, throttle, "
        f"brake), got {kind} {action!r:.80}")


def _bad_action(action: np.ndarray, shape: tuple[int, ...]) -> InvalidActionError:
    """The error for a wrong shape or a non-finite value (built only on the failing path)."""
    per_car = " per car" if len(shape) > 1 else ""
    names = "steer, pedal" if shape[-1] == 2 else "steer, throttle, brake"
    text = np.array2string(np.asarray(action), threshold=12)
    if action.shape != shape:
        return InvalidActionError(
            f"action: expected shape {shape} ({names}{per_car}), got shape "
            f"{action.shape}: {text}")
    try:
        bad = ~np.isfinite(np.asarray(action, dtype=np.float64))
    except (TypeError, ValueError):
        bad = np.ones(shape, dtype=bool)
    where = [tuple(int(i) for i in ix) for ix in np.argwhere(bad)[:4]]
    return InvalidActionError(
        f"action: every value must be a finite number; not finite at index {where}: {text}")


_DOC_TABLE = """
    | Index | Name              | Min | Max | Unit (before normalisation)                      |
    |-------|-------------------|-----|-----|--------------------------------------------------|
    | 0     | angle             | -1  | 1   | rad / pi: car heading minus reference heading    |
    | 1-19  | track_-90..track_90 | -1 | 1  | m / 200: range finders, -1 when off track        |
    | 20    | trackPos          | -inf| inf | (lateral - reference offset) / half width        |
    | 21    | speedX            | -inf| inf | m/s / 83.33 (body longitudinal)                  |
    | 22    | speedY            | -inf| inf | m/s / 83.33 (body lateral, left > 0)             |
    | 23    | speedZ            | -1  | 1   | m/s / 83.33, always 0 (flat tracks)             |
    | 24-27 | wheelSpinVel_FL..RR | -inf| inf | rad/s / 250                                   |
    | 28    | rpm               | 0   | inf | rpm / 10000                                      |
    | 29-32 | lac_20..lac_80    | -inf| inf | 1/m * 10: reference curvature ahead (lac only)   |
"""


def _render_frame(env: Any):
    """The ``rgb_array`` frame of a single or vector env (both hold a ``_Batch`` as ``_b``)."""
    if env.render_mode != "rgb_array":
        return None
    if env._renderer is None:
        env._renderer = TrackRenderer(env.track, env._b.grass_w)
    return env._renderer.frame(env._b.state, env.car)


class FormulaRacingEnv(gymnasium.Env):
    __doc__ = f"""A racing car at its grip limit on a closed track, observed through telemetry.

    ## Description
    A dynamic single-track car (Fiala tyres on a friction ellipse, aero downforce and drag,
    engine torque curve with an automatic gearbox, rear-wheel drive, brakes limited by grip)
    laps a track of asphalt bordered by grass (lower grip) and walls (damage). The task of the
    Formula RL paper: drive as fast as possible from telemetry alone.

    ## Action Space
    `Box([-1, 0, 0], [1, 1, 1], float32)`: steer (> 0 turns left, 1 = full lock), throttle,
    brake. Values outside are clipped; anything but three finite numbers (a scalar, None, NaN,
    another shape) raises `InvalidActionError` (a `ValueError`). Beyond the paper, `action_mode`
    "pedal": `Box([-1, -1], [1, 1])`, steer and one pedal (throttle = max(pedal, 0), brake =
    max(-pedal, 0)); `applied_controls` is the last step's (steer, throttle, brake).

    ## Observation Space
    Flat float32, 29 values (33 with `lac`); names from
    `formula_tourney.sim.sensors.observation_names(lac)`:
    {_DOC_TABLE}
    ## Rewards
    Per step `Vx * (cos(theta) - |sin(theta)| - w |trackPos|)` with `Vx` in m/s, `theta` the
    angle to the reference line and `w` = `track_pos_weight` (the paper's 1), minus
    `damage_weight` times the damage added in the step. With `progress_reward` (beyond the
    paper) the speed term `Vx * (cos(theta) - |sin(theta)|)` is replaced by the step's progress
    along the track in m/s (what a lap time counts; the inside of a corner earns more).
    A step that ends the episode off track or backwards gives -1; a slow end `-slow_penalty`.
    `info["rewards"]` splits the step's reward into its parts (`sim.reward.PARTS`: along,
    sideways, progress, track_pos, damage, end), which sum to it; the reward model with every
    setting is `sim.reward` (docs/sim.md, "Reward").

    ## Starting State
    On the reference line, `start_s_m` (default 50 m before the start line, or uniform with
    `random_start`; beyond the paper, a share `start_curriculum_share` of them at one of
    `curriculum_starts_m`), heading along the line, at `start_speed_mps` (default at rest). The lap
    clock starts at the first crossing of the start line; each later crossing completes a lap,
    its time interpolated inside the physics substep.

    ## Episode End
    Terminated: off the asphalt (`terminate_off_track`), facing backwards (`terminate_backwards`),
    or progress below `slow_speed_kmh` for `slow_patience_steps` steps (`terminate_slow`).
    Truncated: `max_steps` control steps. `info["termination"]` names the reason.

    ## Arguments
    `gymnasium.make("FormulaRacing-v0", config={{...}}, render_mode="rgb_array")`; `config` (a
    dict or a `sim.config.EnvConfig`) is merged over `default_config()` and validated by
    `EnvConfig`, which documents every key (unknown keys are an error): track (name or Track),
    reference_line ("centre" or offsets per sample), lac, lac_distances_m, control_period_s,
    physics_hz (>= 100), max_steps, terminate_off_track, terminate_backwards, terminate_slow,
    slow_speed_kmh, slow_patience_steps, slow_penalty, damage_weight, random_start,
    start_speed_mps, grass_width_m, grip_scale, grip_scale_range (a grip drawn per episode),
    grip_drying (a drying track), track_pos_weight, progress_reward, action_mode, car (CarParams
    overrides). `info["grip_scale"]` is the episode's grip now (every surface's friction
    multiplier).
    `reset(seed=..., options={{"start_s_m": float, "start_speed_mps": float}})`.

    ## Version History
    * v0: initial version.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}

    def __init__(self, config: Mapping[str, Any] | EnvConfig | None = None,
                 render_mode: str | None = None):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise UserInputError(f"render_mode {render_mode!r}: only 'rgb_array' is supported")
        self.render_mode = render_mode
        self._b = _Batch(1, config)
        self.config = self._b.config  # plain dict of every key (read as env.unwrapped.config)
        self.env_config = self._b.env_config  # the validated EnvConfig behind it
        self.track = self._b.track
        self.reference = self._b.reference
        self.car = self._b.car
        self.observation_names = self._b.names
        self.metadata = {**self.metadata, "render_fps": 1.0 / self._b.period_s}
        self.action_space = action_space_of(self.env_config.action_mode)
        self._pedal = self.env_config.action_mode == "pedal"
        self.observation_space = spaces.Box(self._b.obs_low, self._b.obs_high, dtype=np.float32)
        self._renderer = None
        self._act_row = self._b.actions[0]
        self._out_row = self._b.out[0]
        self._obs_row = self._b.obs[0]

    @staticmethod
    def default_config() -> dict[str, Any]:
        """Every config key with its default (:func:`formula_tourney.sim.config.default_config`)."""
        return default_config()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        b = self._b
        b.reset_car(0, self.np_random, ResetOptions.parse(options))
        b.run()
        b.integrate[0] = 1
        return self._obs_row.copy(), b.info(0)

    @property
    def applied_controls(self) -> np.ndarray:
        """(steer, throttle, brake) of the last step as the kernel read them (before its clip
        to the box): the action itself, or in the ``pedal`` mode its mapping."""
        return self._act_row.copy()

    def step(self, action):
        if self._pedal:
            return self._step_pedal(action)
        row = self._act_row
        # A cheap check (~0.5 us of a ~7 us step), not action_space.contains: NumPy would
        # broadcast a scalar into all three controls and turn None into NaN.
        if type(action) is not np.ndarray or action.dtype.kind not in _REAL_KINDS:
            action = _as_array(action, _ACTION_SHAPE)
        if action.shape != _ACTION_SHAPE:
            raise _bad_action(action, _ACTION_SHAPE)
        try:
            row[:] = action
        except (TypeError, ValueError):
            raise _bad_action(action, _ACTION_SHAPE) from None
        steer, throttle, brake = row.tolist()
        if steer - steer or throttle - throttle or brake - brake:  # x - x is NaN unless finite
            raise _bad_action(action, _ACTION_SHAPE)
        return self._run()

    def _step_pedal(self, action):
        """``step`` in the ``pedal`` action mode: (steer, pedal) mapped onto the kernel's row."""
        action = _as_array(action, _PEDAL_SHAPE)
        if action.shape != _PEDAL_SHAPE or not np.isfinite(action).all():
            raise _bad_action(action, _PEDAL_SHAPE)
        pedal_controls(action, self._act_row)
        return self._run()

    def _run(self):
        """One control period from the action row; the step's return."""
        b = self._b
        b.run()
        out = self._out_row
        lap = out[K.O_LAP_TIME]
        if lap == lap:
            b.record_lap(0, float(lap))
        term = int(out[K.O_TERM])
        truncated = out[K.O_TRUNC] > 0.5
        if term:
            b.termination[0] = TERMINATIONS[term]
        elif truncated:
            b.termination[0] = "max_steps"
        return self._obs_row.copy(), float(out[K.O_REWARD]), term != 0, bool(truncated), b.info(0)

    def render(self):
        return _render_frame(self)


_INFO_COLS = [K.ST_DAMAGE, K.ST_DIST, K.ST_S, K.ST_LAT, K.ST_VX, K.ST_VY, K.ST_OFF,
              K.ST_GRIP_DELTA]
_INFO_KEYS = ("lap_times_s", "lap_damage", "last_lap_s", "best_lap_s", "laps", "damage",
              "distance_m", "s_m", "lateral_m", "speed_mps", "off_track", "termination",
              "grip_scale", "rewards")


class FormulaRacingVectorEnv(VectorEnv):
    """``num_envs`` independent cars on one track, stepped by one compiled call.

    Gymnasium's next-step autoreset: the step after a car's episode ended resets that car (its
    action is ignored), returning its first observation with reward 0 and both flags false.
    ``info`` holds arrays over cars (``_key`` masks all true); see ``FormulaRacingEnv`` for
    the spaces, reward and ends. ``threads > 1`` spreads the cars over that many numba threads
    (sets numba's thread count for the process); the default, 1, suits a worker per core.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5,
                "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, config: Mapping[str, Any] | EnvConfig | None = None,
                 render_mode: str | None = None, threads: int = 1, **kwargs: Any):
        if kwargs:
            raise UserInputError(f"FormulaRacingVectorEnv: unknown argument(s) {sorted(kwargs)}")
        if not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise UserInputError(f"num_envs: expected an integer >= 1, got {num_envs!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise UserInputError(f"render_mode {render_mode!r}: only 'rgb_array' is supported")
        self.render_mode = render_mode
        self.num_envs = int(num_envs)
        self._b = _Batch(self.num_envs, config, threads)
        self.config = self._b.config
        self.env_config = self._b.env_config
        self.track = self._b.track
        self.car = self._b.car
        self.observation_names = self._b.names
        self.single_action_space = action_space_of(self.env_config.action_mode)
        self._pedal = self.env_config.action_mode == "pedal"
        self.single_observation_space = spaces.Box(self._b.obs_low, self._b.obs_high,
                                                   dtype=np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._needs_reset = np.zeros(self.num_envs, dtype=bool)
        self._renderer = None
        self._mask = np.ones(self.num_envs, dtype=bool)
        self._action_shape = (self.num_envs, 2 if self._pedal else 3)
        self._finite = np.zeros(self._action_shape, dtype=bool)

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        if isinstance(seed, list | tuple):
            # one generator draws every car's start: a list can only name that one seed
            distinct = set(seed)
            if len(distinct) > 1:
                raise ValueError(
                    f"reset(seed={list(seed)!r:.80}): the cars' starts come from one generator; "
                    "give one int seed (or a list of one seed repeated)")
            seed = next(iter(distinct), None)
        self._np_random, self._np_random_seed = gymnasium.utils.seeding.np_random(seed)
        b = self._b
        opts = ResetOptions.parse(options)
        for c in range(self.num_envs):
            b.reset_car(c, self._np_random, opts)
        b.run()
        b.integrate[:] = 1
        self._needs_reset[:] = False
        return b.obs.copy(), self._infos()

    def step(self, actions):
        # Lean on purpose: the Python side was ~60-100 us of a 64-car step (~1/3 of it once the
        # kernel was fast); method calls (nonzero, fill) instead of NumPy's wrapper functions.
        b = self._b
        if type(actions) is not np.ndarray or actions.dtype.kind not in _REAL_KINDS:
            actions = _as_array(actions, self._action_shape)
        if actions.shape != self._action_shape:
            raise _bad_action(actions, self._action_shape)
        acts = b.actions
        if self._pedal:
            if not np.isfinite(actions).all():
                raise _bad_action(actions, self._action_shape)
            pedal_controls(actions, acts)
        else:
            try:
                acts[:] = actions
            except (TypeError, ValueError):
                raise _bad_action(actions, self._action_shape) from None
            if not np.isfinite(acts, out=self._finite).all():
                raise _bad_action(actions, self._action_shape)
        if self._needs_reset.any():
            b.reset_cars(self._needs_reset.nonzero()[0], self.np_random)
        b.run()
        b.integrate.fill(1)
        out = b.out
        lap = out[:, K.O_LAP_TIME]
        for c in (lap == lap).nonzero()[0].tolist():
            b.record_lap(c, float(lap[c]))
        term_code = out[:, K.O_TERM]
        terminated = term_code > 0
        truncated = out[:, K.O_TRUNC] > 0.5
        ended = terminated | truncated
        for c in ended.nonzero()[0].tolist():
            code = int(term_code[c])
            b.termination[c] = TERMINATIONS[code] if code else "max_steps"
        self._needs_reset = ended
        return b.obs.copy(), out[:, K.O_REWARD].copy(), terminated, truncated, self._infos()

    def _infos(self) -> dict[str, Any]:
        b = self._b
        st = b.state
        # One gather for the state columns (rows of a fresh array, contiguous), not 4 copies.
        damage, dist, s, lat, vx, vy, off, d_grip = st.T[_INFO_COLS]
        info = {
            "lap_times_s": b.lap_times.copy(),
            "lap_damage": b.lap_damage.copy(),
            "last_lap_s": b.last_lap.copy(),
            "best_lap_s": b.best_lap.copy(),
            "laps": b.laps.copy(),
            "damage": damage,
            "distance_m": dist,
            "s_m": s,
            "lateral_m": lat,
            "speed_mps": np.hypot(vx, vy),
            "off_track": off > 0.5,
            "termination": b.termination.copy(),
            "grip_scale": b.base_grip * (1.0 + d_grip),
            "rewards": R.RewardParts(b.reward_weights, b.reward_in.copy()),
        }
        mask = self._mask
        for key in _INFO_KEYS:
            info["_" + key] = mask
        return info

    def render(self):
        return _render_frame(self)

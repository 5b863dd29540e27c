"""Traffic while training: one learning car among follower bots, with the opponent sensors.

:class:`TrafficEnv` is ``FormulaRacing-v0`` with company: the learner's telemetry, reward, ends
and ``info`` are the single env's (its own ``_Batch`` keeps the lap book-keeping; the race step
moves the cars), its observation gets the 36 opponent sectors appended, and ``bots`` followers
on the min-curvature line start around it (alternately ahead and behind, ``gap_m`` apart
along the track, drawn from the episode's seed) so that it has to pass, defend and not hit
them. A bot that spins or stops leaves the track. ``info`` adds ``contact_kj`` (impact energy
between the learner and the bots this step) and ``position`` (the learner's place among the
cars on the track by race distance, 1 = ahead of all).

With ``bots = 0`` the learner drives exactly as in ``FormulaRacing-v0``
(tests/test_race_traffic.py). A run with ``schedule.traffic_bots`` trains in it and is tested in
it without bots (``training.envs.RunEnvs`` builds it; users can make it by its Gymnasium id
``FormulaRacingTraffic-v0``); its actor takes the opponent block (telemetry + 36 values), which
races recognise. It lives in ``bots``, with the bots it fields, so that ``training`` imports it
downward.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from formula_tourney.bots.race_bot import race_bot
from formula_tourney.errors import UserInputError
from formula_tourney.sim import kernels as K
from formula_tourney.sim.catalog import load_track
from formula_tourney.sim.config import EnvConfig, EnvSettings, ResetOptions
from formula_tourney.sim.env import TERMINATIONS, InvalidActionError, _Batch
from formula_tourney.sim.multicar import lockstep_kernels as RK
from formula_tourney.sim.multicar.simulator import ContactSettings, RaceSim

BOT_PATIENCE_S = 5.0


class TrafficEnv(gymnasium.Env):
    """One learning car and ``bots`` follower bots on one track (see the module docstring)."""

    metadata = {"render_modes": [], "render_fps": 5}

    def __init__(self, config: Mapping[str, Any] | EnvConfig | None = None, bots: int = 3,
                 opponents: bool = True, contact: ContactSettings | None = None,
                 gap_m: tuple[float, float] = (30.0, 150.0)) -> None:
        if not isinstance(bots, int) or not 0 <= bots <= 19:
            raise UserInputError(f"bots: expected 0..19, got {bots!r}")
        if not 0.0 < gap_m[0] <= gap_m[1]:
            raise UserInputError(f"gap_m: expected 0 < low <= high, got {gap_m}")
        cfg = EnvConfig.parse(config)
        track = cfg.track if not isinstance(cfg.track, str) else load_track(cfg.track)
        cfg = cfg.model_copy(update={"track": track})
        self._b = _Batch(1, cfg)
        self.track = track
        self.config = self._b.config
        self.env_config = self._b.env_config
        self.n_bots = bots
        self.gap_m = (float(gap_m[0]), float(gap_m[1]))
        self.opponents = bool(opponents)
        shared = EnvSettings(**{k: getattr(cfg, k) for k in EnvSettings.model_fields})
        self._bots = [race_bot("follower", track, shared, f"bot{k + 1}") for k in range(bots)]
        patience = max(int(round(BOT_PATIENCE_S / cfg.control_period_s)), 1)
        bot_cfgs = [e.config.model_copy(update={
            "terminate_off_track": False, "terminate_backwards": True, "terminate_slow": True,
            "slow_patience_steps": patience, "max_steps": 10 ** 9}) for e in self._bots]
        self.sim = RaceSim([cfg, *bot_cfgs], contact, opponents=self.opponents)
        self._drivers = [e.make_driver() for e in self._bots]
        n_obs = self.sim.obs_size[0]
        low, high = self._b.obs_low, self._b.obs_high
        if self.opponents:
            low = np.concatenate([low, np.zeros(RK.N_OPP, np.float32)])
            high = np.concatenate([high, np.ones(RK.N_OPP, np.float32)])
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self.action_space = spaces.Box(np.array([-1, 0, 0], np.float32),
                                       np.array([1, 1, 1], np.float32), dtype=np.float32)
        self.observation_names = list(self._b.names) + (
            [f"opp_{-180 + 10 * k}" for k in range(RK.N_OPP)] if self.opponents else [])
        self._n_obs = n_obs
        self._actions = np.zeros((1 + bots, 3))
        self._offset = np.zeros(1 + bots)

    def _obs(self) -> np.ndarray:
        return self.sim.observation(0, with_opponents=self.opponents)

    def _sync(self) -> None:
        self._b.state[0] = self.sim.state[0]

    def _info(self) -> dict[str, Any]:
        info = self._b.info(0)
        energy = float(self.sim.pair_energy[0].sum())
        info["contact_kj"] = energy / 1000.0
        dist = self.sim.state[:, K.ST_DIST] + self._offset
        on = self.sim.mode != RK.MODE_OUT
        info["position"] = 1 + int(np.sum(on[1:] & (dist[1:] > dist[0])))
        return info

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        b, sim = self._b, self.sim
        b.reset_car(0, self.np_random, ResetOptions.parse(options))
        sim.state[0] = b.state[0]
        sim.mode[0] = RK.MODE_PLACED
        length = self.track.length_m
        x, y = float(b.state[0, K.ST_X]), float(b.state[0, K.ST_Y])
        s0 = float(self.track.project(x, y, int(b.state[0, K.ST_IDX]))[0])
        speed = float(b.state[0, K.ST_VX])
        self._offset[:] = 0.0
        reach = {1.0: 0.0, -1.0: 0.0}  # how far ahead / behind the last bot was put
        for k in range(self.n_bots):
            side = 1.0 if k % 2 == 0 else -1.0
            reach[side] += float(self.np_random.uniform(*self.gap_m))
            sim.place(1 + k, (s0 + side * reach[side]) % length, 0.0, speed)
            self._offset[1 + k] = side * reach[side]
        sim.step()
        self._sync()
        for k, d in enumerate(self._drivers):
            d.reset(sim.observation(1 + k), sim.opp[1 + k])
        return self._obs(), self._info()

    def step(self, action):
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (3,) or not np.isfinite(a).all():
            raise InvalidActionError(f"action: expected 3 finite numbers (steer, throttle, "
                                     f"brake), got {np.array2string(a, threshold=6)}")
        sim, b = self.sim, self._b
        self._actions[0] = a
        for k, d in enumerate(self._drivers):
            c = 1 + k
            if sim.mode[c] == RK.MODE_DRIVING:
                self._actions[c] = d.act(sim.observation(c), sim.opp[c], sim.state[c])
        sim.step(self._actions)
        self._sync()
        out = sim.out[0]
        lap = out[K.O_LAP_TIME]
        if lap == lap:
            b.record_lap(0, float(lap))
        for c in range(1, sim.n):
            if sim.mode[c] == RK.MODE_DRIVING and sim.out[c, K.O_TERM] > 0:
                sim.remove(c)
        code = int(out[K.O_TERM])
        terminated = code > 0
        truncated = bool(out[K.O_TRUNC] > 0.5)
        if terminated or truncated:
            b.termination[0] = TERMINATIONS[code] if code else "max_steps"
        return self._obs(), float(out[K.O_REWARD]), terminated, truncated, self._info()

"""N cars on one track that can touch and see each other: the simulator side of a race.

:class:`RaceSim` holds the arrays of :func:`lockstep_kernels.step_race` and nothing of a race's
rules (grid, laps to go, classification: ``formula_tourney.race``). Each car brings its own env
configuration, because entrants were trained against different reference lines, with or
without LAC: every car gets the geometry block of its own line and its own config row, built by
the env's own code (:class:`sim.env._Batch`), so its telemetry is exactly what the single env
would give it. What the cars share must agree (track, car, control period, physics rate, grass
width, LAC distances); a mismatch is a :class:`UserInputError` naming the car.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from formula_tourney.errors import UserInputError
from formula_tourney.sim import kernels as K
from formula_tourney.sim.car import set_start
from formula_tourney.sim.catalog import load_track
from formula_tourney.sim.config import EnvConfig
from formula_tourney.sim.env import _Batch
from formula_tourney.sim.multicar import lockstep_kernels as RK
from formula_tourney.sim.track import Track

OPPONENT_NAMES: tuple[str, ...] = tuple(f"opp_{-180 + 10 * k}" for k in range(RK.N_OPP))
"""Names of the opponent block: sector ``opp_<a>`` covers bearings [a, a + 10) deg, left > 0."""

# The geometry columns a car's own config fills (its reference line, and the limit speeds its
# reward's overspeed term reads): cars may differ in them, each distinct set is one layer.
_CAR_COLS = (K.G_REF_OFF, K.G_REF_H, K.G_REF_K, K.G_VLIM)
_SHARED_CFG = (K.C_DT, K.C_NSUB, K.C_GRASS_W, K.C_LENGTH, K.C_ELEV)


class ContactSettings(BaseModel):
    """How cars touch: rigid boxes with restitution, friction and damage from impact energy."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    enabled: bool = Field(True, description="cars collide; false: they pass through each other "
                                            "(the vector env's behaviour)")
    restitution: float = Field(0.2, ge=0.0, le=1.0, description="share of the closing speed "
                               "along the contact normal given back (0 plastic, 1 elastic)")
    friction: float = Field(0.5, ge=0.0, le=2.0, description="Coulomb friction between bodies "
                            "(the same as the wall's)")
    damage_per_kj: float = Field(20.0, ge=0.0, description="damage points per kJ of impact "
                                 "energy, half to each car (a 10 m/s closing hit between two "
                                 "1150 kg cars removes ~27.6 kJ: ~276 points each)")

    def array(self) -> np.ndarray:
        """The kernel's ``ct`` row."""
        ct = np.zeros(RK.N_CONTACT)
        ct[RK.CT_ON] = 1.0 if self.enabled else 0.0
        ct[RK.CT_RESTITUTION] = self.restitution
        ct[RK.CT_FRICTION] = self.friction
        ct[RK.CT_DAMAGE_PER_J] = self.damage_per_kj / 1000.0
        return ct


class RaceSim:
    """N cars, each with its own env config, stepped together by one compiled call."""

    def __init__(self, configs: Sequence[Mapping[str, Any] | EnvConfig],
                 contact: ContactSettings | None = None, opponents: bool = True) -> None:
        if not configs:
            raise UserInputError("a race needs at least one car")
        parsed = [EnvConfig.parse(c, source=f"car {i + 1} config") for i, c in enumerate(configs)]
        first = parsed[0].track
        track = first if isinstance(first, Track) else load_track(first)
        for i, cfg in enumerate(parsed):
            other = cfg.track if isinstance(cfg.track, Track) else None
            if other is None and cfg.track != first:
                raise UserInputError(f"car {i + 1}: track {cfg.track!r} is not the race's "
                                     f"track {first!r}")
            if other is not None and other is not track and other.name != track.name:
                raise UserInputError(f"car {i + 1}: track {other.name!r} is not the race's "
                                     f"track {track.name!r}")
        for i, cfg in enumerate(parsed):
            # Per-episode grip is drawn per car at an env reset, which a race does not do.
            varying = [k for k in ("grip_scale_range", "grip_drying")
                       if getattr(cfg, k, None) is not None]
            if varying:
                raise UserInputError(f"car {i + 1}: {', '.join(varying)} is not supported in "
                                     "races yet (a race runs at one grip: set grip_scale)")
        batches = [_Batch(1, cfg.model_copy(update={"track": track})) for cfg in parsed]
        b0 = batches[0]
        track_cols = [k for k in range(K.N_GEOM) if k not in _CAR_COLS]
        for i, b in enumerate(batches[1:], start=2):
            what = None
            if not np.array_equal(b.params, b0.params) or not np.array_equal(b.torque,
                                                                              b0.torque):
                what = "car"
            elif not np.array_equal(b.cfg[list(_SHARED_CFG)], b0.cfg[list(_SHARED_CFG)]):
                what = "control period, physics rate or grass width"
            elif not np.array_equal(b.geom[:, track_cols], b0.geom[:, track_cols]):
                what = "track surfaces (grip_scale)"
            elif not np.array_equal(b.lac_d, b0.lac_d):
                what = "lac_distances_m"
            if what:
                raise UserInputError(f"car {i}: its {what} differs from car 1's; cars in one "
                                     "race share them")
        self.track = track
        self.car = b0.car
        self.configs = [b.env_config for b in batches]
        self.n = len(batches)
        self.period_s = b0.period_s
        self.grass_w = b0.grass_w
        self.params, self.torque, self.gears = b0.params, b0.torque, b0.gears
        self.elev = b0.elev
        self.lac_d = b0.lac_d
        # One geometry layer per distinct reference line (and limit speeds).
        layers: list[np.ndarray] = []
        keys: list[bytes] = []
        ref_of_car = []
        for b in batches:
            key = b.geom[:, list(_CAR_COLS)].tobytes()
            if key not in keys:
                keys.append(key)
                layers.append(b.geom)
            ref_of_car.append(keys.index(key))
        self.geoms = np.ascontiguousarray(np.stack(layers))
        self.ref_of_car = np.array(ref_of_car, dtype=np.int64)
        self.cfgs = np.ascontiguousarray(np.stack([b.cfg for b in batches]))
        self.names = [list(b.names) for b in batches]
        self.obs_size = [len(nm) for nm in self.names]
        self.contact = contact or ContactSettings()
        self.ct = self.contact.array()
        self.with_opponents = bool(opponents)
        n = self.n
        self.state = np.zeros((n, K.N_STATE))
        self.actions = np.zeros((n, 3))
        self.mode = np.full(n, RK.MODE_OUT, dtype=np.uint8)
        self.obs = np.zeros((n, max(self.obs_size)), dtype=np.float32)
        self.out = np.zeros((n, K.N_OUT))
        self.scratch = np.zeros((n, RK.N_SCRATCH))
        self.near = np.zeros(n, dtype=np.uint8)
        self.pair_touch = np.zeros((n, n))
        self.pair_energy = np.zeros((n, n))
        self.pair_blame = np.zeros((n, n))
        self.opp = np.ones((n, RK.N_OPP))

    def place(self, c: int, s_m: float, lateral_m: float = 0.0, speed_mps: float = 0.0,
              heading_offset_rad: float = 0.0) -> None:
        """Put car ``c`` at track position ``s_m``, ``lateral_m`` left of the centreline,
        rolling along the track at ``speed_mps``; the next :meth:`step` only observes it."""
        x, y, h = self.track.pose_at(float(s_m), float(lateral_m))
        set_start(self.state[c], self.car, float(x), float(y), float(h) + heading_offset_rad,
                  float(speed_mps))
        self.state[c, K.ST_IDX] = int(self.track.index_at(float(s_m)))
        self.mode[c] = RK.MODE_PLACED

    def remove(self, c: int) -> None:
        """Car ``c`` leaves the track (finished or retired): not driven, touched or seen."""
        self.mode[c] = RK.MODE_OUT

    def step(self, actions: np.ndarray | None = None) -> None:
        """One control period for every driving car (placed cars are located and observed,
        then drive from the next step on). ``actions``: ``(n, 3)`` finite (steer, throttle,
        brake); rows of cars that are not driving are ignored."""
        if actions is not None:
            a = np.asarray(actions, dtype=np.float64)
            if a.shape != (self.n, 3):
                raise UserInputError(f"race actions: expected shape ({self.n}, 3), got "
                                     f"{a.shape}")
            driving = self.mode == RK.MODE_DRIVING
            if not np.isfinite(a[driving]).all():
                raise UserInputError("race actions: every value must be a finite number")
            self.actions[:] = a
        RK.step_race(self.state, self.actions, self.mode, self.params, self.torque, self.gears,
                     self.geoms, self.ref_of_car, self.elev, self.cfgs, self.lac_d, self.obs,
                     self.out, self.scratch, self.near, self.ct, self.pair_touch, self.pair_energy,
                     self.pair_blame, self.opp, self.with_opponents)
        self.mode[self.mode == RK.MODE_PLACED] = RK.MODE_DRIVING

    def observation(self, c: int, with_opponents: bool = False) -> np.ndarray:
        """Car ``c``'s telemetry as its own env gives it, plus the opponent block if asked."""
        own = self.obs[c, :self.obs_size[c]]
        if not with_opponents:
            return own.copy()
        return np.concatenate([own, self.opp[c].astype(np.float32)])

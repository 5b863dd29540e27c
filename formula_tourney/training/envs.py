"""One way to build the env of a run: training, tests, ``eval`` and ``replay`` all come here.

The observation depends on the reference line, LAC and the env settings a model was trained
with, so an env built for a checkpoint must be built from the checkpoint's run spec exactly as
training built it (a replay built on its own once drove another line than training had).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import gymnasium
import numpy as np
from gymnasium.wrappers import OrderEnforcing

from formula_tourney.bots.line_offsets import reference_offsets
from formula_tourney.bots.traffic_env import TrafficEnv
from formula_tourney.errors import UserInputError
from formula_tourney.lines.limit import reference_limit_s, reference_limit_speeds_mps
from formula_tourney.sim.catalog import load_track
from formula_tourney.sim.config import EnvConfig
from formula_tourney.sim.track import Track
from formula_tourney.training.curriculum import braking_starts
from formula_tourney.training.run_spec import RunSpec

ENV_ID = "FormulaRacing-v0"


def reference_line(track: Track, kind: str, spec: RunSpec) -> Any:
    """The env's ``reference_line``: "centre", or the offsets of the recorded/mincurv line for
    the run's own car (a changed grip or mass gives another recorded line)."""
    if kind == "centre":
        return "centre"
    car = spec.env.car_params()
    return np.asarray(reference_offsets(track, kind, car), dtype=np.float64)


class RunEnvs:
    """Tracks and reference lines of one run, loaded once, and the envs built from them.

    ``extra_tracks`` adds tracks the run was not trained or tested on (``eval``/``replay`` on an
    unseen track); ``reference`` replaces the spec's line kind (``eval --reference``).
    """

    def __init__(
        self, spec: RunSpec, extra_tracks: Iterable[str] = (), reference: str | None = None
    ) -> None:
        self.spec = spec
        self.reference = reference or spec.reference
        names = [*spec.train_tracks, *spec.test_tracks, *extra_tracks]
        self.tracks: dict[str, Track] = {name: load_track(name) for name in dict.fromkeys(names)}
        self.lines = {
            name: reference_line(track, self.reference, spec) for name, track in self.tracks.items()
        }
        self._limits: dict[tuple[str, float], float] = {}
        self._limit_speeds: dict[tuple[str, float], tuple[float, ...]] = {}

    def config(self, track: str, *, test: bool, max_steps: int | None = None,
               grip_scale: float | None = None) -> EnvConfig:
        """The full env config for ``track``: training episodes start at random places and run
        ``schedule.max_steps``; tests start where the caller puts the car and run
        ``schedule.test_max_steps`` (or ``max_steps``). A test drives at one fixed grip,
        ``grip_scale`` (default the env's), so its lap reads against one reference limit: a
        grip range or a drying track applies to training episodes only."""
        schedule = self.spec.schedule
        steps = max_steps or (schedule.test_max_steps if test else schedule.max_steps)
        env = {k: getattr(self.spec.env, k) for k in type(self.spec.env).model_fields}
        if test:
            env.update(grip_scale_range=None, grip_drying=None, start_curriculum="none",
                       start_curriculum_speed=0.0,
                       grip_scale=self.spec.env.grip_scale if grip_scale is None else grip_scale)
        elif self.spec.env.start_curriculum == "braking":
            env["curriculum_starts_m"] = self.curriculum_starts(track)
        if self.spec.env.overspeed_crash_weight > 0.0 or env["start_curriculum_speed"] > 0.0:
            env["limit_speeds_mps"] = self.limit_speeds(track, env["grip_scale"])
        # parse, not construct: a grip given here (``eval --grip``) is checked like any env key
        return EnvConfig.parse({
            **env,
            "track": self.tracks[track], "reference_line": self.lines[track],
            "lac": self.spec.lac, "max_steps": steps,
            "random_start": False if test else schedule.random_start,
        }, f"{'test ' if test else ''}env of {track}")  # fmt: skip

    def curriculum_starts(self, track: str) -> tuple[float, ...]:
        """The start curriculum's positions on ``track``: before the braking zones of the QSS
        profile of the run's reference line for its car (``training.curriculum``)."""
        return braking_starts(self.tracks[track], self.line_offsets(track),
                              self.spec.env.car_params())  # fmt: skip

    def line_offsets(self, track: str) -> np.ndarray | float:
        """The run's reference line on ``track`` as lateral offsets from the centreline (m; 0:
        the centre line), as the QSS profile (``lines.speed_profile``) takes it."""
        line = self.lines[track]
        return 0.0 if isinstance(line, str) else line

    def limit_speeds(self, track: str, grip_scale: float) -> tuple[float, ...]:
        """The reference limit's speed at each sample of ``track`` at ``grip_scale``, which the
        reward's overspeed crash term reads; computed once per track and grip."""
        key = (track, float(grip_scale))
        if key not in self._limit_speeds:
            car = self.spec.env.car_params()
            speeds = reference_limit_speeds_mps(self.tracks[track], car, grip_scale)
            self._limit_speeds[key] = tuple(float(v) for v in speeds)
        return self._limit_speeds[key]

    def test_limit_s(self, track: str, grip_scale: float) -> float:
        """The reference limit of ``track`` at ``grip_scale`` for the tests table, computed once
        per track and grip; nan for a run that tests at its own grip only (the part's baselines
        carry that limit, and a job need not compute the min-curvature line)."""
        if len(self.spec.test_grips) < 2 or not math.isfinite(grip_scale):
            return math.nan
        key = (track, float(grip_scale))
        if key not in self._limits:
            car = self.spec.env.car_params()
            self._limits[key] = reference_limit_s(self.tracks[track], car, grip_scale)
        return self._limits[key]

    def make(
        self,
        track: str,
        *,
        test: bool,
        max_steps: int | None = None,
        render_mode: str | None = None,
        grip_scale: float | None = None,
    ) -> gymnasium.Env:
        """A FormulaRacing-v0 env for ``track`` (through gymnasium.make, as users build it).

        A run with ``schedule.traffic_bots`` trains among that many bots in TrafficEnv and
        tests there with none: alone, as every run is tested, but with the observation (the
        opponent block) its actor was trained on."""
        config = self.config(track, test=test, max_steps=max_steps, grip_scale=grip_scale)
        bots = self.spec.schedule.traffic_bots
        if bots:
            if render_mode is not None:
                raise UserInputError(f"{track}: a run trained in traffic has no {render_mode!r} "
                                     "render mode; race it with `formula-tourney race --gif`")
            # the wrapper gymnasium.make puts around FormulaRacing-v0: one stack for every run
            return OrderEnforcing(TrafficEnv(config, bots=0 if test else bots))
        return gymnasium.make(
            ENV_ID, config=config, render_mode=render_mode, disable_env_checker=True
        )

    def make_vector(self, track: str, cars: int) -> gymnasium.vector.VectorEnv:
        """``cars`` training cars on ``track`` in one FormulaRacingVectorEnv (through
        ``gymnasium.make_vec`` and the id's vector entry point; next-step autoreset), with the
        training config of :meth:`config`."""
        if self.spec.schedule.traffic_bots:  # RunSpec refuses cars > 1 with traffic
            raise ValueError("a run with traffic_bots drives one car: no vector env")
        config = self.config(track, test=False)
        return gymnasium.make_vec(
            ENV_ID, num_envs=cars, vectorization_mode="vector_entry_point", config=config
        )

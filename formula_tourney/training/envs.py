"""One way to build the env of a run: training, tests, ``eval`` and ``replay`` all come here.

The observation depends on the reference line, LAC and the env settings a model was trained
with, so an env built for a checkpoint must be built from the checkpoint's run spec exactly as
training built it (issue 10: the replay used to drive another line than training had).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import gymnasium
import numpy as np

from formula_tourney.bots.reference import reference_offsets
from formula_tourney.sim.catalog import load_track
from formula_tourney.sim.config import EnvConfig
from formula_tourney.sim.track import Track
from formula_tourney.training.spec import RunSpec

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

    def config(self, track: str, *, test: bool, max_steps: int | None = None) -> EnvConfig:
        """The full env config for ``track``: training episodes start at random places and run
        ``schedule.max_steps``; tests start where the caller puts the car and run
        ``schedule.test_max_steps`` (or ``max_steps``)."""
        schedule = self.spec.schedule
        steps = max_steps or (schedule.test_max_steps if test else schedule.max_steps)
        return EnvConfig(
            **{k: getattr(self.spec.env, k) for k in type(self.spec.env).model_fields},
            track=self.tracks[track], reference_line=self.lines[track], lac=self.spec.lac,
            max_steps=steps, random_start=False if test else schedule.random_start,
        )  # fmt: skip

    def make(
        self,
        track: str,
        *,
        test: bool,
        max_steps: int | None = None,
        render_mode: str | None = None,
    ) -> gymnasium.Env:
        """A FormulaRacing-v0 env for ``track`` (through gymnasium.make, as users build it)."""
        config = self.config(track, test=test, max_steps=max_steps)
        return gymnasium.make(
            ENV_ID, config=config, render_mode=render_mode, disable_env_checker=True
        )

    def make_vector(self, track: str, cars: int) -> gymnasium.vector.VectorEnv:
        """``cars`` training cars on ``track`` in one FormulaRacingVectorEnv (through
        ``gymnasium.make_vec`` and the id's vector entry point; next-step autoreset), with the
        training config of :meth:`config`."""
        config = self.config(track, test=False)
        return gymnasium.make_vec(
            ENV_ID, num_envs=cars, vectorization_mode="vector_entry_point", config=config
        )

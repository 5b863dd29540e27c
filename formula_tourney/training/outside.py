"""An outside entrant checked on its run's own spaces before the run (or tournament) starts.

``agents.outside.check`` proves an entrant can act given the spaces; this module knows where
the spaces come from: the run's first train env (its observation with the setup's LAC and
sensors, its action box, ``schedule.cars``), built once and closed. ``train`` and the
tournament planner call :func:`check_outside` for every outside run specification, so a broken
class, setting or action fails in one line, exit 2, with nothing written. A trained outside
model is read back for ``eval``, ``replay`` and races by :func:`load_outside_model`, through
the entrant's own loader, and driven as :class:`OutsideModel`.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from formula_tourney.agents.outside.check import action_problem, check_entrant, entrant_class
from formula_tourney.agents.protocol import Entrant, EntrantSpaces
from formula_tourney.errors import UserInputError
from formula_tourney.training.envs import RunEnvs
from formula_tourney.training.run_spec import RunSpec


def run_spaces(spec: RunSpec) -> EntrantSpaces:
    """What the loop will build the run's entrant for: one car's observation and action."""
    env = RunEnvs(spec).make(spec.train_tracks[0], test=False)
    try:
        obs_dim = int(np.prod(env.observation_space.shape))
        low = np.asarray(env.action_space.low, np.float32).reshape(-1)
        high = np.asarray(env.action_space.high, np.float32).reshape(-1)
    finally:
        env.close()
    return EntrantSpaces(obs_dim=obs_dim, action_dim=len(low), action_low=low, action_high=high,
                         cars=spec.schedule.cars)  # fmt: skip


def check_outside(spec: RunSpec, source: str) -> str | None:
    """The outside entrant's label once it acted on zeros in the run's spaces; None for one of
    our families. UserInputError naming ``source`` otherwise."""
    if spec.outside is None:
        return None
    return check_entrant(spec.outside, run_spaces(spec), spec.seed, source)


class OutsideModel:
    """An outside entrant's saved model as tests, ``eval``, ``replay`` and races drive ours:
    ``obs_dim``, ``cfg.window`` and a greedy ``act_eval`` of one window, each action checked."""

    def __init__(self, entrant: Entrant, spaces: EntrantSpaces, source: str) -> None:
        self.entrant = entrant
        self.label = str(entrant.label)
        self.obs_dim = spaces.obs_dim
        self.cfg = SimpleNamespace(window=int(entrant.window))
        self.updates = int(getattr(entrant, "updates", 0))
        self._one_car = replace(spaces, cars=1)
        self._source = source

    def act_eval(self, window: np.ndarray) -> np.ndarray:
        """The entrant's greedy ``act`` on a batch of one window."""
        action = np.asarray(self.entrant.act(np.asarray(window, np.float32)[None]))
        problem = action_problem(action, self._one_car)
        if problem:
            raise UserInputError(f"{self._source}: {self.label}: act() {problem}")
        return action[0]

    act = act_eval


def load_outside_model(path: Path, spec: RunSpec, device: str = "cpu") -> OutsideModel:
    """The model at ``path``, written by the outside entrant ``spec`` trained, read by that
    entrant's own loader (``cls.load``; SB3's load for the adapter). Only the caller decides the
    file is a job's (``training.checkpoint``): an SB3 file is unpickled in part."""
    assert spec.outside is not None
    source = f"model {path}"
    cls, _settings = entrant_class(spec.outside, source)
    try:
        entrant = cls.load(Path(path), device)
    except UserInputError:
        raise
    except Exception as err:  # noqa: BLE001 - outside code: its loader's failure is one line
        raise UserInputError(
            f"{source}: {spec.outside.label()} could not load it: {type(err).__name__}: "
            f"{' '.join(str(err).split())[:300]}"
        ) from None
    return OutsideModel(entrant, run_spaces(spec), source)

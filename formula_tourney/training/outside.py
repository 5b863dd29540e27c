"""An outside entrant checked on its run's own spaces before the run (or tournament) starts.

``agents.outside.check`` proves an entrant can act given the spaces; this module knows where
the spaces come from: the run's first train env (its observation with the setup's LAC and
sensors, its action box, ``schedule.cars``), built once and closed. ``train`` and the
tournament planner call :func:`check_outside` for every outside run specification, so a broken
class, setting or action fails in one line, exit 2, with nothing written.
"""

from __future__ import annotations

import numpy as np

from formula_tourney.agents.outside.check import check_entrant
from formula_tourney.agents.protocol import EntrantSpaces
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

"""formula-tourney: deep RL drivers race a car at its grip limit from telemetry alone.

Importing the package registers the Gymnasium ids ``FormulaRacing-v0`` and
``FormulaRacingTraffic-v0`` (entry points are strings, so nothing heavy is imported until an env
is made).
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

import gymnasium

try:  # one home for the version: pyproject.toml, read back from the installed metadata
    __version__ = version("formula-tourney")
except PackageNotFoundError:  # a source tree on sys.path without an install
    __version__ = "0+unknown"

ENV_ID = "FormulaRacing-v0"

TRAFFIC_ENV_ID = "FormulaRacingTraffic-v0"
"""``bots.traffic_env.TrafficEnv``: one learner among follower bots, for users who make envs by id
(a run with ``schedule.traffic_bots`` is built by ``training.envs`` from the class itself)."""

if TRAFFIC_ENV_ID not in gymnasium.registry:
    gymnasium.register(id=TRAFFIC_ENV_ID, entry_point="formula_tourney.bots.traffic_env:TrafficEnv")

if ENV_ID not in gymnasium.registry:
    gymnasium.register(
        id=ENV_ID,
        entry_point="formula_tourney.sim.env:FormulaRacingEnv",
        vector_entry_point="formula_tourney.sim.env:FormulaRacingVectorEnv",
    )

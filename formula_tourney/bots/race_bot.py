"""The follower bot as one car among others: its env config, its line and its driver.

A race (``race.entrants``) and traffic while training (``bots.traffic_env``) field the same bot,
so it is built here, once, below both: the shared env settings with the centre line as the
simulator's reference, and the follower driving the min-curvature line for the settings' car.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from formula_tourney.bots.follower import CarState, Follower
from formula_tourney.bots.line_offsets import reference_offsets
from formula_tourney.errors import UserInputError
from formula_tourney.sim import kernels as K
from formula_tourney.sim.config import EnvConfig, EnvSettings
from formula_tourney.sim.track import Track

BOTS = ("follower",)
"""Bots a race can field (``--bots``)."""
BOT_LINE = "mincurv"


@dataclass
class BotDriver:
    """The follower bot on its line (it reads the true state and does not see other cars)."""

    name: str
    follower: Follower
    kind: str = "bot"
    sees_opponents: bool = False

    def reset(self, obs: np.ndarray, opp: np.ndarray) -> None:
        self.follower.reset()

    def act(self, obs: np.ndarray, opp: np.ndarray, state_row: np.ndarray) -> np.ndarray:
        st = CarState(float(state_row[K.ST_X]), float(state_row[K.ST_Y]),
                      float(state_row[K.ST_PSI]), float(state_row[K.ST_VX]),
                      float(state_row[K.ST_VY]), float(state_row[K.ST_R]))
        return np.asarray(self.follower.act(st), dtype=np.float64)


@dataclass(frozen=True)
class RaceBot:
    """One bot's env config and a factory of fresh drivers (each race or episode gets its own)."""

    name: str
    config: EnvConfig
    make_driver: Callable[[], BotDriver]
    source: str


def race_bot(kind: str, track: Track, settings: EnvSettings | None,
             name: str | None = None) -> RaceBot:
    """A bot on ``track`` with the shared env settings (defaults when None)."""
    if kind not in BOTS:
        raise UserInputError(f"unknown bot {kind!r}; known: {', '.join(BOTS)}")
    env = settings or EnvSettings()
    car = env.car_params()
    offsets = reference_offsets(track, BOT_LINE, car)
    fields = {k: getattr(env, k) for k in type(env).model_fields}
    # nobody reads a bot's reward: it leaves out the term that needs a run's limit speeds
    fields["overspeed_crash_weight"] = 0.0
    config = EnvConfig(**fields, track=track, reference_line="centre")
    label = name or kind

    def make() -> BotDriver:
        return BotDriver(label, Follower(track=track, offsets_m=offsets, car=car,
                                         grip_scale=env.grip_scale))
    return RaceBot(label, config, make, f"{kind} on the {BOT_LINE} line")

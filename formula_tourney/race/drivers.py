"""Who drives a race car: the driver protocol, and a trained model as a driver.

A driver is anything with ``reset(obs, opp)`` and ``act(obs, opp, state_row) -> (3,)``: a model
reads its own telemetry (plus the opponent block if it was trained with one; a model without it
drives blind to the others), a bot (``bots.race_bot.BotDriver``) reads the simulator's state as
the follower always has.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from formula_tourney.agents.buffers import ObservationWindow
from formula_tourney.sim.env import as_controls


class Driver(Protocol):
    """The race loop's view of a driver."""

    name: str
    kind: str
    sees_opponents: bool

    def reset(self, obs: np.ndarray, opp: np.ndarray) -> None: ...

    def act(self, obs: np.ndarray, opp: np.ndarray, state_row: np.ndarray) -> np.ndarray: ...


@dataclass
class ModelDriver:
    """A trained actor, greedy, fed the window of observations it was trained on."""

    name: str
    agent: Any
    sees_opponents: bool
    source: str = ""
    kind: str = "model"
    _window: ObservationWindow | None = field(default=None, init=False, repr=False)
    _stack: np.ndarray | None = field(default=None, init=False, repr=False)

    def _input(self, obs: np.ndarray, opp: np.ndarray) -> np.ndarray:
        if self.sees_opponents:
            return np.concatenate([obs, opp.astype(np.float32)])
        return obs

    def reset(self, obs: np.ndarray, opp: np.ndarray) -> None:
        self._window = ObservationWindow(self.agent.cfg.window)
        self._stack = self._window.reset(self._input(obs, opp))

    def act(self, obs: np.ndarray, opp: np.ndarray, state_row: np.ndarray) -> np.ndarray:
        assert self._window is not None, "reset() first"
        if self._stack is None:
            self._stack = self._window.push(self._input(obs, opp))
        action = as_controls(self.agent.act_eval(self._stack))  # a pedal agent's, too
        self._stack = None  # the next act pushes the observation that this action leads to
        return action


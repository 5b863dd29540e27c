"""Faulty outside entrants for tests/test_entrants_outside.py (named by impl from a tournament)."""

from __future__ import annotations

import numpy as np

from examples.tiny_sac import TinySAC


class Raises(TinySAC):
    """Acts on zeros (passes the up-front check), then raises while exploring."""

    def explore(self, windows: np.ndarray, env_steps: int) -> np.ndarray:
        raise RuntimeError("driver bug at step 0")


class ReturnsNaN(TinySAC):
    """Explores with NaN actions."""

    def explore(self, windows: np.ndarray, env_steps: int) -> np.ndarray:
        return np.full((len(windows), self.spaces.action_dim), np.nan, np.float32)


class WrongShape(TinySAC):
    """Explores with one value too many per car."""

    def explore(self, windows: np.ndarray, env_steps: int) -> np.ndarray:
        return np.zeros((len(windows), self.spaces.action_dim + 1), np.float32)


class BadAtZeros(TinySAC):
    """Fails the up-front check: its greedy action has the wrong shape."""

    def act(self, windows: np.ndarray) -> np.ndarray:
        return np.zeros(self.spaces.action_dim, np.float32)


class NotAnEntrant:
    """Has none of the protocol's members."""

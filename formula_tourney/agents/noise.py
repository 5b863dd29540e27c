"""Exploration noise: OU noise scaled by an annealed epsilon, plus the paper's brake exploration.

Paper, "Extensions / Brake exploration": the OU values are attenuated by epsilon' (1 at the start,
0 at the end of the exploration phase) and added to each of the three action dimensions
independently with probability 0.1; stochastically a stronger noise goes on the brake while the
throttle is lowered by a factor (1 - epsilon'), so exploration does not press both pedals at once.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

ACTION_LOW = np.array([-1.0, 0.0, 0.0], dtype=np.float32)
ACTION_HIGH = np.array([1.0, 1.0, 1.0], dtype=np.float32)
STEER, THROTTLE, BRAKE = 0, 1, 2
PEDAL = 1  # the pedal action mode's second axis: throttle above 0, brake below
PEDAL_LOW = np.array([-1.0, -1.0], dtype=np.float32)
PEDAL_HIGH = np.array([1.0, 1.0], dtype=np.float32)


def action_box(action_dim: int) -> tuple[np.ndarray, np.ndarray]:
    """The env's action box for an action of ``action_dim`` values: (steer, throttle, brake)
    or, in the pedal action mode (beyond the paper), (steer, pedal)."""
    if action_dim == 3:
        return ACTION_LOW, ACTION_HIGH
    if action_dim == 2:
        return PEDAL_LOW, PEDAL_HIGH
    raise ValueError(f"action_dim {action_dim}: the env's actions have 3 (paper) or 2 (pedal)")


def linear_epsilon(step: int, exploration_steps: int, floor: float = 0.0) -> float:
    """Epsilon annealed linearly from 1 at step 0 to ``floor`` at ``exploration_steps`` (then
    ``floor``); the paper's floor is 0. The line is clipped, not rescaled, so a floor leaves the
    paper's epsilon untouched while it is above the floor."""
    return float(max(floor, 1.0 - step / max(1, exploration_steps)))


class NoiseEvent(NamedTuple):
    """What exploration did on one step (for tests and TensorBoard counts)."""

    mask: np.ndarray  # bool (3,): which dimensions received OU noise
    brake_explored: bool  # the brake-exploration rule fired on this step


class OrnsteinUhlenbeck:
    """Per-dimension OU process x <- x + theta (mu - x) + sigma N(0, 1), one step per call.

    Unit time step (one control period): theta and sigma are per step, as in the TORCS DDPG code
    the paper builds on.
    """

    def __init__(
        self,
        theta: np.ndarray,
        sigma: np.ndarray,
        rng: np.random.Generator,
        mu: np.ndarray | None = None,
    ) -> None:
        self.theta = np.asarray(theta, dtype=np.float64)
        self.sigma = np.asarray(sigma, dtype=np.float64)
        self.mu = np.zeros_like(self.theta) if mu is None else np.asarray(mu, dtype=np.float64)
        self.rng = rng
        self.state = self.mu.copy()

    def reset(self) -> None:
        """Start a new episode at the mean (temporal correlation never crosses episodes)."""
        self.state = self.mu.copy()

    def sample(self) -> np.ndarray:
        self.state = (
            self.state
            + self.theta * (self.mu - self.state)
            + self.sigma * self.rng.standard_normal(self.state.shape)
        )
        return self.state.copy()


class BrakeExplorationNoise:
    """Exploration for (steer, throttle, brake) actions, or (steer, pedal) ones.

    Each step: the OU sample, scaled by epsilon, is added to each dimension with probability
    ``noise_prob``. With probability ``brake_prob`` (brake exploration) the brake is instead pulled
    towards a pressure drawn from N(brake_mean, brake_sigma) by the fraction epsilon, and the
    throttle is multiplied by (1 - epsilon) without noise: during brake exploration the throttle
    can only go down, and at epsilon = 1 it is released fully.

    With ``action_dim = 2`` (the pedal action mode, beyond the paper) the OU process runs on
    steer and pedal with the steer and throttle entries of ``ou_theta`` and ``ou_sigma``, and
    brake exploration pulls the pedal towards minus the drawn brake pressure.
    """

    def __init__(
        self,
        rng: np.random.Generator,
        ou_theta: tuple[float, float, float] = (0.15, 0.15, 0.15),
        ou_sigma: tuple[float, float, float] = (0.3, 0.3, 0.1),
        noise_prob: float = 0.1,
        brake_prob: float = 0.1,
        brake_mean: float = 0.5,
        brake_sigma: float = 0.2,
        brake_hold_steps: int = 1,
        action_dim: int = 3,
    ) -> None:
        self.rng = rng
        self.action_dim = int(action_dim)
        self.low, self.high = action_box(self.action_dim)
        self.brake_hold_steps = int(brake_hold_steps)
        self._hold_left = 0
        self._hold_target = 0.0
        dims = slice(0, self.action_dim)
        self.ou = OrnsteinUhlenbeck(np.asarray(ou_theta)[dims], np.asarray(ou_sigma)[dims], rng)
        self.noise_prob = noise_prob
        self.brake_prob = brake_prob
        self.brake_mean = brake_mean
        self.brake_sigma = brake_sigma

    def reset(self) -> None:
        self.ou.reset()
        self._hold_left = 0

    def state_dict(self) -> dict[str, Any]:
        """The OU state, a held brake exploration and the generator's state (plain values):
        what a resumed run needs to draw the same noise."""
        return {
            "ou": self.ou.state.copy(),
            "hold_left": self._hold_left,
            "hold_target": float(self._hold_target),
            "rng": self.rng.bit_generator.state,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.ou.state = np.asarray(state["ou"], dtype=np.float64).copy()
        self._hold_left = int(state["hold_left"])
        self._hold_target = float(state["hold_target"])
        self.rng.bit_generator.state = state["rng"]

    def __call__(self, action: np.ndarray, epsilon: float) -> tuple[np.ndarray, NoiseEvent]:
        """Return the explored action (clipped to the action box) and what was done."""
        action = np.asarray(action, dtype=np.float64)
        ou = self.ou.sample()  # advance every step so correlation does not depend on epsilon
        mask = self.rng.random(self.action_dim) < self.noise_prob
        brake_explored = bool(self.rng.random() < self.brake_prob) and epsilon > 0.0
        if epsilon <= 0.0:
            return action.astype(np.float32), NoiseEvent(np.zeros(self.action_dim, bool), False)
        out = action + epsilon * ou * mask
        if self.brake_hold_steps > 1:
            # beyond the paper: a fired brake exploration is held for a drawn number of steps,
            # since a hairpin needs 8-13 steps of braking that single-step events never show
            # (benchmarks/braking_exploration.py); the paper's rule is hold = 1
            if self._hold_left > 0:
                self._hold_left -= 1
                brake_explored = True
            elif brake_explored:
                self._hold_left = int(self.rng.integers(self.brake_hold_steps))
                self._hold_target = self.brake_mean + self.brake_sigma * self.rng.standard_normal()
        if brake_explored:
            target_brake = (
                self._hold_target
                if self.brake_hold_steps > 1
                else self.brake_mean + self.brake_sigma * self.rng.standard_normal()
            )
            mask = mask.copy()
            if self.action_dim == 2:  # the pedal pulled towards the brake side
                out[PEDAL] = action[PEDAL] + epsilon * (-target_brake - action[PEDAL])
                mask[PEDAL] = False
            else:
                out[BRAKE] = action[BRAKE] + epsilon * (target_brake - action[BRAKE])
                out[THROTTLE] = action[THROTTLE] * (1.0 - epsilon)
                mask[THROTTLE] = False
        out = np.clip(out, self.low, self.high).astype(np.float32)
        return out, NoiseEvent(mask, brake_explored)

"""The entrant protocol: what the training loop, tests, races and replays need of a driver.

An *entrant* is anything that can be trained by ``training.loop`` and then drive: our own
families (``agents.family_entrant.FamilyEntrant`` wraps an ``agents.core.Agent`` with its replay
buffer, exploration noise and update credit) and outside agents (an adapter around a
Stable-Baselines3 model, a class named ``"package.module:Class"`` in a tournament file, an entry
point of the group ``formula_tourney.entrants``). The loop owns the envs, the tests, the tables
and the job folder; the entrant owns everything it learns with. Keeping that line here, in one
small module without torch, lets an outside package implement the interface by duck typing,
and lets the loop check it with ``isinstance(x, Entrant)`` (the protocol is runtime-checkable:
that check looks at the members' presence, not their signatures).

Optional members the loop uses where an entrant has them (ours do; an outside one may skip
them): ``updates`` (gradient updates so far: the episodes table's ``updates``, else 0),
``epsilon`` (the exploration schedule's value: its ``epsilon`` column, else NaN),
``saves_metadata = True`` with ``save(path, extra=...)`` (checkpoints that carry the run
specification for ``eval`` and ``replay``), and ``use_demonstrations(buffer, demo_rows,
bc_weight, bc_q_filter, warm_start)`` (a run with demonstrations; without it such a run fails
with a reason naming the entrant).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
import pydantic


@dataclass(frozen=True)
class EntrantSpaces:
    """What an entrant is built for: one car's observation and action, and how many cars feed it.

    The loop derives it from the run's env before building the entrant, so an entrant never
    needs to know a track or an env class (``agents`` knows no track).
    """

    obs_dim: int
    """Values of one observation (one step; a window is ``window`` of these)."""
    action_dim: int
    """3 (steer, throttle, brake), or 2 in pedal mode."""
    action_low: np.ndarray
    """``(action_dim,)`` float32: the lowest action the env accepts, per component."""
    action_high: np.ndarray
    """``(action_dim,)`` float32: the highest action the env accepts, per component."""
    cars: int
    """Cars stepping in parallel (lanes): ``act``/``explore`` get one window per car."""


@dataclass(frozen=True)
class Transition:
    """One car's step, as the loop saw it (the observations are single steps, not windows).

    Single steps keep the loop independent of how an entrant stores history: our replay buffer
    rebuilds windows from consecutive steps of a car's lane, an outside agent may keep none.
    """

    car: int
    """The car (lane) that made the step, ``0 <= car < spaces.cars``."""
    obs: np.ndarray
    """``(obs_dim,)`` float32: the observation the action was taken on."""
    action: np.ndarray
    """``(action_dim,)`` float32: the action the env applied."""
    reward: float
    """The reward to learn from (the run's reward rule already applied)."""
    next_obs: np.ndarray
    """``(obs_dim,)`` float32: the observation after the step (the episode's last if it ended)."""
    terminated: bool
    """The episode ended in a terminal state (no bootstrap)."""
    truncated: bool
    """The episode was cut off (time limit): the next state is not terminal."""


@runtime_checkable
class Entrant(Protocol):
    """What the training loop, tests, races and replays need of a driver.

    Call order in one training run: ``settings_model()`` validates the settings before any job
    starts; ``build`` once; then per loop step ``episode_started`` for each car whose episode
    began, ``explore`` (or ``act`` in tests), ``observe`` with the step's stored transitions,
    ``update`` once; ``save`` at tests and at the end; ``training_state`` /
    ``restore_training_state`` when a job is checkpointed and resumed. Every array an entrant
    returns is checked by the loop (shape ``(cars, action_dim)``, finite), so a faulty outside
    entrant fails its job with a reason rather than crashing an env.
    """

    label: str
    """Who this is, for tables and messages: ``"WIN1 (ddpg)"``, ``"sb3 2.9.2 SAC"``, ..."""
    window: int
    """Observation steps the policy reads (1 for most outside agents)."""

    @classmethod
    def settings_model(cls) -> type[pydantic.BaseModel]:
        """The pydantic model of this entrant's settings: validated before anything runs."""
        ...

    @classmethod
    def build(
        cls, settings: pydantic.BaseModel, spaces: EntrantSpaces, seed: int, device: str
    ) -> Entrant:
        """A fresh entrant; every random stream it uses derives from ``seed`` (reproducible)."""
        ...

    def act(self, windows: np.ndarray) -> np.ndarray:
        """Greedy actions: ``(cars, window, obs_dim) -> (cars, action_dim)``."""
        ...

    def explore(self, windows: np.ndarray, env_steps: int) -> np.ndarray:
        """Exploring actions, same shapes as ``act``; ``env_steps`` drives any schedule."""
        ...

    def observe(self, transitions: Sequence[Transition]) -> None:
        """The step's stored transitions (a car the env is resetting stores none)."""
        ...

    def update(self, env_steps: int) -> dict[str, float]:
        """Called once per loop step after ``observe``; does 0..n gradient steps and returns
        their losses by name (may be empty). A non-finite loss fails the job (diverged)."""
        ...

    def episode_started(self, car: int) -> None:
        """Car ``car`` began an episode: reset its per-car exploration state (noise)."""
        ...

    def save(self, path: Path) -> None:
        """Write the model a race, replay or test needs to ``path``, atomically."""
        ...

    @classmethod
    def load(cls, path: Path, device: str) -> Entrant:
        """The entrant ``save`` wrote (its own loader: SB3's load for an SB3 adapter)."""
        ...

    def training_state(self) -> dict[str, Any]:
        """Everything needed to resume training bit-identically (buffers, optimisers, RNG
        states, noise, counters), as plain tensors, arrays, numbers, strings, lists and dicts
        (loadable with ``torch.load(weights_only=True)``)."""
        ...

    def restore_training_state(self, state: dict[str, Any]) -> None:
        """Continue from a ``training_state()`` of an entrant built with the same settings."""
        ...

"""The registry of algorithm families: the ``algorithm`` setting's name -> its agent class.

A new family is one module (an :class:`~formula_tourney.agents.core.Agent` subclass with its
target, losses and :class:`~formula_tourney.agents.core.FamilySettings`) and one line here;
``variants.AgentConfig`` takes its settings and validation, ``make_agent`` builds it and
``checkpoints.load_checkpoint`` rebuilds it by the name its checkpoint's config carries.
"""

from __future__ import annotations

from typing import Any

from formula_tourney.agents.core import Agent
from formula_tourney.agents.crossq import CrossQAgent
from formula_tourney.agents.ddpg import DDPGAgent
from formula_tourney.agents.sac import SACAgent
from formula_tourney.agents.td3 import TD3Agent
from formula_tourney.errors import UserInputError

ALGORITHMS: dict[str, type[Agent]] = {
    DDPGAgent.algorithm: DDPGAgent,
    TD3Agent.algorithm: TD3Agent,
    SACAgent.algorithm: SACAgent,
    CrossQAgent.algorithm: CrossQAgent,
}
"""Every registered family by its ``algorithm`` name; the paper's first."""


def get_family(algorithm: str) -> type[Agent]:
    """The agent class registered as ``algorithm``; UserInputError naming the known ones."""
    family = ALGORITHMS.get(algorithm)
    if family is None:
        raise UserInputError(f"unknown algorithm {algorithm!r}; known: {', '.join(ALGORITHMS)}")
    return family


def make_agent(
    cfg: Any, obs_dim: int, action_dim: int = 3, device: str = "cpu", seed: int | None = None
) -> Agent:
    """A fresh agent of ``cfg.algorithm``'s family (``cfg`` a ``variants.AgentConfig``)."""
    return get_family(cfg.algorithm)(cfg, obs_dim, action_dim, device=device, seed=seed)

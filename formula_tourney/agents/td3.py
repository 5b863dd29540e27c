"""TD3 (Fujimoto et al. 2018): twin critics, target policy smoothing, a delayed actor.

Beyond the paper; Stable-Baselines3's lesson that DDPG is TD3 with one critic and no delay. The
skeleton in ``core.py`` with these terms (replay, windows, n-step, PER weights and priorities
from Q_1, and the adopted target as for DDPG):

    (1') y_i = r^(n) + d_i min_j Q'_j(s', clip(mu'(s') + clip(e, -c, c), box)), e ~ N(0, s^2)
    (2') L = sum_j 1/N sum_i w_i (y_i - Q_j(s_i, a_i))^2
    (3') the actor ascends Q_1(s, mu(s)); (3') and the soft update only every policy_delay-th
         update (Fujimoto's order: on the d-th, 2d-th, ...)

The smoothing noise comes from the agent's own generator, so the seed alone fixes it.
"""

from __future__ import annotations

from typing import Any

import torch
from pydantic import Field
from torch import nn

from formula_tourney.agents.core import Agent, FamilySettings
from formula_tourney.agents.networks import TwinCritic


class TD3Settings(FamilySettings):
    """The TD3 family's own settings: target smoothing and the actor's delay."""

    policy_noise: float = Field(
        0.2,
        ge=0.0,
        description="TD3 only: std of the Gaussian target policy smoothing noise added to "
        "mu'(s') in the target, in action units (steer spans 2, each pedal 1).",
    )
    noise_clip: float = Field(
        0.5,
        ge=0.0,
        description="TD3 only: the smoothing noise is clipped to [-noise_clip, noise_clip] "
        "before the noisy target action is clipped to the action box.",
    )
    policy_delay: int = Field(
        2,
        ge=1,
        le=64,
        description="TD3 only: the actor and the target networks are updated once every "
        "policy_delay critic updates.",
    )


class TD3Agent(Agent):
    """TD3: DDPG with clipped double-Q, target smoothing and a delayed actor."""

    algorithm = "td3"
    tourney_families = ("TD3",)
    settings = TD3Settings
    twin_critics = True
    uses_generator = True
    checkpoint_keys = ("actor_target", "generator")

    def __init__(self, cfg: Any, obs_dim: int, action_dim: int = 3, device: str = "cpu",
                 seed: int | None = None) -> None:  # fmt: skip
        super().__init__(cfg, obs_dim, action_dim, device, seed)
        self._policy_delay = cfg.policy_delay

    def _make_critic(self) -> nn.Module:
        cfg = self.cfg
        return TwinCritic(self.obs_dim, self.action_dim, cfg.window, cfg.hidden,
                          cfg.critic_layer_norm)  # fmt: skip

    @torch.no_grad()
    def target(
        self,
        rewards: torch.Tensor,
        discounts: torch.Tensor,
        next_observations: torch.Tensor,
        next_action_windows: torch.Tensor,
    ) -> torch.Tensor:
        """(1'): the smoothed target action, kept inside the box, and the twins' minimum."""
        assert self.actor_target is not None
        cfg = self.cfg
        next_action = self.actor_target(next_observations)
        noise = torch.randn(next_action.shape, generator=self._generator,
                            device=next_action.device) * cfg.policy_noise  # fmt: skip
        noise = noise.clamp(-cfg.noise_clip, cfg.noise_clip)
        next_action = torch.clamp(next_action + noise, self._action_low, self._action_high)
        q_next = self.critic_target(next_observations, next_action, next_action_windows)
        return rewards + discounts * q_next.amin(0)

    def critic_objective(self, critic_loss: torch.Tensor) -> torch.Tensor:
        """(2'): each critic descends its own loss, so the sum of both (twice their mean)."""
        return 2.0 * critic_loss

    def actor_loss(self, q_pi: torch.Tensor, log_pi: torch.Tensor | None) -> torch.Tensor:
        """(3'): the actor follows Q_1."""
        return -q_pi[0].mean()

    def bc_values(self, q: torch.Tensor, q_pi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The cloning term's Q-filter reads Q_1, as the actor loss does."""
        return q[0], q_pi[0]

"""SAC (Haarnoja et al. 2018, automatic temperature): a squashed Gaussian actor, twin critics,
an entropy bonus with a learned temperature alpha.

Beyond the paper. The skeleton in ``core.py`` with these terms (replay, windows, n-step, PER
weights and priorities from Q_1, and the adopted target as for DDPG):

    (1'') y_i = r^(n) + d_i (min_j Q'_j(s', a') - alpha log pi(a'|s')),  a' ~ pi(.|s')
    (2'') L = sum_j 1/N sum_i w_i (y_i - Q_j(s_i, a_i))^2
    (3'') J = 1/N sum_i alpha log pi(a~_i|s_i) - min_j Q_j(s_i, a~_i), a~_i ~ pi(.|s_i)
          reparameterised; the soft update moves the critics' targets only (no target actor)
    (6)   L(alpha) = -1/N sum_i log alpha (log pi(a~_i|s_i) + H_target)

alpha is the value before this update's step in (1''), (3'') and (6), as in SB3. SAC explores by
sampling its own policy (no OU or brake noise); its samples come from the agent's own
generator, so the seed alone fixes them.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from pydantic import Field
from torch import nn

from formula_tourney.agents.core import Agent, FamilySettings, FusedAdam
from formula_tourney.agents.networks import SquashedGaussianActor, TwinCritic


class SACSettings(FamilySettings):
    """The SAC family's own settings: its temperature."""

    alpha_init: float = Field(
        1.0, gt=0.0, description="SAC only: initial entropy temperature alpha (SB3's auto: 1)."
    )
    alpha_lr: float = Field(3e-4, gt=0.0, description="SAC only: Adam learning rate of log alpha.")
    target_entropy: float | None = Field(
        None,
        description="SAC only: entropy that alpha steers the policy to; None is -action_dim "
        "(-3 for steer, throttle, brake).",
    )

    def entropy_target(self, action_dim: int) -> float:
        """SAC's target entropy: ``target_entropy``, or -action_dim when unset."""
        return float(-action_dim if self.target_entropy is None else self.target_entropy)


class SACAgent(Agent):
    """SAC with a learned temperature; ``log_alpha`` has its own gradient buffer and Adam."""

    algorithm = "sac"
    tourney_families = ("SAC",)
    settings = SACSettings
    uses_action_noise = False
    twin_critics = True
    has_target_actor = False
    uses_generator = True
    checkpoint_keys = ("generator", "log_alpha", "alpha_opt")

    def __init__(self, cfg: Any, obs_dim: int, action_dim: int = 3, device: str = "cpu",
                 seed: int | None = None) -> None:  # fmt: skip
        super().__init__(cfg, obs_dim, action_dim, device, seed)
        self.target_entropy = cfg.entropy_target(self.action_dim)
        self.log_alpha = torch.full(
            (1,), float(np.log(cfg.alpha_init)), device=self.device, requires_grad=True
        )
        self.log_alpha.grad = torch.zeros_like(self.log_alpha)
        self.alpha_opt = FusedAdam(
            [self.log_alpha], self.log_alpha, self.log_alpha.grad, lr=cfg.alpha_lr
        )

    @property
    def alpha(self) -> torch.Tensor:
        """The temperature ``exp(log alpha)`` (detached)."""
        return self.log_alpha.detach().exp()

    def _make_actor(self) -> nn.Module:
        cfg = self.cfg
        return SquashedGaussianActor(self.obs_dim, self.actor_window, cfg.hidden,
                                     cfg.throttle_bias_init, cfg.brake_bias_init,
                                     self.action_dim)  # fmt: skip

    def _make_critic(self) -> nn.Module:
        cfg = self.cfg
        return TwinCritic(self.obs_dim, self.action_dim, cfg.window, cfg.hidden,
                          cfg.critic_layer_norm)  # fmt: skip

    def explore(self, obs_window: np.ndarray) -> np.ndarray:
        """A sample ``a ~ pi(.|s)`` for one window (the greedy action is the squashed mean
        ``c + k tanh(m(s))``)."""
        with torch.no_grad():
            action, _ = self.actor.sample(self._window_tensor(obs_window), self._generator)
        return action[0].cpu().numpy()

    @torch.no_grad()
    def target(
        self,
        rewards: torch.Tensor,
        discounts: torch.Tensor,
        next_observations: torch.Tensor,
        next_action_windows: torch.Tensor,
    ) -> torch.Tensor:
        """(1''): a' ~ pi(.|s'), the twins' minimum and the entropy bonus."""
        next_action, log_pi = self.actor.sample(next_observations, self._generator)
        q_next = self.critic_target(next_observations, next_action).amin(0)
        return rewards + discounts * (q_next - self.log_alpha.exp() * log_pi)

    def _policy_action(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """a~ ~ pi(.|s), reparameterised: (3'') reaches the actor through a~."""
        return self.actor.sample(obs, self._generator)

    def critic_objective(self, critic_loss: torch.Tensor) -> torch.Tensor:
        """(2''): each critic descends its own loss, so the sum of both (twice their mean)."""
        return 2.0 * critic_loss

    def actor_loss(self, q_pi: torch.Tensor, log_pi: torch.Tensor | None) -> torch.Tensor:
        """(3''), and (6)'s gradient into log alpha's buffer, both with alpha as it was before
        this update."""
        assert log_pi is not None and self.log_alpha.grad is not None
        alpha = self.log_alpha.detach().exp()
        actor_loss = (alpha * log_pi - q_pi.amin(0)).mean()
        alpha_loss = -(self.log_alpha * (log_pi.detach() + self.target_entropy)).mean()
        self.log_alpha.grad.zero_()
        alpha_loss.backward(inputs=[self.log_alpha])
        return actor_loss

    def bc_values(self, q: torch.Tensor, q_pi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The cloning term's Q-filter reads the twins' minimum, as the actor loss does."""
        return q.amin(0), q_pi.amin(0)

    def _after_actor_step(self) -> None:
        self.alpha_opt.step()

    def state_dict(self) -> dict[str, Any]:
        state = super().state_dict()
        state["log_alpha"] = self.log_alpha.detach().clone()
        state["alpha_opt"] = self.alpha_opt.state_dict()
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"].reshape(self.log_alpha.shape))
        self.alpha_opt.load_state_dict(state["alpha_opt"])

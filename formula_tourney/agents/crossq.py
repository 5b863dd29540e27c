"""CrossQ (Bhatt et al. 2024): SAC with batch-normalised critics and no target networks.

Beyond the paper. SAC's actor, twin critics and learned temperature (``sac.py``), with three
changes that make one update per env step learn as much as many updates of SAC do:

    (1c) the critics carry batch normalisation (``networks.BNTwinCritic``), and
         Q(s, a) and Q(s', a'), a' ~ pi(.|s'), come from ONE training-mode forward pass of the
         joint batch [(s, a); (s', a')], so both halves are normalised by the same statistics
         (separate passes would normalise the bootstrap by the statistics of next states and
         policy actions alone, a distribution shift that breaks BN critics)
    (2c) y_i = r^(n) + d_i (min_j Q_j(s', a') - alpha log pi(a'|s')), Q_j(s', a') from (1c)
         and detached: the online critics bootstrap themselves, no target networks
    (3c) SAC's actor and temperature losses (eq. 3'', 6), the critics in eval mode (running
         statistics), every ``crossq_policy_delay``-th update

All optimisers run Adam with beta1 = ``crossq_adam_beta1`` (0.5 in the paper); the temperature's
at the critic's learning rate. Replay, windows,
n-step sums and PER weights enter as for every family; the PER priority reads Q_1. The update is
``core.py``'s skeleton: this family supplies only its critic pass (``_critic_values``) and says
``moves_targets = False``; the critic target copy the core builds is never read.
"""

from __future__ import annotations

from typing import Any

import torch
from pydantic import Field
from torch import nn

from formula_tourney.agents.core import FamilySettings, FusedAdam
from formula_tourney.agents.networks import BNTwinCritic
from formula_tourney.agents.sac import SACAgent
from formula_tourney.field_marks import marks


class CrossQSettings(FamilySettings):
    """The CrossQ family's own settings: batch norm, Adam's beta1 and the actor's delay.

    The temperature is SAC's at its defaults (alpha from 1, target entropy -action_dim, as
    sb3-contrib's CrossQ); it steps at the critic's learning rate (sb3-contrib uses one rate).
    """

    bn_momentum: float = Field(
        0.01,
        gt=0.0,
        le=1.0,
        description="CrossQ only: momentum of the critics' batch-norm running statistics "
        "(running <- (1 - m) running + m batch), which the actor loss and acting read.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    crossq_adam_beta1: float = Field(
        0.5,
        ge=0.0,
        lt=1.0,
        description="CrossQ only: Adam's beta1 for the actor, critics and temperature (the "
        "paper's 0.5; Adam's usual 0.9 is unstable with BN critics and no targets).",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    crossq_policy_delay: int = Field(
        3,
        ge=1,
        le=64,
        description="CrossQ only: the actor and temperature step once every this many critic "
        "updates (the paper's 3).",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )


class CrossQAgent(SACAgent):
    """CrossQ: the joint-batch BN critic update, no target networks, Adam beta1 0.5."""

    algorithm = "crossq"
    tourney_families = ("CrossQ",)
    settings = CrossQSettings
    mlp_backend = False
    moves_targets = False
    critic_layer_norm_applies = False  # batch-normalised critics

    def __init__(self, cfg: Any, obs_dim: int, action_dim: int = 3, device: str = "cpu",
                 seed: int | None = None) -> None:  # fmt: skip
        super().__init__(cfg, obs_dim, action_dim, device, seed)
        self._policy_delay = cfg.crossq_policy_delay
        betas = (cfg.crossq_adam_beta1, 0.999)
        n_actor = self._actor_flat.numel()
        self.actor_opt = FusedAdam(self._actor_params, self._actor_flat,
                                   self._grad_flat[:n_actor], lr=cfg.actor_lr, betas=betas)
        self.critic_opt = FusedAdam(self._critic_params, self._online_flat[n_actor:],
                                    self._grad_flat[n_actor:], lr=cfg.critic_lr, betas=betas)
        self.alpha_opt = FusedAdam([self.log_alpha], self.log_alpha, self.log_alpha.grad,
                                   lr=cfg.critic_lr, betas=betas)  # fmt: skip
        self.critic.eval()  # training mode only inside the joint pass (1c)

    def _make_critic(self) -> nn.Module:
        cfg = self.cfg
        return BNTwinCritic(self.obs_dim, self.action_dim, cfg.window, cfg.hidden, cfg.bn_momentum)

    def _critic_values(
        self, b: dict[str, torch.Tensor], actions: torch.Tensor, step_actor: bool
    ) -> tuple[torch.Tensor, torch.Tensor, Any, Any, Any]:
        """(1c): one training-mode pass of the BN critics over the joint batch [(s, a);
        (s', a')] with a' ~ pi(.|s'), so both halves share the batch statistics; the target
        bootstraps from that pass's own Q(s', a'), detached (no target networks). Q(s, pi(s))
        for the actor's loss uses the running statistics (eval mode)."""
        obs, next_obs = b["observations"], b["next_observations"]
        n = len(obs)
        alpha = self.log_alpha.detach().exp()
        with torch.no_grad():
            next_action, next_log_pi = self.actor.sample(next_obs, self._generator)
        self.critic.train()
        q_joint = self.critic(torch.cat([obs, next_obs]), torch.cat([actions, next_action]))
        self.critic.eval()
        q, q_next = q_joint[:, :n], q_joint[:, n:].detach()
        y = b["rewards"] + b["discounts"] * (q_next.amin(0) - alpha * next_log_pi)
        if not step_actor:
            return q, y, None, None, None
        policy_action, log_pi = self._policy_action(obs)
        return q, y, policy_action, log_pi, self.critic(obs, policy_action)

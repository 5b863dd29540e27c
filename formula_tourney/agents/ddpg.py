"""The paper's DDPG: one critic, a deterministic actor, and its variants (window, LSTM, MS, PER).

Paper, "Algorithms" (numbering ours), the skeleton in ``core.py`` with these terms:

    (1) y_i   = sum_{k<m} gamma^k r_{i+k} + d_i Q'(s_{i+m}, mu'(s_{i+m}))      m = 1 unless MS
        d_i   = gamma^m, or 0 on a premature end (the adopted target bootstraps on max-steps)
    (2) L(Q)  = 1/N sum_i w_i (y_i - Q(s_i, a_i))^2                          w_i = 1 unless PER
    (3) grad J ~ 1/N sum_i grad_a Q(s_i, a)|_{a = mu(s_i)} grad_theta mu(s_i)   (same Q as (2))
    (4) theta' <- tau theta + (1 - tau) theta'
    (5) p_i   = delta_i^2 + lambda3 |grad_a Q(s_i, a_i)|^2 + eps                    PER only

The variants are configuration: the window (WIN), n-step (MS), PER and the adopted target are
shared settings every family's skeleton reads; the LSTM critic is this family's own (the LSTM
variants keep a plain actor on the current observation: the paper found an LSTM actor
unstable). With the MLP critic the update runs through the hand-written backend
(``mlp_update.py``).
"""

from __future__ import annotations

from typing import Annotated, Any

import torch
from pydantic import Field, model_validator
from torch import nn

from formula_tourney.agents.buffers import ReplayBatch
from formula_tourney.agents.core import Agent, FamilySettings, UpdateInfo
from formula_tourney.agents.mlp_update import BCLoss
from formula_tourney.agents.networks import (
    HL_GAUSS_SIGMA_BINS,
    Actor,
    LSTMCritic,
    MLPCritic,
    hl_gauss_targets,
)
from formula_tourney.field_marks import marks

PreactBound = Annotated[float, Field(gt=0.0, le=50.0)]
ValueBound = Annotated[float, Field(ge=-1e6, le=1e6)]


_SHAPES_OF_THE_BINS = ("critic_value_range", "critic_sigma_bins", "critic_sigma_start_bins",
                       "critic_sigma_warmup_updates", "critic_mse_weight")  # fmt: skip
"""Settings of the classification critic alone: away from their defaults they need bins."""


class DDPGSettings(FamilySettings):
    """The DDPG family's own settings: its LSTM critic (the LSTM variants)."""

    lstm_critic: bool = Field(
        False,
        description="Use the LSTM critic (LSTM after the concatenation of the state and action "
        "streams, over the window); the actor then sees only the current observation.",
    )
    lstm_hidden: int = Field(
        64,
        ge=4,
        le=1024,
        description="LSTM units of the LSTM critic. 64 keeps an update near 1/3 of the MLP rate "
        "on one CPU thread (128 units over 8 steps measured ~17 updates/s).",
    )
    lstm_state_units: int = Field(
        128,
        ge=4,
        le=2048,
        description="Units of the state stream before the concatenation with the action in the "
        "LSTM critic; it sets the LSTM's input width and so most of its cost.",
    )
    preact_penalty: float = Field(
        0.0,
        ge=0.0,
        description="Beyond the paper: the actor's loss also pays this times the squared excess "
        "of each output's pre-activation z beyond +-preact_bound (summed over the action, "
        "averaged over the batch). A squashed output whose |z| runs to tens has a gradient of "
        "~exp(-|z|): the actor can no longer move that action whatever the critic says, and a "
        "run whose actor saturates early (full lock, full throttle) stays there. 0: the paper's "
        "loss.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    preact_bound: tuple[PreactBound, PreactBound] = Field(
        (6.0, 6.0),
        description="Beyond the paper: the |z| up to which preact_penalty costs nothing, for "
        "the steer and for the pedals. 6 lets a pedal reach 0.0025 of its travel from either "
        "end (sigmoid(-6)) and the steer 0.99999 of full lock; a steer held at 6 still has a "
        "gradient of only ~5e-5 (tanh'(6)), at 3 of ~0.01 (0.995 of full lock).",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )


    critic_bins: int = Field(
        0,
        ge=0,
        le=1001,
        description="Beyond the paper: 0, the paper's critic (one output, squared TD error), "
        "or 2..1001: a classification critic (Farebrother et al. 2024) with this many logits "
        "over equal bins spanning critic_value_range; Q is the softmax's mean of the bin "
        "centres, and the critic descends the cross-entropy to the target's HL-Gauss "
        "histogram (a normal of 0.75 bin widths around y), which holds up where the targets "
        "are noisy or bimodal (a braking point that is made or crashed). Not with "
        "lstm_critic.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    critic_sigma_bins: float = Field(
        HL_GAUSS_SIGMA_BINS,
        gt=0.0,
        le=10.0,
        description="Beyond the paper: the spread of the classification critic's target "
        "(critic_bins), in bin widths: the HL-Gauss histogram is a normal of this many bin "
        "widths around y. Farebrother et al. (2024) recommend 0.75; a wider one shares each "
        "target among more bins (a smoother, blunter critic) without coarsening the bins "
        "themselves. Needs critic_bins.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    critic_sigma_start_bins: float = Field(
        0.0,
        ge=0.0,
        le=10.0,
        description="Beyond the paper: with critic_sigma_warmup_updates, the classification "
        "target's width (critic_sigma_bins) starts at this many bin widths and narrows "
        "linearly to critic_sigma_bins over those updates: a wide target brings the first "
        "clean lap forward, a narrow one reaches the best bot (docs/results.md). 0: no "
        "warm-up.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    critic_sigma_warmup_updates: int = Field(
        0,
        ge=0,
        le=10_000_000,
        description="Beyond the paper: the updates over which the classification target "
        "narrows from critic_sigma_start_bins to critic_sigma_bins. 0: no warm-up.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    critic_value_range: tuple[ValueBound, ValueBound] = Field(
        (-100.0, 100.0),
        description="Beyond the paper: the lowest and highest Q the classification critic "
        "(critic_bins) represents; targets outside are clipped into it. A trained `best` "
        "critic's Q reads 18-56 on the built-in tracks (docs/agents.md); -20..70 cost "
        "`technical` its clean laps.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )

    critic_mse_weight: float = Field(
        0.0,
        ge=0.0,
        le=100.0,
        description="Beyond the paper: the classification critic's (critic_bins) loss also "
        "pays this times the paper's squared error of its Q (the softmax's mean) to y, eq. "
        "(2). The cross-entropy to a target 0.75 bins wide moves the mean by a difference of "
        "a fraction of a bin with a pull ~1/sigma^2 of its size, so laps that differ by 1 % "
        "of Q are told apart slowly; the squared error pulls the mean itself. At 0.25 the "
        "oval's laps came out slower, not faster (docs/results.md). 0: the cross-entropy "
        "alone.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )

    @model_validator(mode="after")
    def _bins(self) -> DDPGSettings:
        if self.critic_bins == 1:
            raise ValueError("critic_bins: 0 (the paper's critic) or 2..1001 bins, not 1")
        low, high = self.critic_value_range
        if not low < high:
            raise ValueError(f"critic_value_range: the low end {low} must be below the high "
                             f"end {high}")  # fmt: skip
        if self.critic_bins and self.lstm_critic:
            raise ValueError("critic_bins applies to the MLP critic, not lstm_critic")
        # (on another family's variant the flat config refuses every DDPG setting instead)
        own = getattr(self, "algorithm", "ddpg") == "ddpg"
        if own and bool(self.critic_sigma_start_bins) != bool(self.critic_sigma_warmup_updates):
            raise ValueError("critic_sigma_start_bins and critic_sigma_warmup_updates set the "
                             "target's warm-up together: both or neither")  # fmt: skip
        if own and not self.critic_bins:
            for name in _SHAPES_OF_THE_BINS:
                default = type(self).model_fields[name].default
                value = getattr(self, name)
                if (tuple(value) if isinstance(value, tuple | list) else value) != default:
                    raise ValueError(f"{name} shapes the classification critic: it needs "
                                     "critic_bins of 2 or more")  # fmt: skip
        return self


class DDPGAgent(Agent):
    """The paper's DDPG (Lillicrap et al.) with its variants."""

    algorithm = "ddpg"
    tourney_families = ("DDPG", "LSTM", "MS", "PER")
    settings = DDPGSettings
    beyond_paper = False
    checkpoint_keys = ("actor_target",)
    mlp_backend = True

    def _actor_window(self) -> int:
        return 1 if self.cfg.lstm_critic else int(self.cfg.window)

    def _make_critic(self) -> nn.Module:
        cfg = self.cfg
        if cfg.lstm_critic:
            return LSTMCritic(self.obs_dim, self.action_dim, cfg.window, cfg.lstm_state_units,
                              cfg.lstm_hidden, cfg.hidden[1])  # fmt: skip
        return MLPCritic(self.obs_dim, self.action_dim, cfg.window, cfg.hidden,
                         cfg.critic_layer_norm, max(1, cfg.critic_bins),
                         cfg.critic_value_range, cfg.critic_sigma_bins)  # fmt: skip

    @torch.no_grad()
    def target(
        self,
        rewards: torch.Tensor,
        discounts: torch.Tensor,
        next_observations: torch.Tensor,
        next_action_windows: torch.Tensor,
    ) -> torch.Tensor:
        """Eq. (1): y = r^(n) + d Q'(s', mu'(s')), with d = 0 where the target is y = r."""
        assert self.actor_target is not None
        next_action = self.actor_target(next_observations)
        q_next = self.critic_target(next_observations, next_action, next_action_windows)
        return rewards + discounts * q_next

    def update(
        self, batch: ReplayBatch, per_buffer: Any | None = None, bc: BCLoss | None = None
    ) -> UpdateInfo:
        """The core's update; with a target warm-up (``critic_sigma_warmup_updates``) the
        classification target's width first follows its schedule (:meth:`target_sigma_bins`)."""
        if self.cfg.critic_sigma_warmup_updates:
            assert isinstance(self.critic, MLPCritic)
            self.critic.sigma_bins = self.target_sigma_bins()
        return super().update(batch, per_buffer, bc)

    def target_sigma_bins(self) -> float:
        """The classification target's width in bin widths at this update: from
        ``critic_sigma_start_bins`` linearly to ``critic_sigma_bins`` over
        ``critic_sigma_warmup_updates``, then ``critic_sigma_bins``."""
        cfg = self.cfg
        if not cfg.critic_sigma_warmup_updates:
            return float(cfg.critic_sigma_bins)
        left = max(0.0, 1.0 - self.updates / cfg.critic_sigma_warmup_updates)
        start, end = cfg.critic_sigma_start_bins, cfg.critic_sigma_bins
        return float(end + (start - end) * left)

    def critic_objective(self, critic_loss: torch.Tensor) -> torch.Tensor:
        """Eq. (2) as it is."""
        return critic_loss

    def critic_loss(self, td: torch.Tensor, y: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        """Eq. (2); with ``critic_bins``, the weighted cross-entropy of the logits at ``(s, a)``
        (kept by :meth:`_critic_values`) to the HL-Gauss histogram of ``y``, plus
        ``critic_mse_weight`` times eq. (2) on the softmax's mean."""
        if not self.cfg.critic_bins:
            return super().critic_loss(td, y, weights)
        critic = self.critic
        assert isinstance(critic, MLPCritic)
        target = hl_gauss_targets(y, critic.edges, critic.sigma_bins)
        cross_entropy = -(target * torch.log_softmax(self._q_logits, dim=1)).sum(1)
        loss = (weights * cross_entropy).mean()
        if self.cfg.critic_mse_weight:
            loss = loss + self.cfg.critic_mse_weight * super().critic_loss(td, y, weights)
        return loss

    def _critic_values(
        self, b: dict[str, torch.Tensor], actions: torch.Tensor, step_actor: bool
    ) -> tuple[torch.Tensor, torch.Tensor, Any, Any, Any]:
        """The core's step; with ``critic_bins`` it keeps the logits at ``(s, a)`` for
        :meth:`critic_loss` (DDPG steps its actor on every update)."""
        if not self.cfg.critic_bins:
            return super()._critic_values(b, actions, step_actor)
        critic = self.critic
        assert isinstance(critic, MLPCritic)
        obs = b["observations"]
        y = self.target(b["rewards"], b["discounts"], b["next_observations"],
                        b["next_action_windows"])  # fmt: skip
        policy_action, log_pi = self._policy_action(obs)
        self._q_logits, q_pi = critic.logits_pair(obs, actions, policy_action)
        return critic.value(self._q_logits), y, policy_action, log_pi, q_pi

    def _policy_action(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """mu(s), keeping its pre-activations for the saturation term of :meth:`actor_loss`."""
        assert isinstance(self.actor, Actor)
        self._policy_preact = self.actor.preactivation(obs)
        return self.actor.squash(self._policy_preact), None

    def actor_loss(self, q_pi: torch.Tensor, log_pi: torch.Tensor | None) -> torch.Tensor:
        """Eq. (3): the actor ascends Q(s, mu(s)); with ``preact_penalty`` it also pays
        w mean_i sum_j max(0, |z_ij| - bound_j)^2, bound_j the steer's or the pedals'
        (``mlp_update.MLPUpdate`` writes the same gradient by hand)."""
        loss = -q_pi.mean()
        if self.cfg.preact_penalty:
            z = self._policy_preact
            steer_bound, pedal_bound = self.cfg.preact_bound
            bound = z.new_tensor([steer_bound] + [pedal_bound] * (z.shape[1] - 1))
            excess = z - torch.minimum(torch.maximum(z, -bound), bound)
            loss = loss + self.cfg.preact_penalty * excess.square().sum(-1).mean()
        return loss

"""The paper's DDPG variants, and TD3 and SAC beyond it, as configurations of the one update rule.

A variant never copies the algorithm: WIN1/4/8 set the window ``w`` fed to actor and critic,
LSTM4/8 switch the critic to the LSTM critic over a window of ``w`` states and actions, MS2/3/4
set the n of the multi-step target, PER40k/PER1M switch on prioritized replay with that buffer
size. Beyond the paper, ``algorithm`` selects TD3 or SAC in the same update (``ddpg.py``): DDPG
is TD3 with one critic, no target smoothing and no delay (Stable-Baselines3's view), and SAC
swaps the deterministic actor for a squashed Gaussian and adds the entropy terms; replay,
windows, n-step, PER and the adopted target are shared. Every field carries a description, so
``--help``, tournament files and error messages all read from this one place.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from formula_tourney.errors import UserInputError
from formula_tourney.field_marks import marks
from formula_tourney.sim.reward import BY_NAME as REWARD_SETTINGS

Family = Literal["DDPG", "LSTM", "MS", "PER", "TD3", "SAC"]
Algorithm = Literal["ddpg", "td3", "sac"]
PAPER_FAMILIES: tuple[str, ...] = ("DDPG", "LSTM", "MS", "PER")
FAMILIES: tuple[str, ...] = (*PAPER_FAMILIES, "TD3", "SAC")
ALGORITHM_FAMILIES: dict[str, tuple[str, ...]] = {
    "ddpg": PAPER_FAMILIES, "td3": ("TD3",), "sac": ("SAC",),
}  # fmt: skip
"""The families an algorithm's variants may belong to (a TD3 entrant never competes as PER)."""
TD3_FIELDS: tuple[str, ...] = ("policy_noise", "noise_clip", "policy_delay")
SAC_FIELDS: tuple[str, ...] = ("alpha_init", "alpha_lr", "target_entropy")


class AgentConfig(BaseModel):
    """Hyperparameters of one DDPG variant (the paper's Sections "Algorithms" and "Extensions")."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field("WIN1", description="Variant name as registered (e.g. WIN4, PER1M).")
    family: Family = Field(
        "DDPG",
        description="Algorithm family: the paper's DDPG (the WIN variants), LSTM, MS or PER, or "
        "TD3 or SAC beyond the paper; tournaments promote the best entrant of each family.",
    )
    algorithm: Algorithm = Field(
        "ddpg",
        description="Update rule: ddpg (the paper's: one critic, deterministic actor), td3 "
        "(twin critics with clipped double-Q, target policy smoothing, delayed actor) or sac "
        "(squashed Gaussian actor, twin critics, entropy bonus with a learned temperature).",
    )
    # --- variant axes -------------------------------------------------------------------------
    window: int = Field(
        1,
        ge=1,
        le=64,
        description="Window sampling: the last w observations are stacked as the input of the "
        "actor and the MLP critic; for the LSTM critic, its sequence length over (state, action).",
    )
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
    n_step: int = Field(
        1,
        ge=1,
        le=64,
        description="Multi-step target: n rewards summed before bootstrapping (stops early at "
        "episode ends).",
    )
    prioritized: bool = Field(
        False, description="Prioritized experience replay with a sum tree (PER variants)."
    )
    buffer_size: int = Field(
        1_000_000, ge=1_000, le=20_000_000, description="Replay buffer capacity in transitions."
    )
    # --- prioritized replay -------------------------------------------------------------------
    per_alpha: float = Field(
        0.6, ge=0.0, le=1.0, description="PER exponent: P(i) = p_i^alpha / sum_k p_k^alpha."
    )
    per_beta0: float = Field(
        0.4, ge=0.0, le=1.0, description="Initial importance-sampling exponent beta."
    )
    per_beta_steps: int = Field(
        200_000, ge=1, description="Updates over which beta anneals linearly to 1."
    )
    per_lambda3: float = Field(
        1.0,
        ge=0.0,
        description="Weight of the actor term in p_i = delta_i^2 + lambda3 |grad_a Q|^2 + eps.",
    )
    per_eps: float = Field(
        1e-3, gt=0.0, description="Small constant eps in the priority so every sample can recur."
    )
    # --- DDPG ---------------------------------------------------------------------------------
    gamma: float = Field(0.99, gt=0.0, le=1.0, description="Discount factor gamma.")
    reward_scale: float = REWARD_SETTINGS["reward_scale"].field()
    tau: float = Field(
        0.005,
        gt=0.0,
        le=1.0,
        description="Soft target update: theta' <- tau theta + (1-tau) theta'.",
    )
    crash_penalty: float = REWARD_SETTINGS["crash_penalty"].field()
    actor_lr: float = Field(1e-4, gt=0.0, description="Adam learning rate of the actor.")
    critic_lr: float = Field(1e-3, gt=0.0, description="Adam learning rate of the critic.")
    batch_size: int = Field(256, ge=1, le=65536, description="Minibatch size N per update.")
    hidden: tuple[int, int] = Field(
        (400, 300), description="Hidden units of the actor and the MLP critic (Lillicrap 400-300)."
    )
    learning_starts: int = Field(
        1_000, ge=0, description="Environment steps of pure exploration before updates begin."
    )
    updates_per_step: float = Field(
        1.0, gt=0.0, le=64.0, description="Gradient updates per environment step."
    )
    adopted_target: bool = Field(
        True,
        description="The paper's adopted target: bootstrap on max-steps ends (Gymnasium "
        "`truncated`), y = r only on premature ends. False is the ablation: y = r on every end.",
    )
    brake_bias_init: float = Field(
        -3.0,
        description="Initial bias of the brake output's pre-sigmoid (sigmoid(-3) = 0.05): an "
        "untrained actor at 0.5 brake never leaves the start.",
    )
    throttle_bias_init: float = Field(
        1.0, description="Initial bias of the throttle output's pre-sigmoid (sigmoid(1) = 0.73)."
    )
    # --- TD3 (Fujimoto et al. 2018) -----------------------------------------------------------
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
    # --- SAC (Haarnoja et al. 2018, automatic temperature) --------------------------------------
    alpha_init: float = Field(
        1.0, gt=0.0, description="SAC only: initial entropy temperature alpha (SB3's auto: 1)."
    )
    alpha_lr: float = Field(3e-4, gt=0.0, description="SAC only: Adam learning rate of log alpha.")
    target_entropy: float | None = Field(
        None,
        description="SAC only: entropy that alpha steers the policy to; None is -action_dim "
        "(-3 for steer, throttle, brake).",
    )
    # --- exploration --------------------------------------------------------------------------
    exploration_steps: int = Field(
        100_000,
        ge=1,
        description="Environment steps over which epsilon anneals linearly from 1 to 0.",
    )
    epsilon_floor: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="Beyond the paper: epsilon never anneals below this, so OU and brake "
        "exploration go on for the whole run (as TD3's constant noise does) and the critic keeps "
        "seeing actions beside the actor's; 0: the paper's anneal to pure actor actions.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    eval_ema_updates: int = Field(
        0,
        ge=0,
        description="Beyond the paper: tests (and every drive from a checkpoint) use an "
        "exponential moving average of the actor's weights over about this many updates "
        "(decay 1 - 1/N), the online actor going on learning as before; 0: tests drive the "
        "online actor, as the paper does. Between two tests the online actor moves through "
        "thousands of updates and a snapshot lands wherever the last few put it.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    noise_prob: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="Probability per step and action dimension that the OU noise is added.",
    )
    ou_theta: tuple[float, float, float] = Field(
        (0.15, 0.15, 0.15), description="OU mean reversion per action (steer, throttle, brake)."
    )
    ou_sigma: tuple[float, float, float] = Field(
        (0.3, 0.3, 0.1), description="OU noise scale per action (steer, throttle, brake)."
    )
    brake_explore_prob: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="Probability per step of the paper's brake exploration: a stronger brake "
        "noise while throttle is scaled by (1 - epsilon).",
    )
    brake_explore_mean: float = Field(
        0.5, ge=0.0, le=1.0, description="Mean brake pressure that brake exploration pulls to."
    )
    brake_explore_sigma: float = Field(
        0.2, ge=0.0, description="Gaussian spread of the brake exploration's brake pressure."
    )
    brake_explore_hold_steps: int = Field(
        1,
        ge=1,
        le=100,
        description="Beyond the paper: a brake exploration, once fired, is held for a number of "
        "steps drawn from 1..this (1: the paper's single-step rule). A hairpin needs 8-13 steps "
        "of braking that single-step events never produce (benchmarks/braking_exploration.py).",
        json_schema_extra=marks(beyond_paper=True),
    )

    @model_validator(mode="after")
    def _consistent(self) -> AgentConfig:
        if any(h < 1 for h in self.hidden):
            raise ValueError("hidden units must be positive")
        if self.batch_size > self.buffer_size:
            raise ValueError("batch_size must not exceed buffer_size")
        families = ALGORITHM_FAMILIES[self.algorithm]
        if self.family not in families:
            raise ValueError(
                f"family {self.family} does not fit algorithm {self.algorithm}; allowed: "
                f"{', '.join(families)}"
            )
        if self.algorithm != "ddpg" and self.lstm_critic:
            # twin LSTM critics would need their own q_pair and double the slowest update
            raise ValueError(f"lstm_critic is supported for algorithm ddpg only, not "
                             f"{self.algorithm}; use window > 1 with the MLP critics")  # fmt: skip
        # a setting the algorithm would ignore is an error, not a silent no-op
        for algorithm, fields in (("td3", TD3_FIELDS), ("sac", SAC_FIELDS)):
            if self.algorithm == algorithm:
                continue
            changed = [k for k in fields if getattr(self, k) != type(self).model_fields[k].default]
            if changed:
                raise ValueError(
                    f"{', '.join(changed)} apply to algorithm {algorithm} only, not "
                    f"{self.algorithm}"
                )
        return self

    @property
    def beyond_paper(self) -> bool:
        """True for families the paper did not race (TD3, SAC): tables label them."""
        return self.algorithm != "ddpg"

    @property
    def uses_action_noise(self) -> bool:
        """Whether the training loop adds the OU + brake exploration noise to ``explore``'s
        action (DDPG, TD3); SAC explores by sampling its own policy."""
        return self.algorithm != "sac"

    @property
    def twin_critics(self) -> bool:
        """Clipped double-Q: two critics, the target takes their minimum (TD3, SAC)."""
        return self.algorithm != "ddpg"

    def entropy_target(self, action_dim: int) -> float:
        """SAC's target entropy: ``target_entropy``, or -action_dim when unset."""
        return float(-action_dim if self.target_entropy is None else self.target_entropy)


VARIANTS: dict[str, AgentConfig] = {
    "WIN1": AgentConfig(name="WIN1", family="DDPG", window=1),
    "WIN4": AgentConfig(name="WIN4", family="DDPG", window=4),
    "WIN8": AgentConfig(name="WIN8", family="DDPG", window=8),
    "LSTM4": AgentConfig(name="LSTM4", family="LSTM", window=4, lstm_critic=True),
    "LSTM8": AgentConfig(name="LSTM8", family="LSTM", window=8, lstm_critic=True),
    "MS2": AgentConfig(name="MS2", family="MS", n_step=2),
    "MS3": AgentConfig(name="MS3", family="MS", n_step=3),
    "MS4": AgentConfig(name="MS4", family="MS", n_step=4),
    "PER40k": AgentConfig(name="PER40k", family="PER", prioritized=True, buffer_size=40_000),
    "PER1M": AgentConfig(name="PER1M", family="PER", prioritized=True, buffer_size=1_000_000),
}
"""The paper's ten variants (section "Algorithms"), in its order."""

BEYOND_PAPER_VARIANTS: dict[str, AgentConfig] = {
    # MLP critics, window 1. TD3: Fujimoto et al.'s 400-300 nets and lr 1e-3 for both, SB3's
    # batch 256, their smoothing 0.2 / clip 0.5 / delay 2 (the field defaults); SAC (Haarnoja et
    # al., SB3): 256-256 nets, lr 3e-4 everywhere, batch 256, tau 0.005, alpha from 1
    "TD3": AgentConfig(name="TD3", family="TD3", algorithm="td3", actor_lr=1e-3),
    "SAC": AgentConfig(
        name="SAC",
        family="SAC",
        algorithm="sac",
        hidden=(256, 256),
        actor_lr=3e-4,
        critic_lr=3e-4,
        alpha_lr=3e-4,
    ),
}
"""Registered variants of families the paper did not race; ``beyond_paper`` is True for each."""

ALL_VARIANTS: dict[str, AgentConfig] = {**VARIANTS, **BEYOND_PAPER_VARIANTS}
"""Every registered variant: the paper's ten, then those beyond the paper."""


NAMED_SETTINGS: tuple[str, ...] = ("window", "lstm_critic", "n_step", "prioritized", "buffer_size")
"""The settings a paper variant's name stands for: WIN4's window, LSTM's critic, MS3's n-step,
PER40k's prioritized 40k buffer."""


def named_settings(name: str) -> frozenset[str]:
    """The settings the registered variant ``name`` fixes by its name.

    A preset's common overrides leave these alone: `fast`'s 200k buffer applied to both PER
    variants made PER40k and PER1M one variant under two names (replication pilot, 2026-12-01).
    """
    return frozenset(get_variant(name).model_fields_set & set(NAMED_SETTINGS))


def variant_names() -> list[str]:
    """Registered variant names: the paper's ten in its order, then those beyond the paper."""
    return list(ALL_VARIANTS)


def get_variant(name: str, overrides: dict[str, Any] | None = None) -> AgentConfig:
    """The registered variant ``name`` with ``overrides`` applied and validated.

    Unknown names, unknown override keys and out-of-range values raise UserInputError naming the
    key, so a typo in a tournament file never silently trains the default.
    """
    if name not in ALL_VARIANTS:
        raise UserInputError(f"unknown variant {name!r}; known: {', '.join(ALL_VARIANTS)}")
    base = ALL_VARIANTS[name]
    if not overrides:
        return base
    fixed = [k for k in ("name", "family", "algorithm") if k in overrides]
    if fixed:
        raise UserInputError(f"variant {name}: overrides may not change 'name', 'family' or "
                             f"'algorithm' (got {', '.join(fixed)})")  # fmt: skip
    try:
        return AgentConfig.model_validate({**base.model_dump(), **overrides})
    except ValidationError as err:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or 'value'}: {e['msg']}" for e in err.errors()
        )
        raise UserInputError(f"variant {name} overrides: {problems}") from None

"""The registered variants, and ``AgentConfig``: every setting of an agent, validated once.

A variant is a configuration, never a copy of an algorithm: WIN1/4/8 set the window ``w`` fed to
actor and critic, LSTM4/8 switch the DDPG critic to the LSTM critic over a window of ``w``
states and actions, MS2/3/4 set the n of the multi-step target, PER40k/PER1M switch on
prioritized replay with that buffer size; TD3, SAC and CrossQ (beyond the paper) are variants
of their own families. ``algorithm`` names the family (``families.py``), ``family`` the group a
tournament promotes the best entrant of. :class:`AgentConfig` joins the settings every family
shares (:class:`SharedSettings`) with each family's own (declared in its module), under flat
keys, so tournament files, presets and ``train --set`` name them the same way; a family's
setting set on a variant of another family is an error, not a silent no-op. Every field carries
a description, so ``--help``, tournament files and error messages all read from this one place.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from formula_tourney.agents.families import ALGORITHMS
from formula_tourney.errors import UserInputError
from formula_tourney.field_marks import marks
from formula_tourney.sim.reward import BY_NAME as REWARD_SETTINGS

MAX_HIDDEN_UNITS = 16_384
"""Widest hidden layer: a 16384 x 16384 float32 layer is 1 GiB; a wider one is a typo that
would fail to allocate in every job (the paper's nets are 400-300)."""
HiddenUnits = Annotated[int, Field(ge=1, le=MAX_HIDDEN_UNITS, strict=True)]


class SharedSettings(BaseModel):
    """The settings every family's update reads (the paper's Sections "Algorithms" and
    "Extensions"); :class:`AgentConfig` adds each family's own."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    name: str = Field("WIN1", description="Variant name as registered (e.g. WIN4, PER1M).")
    family: str = Field(
        "DDPG",
        description="Tournament family: the paper's DDPG (the WIN variants), LSTM, MS or PER, or "
        "TD3, SAC or CrossQ beyond the paper; tournaments promote the best entrant of each "
        "family. It must be one its algorithm's variants may carry.",
    )
    algorithm: str = Field(
        "ddpg",
        description="Algorithm family (agents.families): ddpg (the paper's: one critic, "
        "deterministic actor), td3 (twin critics with clipped double-Q, target policy "
        "smoothing, delayed actor), sac (squashed Gaussian actor, twin critics, entropy "
        "bonus with a learned temperature) or crossq (SAC with batch-normalised critics and no "
        "target networks).",
    )
    # --- variant axes -------------------------------------------------------------------------
    window: int = Field(
        1,
        ge=1,
        le=64,
        description="Window sampling: the last w observations are stacked as the input of the "
        "actor and the MLP critic; for the LSTM critic, its sequence length over (state, action).",
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
    crash_penalty_decay_steps: int = REWARD_SETTINGS["crash_penalty_decay_steps"].field()
    actor_lr: float = Field(1e-4, gt=0.0, description="Adam learning rate of the actor.")
    critic_lr: float = Field(1e-3, gt=0.0, description="Adam learning rate of the critic.")
    lr_decay_updates: int = Field(
        0,
        ge=0,
        le=1_000_000_000,
        description="Beyond the paper: the actor's and critic's learning rates fall linearly "
        "from actor_lr and critic_lr to lr_final_fraction of them over this many updates, "
        "then stay there, so that a driver near its best lap stops wandering around it. 0: "
        "constant rates, as the paper's.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    lr_final_fraction: float = Field(
        0.1,
        gt=0.0,
        le=1.0,
        description="Beyond the paper: with lr_decay_updates, the fraction of actor_lr and "
        "critic_lr the rates end at.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    batch_size: int = Field(256, ge=1, le=65536, description="Minibatch size N per update.")
    hidden: tuple[HiddenUnits, HiddenUnits] = Field(
        (400, 300),
        description="Hidden units of the actor and the MLP critic (Lillicrap 400-300), each "
        f"1..{MAX_HIDDEN_UNITS}.",
    )
    critic_layer_norm: bool = Field(
        False,
        description="Beyond the paper: a LayerNorm before each hidden ReLU of the MLP critics "
        "(DDPG's, TD3's and SAC's; RLPD, Ball et al. 2023), which bounds Q's extrapolation to "
        "actions the buffer never holds. DDPG then updates through autograd (the hand-written "
        "backend has no norm). Not with lstm_critic, nor CrossQ's batch-norm critics.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    obs_norm: bool = Field(
        False,
        description="Beyond the paper: every observation value is standardised by the running "
        "mean and standard deviation of all observations stored so far, in acting, tests and "
        "updates alike (agents/obs_norm.py); a checkpoint carries the statistics it drives "
        "with. Off: the sensors' fixed scaling alone, as the paper.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
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


class AgentConfig(*reversed([f.settings for f in ALGORITHMS.values()]), SharedSettings):
    """Hyperparameters of one variant: the shared settings, then each registered family's own
    (its ``settings`` model), as flat keys. No float setting may be infinite or NaN (a learning
    rate of inf diverges in every job): ``allow_inf_nan=False`` covers each family's too."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @model_validator(mode="after")
    def _consistent(self) -> AgentConfig:
        if self.batch_size > self.buffer_size:
            raise ValueError("batch_size must not exceed buffer_size")
        if self.crash_penalty_decay_steps and not self.crash_penalty:
            raise ValueError("crash_penalty_decay_steps decays the crash penalty: it needs a "
                             "crash_penalty above 0")
        if self.algorithm not in ALGORITHMS:
            raise ValueError(
                f"unknown algorithm {self.algorithm!r}; known: {', '.join(ALGORITHMS)}"
            )
        own = ALGORITHMS[self.algorithm]
        if self.critic_layer_norm and (self.lstm_critic or not own.critic_layer_norm_applies):
            raise ValueError(
                "critic_layer_norm applies to the MLP critics (ddpg without lstm_critic, td3, "
                f"sac), not {'lstm_critic' if self.lstm_critic else self.algorithm}"
            )
        if self.family not in own.tourney_families:
            raise ValueError(
                f"family {self.family} does not fit algorithm {self.algorithm}; allowed: "
                f"{', '.join(own.tourney_families)}"
            )
        # a setting the algorithm would ignore is an error, not a silent no-op
        defaults = type(self).model_fields
        for other in ALGORITHMS.values():
            if other is own:
                continue
            changed = [k for k in other.settings.model_fields
                       if k not in own.settings.model_fields
                       and getattr(self, k) != defaults[k].default]  # fmt: skip
            if changed:
                raise ValueError(
                    f"{', '.join(changed)} apply to algorithm {other.algorithm} only, not "
                    f"{self.algorithm}"
                )
        return self

    @property
    def beyond_paper(self) -> bool:
        """True for families the paper did not race (TD3, SAC): tables label them."""
        return ALGORITHMS[self.algorithm].beyond_paper

    @property
    def uses_action_noise(self) -> bool:
        """Whether the training loop adds the OU + brake exploration noise to ``explore``'s
        action (DDPG, TD3); SAC explores by sampling its own policy."""
        return ALGORITHMS[self.algorithm].uses_action_noise

    @property
    def twin_critics(self) -> bool:
        """Clipped double-Q: two critics, the target takes their minimum (TD3, SAC)."""
        return ALGORITHMS[self.algorithm].twin_critics


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
    # CrossQ (Bhatt et al. 2024, sb3-contrib's defaults): lr 1e-3 everywhere, actor delay 3,
    # Adam beta1 0.5, BN momentum 0.01 (the field defaults); 256-256 critics instead of the
    # paper's 2048-2048 ones, ~57x the multiply-adds per update on a CPU
    "CrossQ": AgentConfig(
        name="CrossQ",
        family="CrossQ",
        algorithm="crossq",
        hidden=(256, 256),
        actor_lr=1e-3,
        critic_lr=1e-3,
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
    variants would make PER40k and PER1M one variant under two names.
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
    return parse_config({**base.model_dump(), **overrides}, f"variant {name} overrides")


def parse_config(data: Any, source: str) -> AgentConfig:
    """``data`` validated as an AgentConfig; one UserInputError ``SOURCE: KEY: PROBLEM; ...``
    otherwise."""
    try:
        return AgentConfig.model_validate(data)
    except ValidationError as err:
        raise UserInputError(f"{source}: {validation_problems(err)}") from None


def validation_problems(err: ValidationError) -> str:
    """pydantic's errors as ``key: problem; ...`` on one line: a rule across keys (batch_size
    and buffer_size) names its keys in its own words, never "1 validation error for ..."."""
    return "; ".join(
        (f"{'.'.join(str(p) for p in e['loc'])}: " if e["loc"] else "")
        + str(e["msg"]).removeprefix("Value error, ")
        for e in err.errors()
    )

"""The paper's DDPG variants as named configurations of the one update rule in ``ddpg.py``.

A variant never copies the algorithm: WIN1/4/8 set the window ``w`` fed to actor and critic,
LSTM4/8 switch the critic to the LSTM critic over a window of ``w`` states and actions, MS2/3/4
set the n of the multi-step target, PER40k/PER1M switch on prioritized replay with that buffer
size. Every field carries a description, so ``--help``, tournament files and error messages all
read from this one place.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from formula_tourney.errors import UserInputError

Family = Literal["DDPG", "LSTM", "MS", "PER"]
FAMILIES: tuple[str, ...] = ("DDPG", "LSTM", "MS", "PER")


class AgentConfig(BaseModel):
    """Hyperparameters of one DDPG variant (the paper's Sections "Algorithms" and "Extensions")."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field("WIN1", description="Variant name as registered (e.g. WIN4, PER1M).")
    family: Family = Field(
        "DDPG",
        description="Paper's algorithm family: DDPG (the WIN variants), LSTM, MS or PER; "
        "tournaments promote the best entrant of each family.",
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
    reward_scale: float = Field(
        0.02,
        gt=0.0,
        description="Rewards are multiplied by this before they enter the replay buffer. The "
        "paper's reward is Vx in m/s per step (up to ~80), so Q reaches thousands; scaled, the "
        "critic starts near its targets' size.",
    )
    tau: float = Field(
        0.005,
        gt=0.0,
        le=1.0,
        description="Soft target update: theta' <- tau theta + (1-tau) theta'.",
    )
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
    # --- exploration --------------------------------------------------------------------------
    exploration_steps: int = Field(
        100_000,
        ge=1,
        description="Environment steps over which epsilon anneals linearly from 1 to 0.",
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

    @model_validator(mode="after")
    def _consistent(self) -> AgentConfig:
        if any(h < 1 for h in self.hidden):
            raise ValueError("hidden units must be positive")
        if self.batch_size > self.buffer_size:
            raise ValueError("batch_size must not exceed buffer_size")
        return self


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


def variant_names() -> list[str]:
    """Registered variant names in the paper's order."""
    return list(VARIANTS)


def get_variant(name: str, overrides: dict[str, Any] | None = None) -> AgentConfig:
    """The registered variant ``name`` with ``overrides`` applied and validated.

    Unknown names, unknown override keys and out-of-range values raise UserInputError naming the
    key, so a typo in a tournament file never silently trains the default.
    """
    if name not in VARIANTS:
        raise UserInputError(f"unknown variant {name!r}; known: {', '.join(VARIANTS)}")
    base = VARIANTS[name]
    if not overrides:
        return base
    if "name" in overrides or "family" in overrides:
        raise UserInputError(f"variant {name}: overrides may not change 'name' or 'family'")
    try:
        return AgentConfig.model_validate({**base.model_dump(), **overrides})
    except ValidationError as err:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or 'value'}: {e['msg']}" for e in err.errors()
        )
        raise UserInputError(f"variant {name} overrides: {problems}") from None

"""TrainConfig: everything one training run needs, validated before anything is written.

The tournament runner builds one of these per job; ``formula-tourney train`` builds one from its
options. Every field has a description, so the CLI help and the tournament file reference come
from here.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from formula_tourney.errors import UserInputError

Reference = Literal["centre", "recorded", "mincurv"]
Device = Literal["auto", "cpu", "cuda"]


class TrainConfig(BaseModel):
    """One run: a variant trained on one track or a list, tested periodically with epsilon = 0."""

    model_config = ConfigDict(extra="forbid")

    variant: str = Field("WIN1", description="Variant name registered in agents.variants.")
    overrides: dict[str, Any] = Field(
        default_factory=dict,
        description="Variant hyperparameters to override (keys of agents.variants.AgentConfig).",
    )
    train_tracks: list[str] = Field(
        default_factory=lambda: ["oval"],
        min_length=1,
        description="Tracks to train on; one is drawn per episode (gen-<seed> names count).",
    )
    reference: Reference = Field(
        "centre",
        description="Reference line of the reward and LAC: centre (MOT), recorded (the "
        "follower bot's driven line) or mincurv (minimum-curvature racing line).",
    )
    lac: bool = Field(False, description="Add the look-ahead curvature (LAC) to the observation.")
    episodes: int = Field(100, ge=1, description="Training episodes.")
    seed: int = Field(0, ge=0, description="Seed of weights, replay, exploration and env starts.")
    max_steps: int = Field(
        1000, ge=1, description="Control steps per training episode (truncated at the end)."
    )
    random_start: bool = Field(
        True, description="Start training episodes at random places on the track."
    )
    test_every_episodes: int = Field(
        10, ge=1, description="Run the tests after every this many training episodes (and last)."
    )
    test_tracks: list[str] = Field(
        default_factory=list, description="Tracks to test on; empty means the train tracks."
    )
    test_starts: int = Field(
        3, ge=1, le=64, description="Start positions per test track, evenly spaced on the lap."
    )
    test_max_steps: int = Field(
        1500, ge=1, description="Control steps per test episode (enough for two laps)."
    )
    save_test_checkpoints: bool = Field(
        False, description="Keep a checkpoint ep-<N>.pt at every test, not only best and last."
    )
    device: Device = Field("auto", description="Torch device: auto picks CUDA when present.")
    threads: int = Field(
        1, ge=1, le=256, description="torch threads in this process (one per worker measured best)."
    )
    env_overrides: dict[str, Any] = Field(
        default_factory=dict,
        description="Extra FormulaRacing-v0 config keys (car, physics_hz, ...).",
    )

    @field_validator("train_tracks", "test_tracks")
    @classmethod
    def _no_blank(cls, v: list[str]) -> list[str]:
        if any(not isinstance(t, str) or not t.strip() for t in v):
            raise ValueError("track names must be non-empty strings")
        return v

    @property
    def effective_test_tracks(self) -> list[str]:
        return self.test_tracks or list(self.train_tracks)

    @classmethod
    def parse(cls, data: dict[str, Any], source: str = "config") -> TrainConfig:
        """Validate ``data``; errors become UserInputError naming ``source`` and the key."""
        try:
            return cls.model_validate(data)
        except ValidationError as err:
            problems = "; ".join(
                f"{'.'.join(str(p) for p in e['loc']) or 'value'}: {e['msg']}" for e in err.errors()
            )
            raise UserInputError(f"{source}: {problems}") from None

"""The env's configuration: one pydantic model that owns every FormulaRacing-v0 key.

The env, the run specification (``training.run_spec``) and tournament files all validate env keys
here, so a key's meaning, default and allowed range are written once. Two levels:

- :class:`EnvSettings` holds the knobs a study may change per run (physics, ends, reward terms,
  the car). Tournament ``env_overrides`` and ``train --env-set`` are partial EnvSettings: the keys
  a user set are ``model_fields_set``.
- :class:`EnvConfig` adds the keys a *run* owns (track, reference line, LAC, episode length,
  random starts): a run specification sets those from its own fields, so an override cannot
  silently fight them.

The reward's keys are declared in ``sim.reward`` (the reward model) and only held here.

Like highway-env, a user's dict is merged over the defaults; unlike it, unknown keys are an error.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from formula_tourney.errors import UserInputError
from formula_tourney.field_marks import marks
from formula_tourney.sim import reward as R
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.track import Track


def _real(value: Any) -> Any:
    """Numbers only: pydantic's lax mode would turn ``true`` or ``"3"`` into a float."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(
        value, (int, float, np.integer, np.floating)
    ):
        raise ValueError(f"expected a number, got {value!r}")
    if not math.isfinite(float(value)):
        raise ValueError(f"expected a finite number, got {value!r}")
    return float(value)


def _integer(value: Any) -> Any:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"expected an integer, got {value!r}")
    return int(value)


def _boolean(value: Any) -> Any:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"expected true or false, got {value!r}")
    return bool(value)


Real = Annotated[float, BeforeValidator(_real)]
Integer = Annotated[int, BeforeValidator(_integer)]
Boolean = Annotated[bool, BeforeValidator(_boolean)]

GRIP_MIN, GRIP_MAX = 0.2, 1.5
GripScale = Annotated[Real, Field(ge=GRIP_MIN, le=GRIP_MAX)]
"""A friction multiplier (ice ~0.3, wet ~0.6-0.8, dry 1): the one range every grip key shares."""

RUN_OWNED_KEYS: tuple[str, ...] = ("track", "reference_line", "lac", "max_steps", "random_start",
                                   "curriculum_starts_m", "limit_speeds_mps")  # fmt: skip
"""Env keys a run specification sets from its own fields (never from env overrides)."""


class GripDrying(BaseModel):
    """A drying track: each episode starts at ``start`` grip, which rises linearly with the
    distance driven to ``grip_scale`` (the dry grip) after ``over_laps`` laps and stays there."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    start: GripScale = Field(description="Grip scale at the start of every episode (wet).")
    over_laps: Annotated[Real, Field(gt=0.0, le=1000.0)] = Field(
        description="Laps of distance driven (since reset) until the track is dry."
    )


class EnvSettings(BaseModel):
    """FormulaRacing-v0 settings a study may change; every run of a tournament part shares them."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    lac_distances_m: tuple[Annotated[Real, Field(gt=0.0)], ...] = Field(
        (20.0, 40.0, 60.0, 80.0),
        min_length=1,
        max_length=32,
        description="Distances ahead (m) at which LAC reads the reference line's curvature "
        "(each in (0, track length); the env checks the upper bound once it has the track).",
    )
    control_period_s: Real = Field(
        0.2, gt=0.0, le=10.0, description="Seconds between two actions (the paper's 200 ms)."
    )
    physics_hz: Real = Field(
        100.0, ge=100.0, le=10000.0, description="Physics substeps per second inside a step."
    )
    terminate_off_track: Boolean = Field(
        True, description="End the episode (terminated, reward -1) when the car leaves the track."
    )
    terminate_backwards: Boolean = Field(
        True, description="End the episode (terminated) when the car drives backwards."
    )
    terminate_slow: Boolean = Field(
        True, description="End the episode (terminated) after too slow progress."
    )
    slow_speed_kmh: Real = Field(
        10.0, ge=0.0, le=400.0, description="Below this speed a step counts as slow."
    )
    slow_patience_steps: Integer = Field(
        25, ge=1, description="Consecutive slow steps that end the episode."
    )
    slow_penalty: Real = R.BY_NAME["slow_penalty"].field()
    damage_weight: Real = R.BY_NAME["damage_weight"].field()
    track_pos_weight: Real = R.BY_NAME["track_pos_weight"].field()
    progress_reward: Boolean = R.BY_NAME["progress_reward"].field()
    wall_energy_weight: Real = R.BY_NAME["wall_energy_weight"].field()
    overspeed_crash_weight: Real = R.BY_NAME["overspeed_crash_weight"].field()
    start_speed_mps: Real = Field(
        0.0, ge=0.0, le=100.0, description="Speed at reset along the reference line."
    )
    grass_width_m: Real = Field(
        5.0, ge=0.0, le=100.0, description="Grass beyond each asphalt edge before the wall."
    )
    grip_scale: GripScale = Field(
        1.0,
        description="Multiplier on every surface's friction (road and side): < 1 a slippery "
        "track, > 1 a grippy one (docs/sim.md, Surfaces).",
    )
    grip_scale_range: tuple[GripScale, GripScale] | None = Field(
        None,
        description="[lo, hi]: each episode (each car's, in a vector env) draws its grip scale "
        "uniformly from this range with the env's seeded RNG, in place of grip_scale (leave "
        "grip_scale at 1). None: every episode at grip_scale.",
        json_schema_extra=marks(added_in_layout=2),
    )
    grip_drying: GripDrying | None = Field(
        None,
        description="A drying track, {start, over_laps}: each episode's grip rises from start "
        "to grip_scale over that many laps driven. None: no drying.",
        json_schema_extra=marks(added_in_layout=2),
    )
    action_mode: Literal["paper", "pedal"] = Field(
        "paper",
        description="Beyond the paper with 'pedal': the action is (steer, pedal) in [-1, 1]^2, "
        "pedal > 0 the throttle and pedal < 0 the brake pressure (Fuchs et al. 2021's Gran "
        "Turismo driver), so noise around 0 brakes half the time and both pedals are never "
        "pressed at once. 'paper': (steer, throttle, brake).",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    start_curriculum: Literal["none", "braking"] = Field(
        "none",
        description="Beyond the paper with 'braking': a share start_curriculum_share of "
        "training episodes starts before a braking zone of the reference line's QSS speed "
        "profile (training.curriculum), where exploration rarely brakes long enough; tests "
        "start as always. 'none': every start as random_start says.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    start_curriculum_share: Annotated[Real, Field(ge=0.0, le=1.0)] = Field(
        0.5,
        description="Beyond the paper: the share of training episodes the start curriculum "
        "places (the rest start as random_start says).",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    start_curriculum_speed: Annotated[Real, Field(ge=0.0, le=1.0)] = Field(
        0.0,
        description="Beyond the paper: a curriculum start rolls at this fraction of the "
        "reference limit's speed there (limit_speeds_mps, which a training run fills), so the "
        "car meets the braking zone as fast as a lap would bring it: from rest it reaches a "
        "hairpin too slowly to need the brakes. 0: at start_speed_mps, as other starts.",
        json_schema_extra=marks(added_in_layout=2, beyond_paper=True),
    )
    car: dict[str, Any] = Field(
        default_factory=dict,
        description="Overrides of the car's physical constants (keys of sim.car_params."
        "CarParams, e.g. mu, mass_kg).",
    )

    @field_validator("car")
    @classmethod
    def _car_params(cls, value: dict[str, Any]) -> dict[str, Any]:
        try:
            CarParams(**value)
        except ValidationError as err:
            problems = "; ".join(
                f"{'.'.join(str(p) for p in e['loc']) or 'value'}: {e['msg']}"
                for e in err.errors()
            )
            allowed = ", ".join(CarParams.model_fields)
            raise ValueError(
                f"invalid car parameters ({problems}); allowed keys: {allowed}"
            ) from None
        return dict(value)

    @model_validator(mode="after")
    def _one_grip_source(self) -> EnvSettings:
        """An episode's grip comes from one key: a range drawn at reset, a drying schedule or
        the fixed grip_scale; two of them would each silently override the other."""
        if self.grip_scale_range is not None:
            lo, hi = self.grip_scale_range
            if lo > hi:
                raise ValueError(f"grip_scale_range: lo {lo} above hi {hi}; give [lo, hi]")
            if self.grip_drying is not None:
                raise ValueError("grip_scale_range and grip_drying: set one, not both")
            if self.grip_scale != 1.0:
                raise ValueError("grip_scale_range replaces grip_scale: leave grip_scale at 1")
        return self

    @model_validator(mode="after")
    def _curriculum_speed_has_curriculum(self) -> EnvSettings:
        if self.start_curriculum_speed > 0.0 and self.start_curriculum == "none":
            raise ValueError("start_curriculum_speed sets the speed of the start curriculum's "
                             "starts: it needs start_curriculum 'braking'")
        return self

    def car_params(self) -> CarParams:
        """The car these settings describe."""
        return CarParams(**self.car)

    def overrides(self) -> dict[str, Any]:
        """Only the keys a user set, as plain JSON-able values (what a run spec stores)."""
        return self.model_dump(mode="json", exclude_unset=True)

    @classmethod
    def parse(cls, data: Mapping[str, Any] | None, source: str = "env overrides") -> EnvSettings:
        """Validate a user's partial dict; UserInputError names ``source``, the key and the
        allowed keys."""
        return _parse(cls, data, source)


class EnvConfig(EnvSettings):
    """Every FormulaRacing-v0 key: the settings plus what one run (or one drive) sets itself."""

    model_config = ConfigDict(extra="forbid", frozen=True, arbitrary_types_allowed=True)

    track: str | Track = Field(
        "oval", description="Track name (built-in, user, gen-<seed>, .toml/.xml path) or Track."
    )
    reference_line: Any = Field(
        "centre",
        description="'centre' or one lateral offset (m, left > 0) per track sample "
        "(bots.line_offsets.reference_offsets gives the other lines).",
    )
    lac: Boolean = Field(False, description="Add the look-ahead curvature to the observation.")
    max_steps: Integer = Field(
        1000, ge=1, description="Control steps per episode; the end is a truncation."
    )
    random_start: Boolean = Field(
        False, description="Start each episode at a random place on the track."
    )
    curriculum_starts_m: tuple[Real, ...] = Field(
        (),
        description="Track positions (m) that a share start_curriculum_share of episodes "
        "starts at, drawn uniformly among them; a training run fills them for its "
        "start_curriculum (training.curriculum). Empty: none.",
    )

    limit_speeds_mps: tuple[Real, ...] = Field(
        (),
        description="The reference limit's QSS speed (m/s) at each track sample, which the "
        "reward's overspeed_crash_weight term and start_curriculum_speed read; a training run "
        "fills it "
        "(training.envs). Empty: none.",
    )

    @model_validator(mode="after")
    def _limit_speeds_where_read(self) -> EnvConfig:
        """The keys that read the limit's speeds: the overspeed crash term and the curriculum's
        rolling starts."""
        for key in ("overspeed_crash_weight", "start_curriculum_speed"):
            if getattr(self, key) > 0.0 and not self.limit_speeds_mps:
                raise ValueError(
                    f"{key} needs limit_speeds_mps, the limit's speed at each track sample (a "
                    "training run fills them: training.envs.RunEnvs)"
                )
        return self

    @model_validator(mode="after")
    def _curriculum_has_starts(self) -> EnvConfig:
        if self.start_curriculum != "none" and not self.curriculum_starts_m:
            raise ValueError(
                f"start_curriculum {self.start_curriculum!r} needs curriculum_starts_m (a "
                "training run fills them: training.curriculum.braking_starts)"
            )
        return self

    @field_validator("track", mode="before")
    @classmethod
    def _track(cls, value: Any) -> Any:
        # Before pydantic's own union check: Track is a dataclass, which pydantic would also
        # build from a dict, and its union errors name 'track.str' / 'track.Track'.
        if not isinstance(value, (str, Track)):
            raise ValueError(f"expected a track name or a Track, got {type(value).__name__}")
        return value

    @field_validator("reference_line")
    @classmethod
    def _reference(cls, value: Any) -> Any:
        if isinstance(value, str):
            if value != "centre":
                raise ValueError(
                    f"{value!r} is not 'centre'; pass an array of offsets "
                    "(bots.line_offsets.reference_offsets) for other lines"
                )
            return value
        try:
            offsets = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            offsets = np.empty(0)
        if offsets.ndim != 1 or offsets.size == 0 or not np.all(np.isfinite(offsets)):
            raise ValueError(
                "expected 'centre' or a 1-D array of finite offsets (one per track sample)"
            )
        return offsets

    def as_dict(self) -> dict[str, Any]:
        """Every key with its value, as the env's ``config`` dict (values not copied or dumped:
        a Track or an offsets array stays the object that was passed)."""
        out = {name: getattr(self, name) for name in type(self).model_fields}
        out["car"] = dict(self.car)
        return out

    @classmethod
    def parse(cls, data: Mapping[str, Any] | EnvSettings | None, source: str = "config",
              ) -> EnvConfig:
        """Validate a dict merged over the defaults (or take an EnvConfig / EnvSettings)."""
        return _parse(cls, data, source)


class ResetOptions(BaseModel):
    """``options`` of ``env.reset``: where and how fast the car starts (default: the config's)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    start_s_m: Real | None = Field(
        None, description="Track position (m along the centreline) of the start; any real "
        "number, taken modulo the track length."
    )
    start_speed_mps: Real | None = Field(
        None, ge=0.0, le=100.0, description="Speed at the start along the reference line."
    )

    @classmethod
    def parse(cls, data: Mapping[str, Any] | None) -> ResetOptions:
        return _parse(cls, data, "reset options", noun="option")


def _parse(model: type[BaseModel], data: Any, source: str, noun: str = "config key") -> Any:
    if data is None:
        return model()
    if type(data) is model:
        return data  # already validated (frozen), nothing to merge
    if isinstance(data, EnvSettings):
        data = {k: getattr(data, k) for k in data.model_fields_set}
    if not isinstance(data, Mapping):
        raise UserInputError(f"{source}: expected a dict, got {type(data).__name__}")
    try:
        return model.model_validate(dict(data))
    except ValidationError as err:
        raise UserInputError(describe(err, model, source, noun)) from None


def describe(err: ValidationError, model: type[BaseModel], source: str,
             noun: str = "config key") -> str:
    """``source: config key 'k': problem`` lines, listing the allowed keys for unknown ones."""
    lines = []
    for item in err.errors():
        key = ".".join(str(p) for p in item["loc"]) or "value"
        if item["type"] == "extra_forbidden":
            lines.append(
                f"{source}: unknown {noun} '{key}'; known {noun.split()[-1]}s: "
                f"{', '.join(sorted(model.model_fields))}"
            )
        else:
            msg = str(item["msg"]).removeprefix("Value error, ")
            # a check across keys (a model validator) has no location; its message names them
            lines.append(f"{source}: {noun} '{key}': {msg}" if item["loc"] else f"{source}: {msg}")
    return "\n".join(lines)


def default_config() -> dict[str, Any]:
    """Every env key with its default (highway-env style), as a plain dict."""
    return dict(EnvConfig().model_dump())

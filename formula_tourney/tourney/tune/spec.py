"""The tune file: ``[train]`` settings, ``[search]`` space, objective, sampler, pruner, retries.

The search space's keys are the variant's hyperparameters (``agents.variants.AgentConfig``);
``[train]`` takes the same job settings as a tournament part. A trial's run specification is
built by ``training.run_spec.build_run_spec`` through :func:`trial_spec`, the same path the
tournament plan takes; :func:`check_tune` builds the specs of the search space's corners in the
parent, so an impossible value fails before a study is created. ``[objective]`` picks what a
trial scores: its best clean test lap (the default), or the CPU-seconds it takes to a milestone
(``tourney.tune.worker.CpuMilestone``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from formula_tourney.agents.variants import AgentConfig
from formula_tourney.errors import UserInputError
from formula_tourney.safeio import check_name
from formula_tourney.tourney.plan import spec_settings
from formula_tourney.tourney.spec import (
    JobSettings,
    Setup,
    describe_errors,
    error_at,
    parse_toml,
    read_spec_text,
)
from formula_tourney.training.run_spec import RunSpec, build_run_spec


class SearchParam(BaseModel):
    """One dimension of the search space: a float/int range or a list of choices."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    type: Literal["float", "int", "categorical"] | None = Field(
        None, description="float, int or categorical (default: categorical with choices, "
        "int when low and high are integers, else float)."
    )
    low: float | None = Field(None, description="Lower bound (inclusive).")
    high: float | None = Field(None, description="Upper bound (inclusive).")
    log: bool = Field(False, description="Sample on a log scale (learning rates).")
    step: float | None = Field(None, gt=0, description="Grid step inside [low, high].")
    choices: list[Any] | None = Field(None, min_length=1, description="Values to choose from.")

    @model_validator(mode="after")
    def _shape(self) -> SearchParam:
        if self.choices is None and (self.low is None or self.high is None):
            raise ValueError("give low and high, or choices")
        if self.low is not None and self.high is not None and self.low > self.high:
            raise ValueError("low must be <= high")
        if self.log and self.low is not None and self.low <= 0:
            raise ValueError("log scale needs low > 0")
        return self

    def kind(self) -> str:
        if self.type is not None:
            return self.type
        if self.choices is not None:
            return "categorical"
        if float(self.low).is_integer() and float(self.high).is_integer() and (
            self.step is None or float(self.step).is_integer()
        ) and not self.log:
            return "int"
        return "float"

    def corners(self) -> list[Any]:
        """The values that bound this dimension (its ends, or every choice)."""
        if self.kind() == "categorical":
            return list(self.choices or [])
        cast = int if self.kind() == "int" else float
        return [cast(self.low), cast(self.high)]


class TuneTrain(JobSettings):
    """What each trial trains: tracks, one reference setup, and the job settings."""

    train_tracks: list[str] = Field(min_length=1, description="Tracks trained on; the lap on "
                                    "the first is the objective.")
    test_tracks: list[str] | None = Field(None, description="Tracks tested (default: train).")
    setup: Setup = Field(default_factory=Setup, description="Reference line and LAC.")
    seed: int = Field(0, ge=0, description="Training seed of every trial (one seed per trial).")


class Sampler(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    seed: int | None = Field(
        0, description="TPE seed (reproducible suggestions); each worker process draws from its "
        "own stream derived from it."
    )
    n_startup_trials: int = Field(5, ge=0, description="Random trials before TPE models.")


class Pruner(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    kind: Literal["median", "none"] = Field("median", description="median: stop a trial whose "
                                            "reported value is worse than the median of the "
                                            "complete trials at that step.")
    n_startup_trials: int = Field(3, ge=0, description="Trials never pruned.")
    n_warmup_steps: int = Field(0, ge=0, description="Steps before pruning starts: episodes "
                                "for best_lap, percent of budget_cpu_s for the cpu_s_* kinds.")


OBJECTIVE_KINDS: tuple[str, ...] = ("best_lap", "cpu_s_to_first_clean_lap",
                                    "cpu_s_to_beat_follower")  # fmt: skip
CPU_KINDS: tuple[str, ...] = OBJECTIVE_KINDS[1:]
_OBJECTIVE_VALUES = {
    "kind": ", ".join(OBJECTIVE_KINDS),
    "line": "centre, mincurv",
    "budget_cpu_s": "CPU-seconds > 0",
    "penalty_factor": "a number > 1",
}


class Objective(BaseModel):
    """What a trial scores (lower is better)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["best_lap", "cpu_s_to_first_clean_lap", "cpu_s_to_beat_follower"] = Field(
        "best_lap", description="best_lap: the best clean test lap on the key track (s); "
        "cpu_s_to_first_clean_lap: CPU-seconds of training until a test's first clean lap; "
        "cpu_s_to_beat_follower: CPU-seconds until a clean test lap faster than the follower "
        "bot on `line`."
    )
    line: Literal["centre", "mincurv"] = Field(
        "centre", description="cpu_s_to_beat_follower: the line of the key track the follower "
        "drives (its best of 2 laps, for the run's car, is the lap to beat)."
    )
    budget_cpu_s: float | None = Field(
        None, gt=0, description="cpu_s_* kinds (required): a trial stops at its milestone or "
        "when its process CPU time since the start of training passes this."
    )
    penalty_factor: float = Field(
        2.0, gt=1, description="cpu_s_* kinds: a trial that misses its milestone within the "
        "budget scores budget_cpu_s x penalty_factor."
    )

    @property
    def cpu(self) -> bool:
        """Whether this objective counts CPU-seconds (else it is the best lap)."""
        return self.kind in CPU_KINDS

    def miss_score(self) -> float:
        """The value of a trial that misses its milestone (cpu_s_* kinds)."""
        return float(self.budget_cpu_s or 0.0) * self.penalty_factor


class TuneSpec(BaseModel):
    """A tune file: ``[train]`` settings, ``[search]`` space, sampler, pruner, retries."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(description="Results go to <results>/<name>/optuna/.")
    train: TuneTrain = Field(description="What each trial trains.")
    search: dict[str, SearchParam] = Field(min_length=1, description="Search space by "
                                           "hyperparameter name.")
    sampler: Sampler = Field(default_factory=Sampler, description="TPE sampler settings.")
    pruner: Pruner = Field(default_factory=Pruner, description="Pruner settings.")
    max_retry: int = Field(2, ge=0, description="Times a trial killed with its process is "
                           "run again with the same parameters.")
    no_finish_penalty_s: float = Field(1000.0, gt=0, description="best_lap objective of a "
                                       "trial without a clean lap.")
    objective: Objective = Field(default_factory=Objective, description="What a trial scores: "
                                 "an [objective] table, or just its kind.")


def load_tune_spec(path: str | Path) -> tuple[TuneSpec, str]:
    """Read and validate a tune file (search keys checked against AgentConfig's fields)."""
    path = Path(path)
    text = read_spec_text(path, "tune")
    raw = parse_toml(text, path)
    for key in raw:
        if key not in TuneSpec.model_fields:
            raise error_at(path, text, (key,), "unknown key; allowed keys: "
                           f"{', '.join(TuneSpec.model_fields)}")
    if "objective" in raw:
        raw["objective"] = _objective(raw["objective"], path, text).model_dump(exclude_unset=True)
    try:
        spec = TuneSpec.model_validate(raw)
    except ValidationError as err:
        raise UserInputError(describe_errors(err, path, text, TuneSpec)) from None
    try:
        check_name(spec.name, "tune name")
    except UserInputError as err:
        raise error_at(path, text, ("name",), str(err)) from None
    allowed = [k for k in AgentConfig.model_fields if k not in ("name", "family")]
    for key in spec.search:
        if key not in allowed:
            raise error_at(path, text, ("search", key),
                           f"unknown hyperparameter; allowed values: {', '.join(allowed)}")
    return spec, text


def _objective(value: Any, path: Path, text: str) -> Objective:
    """The ``objective`` table (or a bare kind) checked key by key: every problem names its line
    and the allowed values, and a key that the kind does not use is an error."""
    if isinstance(value, str):
        value = {"kind": value}
    if not isinstance(value, dict):
        raise error_at(path, text, ("objective",), "give a table (kind = ..., budget_cpu_s = ...) "
                       f"or a kind; allowed kinds: {_OBJECTIVE_VALUES['kind']}")
    for key in value:
        if key not in Objective.model_fields:
            raise error_at(path, text, ("objective", key), "unknown key; allowed keys: "
                           f"{', '.join(Objective.model_fields)}")
    try:
        objective = Objective.model_validate(value)
    except ValidationError as err:
        item = err.errors()[0]
        key = str(item["loc"][0])
        problem = " is not allowed" if item["type"] == "literal_error" else f": {item['msg']}"
        raise error_at(path, text, ("objective", key), f"{value.get(key)!r}{problem}; "
                       f"allowed values: {_OBJECTIVE_VALUES[key]}") from None
    kinds = ", ".join(CPU_KINDS)
    if objective.cpu and objective.budget_cpu_s is None:
        raise error_at(path, text, ("objective", "kind"), f"{objective.kind} needs budget_cpu_s "
                       f"(allowed values: {_OBJECTIVE_VALUES['budget_cpu_s']})")
    for key in ("budget_cpu_s", "penalty_factor"):
        if not objective.cpu and key in value:
            raise error_at(path, text, ("objective", key), f"only the CPU-second kinds take "
                           f"{key}; allowed with kind = {kinds}")
    if "line" in value and objective.kind != "cpu_s_to_beat_follower":
        raise error_at(path, text, ("objective", "line"), "only kind = cpu_s_to_beat_follower "
                       "takes a line")
    return objective


def trial_spec(
    spec: TuneSpec, variant: str, params: dict[str, Any], base_dir: Path, source: str
) -> RunSpec:
    """The run specification of one trial: ``[train]`` with the trial's hyperparameters."""
    train = spec.train
    settings = {k: getattr(train, k) for k in JobSettings.model_fields}
    return build_run_spec(
        variant=variant, overrides={**(train.variant_overrides or {}), **params},
        train_tracks=train.train_tracks, test_tracks=train.test_tracks,
        reference=train.setup.reference, lac=train.setup.lac, seed=train.seed,
        track_base_dir=base_dir, source=source, **spec_settings(settings),
    )  # fmt: skip


def check_tune(spec: TuneSpec, text: str, path: Path, variant: str) -> RunSpec:
    """Build the trial spec at every corner of the search space (one dimension at a time, the
    others at the variant's values); errors name the file and line. Returns the base spec."""
    base_dir = path.resolve().parent
    try:
        base = trial_spec(spec, variant, {}, base_dir, f"{path}: [train]")
    except UserInputError as err:
        raise error_at(path, text, ("train",), str(err)) from None
    for name, param in spec.search.items():
        for value in param.corners():
            try:
                trial_spec(spec, variant, {name: value}, base_dir, f"{path}: search.{name}")
            except UserInputError as err:
                raise error_at(path, text, ("search", name),
                               f"{value!r} is not a valid {name} for {variant}: {err}") from None
    return base

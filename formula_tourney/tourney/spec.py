"""The tournament file: a pydantic schema for ``tournaments/*.toml`` and errors that point at lines.

A tournament declares variants (name, family, hyperparameter overrides), studies made of ordered
parts (entrants or "promoted from part X", train/test tracks, reference-line setups with LAC on or
off, episodes, seeds, test schedule), promotion rules, baselines to race and the model selection
(best lap, or the paper's "general model"). Every field carries a description, so the TOML
reference in ``docs/tourney.md``, ``--help`` and error messages come from one place.

Job settings are not redefined here: a part's schedule keys, device and threads take their type,
range and description from ``training.run_spec`` (``Schedule``, ``RunSpec``), its env overrides are
``sim.config.EnvSettings``, so a bad value is an error at its line before anything is planned.

Errors are ``UserInputError`` naming ``file:line: key`` and the allowed values. ``tomllib`` keeps
no line numbers, so :class:`TomlLocator` scans the text once (linear in its size) and maps each
key to its line; files over :data:`MAX_SPEC_BYTES` are refused before they are read.
"""

from __future__ import annotations

import functools
import math
import re
import stat
import tomllib
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from formula_tourney.agents.outside.naming import FORMS as OUTSIDE_FORMS
from formula_tourney.agents.outside.naming import OutsideEntrant
from formula_tourney.agents.variants import ALL_VARIANTS, BEYOND_PAPER_VARIANTS, VARIANTS
from formula_tourney.claims.schema import ClaimSet
from formula_tourney.errors import UserInputError
from formula_tourney.lines.kinds import LINE_LABELS, ReferenceKind
from formula_tourney.race.settings import RaceSettings
from formula_tourney.results.layout import (
    ADAPTIVE_FILE,
    BASELINE_DIR,
    ESTIMATE_FILE,
    INDEX_FILE,
    LOCK_FILE,
    OPTUNA_DIR,
    RACES_DIR,
)
from formula_tourney.safeio import check_name, read_user_text
from formula_tourney.sim.config import RUN_OWNED_KEYS, EnvSettings
from formula_tourney.training.presets import PRESETS, get_preset
from formula_tourney.training.run_spec import (
    MAX_SEED,
    RUN_OWNED_HINTS,
    DemoSettings,
    RunSpec,
    Schedule,
)

MAX_SPEC_BYTES = 1024 * 1024
"""Largest tournament or tune file read (1 MiB; study2.toml is under 4 KiB). A bigger file is
refused by its size before it is read, so a huge or endless file cannot stall a dry run."""

# The paper's ten variants (section "Algorithms"); agents.variants defines what each one is.
PAPER_VARIANTS: tuple[str, ...] = tuple(VARIANTS)
# Registered variants of families the paper did not race (TD3, SAC): entrants = "all+beyond"
BEYOND_PAPER: tuple[str, ...] = tuple(BEYOND_PAPER_VARIANTS)
ALL_AND_BEYOND_ENTRANTS = "all+beyond"
"""``entrants`` value for "all" plus every registered variant beyond the paper."""


def default_family(variant: str) -> str:
    """The paper's family of a registered variant (WIN* -> DDPG, PER1M -> PER), else the name's
    leading letters."""
    if variant in ALL_VARIANTS:
        return str(ALL_VARIANTS[variant].family)
    match = re.match(r"[A-Za-z]+", variant)
    return match.group(0).upper() if match else variant


RESERVED_NAMES: tuple[str, ...] = (INDEX_FILE, ESTIMATE_FILE, LOCK_FILE, OPTUNA_DIR,
                                   BASELINE_DIR, RACES_DIR, ADAPTIVE_FILE)
"""Names the results folder of a tournament uses itself (``results.layout``): a part named so
would be a folder where a file lives. Names starting with one are refused too (the index's
``index.sqlite.corrupt``, ``index.sqlite-journal``)."""

MAX_NESTING = 100
"""Deepest nesting of arrays and inline tables read (a tournament file needs 4)."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def _check_preset(value: str | None) -> str | None:
    """A preset name known to ``training.presets`` (its error lists the known ones)."""
    if value is not None:
        try:
            get_preset(value)
        except UserInputError as err:
            raise ValueError(str(err)) from None
    return value


def _unset_or(model: type[BaseModel], name: str) -> Any:
    """The type of ``model.<name>`` made optional (None = unset here), keeping the owner's
    constraints and description, so a range is written once (in ``training.run_spec``)."""
    info = model.model_fields[name]
    inner = Annotated[(info.annotation, *info.metadata)] if info.metadata else info.annotation
    return Annotated[inner | None, Field(description=info.description)]


class VariantEntry(_Strict):
    """One competitor algorithm: a named agents variant plus hyperparameter overrides."""

    base: str | None = Field(
        None,
        description="Name of the agents variant this entry configures (default: the table key, "
        "e.g. WIN4).",
    )
    family: str | None = Field(
        None,
        description="Family for 'best per family' promotion (default: the base variant's family "
        "in agents.variants: DDPG, LSTM, MS, PER, or TD3, SAC beyond the paper).",
    )
    overrides: dict[str, Any] = Field(
        default_factory=dict,
        description="Variant hyperparameters to change (keys of agents.variants.AgentConfig).",
    )
    demos: DemoSettings | None = Field(
        None,
        description="Learn from the follower's demonstrations (beyond the paper; the entrant is "
        "labelled so); wins over the part's demos.",
    )
    cars: _unset_or(Schedule, "cars") = None
    env_steps: _unset_or(Schedule, "env_steps") = None
    preset: str | None = Field(
        None,
        description=f"Named settings preset (training.presets: {', '.join(PRESETS)}); wins "
        "over the part's; anything but 'paper' is labelled beyond the paper.",
    )

    impl: str | None = Field(None, description=OutsideEntrant.model_fields["impl"].description)
    entry: str | None = Field(None, description=OutsideEntrant.model_fields["entry"].description)
    sb3: str | None = Field(None, description=OutsideEntrant.model_fields["sb3"].description)
    sb3_contrib: str | None = Field(
        None, description=OutsideEntrant.model_fields["sb3_contrib"].description
    )
    kwargs: dict[str, Any] | None = Field(
        None, description=OutsideEntrant.model_fields["kwargs"].description
    )
    settings: dict[str, Any] | None = Field(
        None, description=OutsideEntrant.model_fields["settings"].description
    )

    _preset = field_validator("preset")(_check_preset)

    @model_validator(mode="after")
    def _outside(self) -> VariantEntry:
        """An outside entrant is named by exactly one form and takes none of our variants'
        agent keys (base, overrides, demos)."""
        named = [k for k in OUTSIDE_FORMS if getattr(self, k) is not None]
        if not named and (self.kwargs is not None or self.settings is not None):
            raise ValueError(f"kwargs/settings belong to an outside entrant: give one of "
                             f"{', '.join(OUTSIDE_FORMS)}")  # fmt: skip
        if named:
            ours = [k for k in ("base", "overrides", "demos") if k in self.model_fields_set]
            if ours:
                raise ValueError(f"{', '.join(ours)}: an outside entrant ({named[0]}) takes no "
                                 "agent keys of our variants; its own go in settings (impl, "
                                 "entry) or kwargs (sb3, sb3_contrib)")  # fmt: skip
            self.outside()  # exactly one form, a well-formed impl
        return self

    def outside(self) -> OutsideEntrant | None:
        """The outside entrant this entry names, or None for one of our variants."""
        if all(getattr(self, k) is None for k in OUTSIDE_FORMS):
            return None
        return OutsideEntrant(**{k: getattr(self, k) for k in OUTSIDE_FORMS},
                              kwargs=self.kwargs or {}, settings=self.settings or {})  # fmt: skip


class Setup(_Strict):
    """A reference line and whether the agent sees its look-ahead curvature (LAC)."""

    reference: ReferenceKind = Field(
        "centre",
        description="Reference line of reward and telemetry: centre (paper's MOT), recorded "
        "(the follower bot's driven line, paper's RC) or mincurv (minimum-curvature line).",
    )
    lac: bool = Field(False, description="Add look-ahead curvature of the reference line to the "
                      "observation.")


class Baseline(_Strict):
    """A non-learning driver raced on every track of a part, for the lap-time tables."""

    bot: Literal["follower", "genetic"] = Field(
        description="follower: the handcrafted line follower (the paper's Tita); genetic: the "
        "follower on a line found by the genetic search (Cardamone et al. 2010)."
    )
    reference: ReferenceKind = Field(
        "mincurv",
        description="Line the follower bot drives (ignored for the genetic bot, which drives "
        "its own line).",
    )
    laps: int = Field(2, ge=1, le=20, description="Laps driven; the best clean lap counts.")


class Promotion(_Strict):
    """Who goes from the source part to this one: ranked by lap time over seeds."""

    metric: Literal["aLT", "bLT"] = Field(
        "aLT",
        description="Ranking: aLT = mean over seeds of each seed's best clean lap (the paper's "
        "choice); bLT = the best clean lap of any seed.",
    )
    best_per_family: bool = Field(
        True, description="Keep only the best entrant of each family (DDPG, LSTM, MS, PER)."
    )
    top_k: int | None = Field(
        None, ge=1, description="Then keep the k best overall (all when omitted)."
    )
    min_finish_rate: float = Field(
        0.0,
        ge=0.0,
        le=1.0,
        description="Fraction of an entrant's seeds that must have a clean timed lap to be ranked.",
    )
    unfinished: Literal["exclude", "by_distance"] = Field(
        "exclude",
        description="Entrants below the finish rate: exclude (the paper ranks lap times only), "
        "or classify them after all finishers by the mean distance their tests covered (as "
        "motorsport classifies retirements; for short demo budgets).",
    )


class Selection(_Strict):
    """Which checkpoint of a run is reported: the best lap, or the paper's general model."""

    kind: Literal["best", "general"] = Field(
        "best",
        description="best: the best clean lap on the train track; general: among periodic test "
        "checkpoints that also finish every unseen test track, the best on the train track (for "
        "runs never tested on their train tracks: clean laps on the most unseen tracks).",
    )
    min_unseen_finish_rate: float = Field(
        0.5,
        gt=0.0,
        le=1.0,
        description="For 'general': fraction of the test starts on each unseen track that must "
        "finish a lap (not read for runs never tested on their train tracks).",
    )


class JobSettings(_Strict):
    """Training settings of every job in a part; unset values fall back to [defaults], then to
    the run specification's own defaults (``training.run_spec.Schedule`` and ``RunSpec``)."""

    seeds: int | None = Field(None, ge=1, le=1000, strict=True,
                              description="Independent runs per entrant.")
    episodes: _unset_or(Schedule, "episodes") = None
    env_steps: _unset_or(Schedule, "env_steps") = None
    max_steps: _unset_or(Schedule, "max_steps") = None
    random_start: _unset_or(Schedule, "random_start") = None
    test_every_episodes: _unset_or(Schedule, "test_every_episodes") = None
    test_starts: _unset_or(Schedule, "test_starts") = None
    test_max_steps: _unset_or(Schedule, "test_max_steps") = None
    save_test_checkpoints: _unset_or(Schedule, "save_test_checkpoints") = None
    test_grip_scales: _unset_or(Schedule, "test_grip_scales") = None
    cars: _unset_or(Schedule, "cars") = None
    traffic_bots: _unset_or(Schedule, "traffic_bots") = None
    budget_cpu_s: _unset_or(Schedule, "budget_cpu_s") = None
    stop_at: _unset_or(Schedule, "stop_at") = None
    resume_every_cpu_s: _unset_or(Schedule, "resume_every_cpu_s") = None
    demos: DemoSettings | None = Field(
        None, description="Demonstrations for every entrant here (beyond the paper)."
    )
    preset: str | None = Field(
        None, description="Named settings preset for every entrant here (training.presets)."
    )
    device: _unset_or(RunSpec, "device") = None
    threads: _unset_or(RunSpec, "threads") = None
    env_overrides: EnvSettings | None = Field(
        None,
        description="FormulaRacing-v0 settings to change (keys of sim.config.EnvSettings, e.g. "
        "slow_patience_steps); the run's own keys (lac, max_steps, ...) are set elsewhere.",
    )
    variant_overrides: dict[str, Any] | None = Field(
        None,
        description="Hyperparameters applied to every variant here (e.g. smaller nets for a "
        "demo); a variant's own overrides win.",
    )

    _preset = field_validator("preset")(_check_preset)

    @field_validator("env_overrides", mode="before")
    @classmethod
    def _not_run_owned(cls, value: Any) -> Any:
        """An env key the run sets itself would silently fight the setup."""
        if isinstance(value, Mapping):
            owned = [k for k in value if k in RUN_OWNED_KEYS]
            if owned:
                raise ValueError("; ".join(
                    f"'{k}' is a run setting, not an env override: set it with "
                    f"{RUN_OWNED_HINTS.get(k, k)}" for k in owned
                ))  # fmt: skip
        return value


class RacePartSettings(RaceSettings):
    """A race part's races: the race rules (``race.settings.RaceSettings``) plus how many, who
    else starts, and the points."""

    races: int = Field(3, ge=1, le=100, description="Races run, each on the qualifying grid "
                       "rotated by one more slot, with seed seed + k.")
    bots: list[Literal["follower"]] = Field(default_factory=list, description="Bots that "
                                            "start too (the follower on the mincurv line).")
    points: list[float] = Field(default_factory=lambda: [25, 18, 15, 12, 10, 8, 6, 4, 2, 1],
                                min_length=1, description="Points for P1, P2, ...")
    seed: int = Field(0, ge=0, description="Seed of the first race's grid jitter.")

    @field_validator("points")
    @classmethod
    def _points(cls, value: list[float]) -> list[float]:
        if any(not math.isfinite(v) or v < 0 for v in value):
            raise ValueError("points must be finite numbers >= 0")
        return value

    def race_settings(self) -> RaceSettings:
        """The rules of one race."""
        return RaceSettings(**{k: getattr(self, k) for k in RaceSettings.model_fields})


class Part(JobSettings):
    """One stage of a study: entrants x setups x seeds jobs trained on the same tracks."""

    name: str = Field(description="Part name, also its results folder.")
    study: str = Field("main", description="Study this part belongs to (e.g. study1).")
    entrants: list[str] | Literal["all", "all+beyond"] | None = Field(
        None,
        description="Variant names competing here; \"all\" for every declared variant and the "
        "paper's ten; \"all+beyond\" for those plus the registered variants beyond the paper "
        "(TD3, SAC). Exactly one of entrants and promoted_from.",
    )
    promoted_from: str | None = Field(
        None, description="Take entrants from this earlier part, by the promotion rules."
    )
    promotion: Promotion = Field(
        default_factory=Promotion, description="How promoted_from picks its entrants."
    )
    setups: list[Setup] = Field(
        default_factory=lambda: [Setup()],
        min_length=1,
        description="Reference line / LAC combinations; each makes its own entrant "
        "(<variant>-MOT, <variant>-RC-LAC, ...).",
    )
    train_tracks: list[str] = Field(min_length=1, description="Tracks trained on (first = "
                                    "the track lap times and promotion are measured on).")
    test_tracks: list[str] | None = Field(
        None, description="Tracks tested on periodically (default: the train tracks)."
    )
    selection: Selection = Field(default_factory=Selection, description="Model selection.")
    baselines: list[Baseline] = Field(
        default_factory=list, description="Bots raced on every test track of this part."
    )
    kind: Literal["train", "race"] = Field(
        "train", description="train: entrants x setups x seeds training jobs; race: the best "
        "models of the entrants promoted from `promoted_from` race each other (and `race.bots`) "
        "on the first of `train_tracks`, one race job run by `formula-tourney run` after the "
        "source part promotes (docs/races.md).")
    race: RacePartSettings | None = Field(
        None, description="The races of a part of kind race.")

    @field_validator("name", "study")
    @classmethod
    def _safe_name(cls, value: str) -> str:
        try:
            check_name(value, "name")
        except UserInputError as err:
            raise ValueError(str(err)) from None
        if value.startswith(RESERVED_NAMES):
            raise ValueError(f"{value!r} is a name the results folder uses itself; a part or "
                             f"study name must not start with {', '.join(RESERVED_NAMES)}")
        return value

    @model_validator(mode="after")
    def _one_source(self) -> Part:
        if (self.entrants is None) == (self.promoted_from is None):
            raise ValueError("give exactly one of 'entrants' and 'promoted_from'")
        return self

    @model_validator(mode="after")
    def _race_part(self) -> Part:
        if self.kind == "race":
            if self.promoted_from is None:
                raise ValueError("a part of kind race takes its entrants with 'promoted_from' "
                                 "(their trained models)")
            if self.race is None:
                self.race = RacePartSettings()
        elif self.race is not None:
            raise ValueError("'race' settings need kind = \"race\"")
        return self

    def all_test_tracks(self) -> list[str]:
        """Test tracks, defaulting to the train tracks."""
        return list(self.test_tracks) if self.test_tracks else list(self.train_tracks)


# ------------------------------------------------------------------------ sequential runs


class Adaptive(_Strict):
    """A sequential run (``[adaptive]``; ``tourney.adaptive``): every training part starts at
    ``min_seeds`` per entrant; after each wave the claims are read again with their
    anytime-valid confidence sequences, and the next wave's seeds go to the entrants of the
    undecided claims, where one more run buys the most decision per CPU-second. The run ends
    when every claim is decided, the budget is spent, or the undecided claims' entrants are at
    ``max_seeds``. A part's own ``seeds`` is not used."""

    min_seeds: int = Field(3, ge=2, le=1000, strict=True,
                           description="Seeds every entrant of a training part starts with.")
    max_seeds: int = Field(20, ge=2, le=1000, strict=True,
                           description="Most seeds an entrant gets.")
    wave_seeds: int = Field(4, ge=1, le=1000, strict=True,
                            description="New runs (jobs) one wave adds in all; the claims are "
                            "read again after each wave (match it to the workers).")
    budget_cpu_h: float | None = Field(
        None, gt=0.0, allow_inf_nan=False,
        description="CPU-hours (summed job seconds) the seeds beyond min_seeds may bring the "
        "run to; a wave that would pass it is not started. `run --budget-cpu-h` sets it too.")

    @model_validator(mode="after")
    def _ordered(self) -> Adaptive:
        if self.max_seeds < self.min_seeds:
            raise ValueError(f"max_seeds ({self.max_seeds}) must be >= min_seeds "
                             f"({self.min_seeds})")
        return self


class Tournament(_Strict):
    """A whole tournament file: variants, default settings and the ordered parts of its studies."""

    name: str = Field(description="Tournament name: results go to <results>/<name>/.")
    description: str = Field("", description="One line shown by --dry-run and the report.")
    seed_base: int = Field(0, ge=0, le=MAX_SEED - 1000, strict=True,
                           description="Seed of run n is seed_base + n.")
    variants: dict[str, VariantEntry] = Field(
        default_factory=dict,
        description="Competitors by name. Undeclared registered variants (the paper's WIN1 ... "
        "PER1M, and TD3, SAC beyond it) are available with their defaults.",
    )
    defaults: JobSettings = Field(
        default_factory=JobSettings, description="Settings shared by all parts."
    )
    parts: list[Part] = Field(min_length=1, description="Parts in running order.")
    claims: ClaimSet | None = Field(
        None,
        description="Findings the report checks: include = [\"paper\"] and [[claims.claim]] "
        "tables (claims.schema; docs/claims.md). A sequential run ([adaptive]) reads "
        "them after every wave; otherwise the run does not use them.",
    )
    adaptive: Adaptive | None = Field(
        None, description="Run sequentially: seeds added in waves where the claims are "
        "undecided (docs/claims.md, \"Sequential runs\").",
    )

    @field_validator("name")
    @classmethod
    def _safe_name(cls, value: str) -> str:
        try:
            return check_name(value, "tournament name")
        except UserInputError as err:
            raise ValueError(str(err)) from None

    @field_validator("variants")
    @classmethod
    def _safe_variant_names(cls, value: dict[str, VariantEntry]) -> dict[str, VariantEntry]:
        for key in value:
            try:
                check_name(key, "variant name")
            except UserInputError as err:
                raise ValueError(str(err)) from None
        return value

    def variant(self, name: str) -> VariantEntry:
        """The declared entry of a variant, or the default entry of a registered variant."""
        return self.variants.get(name) or VariantEntry()

    def variant_names(self, beyond_paper: bool = False) -> list[str]:
        """Declared variants first, then the paper variants not declared (what "all" means);
        ``beyond_paper``: then the registered variants beyond the paper ("all+beyond")."""
        names = list(self.variants)
        names += [v for v in PAPER_VARIANTS if v not in self.variants]
        if beyond_paper:
            names += [v for v in BEYOND_PAPER if v not in self.variants]
        return names

    def entrant_names(self, entrants: list[str] | str) -> list[str]:
        """A part's declared ``entrants`` as variant names, "all" and "all+beyond" resolved."""
        if isinstance(entrants, str):  # the schema allows only the two keywords
            return self.variant_names(beyond_paper=entrants == ALL_AND_BEYOND_ENTRANTS)
        return list(entrants)

    def settings(self, part: Part) -> dict[str, Any]:
        """Resolved job settings of a part: part value, else [defaults] value; None = unset."""
        out: dict[str, Any] = {}
        for key in JobSettings.model_fields:
            value = getattr(part, key)
            out[key] = value if value is not None else getattr(self.defaults, key)
        return out


# ----------------------------------------------------------------------------------- locating


class TomlLocator:
    """Line numbers of keys in a TOML text, for error messages; built once per text.

    Tracks the current table while scanning, counting ``[[array]]`` headers so that the second
    ``[[parts]]`` is path ``("parts", 1)``. Values spanning lines (inline tables, arrays) map all
    their nested keys to the line of the key that opens them; the bodies of multi-line strings
    are skipped. Each line is looked at with ``str`` methods and one anchored character-class
    match, so the scan is linear in the text (a backtracking pattern here once took minutes on a
    line of spaces).
    """

    _NAME = re.compile(r"[A-Za-z0-9_\-\"'. ]+")

    def __init__(self, text: str) -> None:
        self.lines: dict[tuple[Any, ...], int] = {}
        array_counts: dict[tuple[Any, ...], int] = {}
        table: tuple[Any, ...] = ()
        open_string: str | None = None  # delimiter of the multi-line string being skipped
        for number, raw in enumerate(text.splitlines(), start=1):
            line = raw.strip()
            if open_string is not None:
                if line.count(open_string) % 2 == 1:
                    open_string = None
                continue
            if not line or line.startswith("#"):
                continue
            header = self._header(line)
            if header is not None:
                is_array, names = header
                parent = self._resolve(names[:-1], array_counts)
                if is_array:
                    base = parent + (names[-1],)
                    index = array_counts.get(base, -1) + 1
                    array_counts[base] = index
                    table = base + (index,)
                    self.lines.setdefault(base, number)
                else:
                    table = parent + (names[-1],)
                self.lines[table] = number
                continue
            eq = line.find("=")
            if eq <= 0:
                continue
            key = line[:eq].strip()
            if self._NAME.fullmatch(key):
                self.lines.setdefault(table + tuple(_split_key(key)), number)
            value = line[eq + 1:]
            for delimiter in ('"""', "'''"):
                if value.count(delimiter) % 2 == 1:
                    open_string = delimiter
                    break

    @classmethod
    def _header(cls, line: str) -> tuple[bool, tuple[str, ...]] | None:
        """``(is_array, names)`` of a ``[table]`` or ``[[array]]`` line, else None."""
        if not line.startswith("["):
            return None
        is_array = line.startswith("[[")
        close = "]]" if is_array else "]"
        end = line.find(close)
        if end < 0:
            return None
        rest = line[end + len(close):].strip()
        name = line[2 if is_array else 1:end].strip()
        if (rest and not rest.startswith("#")) or not name or not cls._NAME.fullmatch(name):
            return None
        return is_array, tuple(_split_key(name))

    @staticmethod
    def _resolve(names: tuple[str, ...], array_counts: dict[tuple[Any, ...], int]) -> tuple:
        """Insert the current index after every array-of-tables name in a header path."""
        out: tuple[Any, ...] = ()
        for name in names:
            out = out + (name,)
            if out in array_counts:
                out = out + (array_counts[out],)
        return out

    def line_of(self, loc: tuple[Any, ...]) -> int | None:
        """Line of the longest known prefix of ``loc`` (the key itself, else its table)."""
        for end in range(len(loc), 0, -1):
            line = self.lines.get(tuple(loc[:end]))
            if line is not None:
                return line
        return None


@functools.lru_cache(maxsize=4)
def locator_for(text: str) -> TomlLocator:
    """The locator of ``text``, built once however many errors point into it."""
    return TomlLocator(text)


def _split_key(text: str) -> list[str]:
    return [part.strip().strip("\"'") for part in text.split(".")]


def _model_at(loc: tuple[Any, ...], root: type[BaseModel]) -> type[BaseModel] | None:
    """The pydantic model whose fields live at ``loc`` below ``root`` (to list allowed keys)."""
    model: type[BaseModel] | None = root
    for item in loc:
        if model is None:
            return None
        if isinstance(item, int):
            continue
        field = model.model_fields.get(str(item))
        if field is None:
            return None
        model = _inner_model(field.annotation)
        if model is None and str(item) == "variants":
            model = VariantEntry
    return model


def _inner_model(annotation: Any) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):
        found = _inner_model(arg)
        if found is not None:
            return found
    return None


def _key_text(loc: tuple[Any, ...]) -> str:
    out = ""
    for item in loc:
        out += f"[{item}]" if isinstance(item, int) else (f".{item}" if out else str(item))
    return out


def describe_errors(
    err: ValidationError, path: Path, text: str, root: type[BaseModel] | None = None
) -> str:
    """Turn pydantic errors of a TOML file validated as ``root`` (default: a tournament) into
    ``file:line: key: problem (allowed ...)`` lines; tune and claims files use it too."""
    root = Tournament if root is None else root
    locator = locator_for(text)
    out = []
    for item in err.errors():
        loc = tuple(item["loc"])
        # Union members appear in the loc (e.g. 'list[str]', 'literal[...]'); drop them.
        loc = tuple(x for x in loc if isinstance(x, int) or not _looks_like_type(str(x)))
        line = locator.line_of(loc)
        where = f"{path}:{line}" if line else str(path)
        msg = item["msg"]
        if item["type"] == "extra_forbidden":
            model = _model_at(loc[:-1], root) if len(loc) > 1 else root
            if root is Tournament and loc and loc[0] == "variants" and len(loc) == 3:
                model = VariantEntry
            if root is Tournament and loc and loc[0] == "parts" and len(loc) == 3:
                model = Part
            allowed = ", ".join(model.model_fields) if model else "?"
            msg = f"unknown key; allowed keys: {allowed}"
        elif item["type"] == "missing":
            msg = "required key is missing"
        else:
            field = _field_at(loc, root)
            if field is not None and field.description and "literal" not in item["type"]:
                msg = f"{msg} ({field.description})"
        out.append(f"{where}: {_key_text(loc) or '(file)'}: {msg}")
    return "\n".join(out)


def _looks_like_type(text: str) -> bool:
    return text.startswith(("list[", "literal[", "dict[", "str", "int", "bool", "float",
                            "function-", "none"))


def _field_at(loc: tuple[Any, ...], root: type[BaseModel]) -> Any:
    names = [x for x in loc if not isinstance(x, int)]
    if not names:
        return None
    model = _model_at(tuple(loc[:-1]), root) if len(loc) > 1 else root
    if model is None:
        return None
    return model.model_fields.get(str(names[-1]))


# ------------------------------------------------------------------------------------ loading


def load_spec(path: str | Path) -> tuple[Tournament, str]:
    """Read and validate a tournament file; return the spec and its text (for line lookups).

    Only structure is checked here; names of variants and parts are checked by
    :func:`check_references`, and every job's run specification (tracks, overrides) is built
    by ``tourney.plan`` before anything is written.
    """
    path = Path(path)
    text = read_spec_text(path, "tournament")
    return parse_spec(text, path), text


def read_spec_text(path: Path, what: str) -> str:
    """A tournament or tune file's text; its size is checked (``stat``) before it is read."""
    try:
        info = path.stat()
    except OSError:
        info = None  # read_user_text words the missing or unreadable file
    if info is not None and not stat.S_ISREG(info.st_mode):
        raise UserInputError(f"{path}: the {what} file is not a regular file")
    if info is not None and info.st_size > MAX_SPEC_BYTES:
        raise UserInputError(
            f"{path}: the {what} file is {info.st_size / 1024 / 1024:.1f} MiB; at most "
            f"{MAX_SPEC_BYTES // 1024} KiB is read (a tournament file describes a plan, not data)"
        )
    return read_user_text(path, what)


def parse_toml(text: str, path: Path) -> dict[str, Any]:
    """TOML text as a dict; bad TOML is one line naming ``path`` (tournament, tune and claims
    files all read through here)."""
    depth = _nesting_depth(text)
    if depth > MAX_NESTING:
        raise UserInputError(f"{path}: arrays or inline tables nested {depth} deep; at most "
                             f"{MAX_NESTING} levels of nesting are read")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise UserInputError(f"{path}: not valid TOML: {err}") from None


def _nesting_depth(text: str) -> int:
    """Deepest run of open ``[``/``{`` outside strings and comments, found in one linear scan
    (tomllib recurses once per level and would raise RecursionError first)."""
    depth = deepest = 0
    quote: str | None = None
    escaped = comment = False
    for char in text:
        if comment:
            comment = char != "\n"
        elif quote is not None:
            if escaped:
                escaped = False
            elif char == "\\" and quote == '"':
                escaped = True
            elif char == quote:
                quote = None
        elif char in "\"'":
            quote = char
        elif char == "#":
            comment = True
        elif char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth = max(depth - 1, 0)
    return deepest


def parse_spec(text: str, path: Path) -> Tournament:
    """Validate tournament TOML text; ``path`` only names the file in error messages."""
    raw = parse_toml(text, path)
    try:
        spec = Tournament.model_validate(raw)
    except ValidationError as err:
        raise UserInputError(describe_errors(err, path, text)) from None
    check_references(spec, path, text)
    return spec


def error_at(path: Path, text: str, loc: tuple[Any, ...], message: str) -> UserInputError:
    """A UserInputError ``file:line: key: message`` for a key path in the tournament file."""
    line = locator_for(text).line_of(loc)
    where = f"{path}:{line}" if line else str(path)
    return UserInputError(f"{where}: {_key_text(loc)}: {message}")


def check_references(spec: Tournament, path: Path, text: str) -> None:
    """Cross-field rules: unique part names, promotion only from earlier parts, known variants."""
    names = spec.variant_names(beyond_paper=True)
    known = set(names)
    seen: dict[str, int] = {}
    for index, part in enumerate(spec.parts):
        if part.name in seen:
            raise error_at(path, text, ("parts", index, "name"),
                           f"part name {part.name!r} is already used by parts[{seen[part.name]}]")
        if part.promoted_from is not None and part.promoted_from not in seen:
            earlier = ", ".join(seen) or "(none: this is the first part)"
            raise error_at(path, text, ("parts", index, "promoted_from"),
                           f"unknown part {part.promoted_from!r}; allowed values (earlier "
                           f"parts): {earlier}")
        seen[part.name] = index
        if isinstance(part.entrants, list):
            if not part.entrants:
                raise error_at(path, text, ("parts", index, "entrants"),
                               "empty list; name at least one variant or use \"all\" or "
                               "\"all+beyond\"")
            for name in part.entrants:
                if name not in known:
                    raise error_at(path, text, ("parts", index, "entrants"),
                                   f"unknown variant {name!r}; allowed values: "
                                   f"{', '.join(names)}, \"all\", \"all+beyond\"")
        setups = [(s.reference, s.lac) for s in part.setups]
        if len(set(setups)) != len(setups):
            raise error_at(path, text, ("parts", index, "setups"),
                           "the same reference/lac setup is listed twice")
        if part.selection.kind == "general" and not set(part.all_test_tracks()) - set(
            part.train_tracks
        ):
            raise error_at(path, text, ("parts", index, "selection", "kind"),
                           "'general' needs test_tracks that are not train tracks")
        if part.kind == "train":
            check_competence(spec, index, path, text)
    for name, entry in spec.variants.items():
        if entry.base is not None and entry.base not in ALL_VARIANTS and entry.base not in (
            spec.variants
        ):
            raise error_at(path, text, ("variants", name, "base"),
                           f"unknown base variant {entry.base!r}; allowed values: "
                           f"{', '.join(ALL_VARIANTS)}")


COMPETENCE_BOTS = ("centre", "mincurv")
"""The follower's lines a part with a CPU budget races as baselines: its time-to-competence
table (``report.competence_table``) times the runs until they beat each."""


def check_competence(spec: Tournament, index: int, path: Path, text: str) -> None:
    """A part's competence keys: ``stop_at`` needs a ``budget_cpu_s`` (a run that never beats
    the bot must still end), and a budget needs the follower's baselines on the centre and
    min-curvature lines, the bots its milestones are set by."""
    part = spec.parts[index]
    settings = spec.settings(part)

    def where(key: str) -> tuple[Any, ...]:
        return ("parts", index, key) if getattr(part, key) is not None else ("defaults", key)

    if settings["stop_at"] not in (None, "none") and settings["budget_cpu_s"] is None:
        raise error_at(path, text, where("stop_at"),
                       f"stop_at = {settings['stop_at']!r} needs budget_cpu_s (the CPU-seconds "
                       "a run may spend before it stops without reaching the bot)")
    if settings["budget_cpu_s"] is None:
        return
    raced = {b.reference for b in part.baselines if b.bot == "follower"}
    missing = [line for line in COMPETENCE_BOTS if line not in raced]
    if missing:
        wanted = ", ".join(f'{{bot = "follower", reference = "{line}"}}' for line in missing)
        raise error_at(path, text, where("budget_cpu_s"),
                       "a CPU budget times the runs until they beat the follower on the "
                       f"{' and '.join(COMPETENCE_BOTS)} lines: add baselines = [{wanted}] "
                       f"to part {part.name!r}")


def entrant_name(variant: str, setup: Setup) -> str:
    """<variant>-<MOT|RC|MC>[-LAC]: unique within a part, safe as a folder name."""
    name = f"{variant}-{LINE_LABELS[setup.reference]}" + ("-LAC" if setup.lac else "")
    return check_name(name, "entrant name")

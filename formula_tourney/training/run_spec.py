"""The run specification: everything one training run needs, built and validated once.

``build_run_spec`` is the one function that turns user settings (a tournament part, a tune
trial, the ``train`` command's options) into a :class:`RunSpec`; it runs in the parent process,
so a bad value fails before anything is written. The spec travels to workers as JSON, is what a
job folder's ``config.json`` and a checkpoint hold, and is never re-defaulted downstream.

A spec is made of five owned parts: the agent's configuration (``agents.variants.AgentConfig``),
the env's settings (``sim.config.EnvSettings``), the reference line and LAC, the schedule (with
``cars``, how many cars drive into the one replay buffer) and the optional demonstrations
(:class:`DemoSettings`). Keys an env override would share with the run (``lac``, ``max_steps``,
...) are not env settings at all, so setup and override can never both set one.

Settings added during results layout 2 carry the mark ``added_in_layout`` on their Field
(``field_marks``: ``schedule.cars``, ``schedule.env_steps``, ``demos``, the agent's
``crash_penalty``, the env's ``progress_reward`` and others) and are left out of
:meth:`RunSpec.to_json` while at their defaults: a default run's ``config.json``, checkpoints and
:meth:`RunSpec.digest` are byte for byte what they were before those settings existed, so a
resumed tournament still recognises its finished jobs. The mark ``beyond_paper`` names the
settings of mechanisms the paper does not have (:meth:`RunSpec.beyond_paper`).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    TypeAdapter,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_core import to_jsonable_python

from formula_tourney.agents.outside.kind import OutsideEntrant
from formula_tourney.agents.variants import (
    AgentConfig,
    get_variant,
    named_settings,
    validation_problems,
)
from formula_tourney.errors import UserInputError
from formula_tourney.field_marks import added_in_layout, beyond_paper, marks
from formula_tourney.lines.kinds import ReferenceKind
from formula_tourney.results.identity import training_digest
from formula_tourney.sim.catalog import check_track_name
from formula_tourney.sim.config import RUN_OWNED_KEYS, EnvSettings, GripScale
from formula_tourney.sim.reward import BY_NAME as REWARD_SETTINGS
from formula_tourney.training.presets import get_preset

Device = Literal["auto", "cpu", "cuda"]

RUN_OWNED_HINTS: dict[str, str] = {
    "track": "train_tracks / test_tracks",
    "reference_line": "the setup's reference",
    "lac": "the setup's lac",
    "max_steps": "max_steps (training) and test_max_steps (tests)",
    "random_start": "random_start",
    "curriculum_starts_m": "start_curriculum (the run finds them on its reference line)",
    "limit_speeds_mps": "overspeed_crash_weight (the run finds them on the reference limit)",
}
"""Where to set each env key that a run owns, for the error when an override names one."""


MAX_SEED = 2**32 - 1
"""Largest seed: numpy's legacy and numba's generators take 32-bit seeds."""


class _Frozen(BaseModel):
    """Floats are finite in every model here (``inf`` is no budget or grip a run can use)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Schedule(_Frozen):
    """How long a run trains and how often, from where and how long it is tested."""

    episodes: int = Field(100, ge=1, le=10**9, strict=True, description="Training episodes.")
    env_steps: int | None = Field(
        None,
        ge=1,
        le=10**10,
        strict=True,
        description="Env-step budget: the run also ends at the first finished episode at or "
        "after this many env steps (car-steps), with a last test round. Episodes are a poor "
        "clock on a hard track (a run that crashes early spends hundreds of episodes in a few "
        "thousand steps); env steps fix the cost of a run and keep it deterministic. None: "
        "episodes alone.",
        json_schema_extra=marks(added_in_layout=2),
    )
    max_steps: int = Field(
        1000, ge=1, le=10**7,
        strict=True, description="Control steps per training episode (truncated at the end)."
    )
    random_start: bool = Field(
        True, description="Start training episodes at random places on the track."
    )
    test_every_episodes: int = Field(
        10, ge=1, le=10**9,
        strict=True, description="Run the tests after every this many training episodes (and last)."
    )
    test_starts: int = Field(
        3, ge=1, le=64,
        strict=True, description="Start positions per test track, evenly spaced on the lap."
    )
    test_max_steps: int = Field(
        1500, ge=1, le=10**7,
        strict=True, description="Control steps per test episode (enough for two laps)."
    )
    save_test_checkpoints: bool = Field(
        False, description="Keep a checkpoint ep-<N>.pt at every test, not only best and last."
    )
    test_grip_scales: tuple[GripScale, ...] = Field(
        (),
        max_length=8,
        description="Grip scales the tests also run at (train on one grip, test on another): "
        "every test round drives each test track at the env's grip_scale (the run's own, which "
        "best checkpoint, promotion and the paper's tables read) and then at each of these; "
        "the tests table records each drive's grip and the reference limit at that grip.",
        json_schema_extra=marks(added_in_layout=2),
    )
    budget_cpu_s: float | None = Field(
        None,
        gt=0,
        le=10**7,
        description="CPU-second budget: the run stops at the first finished episode after its "
        "process has spent this many CPU-seconds (time.process_time) since training started, "
        "without a further test round. CPU time, unlike wall time, does not grow with the "
        "other jobs sharing the machine. None: no CPU budget.",
        json_schema_extra=marks(added_in_layout=2),
    )
    stop_at: Literal["none", "best-bot"] = Field(
        "none",
        description="A lap that ends the run early: best-bot stops it after the first test "
        "round whose clean lap on the key track beats the follower bot on the min-curvature "
        "line (the best bot; with demonstrations also the demonstrator's lap); none: no lap "
        "does.",
        json_schema_extra=marks(added_in_layout=2),
    )

    @field_validator("test_grip_scales")
    @classmethod
    def _distinct_grips(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        if len(set(v)) != len(v):
            raise ValueError(f"{list(v)}: list each grip once")
        return v
    cars: int = Field(
        1,
        ge=1,
        le=1024,
        strict=True,
        description="Cars driven at once into the one replay buffer (FormulaRacingVectorEnv, "
        "each car its own episodes, windows and n-step sums). 1: one FormulaRacing-v0 env with "
        "a train track drawn per episode (the paper's loop). With several train tracks the "
        "cars are split over them as evenly as possible, each keeping its track for the whole "
        "run (so cars must be 1 or >= the number of tracks). `episodes` and "
        "`test_every_episodes` count "
        "finished car-episodes; the agent's `updates_per_step` stays updates per stored "
        "transition (car-step), so a step of N cars earns N times as many updates.",
        json_schema_extra=marks(added_in_layout=2),
    )
    traffic_bots: int = Field(
        0,
        ge=0,
        le=19,
        strict=True,
        description="Traffic while training (beyond the paper): this many follower bots drive "
        "around the learner in every training episode (bots.traffic_env.TrafficEnv, "
        "alternately ahead and behind, 30-150 m apart) and the observation gets the 36 "
        "opponent sectors, so the model can learn to pass and defend; its tests drive alone "
        "with the same observation. 0: the paper's solo FormulaRacing-v0. Needs cars = 1.",
        json_schema_extra=marks(added_in_layout=2),
    )
    resume_every_cpu_s: float = Field(
        300.0,
        gt=0,
        le=10**7,
        description="Write the job's whole training state to its resume file (resume.pt) every "
        "this many CPU-seconds, and on SIGTERM, so a killed, preempted or requeued job "
        "continues where it was, bit for bit (training.resume). Runs of one car only; runs of "
        "several cars start again. Changes no result.",
        json_schema_extra=marks(added_in_layout=2),
    )


SCHEDULE_KEYS: tuple[str, ...] = tuple(Schedule.model_fields)

DEMO_BOT = "follower"
"""The bot that drives demonstrations (``bots.follower``, our Tita)."""


class DemoSettings(_Frozen):
    """Demonstrations: the follower bot's laps seed a second buffer that every batch draws from."""

    laps: int = Field(
        3, ge=1, le=1000, description="Timed laps the follower drives on each train track, in "
        "the env the agent trains in (its random starts, max_steps, reward and observation).",
    )  # fmt: skip
    line: ReferenceKind = Field(
        "mincurv", description="The line the follower drives: centre, mincurv or recorded "
        "(the run's own reference line stays the reward's and the observation's).",
    )  # fmt: skip
    batch_fraction: float = Field(
        0.5, ge=0.0, lt=1.0, description="Share of every batch drawn from the demonstrations "
        "(round(batch_size * fraction) rows); 0.5 is RLPD's symmetric sampling, 0 keeps the "
        "demonstrations for the behaviour-cloning warm start only.",
    )  # fmt: skip
    bc_steps: int = Field(
        0, ge=0, le=1_000_000, description="Behaviour-cloning warm start: Adam steps on the "
        "actor's MSE to the demonstrated actions before RL starts (0 = off).",
    )  # fmt: skip
    bc_lr: float = Field(1e-3, gt=0.0, description="Adam learning rate of the BC warm start.")
    bc_weight: float = Field(
        0.0, ge=0.0, le=1000.0, description="Behaviour cloning inside the actor's loss, all "
        "run long (Nair et al. 2018; TD3+BC's scaling): the actor's loss gains bc_weight x "
        "mean|Q(s, mu(s))| x the mean over the batch's demonstration rows of ||mu(s) - a||^2, "
        "so the weight does not depend on the reward's scale (0 = off).",
        json_schema_extra=marks(added_in_layout=2),
    )  # fmt: skip
    bc_q_filter: bool = Field(
        True, description="Clone a demonstrated action only where the critic rates it above "
        "the actor's own, Q(s, a) > Q(s, mu(s)) (Nair et al.'s Q-filter): the actor can outgrow "
        "the demonstrator once the critic knows better.",
        json_schema_extra=marks(added_in_layout=2),
    )  # fmt: skip

    def demo_rows(self, batch_size: int) -> int:
        """Rows of a batch of ``batch_size`` drawn from the demonstrations."""
        return int(round(batch_size * self.batch_fraction))


class RunSpec(_Frozen):
    """One run: a variant trained on one track or a list, tested periodically with epsilon = 0."""

    variant: str = Field(description="Name of the registered variant the agent config is from.")
    agent: AgentConfig = Field(description="The agent's full configuration (overrides applied).")
    env: EnvSettings = Field(
        default_factory=EnvSettings, description="FormulaRacing-v0 settings shared by all envs."
    )
    train_tracks: tuple[str, ...] = Field(
        min_length=1, description="Tracks to train on; one is drawn per episode."
    )
    test_tracks: tuple[str, ...] = Field(
        min_length=1, description="Tracks to test on (the first train track is the key track)."
    )
    reference: ReferenceKind = Field(
        "centre",
        description="Reference line of the reward and LAC: centre (MOT), recorded (the "
        "follower bot's driven line) or mincurv (minimum-curvature racing line).",
    )
    lac: bool = Field(False, description="Add the look-ahead curvature (LAC) to the observation.")
    schedule: Schedule = Field(default_factory=Schedule, description="Training and tests.")
    seed: int = Field(0, ge=0, le=MAX_SEED, strict=True,
                      description="Seed of weights, replay, exploration and env starts.")
    device: Device = Field("auto", description="Torch device: auto picks CUDA when present.")
    threads: int = Field(
        1, ge=1, le=256, description="torch threads in this process (one per worker measured best)."
    )
    demos: DemoSettings | None = Field(
        None, description="Demonstrations by the follower bot (None: none, the paper's runs).",
        json_schema_extra=marks(added_in_layout=2),
    )
    preset: str = Field(
        "paper", description="The named preset (training.presets) the settings started from.",
        json_schema_extra=marks(added_in_layout=2),
    )
    outside: OutsideEntrant | None = Field(
        None, description="An outside entrant (agents.outside: impl, entry point or SB3 "
        "algorithm) trained through the entrant protocol; None: one of our families. With "
        "one, `agent` holds only the reward settings its transitions are stored with.",
        json_schema_extra=marks(added_in_layout=2),
    )  # fmt: skip

    @model_validator(mode="after")
    def _consistent(self) -> RunSpec:
        if self.outside is not None and self.demos is not None:
            raise ValueError(
                f"entrant {self.variant} ({self.outside.label()}) is an outside entrant: "
                "demos feed our families' replay buffers only"
            )
        tracks = len(dict.fromkeys(self.train_tracks))
        if self.schedule.cars > 1 and self.schedule.cars < tracks:
            raise ValueError(
                f"schedule.cars ({self.schedule.cars}) must be 1 or at least the number of "
                f"train tracks ({tracks}): each track needs a car"
            )
        if self.schedule.traffic_bots and (self.schedule.cars > 1 or self.demos is not None):
            raise ValueError(
                f"schedule.traffic_bots ({self.schedule.traffic_bots}) drives one learner "
                "among bots: it needs cars = 1 and no demos"
            )
        if self.demos is not None:
            rows = self.demos.demo_rows(self.agent.batch_size)
            if rows >= self.agent.batch_size:
                raise ValueError(
                    f"demos.batch_fraction {self.demos.batch_fraction} leaves no online rows "
                    f"in a batch of {self.agent.batch_size}"
                )
            if self.demos.bc_weight > 0.0 and rows == 0:
                raise ValueError(
                    f"demos.bc_weight {self.demos.bc_weight} clones the batch's demonstration "
                    f"rows, but batch_fraction {self.demos.batch_fraction} gives none in a "
                    f"batch of {self.agent.batch_size}"
                )
        return self

    @property
    def test_grips(self) -> tuple[float, ...]:
        """Every grip the tests run at: the run's own (``env.grip_scale``) first, then the other
        ``schedule.test_grip_scales`` (the own one listed again changes nothing)."""
        own = self.env.grip_scale
        return (own, *(g for g in self.schedule.test_grip_scales if g != own))

    @field_validator("train_tracks", "test_tracks")
    @classmethod
    def _no_blank(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        if any(not t.strip() for t in v):
            raise ValueError("track names must be non-empty strings")
        return v

    @property
    def key_track(self) -> str:
        """The track lap times, best checkpoints and promotion are measured on."""
        first = self.train_tracks[0]
        return first if first in self.test_tracks else self.test_tracks[0]

    def beyond_paper(self) -> list[str]:
        """What this run adds to the paper's setup, for the "beyond paper" label of every table:
        a preset, a family beyond the paper's, demonstrations, a beyond-paper setting off what
        its preset gives, more than one car per learner, traffic."""
        out = []
        if self.outside is not None:
            out.append(f"outside entrant {self.outside.label()}")
        if self.preset != "paper":
            out.append(f"preset {self.preset}")
        if self.outside is not None:
            pass  # its own settings are not ours: no family or setting label applies
        elif self.agent.beyond_paper:
            out.append(self.agent.family)
        if self.demos is not None:
            out.append(f"demos ({DEMO_BOT} on {self.demos.line})")
        if self.outside is None:
            out.extend(self._beyond_paper_settings())
        if self.schedule.cars > 1:
            out.append(f"{self.schedule.cars} cars")
        if self.schedule.traffic_bots:
            out.append(f"traffic ({self.schedule.traffic_bots} {DEMO_BOT} bots)")
        return out

    def _beyond_paper_settings(self) -> list[str]:
        """``KEY VALUE`` for each agent or env setting marked ``beyond_paper`` that differs from
        what the run's preset gives (its value, else the paper's default): a preset's own
        choices are named by "preset NAME", a user's change on top of it is named here."""
        preset = get_preset(self.preset)
        preset_agent = preset.agent_overrides(self.agent.family, named_settings(self.variant))
        # compared as JSON, as the defaults are: a pair is a tuple here and a list there
        base = {"agent": {**_DEFAULTS["agent"], **to_jsonable_python(preset_agent)},
                "env": {**_DEFAULTS["env"], **to_jsonable_python(preset.env)}}
        values = {"agent": self.agent.model_dump(mode="json"),
                  "env": self.env.model_dump(mode="json")}  # fmt: skip
        return [_setting_label(key, values[section][key])
                for section in ("agent", "env")
                for key, field in _SECTIONS[section].model_fields.items() if beyond_paper(field)
                if values[section][key] != base[section][key]]  # fmt: skip

    def to_json(self) -> dict[str, Any]:
        """Plain JSON data (what config.json, checkpoints and worker messages carry); the
        settings marked ``added_in_layout`` are left out at their defaults (module docstring)."""
        data = self.model_dump(mode="json")
        _omit_newer_defaults(RunSpec, data)
        return data

    def digest(self) -> str:
        """Short hash of the spec: a resumed tournament compares it to tell a changed file."""
        text = json.dumps(self.to_json(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def training_digest(self) -> str:
        """Short hash of what the training depends on: the spec without its test settings
        (``results.identity``); a report must count runs sharing it as one sample."""
        return training_digest(self.to_json())

    @classmethod
    def from_json(cls, data: Mapping[str, Any], source: str) -> RunSpec:
        """A spec read back from a file; UserInputError naming ``source`` when it is not one."""
        try:
            return cls.model_validate(dict(data))
        except ValidationError as err:
            raise UserInputError(
                f"{source}: not a run specification: {validation_problems(err)}") from None


def _setting_label(key: str, value: Any) -> str:
    """``KEY VALUE`` for a number or a name, ``KEY`` for a switch that is on, ``no KEY`` for one
    off, ``KEY A/B`` for a pair of numbers."""
    if isinstance(value, bool):
        return key if value else f"no {key}"
    if isinstance(value, str):
        return f"{key} {value}"
    if isinstance(value, tuple | list):
        return f"{key} {'/'.join(f'{v:g}' for v in value)}"
    return f"{key} {value:g}"




_SECTIONS: dict[str, type[BaseModel]] = {
    "agent": AgentConfig, "env": EnvSettings, "schedule": Schedule, "demos": DemoSettings,
}
"""The model of each section of a run specification."""

_DEFAULTS: dict[str, dict[str, Any]] = {
    section: model().model_dump(mode="json") for section, model in _SECTIONS.items()
}
"""Each section's defaults as JSON, read from its model: the one owner of every default."""


def _newer_defaults(model: type[BaseModel]) -> dict[str, Any]:
    """The JSON default of each of ``model``'s settings marked ``added_in_layout``."""
    return {
        name: TypeAdapter(field.annotation).dump_python(
            field.get_default(call_default_factory=True), mode="json")
        for name, field in model.model_fields.items() if added_in_layout(field) is not None
    }  # fmt: skip


_NEWER_DEFAULTS: dict[type[BaseModel], dict[str, Any]] = {
    model: _newer_defaults(model) for model in (RunSpec, *_SECTIONS.values())
}


def _omit_newer_defaults(model: type[BaseModel], data: dict[str, Any]) -> None:
    """Delete from ``data`` (``model`` as JSON) each setting added within a layout that is at
    its default, and the same in each section it holds."""
    for name, default in _NEWER_DEFAULTS[model].items():
        if name in data and data[name] == default:
            del data[name]
    for name, section in _SECTIONS.items():
        if model is RunSpec and isinstance(data.get(name), dict):
            _omit_newer_defaults(section, data[name])


OUTSIDE_BASE = "WIN1"
"""The registered variant whose configuration an outside entrant's run carries: only its reward
settings (``sim.reward``) are read, when the loop stores a transition."""


def build_run_spec(
    *,
    variant: str,
    overrides: Mapping[str, Any] | None = None,
    train_tracks: list[str] | tuple[str, ...],
    test_tracks: list[str] | tuple[str, ...] | None = None,
    reference: str = "centre",
    lac: bool = False,
    schedule: Mapping[str, Any] | None = None,
    env_overrides: Mapping[str, Any] | EnvSettings | None = None,
    seed: int = 0,
    device: str = "auto",
    threads: int = 1,
    demos: Mapping[str, Any] | DemoSettings | None = None,
    preset: str = "paper",
    track_base_dir: Path | None = None,
    source: str = "run settings",
    outside: OutsideEntrant | Mapping[str, Any] | None = None,
) -> RunSpec:
    """The one way to make a RunSpec; every problem is a UserInputError naming ``source``.

    ``schedule`` holds keys of :class:`Schedule` (unset ones keep its defaults);
    ``env_overrides`` keys of ``sim.config.EnvSettings``. An env override of a key the run owns
    (``lac``, ``max_steps``, ...) is refused with where to set it instead. Track names are checked
    (not built) by ``sim.catalog.check_track_name``; relative file paths resolve against
    ``track_base_dir``. ``demos`` holds keys of :class:`DemoSettings` (an empty mapping takes
    its defaults; None: no demonstrations). ``preset`` (``training.presets``) supplies agent
    overrides, schedule keys, env keys and demonstrations first; the caller's own settings win
    over it, key by key (``demos`` and ``env_overrides`` too).

    ``outside`` names an outside entrant (``agents.outside.naming.OutsideEntrant``; ``variant``
    is then its name in the tournament, not a registered variant): only the reward settings of
    the preset and ``overrides`` apply (the agent configuration of :data:`OUTSIDE_BASE` holds
    them), so every entrant of a part learns from the same stored reward.
    """
    chosen = get_preset(preset)
    if outside is not None:
        base = OUTSIDE_BASE
        preset_agent = chosen.agent_overrides(get_variant(base).family, named_settings(base))
        wanted = {**preset_agent, **dict(overrides or {})}
        agent = get_variant(base, {k: v for k, v in wanted.items() if k in REWARD_SETTINGS})
        chosen = chosen.model_copy(update={"demos": None})  # a preset's demos are our families'
    else:
        preset_agent = chosen.agent_overrides(get_variant(variant).family,
                                              named_settings(variant))  # fmt: skip
        agent = get_variant(variant, {**preset_agent, **dict(overrides or {})})
    schedule = {**chosen.schedule, **dict(schedule or {})}
    if chosen.demos is not None and not isinstance(demos, DemoSettings):
        demos = {**chosen.demos, **dict(demos or {})}  # the caller's keys win, one by one
    env = _env_settings(env_overrides, source, chosen.env)
    unknown = sorted(set(schedule or {}) - set(SCHEDULE_KEYS))
    if unknown:
        raise UserInputError(
            f"{source}: unknown schedule key(s) {', '.join(unknown)}; allowed keys: "
            f"{', '.join(SCHEDULE_KEYS)}"
        )
    trains = [check_track_name(t, track_base_dir) for t in train_tracks]
    tests = [check_track_name(t, track_base_dir) for t in (test_tracks or [])] or list(trains)
    try:
        return RunSpec(
            variant=variant, agent=agent, env=env, train_tracks=tuple(trains),
            test_tracks=tuple(tests), reference=reference, lac=lac,
            schedule=Schedule(**dict(schedule or {})), seed=seed, device=device, threads=threads,
            demos=demos if demos is None or isinstance(demos, DemoSettings) else dict(demos),
            preset=preset, outside=outside,
        )  # fmt: skip
    except ValidationError as err:
        raise UserInputError(f"{source}: {validation_problems(err)}") from None


def _env_settings(overrides: Mapping[str, Any] | EnvSettings | None, source: str,
                  preset_env: Mapping[str, Any] | None = None) -> EnvSettings:
    """The run's env settings: the preset's env keys under the user's overrides (the keys a
    user set win, one by one, as for agent settings)."""
    if isinstance(overrides, EnvSettings):
        if not preset_env:
            return overrides
        overrides = overrides.overrides()  # the keys its user set, to go over the preset's
    owned = sorted(set(overrides or {}) & set(RUN_OWNED_KEYS))
    if owned:
        where = "; ".join(f"'{k}' is set by {RUN_OWNED_HINTS[k]}" for k in owned)
        raise UserInputError(f"{source}: env override(s) of run settings: {where}")
    return EnvSettings.parse({**dict(preset_env or {}), **dict(overrides or {})},
                             f"{source}: env overrides")

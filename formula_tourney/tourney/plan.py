"""The plan: a validated tournament turned into jobs (entrant x seed x part) and baseline drives.

Every training job's run specification is built here, in the parent, by
``training.run_spec.build_run_spec`` (the one function ``tune`` and the ``train`` command call too):
a part's settings and ``[defaults]`` give the schedule, device, threads and env overrides, its
setup the reference line and LAC, the variant its agent configuration, the tournament's
``seed_base`` the seed. :meth:`Planner.validate` builds the spec of every job that can exist,
promoted parts with every variant they could receive, so a bad value is an error at its line
(``file:line: key``) before anything is written. A part's jobs are known once its entrants
are: at once for declared entrants, after promotion for ``promoted_from`` parts.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic_core import to_jsonable_python

from formula_tourney.agents.variants import get_variant
from formula_tourney.errors import UserInputError
from formula_tourney.results.layout import baseline_rel_path, job_rel_path, trace_name
from formula_tourney.sim.catalog import check_track_name
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.spec import (
    Part,
    Setup,
    Tournament,
    default_family,
    entrant_name,
    error_at,
)
from formula_tourney.training.outside import check_outside
from formula_tourney.training.run_spec import SCHEDULE_KEYS, RunSpec, build_run_spec


@dataclass
class PlannedPart:
    """A part with its entrants when known (None while they wait for promotion)."""

    part: Part
    position: int
    variants: list[str] | None
    jobs: list[Job] = field(default_factory=list)
    baselines: list[Job] = field(default_factory=list)
    key_track: str = ""
    """Canonical name of the track the part's lap times and promotion are measured on."""


def resolve_variant(spec: Tournament, name: str) -> tuple[str, str, dict[str, Any]]:
    """(agents variant, family, overrides) of a declared or paper variant; bases chain."""
    overrides: dict[str, Any] = {}
    family: str | None = None
    current = name
    seen: set[str] = set()
    while current in spec.variants and current not in seen:
        seen.add(current)
        entry = spec.variants[current]
        if entry.outside() is not None:  # its own family: promotion ranks it on its own
            return current, entry.family or current, {}
        overrides = {**entry.overrides, **overrides}
        family = family or entry.family
        if entry.base is None or entry.base == current:
            break
        current = entry.base
    return current, family or default_family(current), overrides


def variant_run_settings(spec: Tournament, name: str) -> dict[str, Any]:
    """Run settings a declared variant entry sets itself (demos, cars, env_steps, preset); the
    nearest entry in its base chain wins, and they win over the part's."""
    out: dict[str, Any] = {}
    current, seen = name, set()
    while current in spec.variants and current not in seen:
        seen.add(current)
        entry = spec.variants[current]
        for key in ("demos", "cars", "env_steps", "preset"):
            if key not in out and getattr(entry, key) is not None:
                out[key] = getattr(entry, key)
        if entry.base is None or entry.base == current:
            break
        current = entry.base
    return out


def part_variants(spec: Tournament, part: Part) -> list[str] | None:
    """Declared entrants of a part ("all", "all+beyond" resolved), None for promoted parts."""
    if part.entrants is None:
        return None
    return spec.entrant_names(part.entrants)


def possible_variants(spec: Tournament, part: Part) -> list[str]:
    """Every variant a part can run: its entrants, or those its source part can promote."""
    by_name = {p.name: p for p in spec.parts}
    declared = part_variants(spec, part)
    while declared is None:  # promotion only comes from earlier parts (tourney.spec checks)
        part = by_name[str(part.promoted_from)]
        declared = part_variants(spec, part)
    return declared


def spec_settings(settings: dict[str, Any], force_checkpoints: bool = False) -> dict[str, Any]:
    """``build_run_spec`` keyword arguments from resolved job settings (None = unset)."""
    schedule = {k: settings[k] for k in SCHEDULE_KEYS if settings.get(k) is not None}
    if force_checkpoints:
        schedule["save_test_checkpoints"] = True
    out: dict[str, Any] = {"schedule": schedule, "env_overrides": settings.get("env_overrides"),
                           "demos": settings.get("demos")}
    for key in ("device", "threads", "preset"):
        if settings.get(key) is not None:
            out[key] = settings[key]
    return out


def baseline_digest(spec: dict[str, Any]) -> str:
    """A baseline job's settings as a hash: a results folder holding the bot's drive in
    another car (or for other laps) is refused on resume, as a train job of other settings is."""
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


def _shared_trace(tracks: tuple[str, ...]) -> tuple[str, str] | None:
    """Two distinct tracks whose trace files (``results.layout.trace_name``) would be one file,
    else None: one test drive would overwrite the other's trace and baseline."""
    seen: dict[str, str] = {}
    for track in tracks:
        other = seen.setdefault(trace_name(track), track)
        if other != track:
            return other, track
    return None


class Planner:
    """Jobs of one tournament file; run specs are built once per part x variant x setup."""

    def __init__(self, spec: Tournament, path: Path, text: str, root: Path) -> None:
        self.spec = spec
        self.path = Path(path)
        self.text = text
        self.root = Path(root)
        self.base_dir = self.path.resolve().parent
        """Relative track paths in the file resolve against the file's folder."""
        self._tracks: dict[int, tuple[tuple[str, ...], tuple[str, ...]]] = {}
        self._specs: dict[tuple[int, str, int], RunSpec] = {}
        self.entrant_seeds: dict[tuple[str, str], int] | None = None
        """Seeds per (part, entrant) in a sequential run (``tourney.adaptive`` sets it; an
        entrant not in it has ``[adaptive] min_seeds``); None: every part its ``seeds``."""
        self._checked: set[str] = set()
        """Outside runs (their spec but the seed) that acted on zeros already."""

    def seeds(self, part: Part, entrant: str) -> int:
        """How many seeds (jobs) an entrant of a part runs now."""
        if self.spec.adaptive is not None:
            return (self.entrant_seeds or {}).get((part.name, entrant),
                                                  self.spec.adaptive.min_seeds)
        return self.spec.settings(part)["seeds"] or 1

    # ------------------------------------------------------------------ run specifications
    def tracks(self, index: int) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """Canonical (train, test) track names of part ``index``; errors point at the key."""
        if index not in self._tracks:
            part = self.spec.parts[index]
            found = []
            for key, names in (("train_tracks", part.train_tracks),
                               ("test_tracks", part.all_test_tracks())):  # fmt: skip
                try:
                    found.append(tuple(check_track_name(n, self.base_dir) for n in names))
                except UserInputError as err:
                    raise error_at(self.path, self.text, ("parts", index, key),
                                   str(err)) from None
            clash = _shared_trace(found[1])
            if clash is not None:
                key = "test_tracks" if part.test_tracks else "train_tracks"
                raise error_at(self.path, self.text, ("parts", index, key),
                               f"tracks {clash[0]!r} and {clash[1]!r} would share the trace "
                               f"and baseline file name {trace_name(clash[0])!r} (characters "
                               "other than A-Z a-z 0-9 _ . + - become '_', names are cut at "
                               "100 characters): rename one of the files")
            self._tracks[index] = (found[0], found[1])
        return self._tracks[index]

    def key_track(self, index: int) -> str:
        """Where the part's lap times count (``RunSpec.key_track``, the same for all its jobs)."""
        part = self.spec.parts[index]
        return self.run_spec(index, possible_variants(self.spec, part)[0], 0).key_track

    def run_spec(self, index: int, variant: str, setup_index: int, seed: int = 0) -> RunSpec:
        """The run specification of one job (``seed`` counts from 0 within the entrant)."""
        key = (index, variant, setup_index)
        if key not in self._specs:
            self._specs[key] = self._build(index, variant, setup_index)
        base = self._specs[key]
        if seed == 0:
            return base
        return base.model_copy(update={"seed": self.spec.seed_base + seed})

    def _build(self, index: int, variant: str, setup_index: int) -> RunSpec:
        part = self.spec.parts[index]
        setup = part.setups[setup_index]
        trains, tests = self.tracks(index)
        base, _family, own = resolve_variant(self.spec, variant)
        settings = {**self.spec.settings(part), **variant_run_settings(self.spec, variant)}
        outside = self.spec.variant(variant).outside()
        try:
            return build_run_spec(
                variant=base, overrides={**(settings["variant_overrides"] or {}), **own},
                outside=outside,
                train_tracks=trains, test_tracks=tests, reference=setup.reference,
                lac=setup.lac, seed=self.spec.seed_base, track_base_dir=self.base_dir,
                source=f"{part.name}/{entrant_name(variant, setup)}",
                **spec_settings(settings, part.selection.kind == "general"),
            )  # fmt: skip
        except UserInputError as err:
            raise error_at(self.path, self.text, self._blame(index, variant),
                           str(err)) from None

    def _blame(self, index: int, variant: str) -> tuple[Any, ...]:
        """Where in the file a failing spec comes from: the variant's own overrides, the shared
        variant_overrides (part or [defaults]), or else the part."""
        part = self.spec.parts[index]
        if self.spec.variant(variant).outside() is not None:
            return ("variants", variant)
        base, _family, own = resolve_variant(self.spec, variant)
        shared = self.spec.settings(part)["variant_overrides"] or {}
        try:
            get_variant(base, own)
        except UserInputError:
            return ("variants", variant, "overrides")
        try:
            get_variant(base, {**shared, **own})
        except UserInputError:
            if part.variant_overrides is not None:
                return ("parts", index, "variant_overrides")
            return ("defaults", "variant_overrides")
        return ("parts", index)

    # ------------------------------------------------------------------ jobs
    def jobs(self, index: int, variants: list[str]) -> list[Job]:
        """Jobs of a part for the given variants: variant x setup x seed, in that order."""
        part = self.spec.parts[index]
        if part.kind == "race":
            # A race part trains nothing: promotion names its entrants, whose models then race
            # in the part's one race job (tourney.race_part.race_job, made by the scheduler).
            return []
        out = []
        for variant in variants:
            _base, family, _ = resolve_variant(self.spec, variant)
            for setup_index, setup in enumerate(part.setups):
                entrant = entrant_name(variant, setup)
                for seed in range(self.seeds(part, entrant)):
                    run = self.run_spec(index, variant, setup_index, seed)
                    rel = job_rel_path(part.name, entrant, seed)
                    out.append(Job(
                        job_id=rel, kind="train", part=part.name, out_dir=str(self.root / rel),
                        spec=run.to_json(), config_hash=run.digest(), position=index,
                        meta={
                            "study": part.study, "part": part.name, "entrant": entrant,
                            "variant": variant, "family": family, "seed": seed,
                            "reference": setup.reference, "lac": setup.lac,
                            "train_tracks": list(run.train_tracks), "path": rel,
                            "selection": part.selection.model_dump(),
                        },
                    ))  # fmt: skip
        return out

    def baselines(self, index: int) -> list[Job]:
        """One drive per baseline x test track of the part."""
        part = self.spec.parts[index]
        _trains, tests = self.tracks(index)
        # The bots drive the part's car: a bot in another car than the entrants' is no anchor.
        env = self.spec.settings(part)["env_overrides"]
        car = dict(env.car) if env is not None else {}
        out = []
        for baseline in part.baselines:
            reference = "genetic" if baseline.bot == "genetic" else baseline.reference
            for track in tests:
                rel = baseline_rel_path(part.name, baseline.bot, reference, track)
                spec = {"bot": baseline.bot, "reference": reference, "track": track,
                        "laps": baseline.laps, "car": car}
                out.append(Job(
                    job_id=rel, kind="baseline", part=part.name, out_dir=str(self.root / rel),
                    spec=spec, config_hash=baseline_digest(spec),
                    meta={"part": part.name, "bot": baseline.bot, "reference": reference,
                          "track": track, "path": rel},
                    position=index,
                ))  # fmt: skip
        return out

    def plan(self) -> list[PlannedPart]:
        """Parts in order with the jobs known now (promoted parts get theirs after promotion)."""
        planned = []
        for index, part in enumerate(self.spec.parts):
            variants = part_variants(self.spec, part)
            jobs = self.jobs(index, variants) if variants is not None else []
            planned.append(PlannedPart(part, index, variants, jobs, self.baselines(index),
                                       self.key_track(index)))
        return planned

    def validate(self) -> int:
        """Build every job's run specification that can exist; returns how many were built.

        Promoted parts are built with every variant their source could promote, so a bad
        override there fails now rather than hours later. Declared variants that no part runs
        are checked too (a typo in one is still a typo).
        """
        for name in self.spec.variants:
            if self.spec.variants[name].outside() is not None:
                continue  # checked on its run's spaces below (check_outside)
            base, _family, own = resolve_variant(self.spec, name)
            try:
                get_variant(base, own)
            except UserInputError as err:
                raise error_at(self.path, self.text, ("variants", name, "overrides"),
                               str(err)) from None
        built = 0
        for index, part in enumerate(self.spec.parts):
            self.tracks(index)
            for variant in possible_variants(self.spec, part):
                for setup_index in range(len(part.setups)):
                    run = self.run_spec(index, variant, setup_index)
                    if run.outside is not None and part.kind == "train":
                        self._check_outside(index, variant, setup_index, run)
                    built += 1
        return built

    def _check_outside(self, index: int, variant: str, setup_index: int, run: RunSpec) -> None:
        """An outside entrant acts on zeros in the part's spaces (once per distinct run)."""
        key = json.dumps({**run.to_json(), "seed": 0}, sort_keys=True)
        if key in self._checked:
            return
        setup = self.spec.parts[index].setups[setup_index]
        try:
            check_outside(run, f"entrant {entrant_name(variant, setup)}")
        except UserInputError as err:
            raise error_at(self.path, self.text, ("variants", variant), str(err)) from None
        self._checked.add(key)


    def describe(self, planned: list[PlannedPart]) -> dict[str, Any]:
        """The plan as data (for --dry-run and --json): parts, entrants, job counts, budgets."""
        spec = self.spec
        parts = []
        total_jobs = 0
        for item in planned:
            part = item.part
            seeds = self.seeds(part, "")  # a sequential run: min_seeds, its start
            source: dict[str, Any]
            if item.variants is not None:
                source = {"entrants": item.variants}
                n_jobs: int | None = len(item.jobs)
            else:
                rule = part.promotion
                source = {
                    "promoted_from": part.promoted_from,
                    "rule": ("best per family, " if rule.best_per_family else "")
                    + (f"top {rule.top_k} " if rule.top_k else "all ")
                    + f"by {rule.metric}, finish rate >= {rule.min_finish_rate:g}"
                    + (", unfinished classified by distance" if rule.unfinished == "by_distance"
                       else ""),
                }  # fmt: skip
                n_jobs = None
            total_jobs += n_jobs or 0
            variants = possible_variants(spec, part)
            run = self.run_spec(item.position, variants[0], 0) if variants else None
            schedule = run.schedule.model_dump() if run is not None else {}
            # the part's own budget; an entrant's own one is in entrant_settings
            schedule["env_steps"] = spec.settings(part)["env_steps"]
            parts.append({
                "part": part.name,
                "study": part.study,
                **source,
                "setups": [setup_label(s) for s in part.setups],
                "train_tracks": list(part.train_tracks),
                "test_tracks": part.all_test_tracks(),
                "seeds": seeds,
                **{k: schedule.get(k) for k in ("episodes", "env_steps", "max_steps",
                                                "test_every_episodes", "test_starts",
                                                "test_max_steps", "test_grip_scales",
                                                "budget_cpu_s", "stop_at")},
                "env_overrides": run.env.overrides() if run is not None else {},
                # a variant entry's demos/cars/env_steps/preset win over the part's: show them
                "entrant_settings": {v: to_jsonable_python(own) for v in variants
                                     if (own := variant_run_settings(spec, v))},
                "selection": part.selection.kind,
                "kind": part.kind,
                **({"races": part.race.races, "race_laps": part.race.laps,
                    "race_bots": list(part.race.bots), "race_start": part.race.start,
                    "race_grid": part.race.grid, "race_points": list(part.race.points),
                    "race_contact": part.race.contact.enabled}
                   if part.race is not None else {}),
                "jobs": 0 if part.kind == "race" else n_jobs,
                "jobs_per_entrant": 0 if part.kind == "race" else seeds * len(part.setups),
                "baselines": [f"{b.spec['bot']}:{b.spec['reference']}@{b.spec['track']}"
                              for b in item.baselines],
            })  # fmt: skip
        return {"tournament": spec.name, "description": spec.description, "parts": parts,
                "known_jobs": total_jobs}


def setup_label(setup: Setup) -> str:
    """``LAC+recorded``-style label of a setup for the plan view."""
    return ("LAC+" if setup.lac else "") + setup.reference

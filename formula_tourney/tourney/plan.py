"""The plan: a validated tournament turned into jobs (entrant x seed x part) and baseline drives.

A part's jobs are known once its entrants are: at once for declared entrants, after promotion for
``promoted_from`` parts. Each training job carries the keyword arguments of
``training.config.TrainConfig``, validated here in the parent so that a bad value fails before
anything is written, and a hash of them so that a resumed run can tell if the file changed.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from formula_tourney.errors import UserInputError
from formula_tourney.tourney.spec import (
    Part,
    Tournament,
    default_family,
    entrant_name,
    error_at,
)
from formula_tourney.tourney.store import baseline_rel_path, job_rel_path

JobKind = Literal["train", "baseline"]


@dataclass(frozen=True)
class Job:
    """One unit of work, sent to a worker process or a Ray task (plain data, picklable)."""

    job_id: str
    kind: JobKind
    part: str
    out_dir: str
    config: dict[str, Any]
    meta: dict[str, Any] = field(default_factory=dict)
    position: int = 0

    @property
    def config_hash(self) -> str:
        return config_hash(self.config)


@dataclass
class PlannedPart:
    """A part with its entrants when known (None while they wait for promotion)."""

    part: Part
    position: int
    variants: list[str] | None
    jobs: list[Job] = field(default_factory=list)
    baselines: list[Job] = field(default_factory=list)


def config_hash(config: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


def resolve_variant(spec: Tournament, name: str) -> tuple[str, str, dict[str, Any]]:
    """(agents variant, family, overrides) of a declared or paper variant; bases chain."""
    overrides: dict[str, Any] = {}
    family: str | None = None
    current = name
    seen: set[str] = set()
    while current in spec.variants and current not in seen:
        seen.add(current)
        entry = spec.variants[current]
        overrides = {**entry.overrides, **overrides}
        family = family or entry.family
        if entry.base is None or entry.base == current:
            break
        current = entry.base
    return current, family or default_family(current), overrides


def part_variants(spec: Tournament, part: Part) -> list[str] | None:
    """Declared entrants of a part, all variants for "all", None for promoted parts."""
    if part.entrants == "all":
        return spec.variant_names()
    if isinstance(part.entrants, list):
        return list(part.entrants)
    return None


def train_kwargs(spec: Tournament, part: Part, variant: str, setup: Any, seed: int) -> dict:
    """Keyword arguments of TrainConfig for one job; unset settings keep TrainConfig's defaults."""
    base, _family, overrides = resolve_variant(spec, variant)
    settings = spec.settings(part)
    kwargs: dict[str, Any] = {
        "variant": base,
        "overrides": {**(settings.get("variant_overrides") or {}), **overrides},
        "train_tracks": list(part.train_tracks),
        "reference": setup.reference,
        "lac": setup.lac,
        "seed": spec.seed_base + seed,
        "test_tracks": part.all_test_tracks(),
    }
    if part.selection.kind == "general":
        kwargs["save_test_checkpoints"] = True
    for key, value in settings.items():
        if key in ("seeds", "variant_overrides") or value is None:
            continue
        kwargs.setdefault(key, value)
    return kwargs


def make_jobs(
    spec: Tournament, part: Part, position: int, variants: list[str], root: Path
) -> list[Job]:
    """Jobs of a part for the given variants: variant x setup x seed, in that order."""
    seeds = spec.settings(part)["seeds"] or 1
    jobs = []
    for variant in variants:
        _base, family, _ = resolve_variant(spec, variant)
        for setup in part.setups:
            entrant = entrant_name(variant, setup)
            for seed in range(seeds):
                rel = job_rel_path(part.name, entrant, seed)
                jobs.append(
                    Job(
                        job_id=rel,
                        kind="train",
                        part=part.name,
                        out_dir=str(root / rel),
                        config=train_kwargs(spec, part, variant, setup, seed),
                        meta={
                            "study": part.study, "part": part.name, "entrant": entrant,
                            "variant": variant, "family": family, "seed": seed,
                            "reference": setup.reference, "lac": setup.lac,
                            "train_tracks": list(part.train_tracks), "path": rel,
                            "selection": part.selection.model_dump(),
                        },
                        position=position,
                    )
                )
    return jobs


def make_baselines(part: Part, position: int, root: Path) -> list[Job]:
    """One drive per baseline x test track of the part."""
    out = []
    for baseline in part.baselines:
        reference = "genetic" if baseline.bot == "genetic" else baseline.reference
        for track in part.all_test_tracks():
            rel = baseline_rel_path(part.name, baseline.bot, reference, track)
            out.append(
                Job(
                    job_id=rel,
                    kind="baseline",
                    part=part.name,
                    out_dir=str(root / rel),
                    config={"bot": baseline.bot, "reference": reference, "track": track,
                            "laps": baseline.laps},
                    meta={"part": part.name, "bot": baseline.bot, "reference": reference,
                          "track": track, "path": rel},
                    position=position,
                )
            )
    return out


def build_plan(spec: Tournament, root: Path) -> list[PlannedPart]:
    """Parts in order with the jobs known now (promoted parts get theirs after promotion)."""
    planned = []
    for position, part in enumerate(spec.parts):
        variants = part_variants(spec, part)
        jobs = make_jobs(spec, part, position, variants, root) if variants is not None else []
        planned.append(PlannedPart(part, position, variants, jobs,
                                   make_baselines(part, position, root)))
    return planned


def validate_plan(spec: Tournament, path: Path, text: str, root: Path) -> None:
    """Check every job config against TrainConfig and every track name, before any write.

    Promoted parts are checked with every variant they could receive, so a bad override there
    also fails now rather than hours later.
    """
    _check_tracks(spec, path, text)
    from formula_tourney.agents.variants import get_variant

    for index, part in enumerate(spec.parts):
        for variant in part_variants(spec, part) or spec.variant_names():
            base, _family, overrides = resolve_variant(spec, variant)
            merged = {**(spec.settings(part).get("variant_overrides") or {}), **overrides}
            try:
                get_variant(base, merged)
            except UserInputError as err:
                loc: tuple[Any, ...] = ("variants", variant, "overrides")
                try:
                    get_variant(base, overrides)
                except UserInputError:
                    pass  # the variant's own overrides are wrong
                else:  # they are fine alone: the shared variant_overrides are to blame
                    loc = ("parts", index, "variant_overrides")
                    if part.variant_overrides is None:
                        loc = ("defaults", "variant_overrides")
                raise error_at(path, text, loc, str(err)) from None
    for name in spec.variants:
        base, _family, overrides = resolve_variant(spec, name)
        try:
            get_variant(base, overrides)
        except UserInputError as err:
            raise error_at(path, text, ("variants", name, "overrides"), str(err)) from None
    try:
        from formula_tourney.training.config import TrainConfig
    except ImportError:  # pragma: no cover - training area not installed
        return
    from pydantic import ValidationError

    names = spec.variant_names()
    for index, part in enumerate(spec.parts):
        variants = part_variants(spec, part) or names
        for job in make_jobs(spec, part, index, variants, root)[:: max(1, _seeds(spec, part))]:
            try:
                TrainConfig(**job.config)
            except ValidationError as err:
                first = err.errors()[0]
                key = str(first["loc"][0]) if first["loc"] else "?"
                loc: tuple[Any, ...]
                variant = job.meta["variant"]
                if key in ("overrides", "variant") and variant in spec.variants:
                    loc = ("variants", variant, "overrides")
                elif key in ("overrides", "variant"):
                    loc = ("parts", index, "entrants")
                else:
                    loc = ("parts", index, key)
                    if key not in part.model_fields_set:
                        loc = ("defaults", key) if key in spec.defaults.model_fields_set else loc
                detail = "; ".join(
                    f"{'.'.join(str(x) for x in e['loc'])}: {e['msg']}" for e in err.errors()
                )
                raise error_at(path, text, loc,
                               f"invalid training setting for {job.meta['entrant']}: "
                               f"{detail}") from None
            except UserInputError as err:
                raise error_at(path, text, ("parts", index),
                               f"{job.meta['entrant']}: {err}") from None


def _seeds(spec: Tournament, part: Part) -> int:
    return int(spec.settings(part)["seeds"] or 1)


def _check_tracks(spec: Tournament, path: Path, text: str) -> None:
    try:
        from formula_tourney.sim.catalog import list_tracks
    except ImportError:  # pragma: no cover - sim area not installed
        return
    known = [str(t["name"]) for t in list_tracks()]
    for index, part in enumerate(spec.parts):
        for key in ("train_tracks", "test_tracks"):
            for name in getattr(part, key) or []:
                if name in known or re.fullmatch(r"gen-\d+", name):
                    continue
                candidate = (path.parent / name) if not Path(name).is_absolute() else Path(name)
                if candidate.suffix in (".toml", ".xml") and candidate.is_file():
                    continue
                raise error_at(path, text, ("parts", index, key),
                               f"unknown track {name!r}; allowed values: {', '.join(known)}, "
                               "gen-<seed>, or a path to a .toml/.xml track file")


def describe_plan(spec: Tournament, planned: list[PlannedPart]) -> dict[str, Any]:
    """The plan as data (for --dry-run and --json): parts, entrants, job counts, budgets."""
    parts = []
    total_jobs = 0
    for item in planned:
        part = item.part
        settings = spec.settings(part)
        seeds = settings["seeds"] or 1
        if item.variants is not None:
            source = {"entrants": item.variants}
            n_jobs = len(item.jobs)
        else:
            rule = part.promotion
            source = {
                "promoted_from": part.promoted_from,
                "rule": ("best per family, " if rule.best_per_family else "")
                + (f"top {rule.top_k} " if rule.top_k else "all ")
                + f"by {rule.metric}, finish rate >= {rule.min_finish_rate:g}"
                + (", unfinished classified by distance" if rule.unfinished == "by_distance"
                   else ""),
            }
            n_jobs = None
        total_jobs += n_jobs or 0
        parts.append({
            "part": part.name,
            "study": part.study,
            **source,
            "setups": [
                ("LAC+" if s.lac else "") + s.reference for s in part.setups
            ],
            "train_tracks": list(part.train_tracks),
            "test_tracks": part.all_test_tracks(),
            "seeds": seeds,
            "episodes": settings["episodes"],
            "max_steps": settings["max_steps"],
            "test_every_episodes": settings["test_every_episodes"],
            "selection": part.selection.kind,
            "jobs": n_jobs,
            "jobs_per_entrant": seeds * len(part.setups),
            "baselines": [f"{b.config['bot']}:{b.config['reference']}@{b.config['track']}"
                          for b in item.baselines],
        })
    return {"tournament": spec.name, "description": spec.description, "parts": parts,
            "known_jobs": total_jobs}

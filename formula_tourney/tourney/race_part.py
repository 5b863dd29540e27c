"""Race parts, parent side: who races with which checkpoint, as one race job of the scheduler.

A part of kind ``race`` trains nothing. Once its source part has closed and promoted, the
scheduler asks :func:`race_job` for the part's one job: each promoted entrant (variant x setup
of the source part) brings its best seed's model (the seed with the best clean lap,
``results.metrics`` via the index; without any clean lap, the seed that drove furthest in its
tests) from ``checkpoints/best.pt`` (``last.pt`` if it never lapped cleanly; the series says
which), and the part's bots start too. The job runs the whole series in one worker
(``tourney.race_worker``): a series of a few cars is minutes, not hours, so one job per part
keeps one owner of the qualifying grid, and resuming is per race file (a finished race is kept,
a missing one is raced again exactly as the first run would have). Files go to
``<part>/_races/`` (``results.folder.RaceFolder``); the index's row of the series (kind
``race``, ``tourney.kinds.race``) holds only its status; the standings are the report's
(``report.race_standings``).
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any

from formula_tourney.results import layout as L
from formula_tourney.results.folder import RaceFolder
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.plan import Planner
from formula_tourney.tourney.spec import Part, entrant_name


def _finite(x: Any) -> bool:
    return x is not None and isinstance(x, float | int) and math.isfinite(float(x))


def best_models(trained: list[dict[str, Any]], root: Path, source: Part,
                variants: list[str]) -> list[dict[str, Any]]:
    """The racing model of each promoted entrant of ``source``: its best seed's checkpoint
    (relative to the tournament folder ``root``), from the index rows of ``source``'s training
    jobs (``trained``). Entrants without a finished seed or checkpoint are left out."""
    rows = [r for r in trained if r["status"] == "done"]
    out = []
    for variant in variants:
        for setup in source.setups:
            entrant = entrant_name(variant, setup)
            mine = [r for r in rows if r["entrant"] == entrant]
            if not mine:
                continue
            lapped = [r for r in mine if _finite(r.get("best_lap_s"))]
            if lapped:
                best = min(lapped, key=lambda r: (float(r["best_lap_s"]), r["seed"]))
            else:
                best = max(mine, key=lambda r: (float(r.get("test_distance_m") or 0.0),
                                                -r["seed"]))
            rel = Path(best.get("path") or best["job_id"]) / L.CHECKPOINTS_DIR
            kind = next((c for c in (L.BEST_CHECKPOINT, L.LAST_CHECKPOINT)
                         if (root / rel / c).is_file()), None)
            if kind is None:
                continue
            out.append({"name": entrant, "job_id": best["job_id"], "seed": best["seed"],
                        "best_lap_s": float(best["best_lap_s"]) if lapped else None,
                        "checkpoint": (rel / kind).as_posix(),
                        "checkpoint_kind": Path(kind).stem})
    return out


def race_job(planner: Planner, index: int, trained: list[dict[str, Any]],
             variants: list[str]) -> Job:
    """The one job of race part ``index``: its whole series, with the models of ``variants``
    (the source part's promotion; ``trained``: the index rows of its training jobs) and the
    part's bots. ``spec`` holds no absolute path but the
    track's, so its digest (the job's config hash) names the series wherever the results
    folder lives; the worker finds checkpoints through ``meta["root"]``."""
    part = planner.spec.parts[index]
    settings = part.race
    assert settings is not None  # kind race always has them (tourney.spec)
    source = next(p for p in planner.spec.parts if p.name == part.promoted_from)
    models = best_models(trained, planner.root, source, variants)
    seen: dict[str, int] = {}
    bots = []
    for bot in settings.bots:
        seen[bot] = seen.get(bot, 0) + 1
        bots.append({"bot": bot, "name": bot if seen[bot] == 1 else f"{bot}#{seen[bot]}"})
    spec = {
        "part": part.name, "track": planner.tracks(index)[0][0], "races": settings.races,
        "seed": settings.seed, "points": list(settings.points),
        "settings": settings.race_settings().model_dump(mode="json"),
        "models": models, "bots": bots,
    }  # fmt: skip
    digest = hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]
    rel = L.races_rel_path(part.name)
    return Job(job_id=rel, kind="race", part=part.name, out_dir=str(planner.root / rel),
               spec=spec, config_hash=digest, position=index,
               meta={"part": part.name, "track": spec["track"], "races": settings.races,
                     "entrants": [m["name"] for m in models] + [b["name"] for b in bots],
                     "path": rel, "config_hash": digest, "root": str(planner.root)})


def series_complete(job: Job) -> bool:
    """Whether the job's folder holds its whole series (every race file and ``series.json`` of
    this config hash): a deleted race file, or a series of other settings, is not."""
    folder = RaceFolder(job.out_dir)
    if not folder.is_complete(int(job.spec["races"])):
        return False
    return folder.series().get("config_hash") == job.config_hash

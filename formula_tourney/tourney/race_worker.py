"""A race part's series in a worker: the grid kept, finished races kept, the rest raced.

Called by ``tourney.runner`` for a job of kind ``race`` (``tourney.race_part.race_job``). The
qualifying laps and the base grid go to ``qualifying.json`` with the job's config hash before
race 0; a resumed job with the same hash keeps them and every race file already written, and
races only the missing ones (``race.series.race_k`` depends on its arguments alone, so a race
raced again equals the lost one). A kept folder of another hash (other entrants or settings)
is cleared first. A race that raises does not stop the others: the job fails at the end naming
it, and a retry races only what is missing. ``series.json`` is written last.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from formula_tourney.race.entrants import bot_entrant, model_entrant
from formula_tourney.race.series import qualify, race_k
from formula_tourney.race.settings import RaceSettings
from formula_tourney.results.folder import RaceFolder
from formula_tourney.sim.catalog import load_track
from formula_tourney.sim.config import EnvSettings
from formula_tourney.tourney.jobs import Job

Progress = Callable[[dict[str, Any]], Any]


class RaceSeriesError(RuntimeError):
    """Some races of a series failed; the others are on disk."""


def run_race_job(job: Job, progress: Progress | None = None) -> dict[str, Any]:
    """Race what is missing of the job's series; returns its ``series.json`` document."""
    task = job.spec
    folder = RaceFolder(job.out_dir)
    races = int(task["races"])
    if folder.is_complete(races) and folder.series().get("config_hash") == job.config_hash:
        return folder.series()
    kept = folder.qualifying()
    if kept is None or kept.get("config_hash") != job.config_hash:
        folder.clear()
        kept = None
    root = Path(job.meta["root"])
    track = load_track(task["track"])
    entrants = [model_entrant(root / m["checkpoint"], task["track"], m["name"])
                for m in task["models"]]
    shared = None
    if entrants:
        first = entrants[0].config
        shared = EnvSettings(**{k: getattr(first, k) for k in EnvSettings.model_fields})
    entrants += [bot_entrant(b["bot"], track, shared, b["name"]) for b in task["bots"]]
    settings = RaceSettings.model_validate(task["settings"])
    if kept is not None:
        laps = kept["qualifying_s"]
        qualifying = None if laps is None else [math.nan if q is None else float(q)
                                                for q in laps]
        base = [int(i) for i in kept["grid"]]
    else:
        qualifying, base = qualify(entrants, settings)
        folder.write_qualifying({
            "config_hash": job.config_hash, "names": [e.name for e in entrants],
            "qualifying_s": None if qualifying is None
            else [q if math.isfinite(q) else None for q in qualifying],
            "grid": base,
        })  # fmt: skip
    have = set(folder.race_numbers())
    failed = []
    for k in range(races):
        if k not in have:
            try:
                folder.write_race(k, race_k(entrants, settings, base, qualifying,
                                            int(task["seed"]), k).to_json())
            except Exception as err:  # one race's crash must not cost the others
                failed.append(f"race {k}: {type(err).__name__}: {err}")
        if progress is not None:
            progress({"episode": k + 1, "episodes": races, "best_lap_s": math.nan,
                      "env_steps": 0})
    if failed:
        raise RaceSeriesError(f"{len(failed)} of {races} races failed ({'; '.join(failed)})")
    series = {
        "part": task["part"], "track": task["track"], "races": races, "seed": task["seed"],
        "points": task["points"], "settings": task["settings"],
        "entrants": [*task["models"], *({"name": b["name"], "kind": "bot", "source": b["bot"]}
                                        for b in task["bots"])],
        "config_hash": job.config_hash,
    }  # fmt: skip
    folder.write_series(series)
    return series

"""A job: one unit of work (a training run, a baseline drive, a race series) as picklable data.

The plan makes jobs, the scheduler queues them, an executor ships them to a worker process or a
Ray task, and ``tourney.runner`` runs them through their kind's object (``tourney.kinds``). A
training job carries its run specification as JSON (``training.run_spec.RunSpec.to_json()``), built
and validated once in the parent; the worker only reads it back. A baseline job carries the bot,
line, track and laps of its drive; a race job the whole series of a race part (its racing models
chosen in the parent from the index).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Job:
    """One unit of work, sent to a worker process or a Ray task."""

    job_id: str
    """``<part>/<entrant>/seed-<n>`` (train), the baseline folder or ``<part>/_races`` (race);
    relative paths."""
    kind: str
    """The name of its kind in ``tourney.kinds.KINDS``."""
    part: str
    out_dir: str
    """Absolute folder the job writes."""
    spec: dict[str, Any] = field(default_factory=dict)
    """Train: the RunSpec as JSON. Baseline: bot, reference, track, laps. Race: a race part's
    series (``tourney.race_part.race_job``: track, races, seed, points, settings, models, bots)."""
    config_hash: str = ""
    """Digest of the job's settings (a training run's ``RunSpec.digest()``), compared on resume
    to tell a changed tournament file and to tell a finished folder of other settings."""
    meta: dict[str, Any] = field(default_factory=dict)
    """Who the job is in its tournament (entrant, variant, family, seed, ...); its kind's
    ``attrs`` of it go to the index."""
    position: int = 0
    """Index of the part in the tournament (earlier parts run first)."""


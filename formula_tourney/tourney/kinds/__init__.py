"""The job kinds of a tournament, one object each (``base.JobKind``), and their registry.

A new kind is one module here with its ``JobKind`` subclass, plus one line in :data:`KINDS`
(plus its tests); docs/tourney.md, "Job kinds", lists what it implements.
"""

from __future__ import annotations

from formula_tourney.errors import UserInputError
from formula_tourney.tourney.kinds.base import CannotRun, JobKind
from formula_tourney.tourney.kinds.baseline import BaselineKind
from formula_tourney.tourney.kinds.race import RaceKind
from formula_tourney.tourney.kinds.train import TrainKind

KINDS: dict[str, JobKind] = {kind.name: kind for kind in (
    TrainKind(),
    BaselineKind(),
    RaceKind(),
)}
"""Every job kind by name, in the order a part's jobs are queued (training runs first)."""

TRAIN = KINDS["train"]
BASELINE = KINDS["baseline"]
RACE = KINDS["race"]


def kind_of(name: str) -> JobKind:
    """The kind object named ``name``; an unknown name (an index written by another version,
    a hand-made job) is a UserInputError listing the known kinds."""
    try:
        return KINDS[name]
    except KeyError:
        raise UserInputError(f"unknown job kind {name!r}; known kinds: "
                             f"{', '.join(KINDS)}") from None


__all__ = ["BASELINE", "KINDS", "RACE", "TRAIN", "CannotRun", "JobKind", "kind_of"]

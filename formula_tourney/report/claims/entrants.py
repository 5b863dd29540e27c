"""Which runs are one entrant, so that a claim or a profile compares like with like.

Two runs are the same entrant when they agree on four things, the ``ENTRANT_KEYS``:

- ``variant``: the tables' row name (``paper_tables.row_names``: the variant, or the entrant
  where one part holds two entrants of a variant, e.g. an ablation pair);
- ``line``: the reference line and look-ahead curvature (LAC);
- ``train_track``: where the run trained first (where its lap times count);
- ``setup``: what the run adds to the paper's setup (``RunSpec.beyond_paper``, stored in each
  job's ``config.json``: its preset, demonstrations, a beyond-paper setting, several cars).

Runs of one entrant differ only in their seed (and their tests), so their scores are samples of
one distribution. A claim pools entrants only on the keys its ``pool`` names
(``claims.schema.Claim.pool``), and compares an entrant of A with one of B only when both have
the same setup, unless ``setup`` is pooled: a WIN1 trained with preset ``fast-small`` is never
a sample of a WIN1 trained with ``tuned-bc`` and demonstrations.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import get_args

import pandas as pd

from formula_tourney.claims.schema import PoolKey
from formula_tourney.lines.kinds import line_label
from formula_tourney.report.paper_tables import Context, row_names, with_setup

ENTRANT_KEYS: tuple[str, ...] = get_args(PoolKey)
"""What makes runs one entrant: the keys a claim may pool."""


def first_train_track(job: pd.Series) -> str:
    """Where a run's lap times count (``RunSpec.key_track``: its first train track)."""
    tracks = job["train_tracks"]
    return str(tracks[0]) if len(tracks) else ""


@dataclass(frozen=True)
class Entrant:
    """Runs alike in every key not pooled: what they share and the label tables use."""

    label: str
    setup: tuple[str, ...] | None
    """The runs' beyond-paper labels; None where the setup is pooled."""
    jobs: pd.DataFrame

    def same_setup(self, other: Entrant) -> bool:
        """Whether the two may be compared: the same setup, or either's setup pooled."""
        return self.setup is None or other.setup is None or self.setup == other.setup


@dataclass(frozen=True)
class _Run:
    """The four entrant keys of one run."""

    variant: str
    reference: str
    lac: bool
    train_track: str
    setup: tuple[str, ...]

    def key(self, keys: list[str]) -> tuple[object, ...]:
        every = {"variant": self.variant, "line": (self.reference, self.lac),
                 "train_track": self.train_track, "setup": self.setup}
        return tuple(every[k] for k in keys)

    def label(self, keys: list[str], pooled_name: str) -> str:
        """``WIN1 RC + LAC on technical (beyond paper: preset tuned-bc)``: each key kept."""
        name = self.variant if "variant" in keys else pooled_name
        if "line" in keys:
            name += f" {line_label(self.reference)}" + (" + LAC" if self.lac else "")
        if "train_track" in keys:
            name += f" on {self.train_track}"
        return with_setup(name, list(self.setup)) if "setup" in keys else name


def entrants(ctx: Context, jobs: pd.DataFrame, pool: Iterable[str] = (),
             pooled_name: str = "runs") -> list[Entrant]:
    """``jobs`` split into entrants, in order of first appearance; the keys in ``pool`` are
    left out of the split (``pooled_name`` names the runs where the variant is pooled)."""
    keys = [k for k in ENTRANT_KEYS if k not in set(pool)]
    names = row_names(ctx.jobs)
    groups: dict[tuple[object, ...], tuple[_Run, list[str]]] = {}
    for _, job in jobs.iterrows():
        job_id = str(job["job_id"])
        run = _Run(variant=names.get(job_id, str(job["variant"])),
                   reference=str(job["reference"]), lac=bool(job["lac"]),
                   train_track=first_train_track(job),
                   setup=tuple(ctx.data.beyond_paper.get(job_id) or ()))
        groups.setdefault(run.key(keys), (run, []))[1].append(job_id)
    return [Entrant(label=run.label(keys, pooled_name),
                    setup=run.setup if "setup" in keys else None,
                    jobs=jobs.loc[jobs["job_id"].astype(str).isin(job_ids)])
            for run, job_ids in groups.values()]


def entrant_labels(ctx: Context) -> dict[str, str]:
    """Every job's entrant label, nothing pooled (the performance profile's groups)."""
    return {str(job_id): ent.label for ent in entrants(ctx, ctx.jobs)
            for job_id in ent.jobs["job_id"]}

"""What the Ray-cluster and Slurm tests share: the tiny tournament they run, its index rows, and
the job-table digests of the same tournament run without interruption on the local pool."""

from __future__ import annotations

import functools
import importlib.util
import shutil
import sqlite3
import tempfile
from pathlib import Path

from tourney_fixtures import TINY

from formula_tourney.tourney.api import run_tournament

REPO = Path(__file__).resolve().parents[1]
ENTRANTS = '["WIN1", "MS2"]'

_PATH = REPO / "benchmarks" / "determinism.py"
_SPEC = importlib.util.spec_from_file_location("determinism", _PATH)
determinism = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(determinism)


def tiny_file(folder: Path) -> Path:
    """Two tiny training jobs in one part."""
    path = folder / "tiny.toml"
    path.write_text(TINY.format(entrants=ENTRANTS, p2=""), encoding="utf-8")
    return path


def slow_file(folder: Path) -> Path:
    """One tiny training job in a part named ``slow`` (tests make it sleep through
    ``runner.FAULTS_ENV`` pattern ``slow/*``)."""
    path = folder / "slow.toml"
    path.write_text(TINY.format(entrants='["WIN1"]', p2="").replace('"p1"', '"slow"'))
    return path


def index_rows(results: Path) -> dict[str, dict]:
    """The index's job rows of the tiny tournament under ``results``."""
    db = sqlite3.connect(results / "tiny" / "index.sqlite")
    db.row_factory = sqlite3.Row
    out = {r["job_id"]: dict(r) for r in db.execute("SELECT * FROM jobs")}
    db.close()
    return out


def digests(results: Path) -> dict[str, str]:
    """benchmarks/determinism.py's digest of every job table (machine time left out)."""
    return determinism.folder_digests(results / "tiny")


@functools.cache
def reference_digests() -> dict[str, str]:
    """The digests of an uninterrupted run on the local pool (computed once per session)."""
    folder = Path(tempfile.mkdtemp(prefix="ft-reference-"))
    try:
        run_tournament(tiny_file(folder), workers=2, results_dir=folder / "res")
        found = digests(folder / "res")
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    assert len(found) >= 4, found  # episodes and tests of each job at least
    return found

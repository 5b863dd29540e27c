"""benchmarks/determinism.py: two results folders compared table by table, machine time left out."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
from report_fixtures import build_tournament

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "determinism.py"
_SPEC = importlib.util.spec_from_file_location("determinism", _PATH)
det = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(det)


def test_equal_runs_match_though_their_cpu_and_wall_seconds_differ(tmp_path: Path) -> None:
    before = build_tournament(tmp_path / "a")
    after = build_tournament(tmp_path / "b")
    tables = sorted(after.rglob("episodes.parquet"))
    frame = pd.read_parquet(tables[0])
    frame["seconds"] = frame["seconds"] * 3.0 + 1.0  # another machine's clock, the same run
    frame.to_parquet(tables[0])
    result = det.compare(det.folder_digests(before), det.folder_digests(after))
    assert result["files"] >= 10 and result["identical_share"] == 1.0 and not result["differ"]


def test_a_changed_lap_time_names_its_file(tmp_path: Path) -> None:
    before = build_tournament(tmp_path / "a")
    after = tmp_path / "b"
    shutil.copytree(before, after)
    laps = sorted(after.rglob("laps.parquet"))[0]
    frame = pd.read_parquet(laps)
    frame.loc[0, "lap_time_s"] += 1e-9  # one lap, off in its last digits
    frame.to_parquet(laps)
    (after / "extra.parquet").write_bytes((sorted(after.rglob("tests.parquet"))[0]).read_bytes())
    result = det.compare(det.folder_digests(before), det.folder_digests(after))
    assert result["differ"] == [str(laps.relative_to(after))]
    assert result["only_after"] == ["extra.parquet"] and result["identical_share"] < 1.0


def test_bare_run_prints_an_empty_result() -> None:
    done = subprocess.run([sys.executable, str(_PATH)], capture_output=True, text=True,
                          check=True, timeout=120)  # fmt: skip
    last = json.loads(done.stdout.strip().splitlines()[-1])
    assert last["files"] == 0 and last["identical_share"] is None

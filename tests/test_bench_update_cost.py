"""benchmarks/update_cost.py: a preset's update with and without settings, one JSON line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

_SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "update_cost.py"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(_SCRIPT), *args], capture_output=True, text=True,
                          timeout=120, check=False)  # fmt: skip


def test_it_times_the_presets_update_against_the_same_update_with_the_settings() -> None:
    done = _run("--set", "critic_bins=11", "--rounds", "1", "--updates", "20")
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.strip().splitlines()[-1])
    # best's sizes: 128-128 networks, batch 64
    assert (result["hidden"], result["batch_size"]) == ([128, 128], 64)
    assert result["settings"] == {"critic_bins": 11}
    assert result["anchor_us"] > 0 and result["changed_us"] > 0
    assert abs(result["ratio"] - result["changed_us"] / result["anchor_us"]) < 2e-3


def test_a_bad_setting_is_one_line_and_exit_2() -> None:
    done = _run("--set", "critic_bins=1")
    assert done.returncode == 2 and done.stdout == ""
    assert len(done.stderr.strip().splitlines()) == 1 and "critic_bins" in done.stderr

"""``formula-tourney compile`` (run by ``make setup``): after it, the runs a tournament starts
find every kernel they use in numba's cache and compile nothing themselves (a cold compile cost
~50 s per worker and computes in the last bit differently from the cached code)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

CLI = [sys.executable, "-m", "formula_tourney.cli"]


def _cache_files(cache_dir: Path) -> set[str]:
    return {str(p.relative_to(cache_dir)) for p in cache_dir.rglob("*") if p.is_file()}


def test_after_compile_a_run_and_a_bot_compile_nothing(tmp_path: Path) -> None:
    cache_dir = tmp_path / "numba-cache"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache_dir)}
    done = subprocess.run([*CLI, "compile", "--json"], env=env, capture_output=True, text=True,
                          check=True, timeout=600)
    assert json.loads(done.stdout)["compiled"] is True
    compiled = _cache_files(cache_dir)
    # the vector env's entry point (the rest inline into it) and the QSS line solver
    assert any(".step_cars-" in name and name.endswith(".nbi") for name in compiled), compiled
    assert any("speed_profile._pass-" in name for name in compiled), compiled
    # what the demo's jobs do: train on the oval (another variant, another line) and drive the
    # follower on the other track's min-curvature line
    subprocess.run([*CLI, "train", "--out", str(tmp_path / "run"), "--variant", "WIN4",
                    "--preset", "fast-small", "--track", "oval", "--episodes", "1",
                    "--max-steps", "30", "--test-max-steps", "30", "--test-starts", "1"],
                   env=env, capture_output=True, check=True, timeout=600)
    subprocess.run([*CLI, "bot", "technical", "--line", "mincurv", "--json"], env=env,
                   capture_output=True, check=True, timeout=600)
    assert _cache_files(cache_dir) == compiled

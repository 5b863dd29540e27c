"""Benchmark: quick.toml on 2 workers vs 1 worker (parallel efficiency) and orchestration overhead.

Figures of merit (anchor: the ideal, 1.0 efficiency and 0 s overhead):
- parallel efficiency = wall(1 worker) / (2 * wall(2 workers));
- orchestration overhead = wall time not spent inside ``training.loop.train`` with 1 worker
  (spawn, imports, env and reference-line setup in the worker, index writes, promotion), split
  into in-worker setup (job wall - train seconds) and parent-side time (run wall - job walls).

Run: ``.venv/bin/python benchmarks/tournament_quick.py [--file tournaments/quick.toml]``.
Both runs write to a temporary results folder, so ``results/`` is untouched.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sqlite3
import tempfile
import time
from pathlib import Path

for _key in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_key, "1")


def measure(file: Path, workers: int, results: Path) -> dict[str, float]:
    from formula_tourney.tourney.api import run_tournament

    started = time.perf_counter()
    result = run_tournament(file, workers=workers, results_dir=results)
    wall = time.perf_counter() - started
    db = sqlite3.connect(Path(result["results"]) / "index.sqlite")
    job_wall, train_s, jobs = db.execute(
        "SELECT SUM(wall_s), SUM(json_extract(result, '$.train_seconds')), COUNT(*) FROM jobs "
        "WHERE status='done' AND kind='train'"
    ).fetchone()
    failed = db.execute("SELECT COUNT(*) FROM jobs WHERE status='failed' AND kind='train'"
                        ).fetchone()[0]
    db.close()
    return {
        "workers": workers,
        "wall_s": wall,
        "jobs_done": jobs,
        "jobs_failed": failed,
        "job_wall_s": job_wall or 0.0,
        "train_s": train_s or 0.0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--file", type=Path, default=Path(__file__).resolve().parents[1] / "tournaments/quick.toml"
    )
    parser.add_argument("--episodes", type=int, default=None,
                        help="scale down: every 'episodes = N' in the file becomes this value")
    parser.add_argument("--json", action="store_true", help="print one JSON document")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="ft-bench-") as tmp:
        file = args.file
        if args.episodes is not None:
            file = Path(tmp) / args.file.name
            text = re.sub(r"(?m)^episodes = \d+", f"episodes = {args.episodes}",
                          args.file.read_text(encoding="utf-8"))
            file.write_text(text, encoding="utf-8")
        one = measure(file, 1, Path(tmp) / "w1")
        two = measure(file, 2, Path(tmp) / "w2")
    efficiency = one["wall_s"] / (2.0 * two["wall_s"])
    setup_s = one["job_wall_s"] - one["train_s"]
    parent_s = one["wall_s"] - one["job_wall_s"]
    out = {
        "file": str(args.file),
        "one_worker": one,
        "two_workers": two,
        "parallel_efficiency": efficiency,
        "overhead_s": one["wall_s"] - one["train_s"],
        "overhead_fraction": (one["wall_s"] - one["train_s"]) / one["wall_s"],
        "worker_setup_s": setup_s,
        "parent_s": parent_s,
    }
    if args.json:
        print(json.dumps(out))
        return
    scale = f", episodes scaled to {args.episodes}" if args.episodes else ""
    print(f"{args.file.name}: {one['jobs_done']} jobs ({one['jobs_failed']} failed){scale}")
    print(f"  1 worker : {one['wall_s']:7.1f} s wall, {one['train_s']:7.1f} s inside train()")
    print(f"  2 workers: {two['wall_s']:7.1f} s wall, {two['train_s']:7.1f} s inside train()")
    print(f"parallel efficiency: {efficiency:.2f} (ideal 1.00)")
    print(
        f"orchestration overhead (1 worker): {out['overhead_s']:.1f} s = "
        f"{100 * out['overhead_fraction']:.1f}% of wall (ideal 0%): worker setup "
        f"{setup_s:.1f} s, parent {parent_s:.1f} s"
    )


if __name__ == "__main__":
    main()

"""Time to beat the bot: CPU-seconds until WIN1, tested greedily, laps `oval` faster than the
follower bot on the same reference line.

The run is an ordinary ``training.loop.train`` job; its progress callback stops it as soon as a
test (epsilon = 0, several starts) has a clean lap faster than the bot's best lap, or when the
CPU budget is spent. CPU-seconds are this process's (``time.process_time``), counted from the
start of training: updates, env steps and the tests themselves. The bot's lap and the reference
limit (quasi-steady-state lap on the minimum-curvature line) are computed before the clock starts.

Several seeds (``--seeds 0,1,2,3``, ``--jobs 2`` side by side, each in its own process with its
own CPU clock) give the median CPU-seconds to beat the bot, counting a seed that never beats it
within the budget as infinite. Goal: median <= 600 CPU-seconds. The last line is one JSON object.

    .venv/bin/python benchmarks/time_to_beat_bot.py [--seeds 0,1,2,3] [--jobs 2] [--set KEY=V]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

# Settings of the measured run (WIN1 otherwise at its registered defaults). The exploration
# phase is shortened from the paper-scale 100k steps to fit a 10-minute budget, and the batch is
# Lillicrap et al.'s 64: an update then costs ~1/3 of a 256-batch one on one CPU thread, and on
# `oval` 4 of 4 seeds beat the bot within 600 CPU-s at 64; at 256, with the earlier autograd
# update, 2 of 4 did.
OVERRIDES = {
    "exploration_steps": 40_000, "learning_starts": 1_000, "buffer_size": 200_000,
    "batch_size": 64,
}  # fmt: skip
TEST_EVERY = 5
TEST_STARTS = 3


def parse_overrides(pairs: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` pairs on top of OVERRIDES; values parse as JSON (numbers), else strings."""
    out = dict(OVERRIDES)
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep:
            raise SystemExit(f"--set wants KEY=VALUE, got {pair!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def run_seed(
    track_name: str, reference: str, seed: int, budget_cpu_s: float, max_steps: int,
    overrides: dict[str, Any], out_dir: str | None,
) -> dict[str, Any]:  # fmt: skip
    """One training run in this process; CPU-seconds are this process's own."""
    from formula_tourney.agents.ddpg import configure_torch

    configure_torch(1)
    from formula_tourney.bots.follower import drive
    from formula_tourney.bots.reference import reference_offsets
    from formula_tourney.lines.limit import reference_limit_s
    from formula_tourney.sim.catalog import load_track
    from formula_tourney.training.loop import train
    from formula_tourney.training.spec import build_run_spec

    track = load_track(track_name)
    offsets = reference_offsets(track, reference)
    bot = drive(track, offsets, laps=2)
    bot_lap = float(bot["best_lap_s"])
    limit = float(reference_limit_s(track))
    print(f"seed {seed}: bot {bot_lap:.3f} s, reference limit {limit:.3f} s", file=sys.stderr)

    cfg = build_run_spec(
        variant="WIN1", overrides=overrides, train_tracks=[track_name], reference=reference,
        seed=seed, device="cpu", threads=1,
        schedule={"episodes": 100_000, "max_steps": max_steps, "test_every_episodes": TEST_EVERY,
                  "test_starts": TEST_STARTS, "test_max_steps": int(3 * bot_lap / 0.2) + 100},
    )  # fmt: skip
    cpu0 = time.process_time()
    beaten: dict[str, float] = {}

    def progress(p: dict) -> bool:
        cpu = time.process_time() - cpu0
        best = p["best_lap_s"]
        if best is not None and best < bot_lap and not beaten:
            beaten.update(cpu_s=cpu, env_steps=p["env_steps"], episode=p["episode"], lap=best)
        if p["episode"] % TEST_EVERY == 0:
            print(f"seed {seed}: cpu {cpu:6.0f} s  episode {p['episode']}  env steps "
                  f"{p['env_steps']}  best {'-' if best is None else f'{best:.3f}'}",
                  file=sys.stderr)  # fmt: skip
        return not beaten and cpu < budget_cpu_s

    out = Path(out_dir) / f"seed-{seed}" if out_dir else Path(tempfile.mkdtemp(prefix="ttbb-"))
    summary = train(cfg, out / "job", progress)
    cpu_total = time.process_time() - cpu0
    best = summary["best_lap_s"]
    if best is not None and not math.isfinite(best):
        best = None
    return {
        "seed": seed,
        "bot_best_lap_s": round(bot_lap, 3),
        "reference_limit_s": round(limit, 3),
        "agent_best_lap_s": None if best is None else round(best, 3),
        "beaten": bool(beaten),
        "cpu_s_to_beat": round(beaten["cpu_s"], 1) if beaten else None,
        "cpu_s_total": round(cpu_total, 1),
        "env_steps": summary["env_steps"],
        "updates": summary["updates"],
        "episodes": summary["episodes"],
        "gap_agent_to_limit": None if best is None else round(best / limit - 1.0, 4),
        "gap_bot_to_limit": round(bot_lap / limit - 1.0, 4),
        "job": str(out / "job"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default="oval")
    ap.add_argument("--reference", default="centre", choices=["centre", "recorded", "mincurv"])
    ap.add_argument("--seeds", default="0", help="comma-separated seeds, e.g. 0,1,2,3")
    ap.add_argument("--jobs", type=int, default=1, help="seeds run side by side (processes)")
    ap.add_argument("--budget-cpu-s", type=float, default=600.0)
    ap.add_argument("--max-steps", type=int, default=1000)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="WIN1 setting on top of the benchmark's (repeatable)")  # fmt: skip
    ap.add_argument("--out", default=None, help="folder for the job folders (default: temp)")
    args = ap.parse_args()
    seeds = [int(x) for x in args.seeds.split(",") if x.strip()]
    overrides = parse_overrides(args.set)
    call = (args.track, args.reference)
    tail = (args.budget_cpu_s, args.max_steps, overrides, args.out)
    if args.jobs > 1 and len(seeds) > 1:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(min(args.jobs, len(seeds)), mp.get_context("spawn")) as pool:
            runs = list(pool.map(run_seed, *zip(*[(*call, s, *tail) for s in seeds], strict=True)))
    else:
        runs = [run_seed(*call, s, *tail) for s in seeds]

    times = sorted(r["cpu_s_to_beat"] if r["beaten"] else math.inf for r in runs)
    median = statistics.median(times)
    result = {
        "benchmark": "time_to_beat_bot",
        "track": args.track,
        "reference": args.reference,
        "variant": "WIN1",
        "overrides": overrides,
        "test_every_episodes": TEST_EVERY,
        "test_starts": TEST_STARTS,
        "budget_cpu_s": args.budget_cpu_s,
        "seeds": seeds,
        "beaten": sum(r["beaten"] for r in runs),
        "median_cpu_s_to_beat": None if not math.isfinite(median) else round(median, 1),
        "best_lap_s": [r["agent_best_lap_s"] for r in runs],
        "bot_best_lap_s": runs[0]["bot_best_lap_s"],
        "reference_limit_s": runs[0]["reference_limit_s"],
        "runs": runs,
        "goal_cpu_s": 600.0,
        "goal_met": math.isfinite(median) and median <= 600.0,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()

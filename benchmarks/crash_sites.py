"""Where a run's tests crash once it can lap, and whether its target actor would drive steadier.

The clean-start rate of ``time_to_competence.py`` (clean laps from 2 of 3 test starts from the
first clean lap on) stays low on ``technical``. This reads the job folders a benchmark wrote
(``--out DIR``) and says where the tests after each run's first clean lap left the track: the
track position of every off-track end, in bins of ``--bin-m`` metres, and the share of the most
frequent sites. With ``--starts N`` it also drives each run's last checkpoint from N starts
twice, with the online actor (what the tests drive) and with its slowly moving target actor
(Polyak averages are a known way to steady a policy), and counts the clean laps of each.

    .venv/bin/python benchmarks/crash_sites.py DIR/WIN1-tuned-bc/seed-* [--starts 6]

The last line is one JSON object.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
from collections import Counter  # noqa: E402
from typing import Any  # noqa: E402

from formula_tourney.agents.checkpoints import load_checkpoint  # noqa: E402
from formula_tourney.agents.core import Agent, configure_torch  # noqa: E402
from formula_tourney.results.folder import JobFolder  # noqa: E402
from formula_tourney.results.layout import LAST_CHECKPOINT  # noqa: E402
from formula_tourney.training.envs import RunEnvs  # noqa: E402
from formula_tourney.training.evaluate import run_test_episode, start_positions  # noqa: E402
from formula_tourney.training.run_spec import RunSpec  # noqa: E402


def crash_positions(folder: JobFolder, length_m: float) -> tuple[int, list[float]]:
    """Tests after the first clean lap, and the track position of each off-track end."""
    tests = folder.table("tests")
    lapped = tests[tests["finished"]]
    if lapped.empty:
        return 0, []
    after = tests[tests["episode"] >= lapped["episode"].min()]
    off = after[after["termination"] == "off_track"]
    return len(after), [float((s + d) % length_m) for s, d in
                        zip(off["start_s_m"], off["distance_m"], strict=True)]  # fmt: skip


def clean_laps(agent: Agent, envs: RunEnvs, track: str, starts: list[float]) -> int:
    env = envs.make(track, test=True)
    drives = [run_test_episode(agent, env, track, s0, seed=k, record_trace=False)
              for k, s0 in enumerate(starts)]  # fmt: skip
    return sum(math.isfinite(d.best_lap_s) for d in drives)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("jobs", nargs="*", help="job folders (time_to_competence.py --out DIR); "
                    "none (as `make bench` runs it): nothing to read, an empty result")
    ap.add_argument("--bin-m", type=float, default=20.0, help="width of a crash site")
    ap.add_argument("--top", type=int, default=2, help="sites whose share is reported")
    ap.add_argument("--starts", type=int, default=0,
                    help="also drive the last checkpoint from N starts, online and target actor")
    args = ap.parse_args()  # fmt: skip
    configure_torch(1)
    if not args.jobs:
        print("crash_sites: no job folders given, nothing to read", file=sys.stderr)
    runs: list[dict[str, Any]] = []
    sites: Counter[float] = Counter()
    for job in args.jobs:
        folder = JobFolder(job)
        spec = RunSpec.from_json(folder.config(), job)
        envs = RunEnvs(spec)
        track = spec.key_track
        length_m = envs.tracks[track].length_m
        tests, crashes = crash_positions(folder, length_m)
        sites.update(round(p / args.bin_m) * args.bin_m for p in crashes)
        run: dict[str, Any] = {"job": job, "tests_after_first_lap": tests,
                               "off_track": len(crashes)}  # fmt: skip
        if args.starts:
            agent, _ = load_checkpoint(folder.checkpoint_path(LAST_CHECKPOINT))
            starts = start_positions(length_m, args.starts)
            run["clean_online"] = clean_laps(agent, envs, track, starts)
            assert agent.actor_target is not None  # DDPG and TD3 keep one
            agent.actor.load_state_dict(agent.actor_target.state_dict())
            run["clean_target"] = clean_laps(agent, envs, track, starts)
        print(json.dumps(run))
        runs.append(run)
    total = sum(sites.values())
    top = sites.most_common(args.top)
    result = {
        "benchmark": "crash_sites", "runs": runs, "off_track": total,
        "top_sites_m": [s for s, _ in top],
        "top_share": round(sum(n for _, n in top) / total, 3) if total else None,
    }  # fmt: skip
    if args.starts:
        pairs = [(r["clean_target"], r["clean_online"]) for r in runs]
        result["target_better_same_worse"] = [sum(t > o for t, o in pairs),
                                              sum(t == o for t, o in pairs),
                                              sum(t < o for t, o in pairs)]  # fmt: skip
    print(json.dumps(result))


if __name__ == "__main__":
    main()

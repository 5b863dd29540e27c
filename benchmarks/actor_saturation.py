"""How saturated a trained actor is: its output pre-activations over one greedy test drive.

A squashed output's gradient is about exp(-|z|); this drives a checkpoint's actor from one start
(as a test does) and prints percentiles of each output's pre-activation z and the share of steps
with |z| beyond 5, the figures docs/results.md gives for `best` on `technical` and for the
general driver's collapsed seed.

    .venv/bin/python benchmarks/actor_saturation.py CHECKPOINT [--track technical]

The last line is one JSON object.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402

import numpy as np  # noqa: E402

from formula_tourney.training.envs import RunEnvs  # noqa: E402
from formula_tourney.training.evaluate import (  # noqa: E402
    greedy_windows,
    load_run_checkpoint,
    start_positions,
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("--track", default="technical")
    ap.add_argument("--max-steps", type=int, default=1500)
    args = ap.parse_args()
    agent, spec, _ = load_run_checkpoint(args.checkpoint)
    envs = RunEnvs(spec, extra_tracks=[args.track])
    env = envs.make(args.track, test=True, max_steps=args.max_steps)
    start = start_positions(envs.tracks[args.track].length_m, 1)[0]
    zs, info = [], {}
    for stack, _, step_info in greedy_windows(agent, env, start):  # the actor a test drives
        zs.append(agent.eval_preactivation(stack))
        info = step_info  # the last step's tells how the drive ended
    z = np.asarray(zs)
    names = ["steer", "throttle", "brake"] if z.shape[1] == 3 else ["steer", "pedal"]
    out = {name: {"percentiles_1_10_50_90_99": np.round(np.percentile(z[:, i],
                                                                      [1, 10, 50, 90, 99]), 1)
                  .tolist(), "share_beyond_5": round(float((np.abs(z[:, i]) > 5).mean()), 3)}
           for i, name in enumerate(names)}  # fmt: skip
    for name, row in out.items():
        print(f"{name}: {row}")
    print(json.dumps({"benchmark": "actor_saturation", "checkpoint": args.checkpoint,
                      "track": args.track, "steps": len(z), "termination": info.get("termination"),
                      "outputs": out}))


if __name__ == "__main__":
    main()

"""What a trained critic reads: Q(s, mu(s)) along greedy test drives of one checkpoint.

The Q a critic reaches on a track is what ``critic_value_range`` (the classification critic's
bins, DDPG family) has to span; these are the figures docs/agents.md gives per built-in track
for a trained `best` critic. It drives the actor a test drives from ``--starts`` spread starts,
reads the critic at each step's state and greedy action, and prints percentiles of Q and the
termination of each drive.

    .venv/bin/python benchmarks/critic_values.py CHECKPOINT [--track oval] [--starts 3]

The last line is one JSON object.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402

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
    ap.add_argument("--starts", type=int, default=3)
    ap.add_argument("--max-steps", type=int, default=3000)
    args = ap.parse_args()
    agent, spec, _ = load_run_checkpoint(args.checkpoint)
    try:  # one read before the drive: a critic it cannot read is refused here, not mid-drive
        agent.eval_q(np.zeros((agent.cfg.window, agent.obs_dim), np.float32),
                     np.zeros(agent.action_dim, np.float32))  # fmt: skip
    except TypeError as err:
        sys.exit(f"error: {args.checkpoint}: {err}")
    envs = RunEnvs(spec, extra_tracks=[args.track])
    env = envs.make(args.track, test=True, max_steps=args.max_steps)
    qs: list[float] = []
    ends: list[str] = []
    for start in start_positions(envs.tracks[args.track].length_m, args.starts):
        info: dict = {}
        for stack, action, step_info in greedy_windows(agent, env, start):
            info = step_info  # the last step's tells how the drive ended
            qs.append(agent.eval_q(stack, action))
        ends.append(str(info.get("termination")))
    pct = np.round(np.percentile(qs, [1, 10, 50, 90, 99]), 1).tolist()
    print(f"Q percentiles 1, 10, 50, 90, 99: {pct}; drives end: {', '.join(ends)}")
    print(json.dumps({"benchmark": "critic_values", "checkpoint": args.checkpoint,
                      "track": args.track, "steps": len(qs), "terminations": ends,
                      "q_percentiles_1_10_50_90_99": pct,
                      "critic_value_range": list(agent.cfg.critic_value_range)
                      if getattr(agent.cfg, "critic_bins", 0) else None}))


if __name__ == "__main__":
    main()

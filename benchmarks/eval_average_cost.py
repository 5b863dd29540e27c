"""What the tests' average of the actor (``eval_ema_updates``) costs per DDPG update.

Two WIN1 agents at `tuned-bc-ema`'s sizes (128-128 networks, batch 64), one keeping the average
over 3 000 updates and one not, update on the same batches in interleaved rounds in one process,
one thread: the update without the average is the anchor. The average is one lerp over the
actor's flat weights after each actor step, so the goal is a few per cent at most.

    .venv/bin/python benchmarks/eval_average_cost.py [--rounds 4] [--updates 2000]

The last line is one JSON object.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from formula_tourney.agents.ddpg import DDPGAgent, configure_torch  # noqa: E402
from formula_tourney.agents.replay import make_buffer  # noqa: E402
from formula_tourney.agents.variants import get_variant  # noqa: E402

OBS_DIM = 60  # technical with LAC, where tuned-bc-ema was measured
BATCH, EMA_UPDATES = 64, 3000
GOAL_RATIO = 1.05


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--updates", type=int, default=2000, help="updates per timed block")
    args = ap.parse_args()
    configure_torch(1)
    buf = make_buffer(20_000, OBS_DIM, 3, prioritized=False, gamma=0.976, n_step=1, window=1,
                      bootstrap_on_truncation=True, seed=0)  # fmt: skip
    rng = np.random.default_rng(0)
    for t in range(10_000):
        buf.add(rng.normal(size=OBS_DIM), rng.random(3), 1.0 + rng.normal(),
                rng.normal(size=OBS_DIM), terminated=False, truncated=t % 500 == 499)  # fmt: skip
    batches = [buf.sample(BATCH) for _ in range(400)]
    agents = {
        name: DDPGAgent(get_variant("WIN1", {"hidden": (128, 128), "batch_size": BATCH,
                                             "eval_ema_updates": n}), OBS_DIM, seed=0)
        for name, n in (("plain", 0), ("averaged", EMA_UPDATES))
    }  # fmt: skip
    us: dict[str, list[float]] = {name: [] for name in agents}
    for _ in range(args.rounds):
        for name, agent in agents.items():
            t0 = time.process_time()
            for k in range(args.updates):
                agent.update(batches[k % len(batches)])
            us[name].append((time.process_time() - t0) / args.updates * 1e6)
    plain, averaged = statistics.median(us["plain"]), statistics.median(us["averaged"])
    print(f"update without the average {plain:.1f} us, with {averaged:.1f} us "
          f"(x{averaged / plain:.3f}; goal <= x{GOAL_RATIO})")  # fmt: skip
    print(json.dumps({
        "benchmark": "eval_average_cost", "batch": BATCH, "eval_ema_updates": EMA_UPDATES,
        "us_per_update": {"plain": round(plain, 1), "averaged": round(averaged, 1)},
        "rounds_us": {k: [round(x, 1) for x in v] for k, v in us.items()},
        "ratio": round(averaged / plain, 3), "goal_ratio": GOAL_RATIO,
        "goal_met": averaged / plain <= GOAL_RATIO,
    }))  # fmt: skip


if __name__ == "__main__":
    main()

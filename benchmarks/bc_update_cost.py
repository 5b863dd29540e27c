"""What cloning in the actor's loss (``demos.bc_weight``) and the tests' average of the actor
(``eval_ema_updates``) each cost per DDPG update.

The same agent updates on the same mixed batches (``agents.buffers.DemoMix``: online rows, then
demonstration rows) with and without the cloning term, and a second agent that keeps the
average over 3 000 updates (``best-demos``'s) updates on them without it, in interleaved
rounds in one process, one thread: the plain update is the anchor of both. Sizes are
``tuned-bc``'s (128-128 networks, batch 64, a quarter of it from the demonstrations).

    .venv/bin/python benchmarks/bc_update_cost.py [--rounds 4] [--updates 2000]

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

from formula_tourney.agents.buffers import DemoMix, ReplayBuffer, make_buffer  # noqa: E402
from formula_tourney.agents.core import configure_torch  # noqa: E402
from formula_tourney.agents.ddpg import DDPGAgent  # noqa: E402
from formula_tourney.agents.mlp_update import BCLoss  # noqa: E402
from formula_tourney.agents.variants import get_variant  # noqa: E402

OBS_DIM = 60  # technical with LAC: the observation tuned-bc's demo part trains on
BATCH, DEMO_ROWS = 64, 16
GOAL_RATIO = 1.10
EMA_UPDATES, GOAL_RATIO_AVERAGE = 3000, 1.05  # one lerp over the actor's weights per update


def _filled(seed: int, n: int) -> ReplayBuffer:
    buf = make_buffer(20_000, OBS_DIM, 3, prioritized=False, gamma=0.976, n_step=1, window=1,
                      bootstrap_on_truncation=True, seed=seed)  # fmt: skip
    rng = np.random.default_rng(seed)
    for t in range(n):
        buf.add(rng.normal(size=OBS_DIM), rng.random(3), 1.0 + rng.normal(),
                rng.normal(size=OBS_DIM), terminated=False, truncated=t % 500 == 499)  # fmt: skip
    return buf


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--updates", type=int, default=2000, help="updates per timed block")
    args = ap.parse_args()
    configure_torch(1)
    mix = DemoMix(_filled(1, 10_000), _filled(2, 3_000), DEMO_ROWS)
    batches = [mix.sample(BATCH) for _ in range(400)]
    agent, averaged = (
        DDPGAgent(get_variant("WIN1", {"hidden": (128, 128), "batch_size": BATCH,
                                       "eval_ema_updates": n}), OBS_DIM, seed=0)
        for n in (0, EMA_UPDATES)
    )  # fmt: skip
    cloning = BCLoss(0.2, DEMO_ROWS)
    us: dict[str, list[float]] = {"plain": [], "cloning": [], "average": []}
    for _ in range(args.rounds):
        for name, learner, bc in (("plain", agent, None), ("cloning", agent, cloning),
                                  ("average", averaged, None)):  # fmt: skip
            t0 = time.process_time()
            for k in range(args.updates):
                learner.update(batches[k % len(batches)], None, bc=bc)
            us[name].append((time.process_time() - t0) / args.updates * 1e6)
    plain, cloned, avg = (statistics.median(us[k]) for k in ("plain", "cloning", "average"))
    print(f"update without cloning {plain:.1f} us, with {cloned:.1f} us "
          f"(x{cloned / plain:.3f}; goal <= x{GOAL_RATIO}); with the tests' average {avg:.1f} us "
          f"(x{avg / plain:.3f}; goal <= x{GOAL_RATIO_AVERAGE})")  # fmt: skip
    print(json.dumps({
        "benchmark": "bc_update_cost", "batch": BATCH, "demo_rows": DEMO_ROWS,
        "eval_ema_updates": EMA_UPDATES,
        "us_per_update": {"plain": round(plain, 1), "cloning": round(cloned, 1),
                          "average": round(avg, 1)},
        "rounds_us": {k: [round(x, 1) for x in v] for k, v in us.items()},
        "ratio": round(cloned / plain, 3), "goal_ratio": GOAL_RATIO,
        "goal_met": cloned / plain <= GOAL_RATIO,
        "ratio_average": round(avg / plain, 3), "goal_ratio_average": GOAL_RATIO_AVERAGE,
        "goal_met_average": avg / plain <= GOAL_RATIO_AVERAGE,
    }))  # fmt: skip


if __name__ == "__main__":
    main()

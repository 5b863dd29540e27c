"""What agent settings cost per update: the DDPG update of a preset with and without them.

Two agents of the same variant and preset, one with the settings given by ``--set`` and one
without (the anchor), update on the same batches in interleaved timed blocks, in one process on
one thread, so the ratio is measured under the same load. Sizes are the preset's (``best``:
400-300 networks, batch 64) and the observation is `technical`'s with LAC.

    .venv/bin/python benchmarks/update_cost.py --set critic_bins=101 [--preset best]
        [--rounds 4] [--updates 1000]

The last line is one JSON object: the median microseconds per update of each, and their ratio.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from formula_tourney.agents.buffers import ReplayBuffer, make_buffer  # noqa: E402
from formula_tourney.agents.core import Agent, configure_torch  # noqa: E402
from formula_tourney.agents.families import make_agent  # noqa: E402
from formula_tourney.agents.variants import get_variant, named_settings  # noqa: E402
from formula_tourney.errors import UserInputError  # noqa: E402
from formula_tourney.training.presets import get_preset  # noqa: E402

OBS_DIM = 60  # technical with LAC


def _filled(seed: int, n: int) -> ReplayBuffer:
    buf = make_buffer(20_000, OBS_DIM, 3, prioritized=False, gamma=0.976, n_step=1, window=1,
                      bootstrap_on_truncation=True, seed=seed)  # fmt: skip
    rng = np.random.default_rng(seed)
    for t in range(n):
        buf.add(rng.normal(size=OBS_DIM), rng.random(3), 1.0 + rng.normal(),
                rng.normal(size=OBS_DIM), terminated=t % 300 == 299, truncated=False)  # fmt: skip
    return buf


def _overrides(pairs: list[str]) -> dict[str, object]:
    """``KEY=VALUE`` pairs; values parse as JSON (numbers, booleans, lists), else stay text."""
    out: dict[str, object] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise UserInputError(f"--set wants KEY=VALUE, got {pair!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def _agent(variant: str, preset: str, extra: dict[str, object]) -> Agent:
    base = get_variant(variant)
    overrides = get_preset(preset).agent_overrides(base.family, named_settings(variant))
    return make_agent(get_variant(variant, {**overrides, **extra}), OBS_DIM, seed=0)


def _time_block(agent: Agent, batches: list, updates: int) -> float:
    """Microseconds of CPU per update over ``updates`` updates."""
    start = time.process_time()
    for i in range(updates):
        agent.update(batches[i % len(batches)])
    return (time.process_time() - start) / updates * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", required=True)
    ap.add_argument("--variant", default="WIN1")
    ap.add_argument("--preset", default="best")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--updates", type=int, default=1000, help="updates per timed block")
    args = ap.parse_args()
    configure_torch(1)
    try:
        extra = _overrides(args.set)
        anchor, changed = _agent(args.variant, args.preset, {}), _agent(args.variant,
                                                                         args.preset, extra)
    except UserInputError as err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    buf = _filled(1, 10_000)
    batches = [buf.sample(anchor.cfg.batch_size) for _ in range(400)]
    for agent in (anchor, changed):  # warm-up: buffers allocated, caches filled
        _time_block(agent, batches, 100)
    times: dict[str, list[float]] = {"anchor": [], "changed": []}
    for _ in range(args.rounds):
        times["anchor"].append(_time_block(anchor, batches, args.updates))
        times["changed"].append(_time_block(changed, batches, args.updates))
    med = {k: statistics.median(v) for k, v in times.items()}
    for k, v in times.items():
        print(f"{k}: {', '.join(f'{t:.1f}' for t in v)} us per update", file=sys.stderr)
    print(json.dumps({
        "benchmark": "update_cost", "variant": args.variant, "preset": args.preset,
        "settings": extra, "batch_size": anchor.cfg.batch_size,
        "hidden": list(anchor.cfg.hidden), "obs_dim": OBS_DIM,
        "anchor_us": round(med["anchor"], 1), "changed_us": round(med["changed"], 1),
        "ratio": round(med["changed"] / med["anchor"], 3),
    }))


if __name__ == "__main__":
    main()

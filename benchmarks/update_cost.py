"""What agent settings cost per update: the DDPG update of a preset with and without them.

Two agents of the same variant and preset, one with the settings given by ``--set`` and one
without (the anchor), update on the same batches in interleaved timed blocks, in one process on
one thread, so the ratio is measured under the same load. Sizes are the preset's (``best``:
128-128 networks, batch 64); the batches are drawn from 10 000 steps of real telemetry on
`technical` with LAC (33 values), driven by uniformly random actions.

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

import gymnasium  # noqa: E402

import formula_tourney  # noqa: E402, F401  (registers FormulaRacing-v0)
from formula_tourney.agents.buffers import ReplayBuffer, make_buffer  # noqa: E402
from formula_tourney.agents.core import Agent, configure_torch  # noqa: E402
from formula_tourney.agents.families import make_agent  # noqa: E402
from formula_tourney.agents.variants import AgentConfig, get_variant, named_settings  # noqa: E402
from formula_tourney.commands.model_options import parse_key_values  # noqa: E402
from formula_tourney.errors import UserInputError  # noqa: E402
from formula_tourney.training.presets import get_preset  # noqa: E402

STEPS = 10_000


def _telemetry(seed: int) -> ReplayBuffer:
    """``STEPS`` transitions of `technical` with LAC under uniformly random actions."""
    env = gymnasium.make("FormulaRacing-v0", config={"track": "technical", "lac": True},
                         disable_env_checker=True)  # fmt: skip
    obs_dim = env.observation_space.shape[0]
    buf = make_buffer(STEPS, obs_dim, 3, prioritized=False, gamma=0.976, n_step=1, window=1,
                      bootstrap_on_truncation=True, seed=seed)  # fmt: skip
    env.action_space.seed(seed)
    obs, _ = env.reset(seed=seed)
    for _ in range(STEPS):
        action = env.action_space.sample()
        next_obs, reward, terminated, truncated, _ = env.step(action)
        buf.add(obs, action, reward, next_obs, terminated, truncated)
        obs = env.reset()[0] if terminated or truncated else next_obs
    return buf


def _config(variant: str, preset: str, extra: dict[str, object]) -> AgentConfig:
    """The variant under the preset, with ``extra`` on top, validated."""
    base = get_variant(variant)
    overrides = get_preset(preset).agent_overrides(base.family, named_settings(variant))
    return get_variant(variant, {**overrides, **extra})


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
        extra = parse_key_values(args.set, "--set")
        configs = [_config(args.variant, args.preset, {}),
                   _config(args.variant, args.preset, extra)]  # fmt: skip
    except UserInputError as err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    buf = _telemetry(1)
    anchor, changed = (make_agent(cfg, buf.obs.shape[1], seed=0) for cfg in configs)
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
        "hidden": list(anchor.cfg.hidden), "obs_dim": anchor.obs_dim,
        "anchor_us": round(med["anchor"], 1), "changed_us": round(med["changed"], 1),
        "ratio": round(med["changed"] / med["anchor"], 3),
    }))


if __name__ == "__main__":
    main()

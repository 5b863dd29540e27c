"""Why the technical track is not learned: the braking a hairpin needs against what exploration
ever produces.

The follower bot laps `technical` on the min-curvature line; its trace says how long the car
must brake before each hairpin (consecutive 200 ms steps with brake >= a threshold). The paper's
exploration (OU noise plus brake exploration, ``agents.noise.BrakeExplorationNoise`` at the
registered defaults) is run on a driver that holds the throttle, at several epsilons, and the
same runs of braking are counted. The ratio says how often exploration shows the critic a
braking zone as long as the track needs: that is the data the DDPG update learns braking from.

    .venv/bin/python benchmarks/braking_exploration.py [--track technical] [--steps 200000]

The last line is one JSON object.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402

import numpy as np  # noqa: E402

from formula_tourney.agents.noise import BrakeExplorationNoise  # noqa: E402
from formula_tourney.agents.variants import get_variant  # noqa: E402
from formula_tourney.bots.follower import (
    _car_state,  # noqa: E402
    drive,  # noqa: E402
)
from formula_tourney.bots.line_offsets import reference_offsets  # noqa: E402
from formula_tourney.sim.catalog import load_track  # noqa: E402
from formula_tourney.training.demos import follower_for  # noqa: E402
from formula_tourney.training.envs import RunEnvs  # noqa: E402
from formula_tourney.training.run_spec import build_run_spec  # noqa: E402

GAMMA = 0.99

BRAKE_THRESHOLD = 0.3


def brake_runs(brake: np.ndarray, threshold: float = BRAKE_THRESHOLD) -> np.ndarray:
    """Lengths (in steps) of the runs of consecutive steps with brake >= ``threshold``."""
    on = np.concatenate([[False], np.asarray(brake) >= threshold, [False]])
    edges = np.flatnonzero(on[1:] != on[:-1])
    return edges[1::2] - edges[::2]


def exploration_runs(epsilon: float, steps: int, hold: int = 1, seed: int = 0) -> np.ndarray:
    """Braking runs of the exploration on an actor holding throttle 0.9, brake 0.05 (hold 1:
    the paper's rule; more: ``brake_explore_hold_steps``, beyond the paper)."""
    cfg = get_variant("WIN1", {"brake_explore_hold_steps": hold})
    noise = BrakeExplorationNoise(
        np.random.default_rng(seed), cfg.ou_theta, cfg.ou_sigma, cfg.noise_prob,
        cfg.brake_explore_prob, cfg.brake_explore_mean, cfg.brake_explore_sigma,
        cfg.brake_explore_hold_steps,
    )  # fmt: skip
    actor = np.array([0.0, 0.9, 0.05])
    brake = np.empty(steps)
    for k in range(steps):
        if k % 1000 == 0:
            noise.reset()  # episodes of 1000 steps, as in training
        brake[k] = noise(actor, epsilon)[0][2]
    return brake_runs(brake)


def discounted(rewards: list[float], terminal: bool, gamma: float = GAMMA) -> float:
    """sum_k gamma^k r_k over the drive (a crash ends it: terminal, nothing bootstraps)."""
    return float(sum(r * gamma**k for k, r in enumerate(rewards)))


def zone_returns(track_name: str, horizon: int = 100) -> list[dict]:
    """For each of the follower's braking zones on the training env (recorded line + LAC, the
    paper's best setup): the discounted return over ``horizon`` steps from the zone's start when
    the car brakes as the follower does, against the same start when it keeps the throttle on
    until the env ends the episode. If the reward did not make braking pay within gamma's
    horizon, no amount of exploration could teach it."""
    spec = build_run_spec(variant="WIN1", train_tracks=[track_name], reference="recorded",
                          lac=True, schedule={"max_steps": 3000})  # fmt: skip
    envs = RunEnvs(spec)
    env = envs.make(track_name, test=True, max_steps=3000)
    bot = follower_for(envs, track_name, "mincurv")
    _, info = env.reset(seed=0)
    bot.reset()
    where, brakes = [], []
    while True:
        action = np.asarray(bot.act(_car_state(env)), dtype=np.float32)
        where.append((float(info["s_m"]), float(info["speed_mps"])))
        brakes.append(float(action[2]))
        _, _, terminated, truncated, info = env.step(action)
        if terminated or truncated or info["laps"] >= 1:
            break
    on = np.concatenate([[False], np.asarray(brakes) >= BRAKE_THRESHOLD, [False]])
    starts = np.flatnonzero(on[1:-1] & ~on[:-2])
    out = []
    for k in starts:
        if k < 10:  # the standing start
            continue
        s_m, speed = where[k]
        result = {"start_s_m": round(s_m, 1), "speed_kmh": round(3.6 * speed, 1)}
        for name, brake in (("brakes", True), ("no_brake", False)):
            env.reset(seed=0, options={"start_s_m": s_m, "start_speed_mps": speed})
            bot.reset()
            rewards, terminal = [], False
            for _ in range(horizon):
                action = np.asarray(bot.act(_car_state(env)), dtype=np.float32)
                if not brake:
                    action[1], action[2] = 1.0, 0.0
                _, reward, terminated, truncated, _ = env.step(action)
                rewards.append(float(reward))
                if terminated or truncated:
                    terminal = bool(terminated)
                    break
            result[name] = round(discounted(rewards, terminal), 1)
            result[f"{name}_ends"] = "crash" if terminal else "drives on"
        out.append(result)
    env.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default="technical")
    ap.add_argument("--steps", type=int, default=200_000)
    args = ap.parse_args()
    track = load_track(args.track)
    lap = drive(track, reference_offsets(track, "mincurv"), laps=1)
    trace = lap["trace"]
    speed = np.asarray(trace["speed_kmh"])
    needed = brake_runs(np.asarray(trace["brake"]))
    # the braking zones of one flying lap: drop the standing start's first steps
    zones = [int(n) for n in needed if n >= 2]
    longest = max(zones) if zones else 0
    rows = {}
    for hold in (1, 15):
        for epsilon in (1.0, 0.5, 0.1):
            runs = exploration_runs(epsilon, args.steps, hold)
            per_1000 = {f"ge_{n}": float((runs >= n).sum() * 1000 / args.steps)
                        for n in (1, 3, 8, max(longest, 1))}  # fmt: skip
            key = f"hold {hold}, epsilon {epsilon}"
            rows[key] = {"longest_run_steps": int(runs.max()) if runs.size else 0,
                         "runs_per_1000_steps": per_1000}  # fmt: skip
            print(f"{key}: longest braking run {rows[key]['longest_run_steps']} steps; per 1000 "
                  f"steps: {per_1000}", file=sys.stderr)  # fmt: skip
    print(f"follower on {args.track} (mincurv): lap {lap['best_lap_s']:.2f} s, braking zones "
          f"{zones} steps (>= {BRAKE_THRESHOLD}), speed {speed.min():.0f}-{speed.max():.0f} km/h",
          file=sys.stderr)  # fmt: skip
    zones_returns = zone_returns(args.track)
    for z in zones_returns:
        print(f"braking zone at s = {z['start_s_m']} m, {z['speed_kmh']} km/h: discounted return "
              f"braking {z['brakes']} ({z['brakes_ends']}), not braking {z['no_brake']} "
              f"({z['no_brake_ends']})", file=sys.stderr)  # fmt: skip
    print(json.dumps({
        "benchmark": "braking_exploration", "track": args.track,
        "zone_returns": zones_returns, "gamma": GAMMA,
        "brake_threshold": BRAKE_THRESHOLD, "follower_lap_s": lap["best_lap_s"],
        "follower_braking_zones_steps": zones, "longest_needed_steps": longest,
        "exploration": rows, "steps": args.steps,
    }))


if __name__ == "__main__":
    main()

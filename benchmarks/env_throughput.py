"""Env throughput against highway-env, in one run.

Measures, with random actions and wall-clock time:
  (a) ``gymnasium.make("FormulaRacing-v0")`` with full telemetry (29 values + LAC), steps/s;
  (b) ``gymnasium.make_vec(..., num_envs=64, vectorization_mode="vector_entry_point")``,
      car-steps/s;
  (c) highway-env ``racetrack-v0`` with continuous steering+throttle, Kinematics observation and
      no other vehicles, steps/s: the anchor (110-175 steps/s on a 2-core machine, docs/results.md).
Prints a/c (goal >= 500) and b/c (goal >= 2000, one thread); the last line is one
JSON object.

    .venv/bin/python benchmarks/env_throughput.py [--seconds 5] [--track oval] [--threads 1]
"""

from __future__ import annotations

import argparse
import json
import os
import time
import warnings

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402

import formula_tourney  # noqa: E402,F401  (registers FormulaRacing-v0)
from formula_tourney.sim.track import Track  # noqa: E402

GOAL_SINGLE = 500.0  # the single env stays >= 500x highway-env
GOAL_VECTOR = 2000.0  # the 64-car vector env >= 2000x, on one thread
HIGHWAY_CONFIG = {
    "action": {"type": "ContinuousAction", "longitudinal": True, "lateral": True},
    "observation": {"type": "Kinematics"},
    "other_vehicles": 0,
}


def fallback_oval() -> Track:
    """A ~2.3 km oval (radius 150 m, 18 m wide) for when the track catalog is unavailable."""
    straight, radius, step = 680.0, 150.0, 1.0
    xs = np.arange(0.0, straight, step)
    a = np.linspace(-np.pi / 2, np.pi / 2, int(np.pi * radius / step), endpoint=False)
    pts = np.vstack(
        [
            np.c_[xs, 0 * xs],
            np.c_[straight + radius * np.cos(a), radius + radius * np.sin(a)],
            np.c_[straight - xs, 0 * xs + 2 * radius],
            np.c_[radius * np.cos(a + np.pi), radius + radius * np.sin(a + np.pi)],
        ]
    )
    return Track.from_centreline("bench-oval", pts[:, 0], pts[:, 1], 9.0, 9.0)


def resolve_track(name: str) -> tuple[Track | str, str]:
    try:
        from formula_tourney.sim.catalog import load_track

        load_track(name)
        return name, name
    except Exception as exc:  # catalog missing or the name unknown: say so, measure anyway
        print(f"note: track {name!r} unavailable ({exc.__class__.__name__}); using a 2.3 km oval")
        return fallback_oval(), "bench-oval (fallback)"


def time_single(track: Track | str, seconds: float) -> float:
    env = gymnasium.make(
        "FormulaRacing-v0", config={"track": track, "lac": True, "random_start": True}
    )
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform([-1, 0, 0], [1, 1, 1], size=(4096, 3)).astype(np.float32)
    for k in range(200):  # warm up: numba cache load, PassiveEnvChecker's first step
        _, _, term, trunc, _ = env.step(actions[k])
        if term or trunc:
            env.reset()
    steps, t0 = 0, time.perf_counter()
    while True:
        for k in range(1000):
            _, _, term, trunc, _ = env.step(actions[k & 4095])
            if term or trunc:
                env.reset()
        steps += 1000
        if time.perf_counter() - t0 >= seconds:
            return steps / (time.perf_counter() - t0)


def time_vector(track: Track | str, seconds: float, num_envs: int = 64,
                threads: int = 1) -> float:
    venv = gymnasium.make_vec(
        "FormulaRacing-v0",
        num_envs=num_envs,
        vectorization_mode="vector_entry_point",
        config={"track": track, "lac": True, "random_start": True},
        threads=threads,
    )
    venv.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform([-1, 0, 0], [1, 1, 1], size=(64, num_envs, 3)).astype(np.float32)
    for k in range(20):
        venv.step(actions[k % 64])
    steps, t0 = 0, time.perf_counter()
    while True:
        for k in range(50):
            venv.step(actions[k])
        steps += 50
        if time.perf_counter() - t0 >= seconds:
            return steps * num_envs / (time.perf_counter() - t0)


def time_highway(seconds: float) -> float:
    import highway_env  # noqa: F401  (registers racetrack-v0)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # racetrack-v0 "is out of date": the anchor
        env = gymnasium.make("racetrack-v0", config=HIGHWAY_CONFIG)
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(5):
        env.step(env.action_space.sample())
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        steps += 1
        if term or trunc:
            env.reset()
    return steps / (time.perf_counter() - t0)


RACE_CARS = 8
GOAL_RACE = 0.5
"""Race row: per-car rate of an 8-car race over that of 8 independent cars."""


def time_race(track: Track | str, seconds: float, cars: int = RACE_CARS) -> tuple[float, float]:
    """(car-steps/s, share of car-steps in the contact lockstep) of ``cars`` cars racing in a
    pack: a staggered grid rolling at 20 m/s, near full throttle, regridded every 100 steps so
    they stay close (every car near another takes the lockstep path with contact tests)."""
    from formula_tourney.sim.multicar.simulator import RaceSim

    sim = RaceSim([{"track": track, "lac": True}] * cars, opponents=True)
    length = sim.track.length_m

    def grid() -> None:
        for c in range(cars):
            sim.place(c, (length - 10.0 - 8.0 * c) % length, 2.0 if c % 2 == 0 else -2.0, 20.0)
        sim.step()

    rng = np.random.default_rng(0)
    actions = rng.uniform([-0.05, 0.6, 0], [0.05, 1, 0.05], size=(100, cars, 3))
    grid()
    for k in range(20):
        sim.step(actions[k])
    steps, near, t0 = 0, 0, time.perf_counter()
    while True:
        grid()
        for k in range(100):
            sim.step(actions[k])
            near += int(sim.near.sum())
        steps += 100
        if time.perf_counter() - t0 >= seconds:
            return steps * cars / (time.perf_counter() - t0), near / (steps * cars)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="time per measurement")
    parser.add_argument("--track", default="oval", help="track name (catalog)")
    parser.add_argument("--threads", type=int, default=1,
                        help="numba threads for the vector env (1 = one core, as in training)")
    args = parser.parse_args()
    track, track_name = resolve_track(args.track)
    single = time_single(track, args.seconds)
    print(f"(a) FormulaRacing-v0 single env, full telemetry: {single:,.0f} steps/s")
    vector = time_vector(track, args.seconds, threads=args.threads)
    print(f"(b) FormulaRacing-v0 vector env, 64 cars, {args.threads} thread(s): "
          f"{vector:,.0f} car-steps/s")
    race, lockstep = time_race(track, args.seconds)
    independent = time_vector(track, args.seconds, num_envs=RACE_CARS, threads=1)
    ratio_race = race / independent
    print(f"(d) {RACE_CARS}-car race (contact, opponent sensors, {lockstep:.0%} of car-steps in "
          f"the contact lockstep): {race:,.0f} car-steps/s against {independent:,.0f} for "
          f"{RACE_CARS} independent cars: {ratio_race:.2f}x (goal >= {GOAL_RACE})")
    highway = time_highway(args.seconds)
    print(f"(c) highway-env racetrack-v0:                    {highway:,.1f} steps/s")
    ratio_a, ratio_b = single / highway, vector / highway
    print(
        f"a/c = {ratio_a:,.0f} (goal >= {GOAL_SINGLE:.0f}), "
        f"b/c = {ratio_b:,.0f} (goal >= {GOAL_VECTOR:.0f})"
    )
    print(
        json.dumps(
            {
                "benchmark": "env_throughput",
                "track": track_name,
                "seconds_per_measurement": args.seconds,
                "single_steps_per_s": round(single, 1),
                "vector64_car_steps_per_s": round(vector, 1),
                "highway_steps_per_s": round(highway, 2),
                "ratio_single": round(ratio_a, 1),
                "ratio_vector": round(ratio_b, 1),
                "goal_ratio_single": GOAL_SINGLE,
                "goal_ratio_vector": GOAL_VECTOR,
                "single_goal_met": bool(ratio_a >= GOAL_SINGLE),
                "vector_goal_met": bool(ratio_b >= GOAL_VECTOR),
                "race8_car_steps_per_s": round(race, 1),
                "race8_lockstep_share": round(lockstep, 3),
                "independent8_car_steps_per_s": round(independent, 1),
                "ratio_race8": round(ratio_race, 3),
                "race8_goal_met": bool(ratio_race >= GOAL_RACE),
            }
        )
    )


if __name__ == "__main__":
    main()

"""Test episodes: the greedy actor (epsilon = 0) from several starts, timed lap by lap.

A single test from one start is very noisy (an actor that lapped cleanly from 4 of 5 starts spun
from the fifth), so every test drives from ``starts`` positions spread over the lap and
keeps every lap: its time, its damage and whether it was clean. The best clean lap's per-step trace
is kept for plots.

A test drive is fixed by the actor, the track, its start, its grip and its seed
(``drive_seed``); ``run_test_episode`` is the one function that drives it, for the tests of a
run and for ``replay``, so a replayed test drives the very laps its row in ``tests.parquet``
records.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from formula_tourney.agents.buffers import ObservationWindow
from formula_tourney.agents.core import Agent
from formula_tourney.errors import UserInputError
from formula_tourney.results.layout import TRACE_COLUMNS
from formula_tourney.sim.env import as_controls
from formula_tourney.training.checkpoint import load_run_checkpoint
from formula_tourney.training.envs import RunEnvs


@dataclass
class DriveResult:
    """One test drive from one start."""

    track: str
    start_s_m: float
    lap_times_s: list[float]
    lap_damage: list[float]
    damage: float
    reward: float
    steps: int
    termination: str
    distance_m: float = math.nan
    best_trace: pd.DataFrame | None = field(default=None, repr=False)
    grip_scale: float = math.nan
    """The grip the drive ran at (the env's ``info["grip_scale"]``)."""
    steps_trace: pd.DataFrame | None = field(default=None, repr=False)
    """Every step of the drive (trace columns and ``laps``, time from the start), where asked
    for (``keep_steps``): what ``replay`` draws when the drive has no clean lap."""

    @property
    def laps(self) -> int:
        return len(self.lap_times_s)

    @property
    def finished(self) -> bool:
        """At least one full timed lap."""
        return self.laps >= 1

    @property
    def best_lap_s(self) -> float:
        """Best lap with zero lap damage; nan if none."""
        clean = [t for t, d in zip(self.lap_times_s, self.lap_damage, strict=True) if d <= 0.0]
        return min(clean) if clean else math.nan


def start_positions(length_m: float, starts: int, before_line_m: float = 50.0) -> list[float]:
    """``starts`` arc lengths evenly spaced over the lap, the first 50 m before the start line
    (the env's default start), so one of them is always the canonical start."""
    return [float((length_m - before_line_m - k * length_m / starts) % length_m)
            for k in range(starts)]  # fmt: skip


def drive_seed(run_seed: int, start_index: int) -> int:
    """The seed of a run's test drive from its ``start_index``-th start (``start_positions``):
    every start of every run resets the env from a seed of its own."""
    return int(run_seed) * 1000 + int(start_index)


def _xy(info: dict[str, Any], track: Any) -> tuple[float, float]:
    if "x_m" in info and "y_m" in info:
        return float(info["x_m"]), float(info["y_m"])
    x, y, _ = track.pose_at(float(info.get("s_m", 0.0)), float(info.get("lateral_m", 0.0)))
    return float(x), float(y)


def greedy_windows(agent: Agent, env: Any, start_s_m: float, seed: int = 0,
                   ) -> Iterator[tuple[np.ndarray, np.ndarray, dict[str, Any]]]:
    """One greedy drive from ``start_s_m`` as the (observation window, action, info after the
    step) of each step, for scripts that read the agent's networks along a test drive
    (``benchmarks/actor_saturation.py``, ``benchmarks/critic_values.py``)."""
    obs, info = env.reset(seed=seed, options={"start_s_m": float(start_s_m)})
    window = ObservationWindow(agent.cfg.window)
    stack = window.reset(obs)
    while True:
        action = agent.act_eval(stack)
        obs, _, terminated, truncated, info = env.step(action)
        yield stack, action, info
        if terminated or truncated:
            return
        stack = window.push(obs)


def run_test_episode(
    agent: Agent,
    env: Any,
    track_name: str,
    start_s_m: float,
    seed: int,
    record_trace: bool = True,
    keep_steps: bool = False,
) -> DriveResult:
    """Drive one greedy episode from ``start_s_m`` (at rest) until the env ends it; the best
    clean lap's trace with ``record_trace``, every step's with ``keep_steps``."""
    track = getattr(env.unwrapped, "track", None)
    period_s = float(getattr(env.unwrapped, "config", {}).get("control_period_s", 0.2))
    obs, info = env.reset(seed=seed, options={"start_s_m": float(start_s_m)})
    window = ObservationWindow(agent.cfg.window)
    stack = window.reset(obs)
    rows: list[tuple[float, ...]] = []
    total_reward = 0.0
    steps = 0
    while True:
        action = agent.act_eval(stack)
        obs, reward, terminated, truncated, info = env.step(action)
        total_reward += float(reward)
        steps += 1
        if record_trace or keep_steps:
            x, y = _xy(info, track) if track is not None else (math.nan, math.nan)
            steer, throttle, brake = as_controls(action)  # a pedal action's pedals, too
            rows.append((
                steps * period_s, float(info.get("distance_m", math.nan)),
                float(info.get("s_m", math.nan)), float(info.get("lateral_m", math.nan)), x, y,
                float(info.get("speed_mps", math.nan)) * 3.6, float(steer), float(throttle),
                float(brake), float(info.get("laps", 0)),
            ))  # fmt: skip
        if terminated or truncated:
            break
        stack = window.push(obs)
    lap_times = [float(t) for t in info.get("lap_times_s", [])]
    lap_damage = [float(d) for d in info.get("lap_damage", [0.0] * len(lap_times))]
    ep = DriveResult(
        track=track_name,
        start_s_m=float(start_s_m),
        lap_times_s=lap_times,
        lap_damage=lap_damage,
        damage=float(info.get("damage", 0.0)),
        reward=total_reward,
        steps=steps,
        termination=str(info.get("termination") or ("max_steps" if truncated else "")),
        distance_m=float(info.get("distance_m", math.nan)),
        grip_scale=float(info.get("grip_scale", math.nan)),
    )
    if record_trace and math.isfinite(ep.best_lap_s):
        ep.best_trace = _lap_trace(rows, lap_times, lap_damage, ep.best_lap_s)
    if keep_steps:
        ep.steps_trace = pd.DataFrame(np.asarray(rows, dtype=float).reshape(-1, len(TRACE_COLUMNS)
                                                                            + 1),
                                      columns=[*TRACE_COLUMNS, "laps"])
    return ep


def _lap_trace(
    rows: list[tuple[float, ...]],
    lap_times: list[float],
    lap_damage: list[float],
    best: float,
) -> pd.DataFrame:
    """Steps of the best clean lap, time measured from its start.

    Lap k ends at the first step whose lap count reaches k; it began ``lap_time`` earlier (the env
    interpolates crossings inside a physics step, so the window is exact to one control step).
    """
    arr = np.asarray(rows, dtype=float)
    k = next(i for i, (t, d) in enumerate(zip(lap_times, lap_damage, strict=True))
             if d <= 0.0 and t == best) + 1  # fmt: skip
    end_step = int(np.argmax(arr[:, -1] >= k))
    t_end = arr[end_step, 0]
    keep = (arr[:, 0] >= t_end - best) & (arr[:, 0] <= t_end)
    frame = pd.DataFrame(arr[keep, :-1], columns=list(TRACE_COLUMNS))
    frame["time_s"] -= t_end - best
    return frame


def tests_row(ep: DriveResult, episode: int, env_steps: int, checkpoint: str,
              reference_limit_s: float = math.nan) -> dict[str, Any]:
    """The tests.parquet row of one test drive (columns from docs/CONTRACTS.md);
    ``reference_limit_s`` is the limit at the drive's grip (``RunEnvs.test_limit_s``)."""
    return {
        "episode": episode, "env_steps": env_steps, "track": ep.track,
        "start_s_m": ep.start_s_m, "finished": ep.finished, "best_lap_s": ep.best_lap_s,
        "laps": ep.laps, "damage": ep.damage, "reward": ep.reward, "steps": ep.steps,
        "termination": ep.termination, "checkpoint": checkpoint, "distance_m": ep.distance_m,
        "grip_scale": ep.grip_scale, "reference_limit_s": reference_limit_s,
    }  # fmt: skip


def laps_rows(ep: DriveResult, episode: int) -> list[dict[str, Any]]:
    """The laps.parquet rows of one test drive."""
    return [
        {"episode": episode, "track": ep.track, "start_s_m": ep.start_s_m, "lap_index": i,
         "lap_time_s": t, "lap_damage": d, "clean": bool(d <= 0.0), "grip_scale": ep.grip_scale}
        for i, (t, d) in enumerate(zip(ep.lap_times_s, ep.lap_damage, strict=True))
    ]  # fmt: skip


def other_grip_tests(
    agent: Agent,
    envs: RunEnvs,
    track: str,
    env_cache: dict[Any, Any],
    *,
    episode: int,
    env_steps: int,
    checkpoint: str,
    run_seed: int,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """One test round on ``track`` at each of the run's other grips (``RunSpec.test_grips``
    after the first): its tests and laps rows, from the same starts and seeds as the round at
    the run's own grip. These rows feed the per-grip tables only; the best checkpoint, the
    traces and promotion read the own grip. Envs are kept in ``env_cache`` under (track, grip)
    so that the caller closes them with its own."""
    tests: list[dict[str, Any]] = []
    laps: list[dict[str, Any]] = []
    starts = start_positions(envs.tracks[track].length_m, envs.spec.schedule.test_starts)
    for grip in envs.spec.test_grips[1:]:
        key = (track, grip)
        env = env_cache.get(key) or env_cache.setdefault(
            key, envs.make(track, test=True, grip_scale=grip))
        limit = envs.test_limit_s(track, grip)
        for k, s0 in enumerate(starts):
            drive = run_test_episode(agent, env, track, s0, seed=drive_seed(run_seed, k),
                                     record_trace=False)
            tests.append(tests_row(drive, episode, env_steps, checkpoint, limit))
            laps.extend(laps_rows(drive, episode))
    return tests, laps


def evaluate_checkpoint(
    checkpoint: str,
    track: str,
    starts: int = 3,
    max_steps: int = 1500,
    device: str = "cpu",
    reference: str | None = None,
    grip_scale: float | None = None,
) -> dict[str, Any]:
    """Drive a saved agent greedily on ``track`` from ``starts`` starts; the CLI's ``eval``.

    The env is built from the checkpoint's run spec (reference line, LAC, env settings), as in
    training, since the observation depends on them; ``reference`` replaces the line kind and
    ``grip_scale`` the grip (a test at another grip than the run's).
    """
    t0 = time.perf_counter()
    agent, spec, _extra = load_run_checkpoint(checkpoint, device=device)
    envs = RunEnvs(spec, extra_tracks=[track], reference=reference)
    env = envs.make(track, test=True, max_steps=max_steps, grip_scale=grip_scale)
    check_observation_size(env, agent, checkpoint)
    drives = [
        run_test_episode(agent, env, track, s0, seed=k)
        for k, s0 in enumerate(start_positions(envs.tracks[track].length_m, starts))
    ]
    env.close()
    best = min((d.best_lap_s for d in drives if math.isfinite(d.best_lap_s)), default=math.nan)
    return {
        "checkpoint": str(checkpoint),
        "track": track,
        "reference": envs.reference,
        "grip_scale": float(env.unwrapped.env_config.grip_scale),
        "best_lap_s": None if math.isnan(best) else best,
        "laps": sum(d.laps for d in drives),
        "damage": sum(d.damage for d in drives),
        "finished": any(d.finished for d in drives),
        "episodes": len(drives),
        "env_steps": sum(d.steps for d in drives),
        "updates": agent.updates,
        "seconds": time.perf_counter() - t0,
        "drives": [
            {"start_s_m": d.start_s_m, "lap_times_s": d.lap_times_s, "lap_damage": d.lap_damage,
             "termination": d.termination, "best_lap_s": None if math.isnan(d.best_lap_s)
             else d.best_lap_s}
            for d in drives
        ],
    }  # fmt: skip


def check_observation_size(env: Any, agent: Agent, checkpoint: str | os.PathLike) -> None:
    """A checkpoint's actor must fit the env's observation (LAC on in one and off in the other
    would otherwise fail deep inside torch)."""
    obs_dim = int(np.prod(env.observation_space.shape))
    if obs_dim != agent.obs_dim:
        raise UserInputError(
            f"checkpoint {checkpoint} expects {agent.obs_dim} observations, the env gives "
            f"{obs_dim} (LAC or the LAC distances differ?)"
        )

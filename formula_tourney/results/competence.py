"""Time to competence: the CPU-seconds a run trained until it first lapped cleanly and beat each bot.

A run's *milestones*, each the first test round on the key track whose model clean lap
(``results.metrics``: zero damage over all the round's starts) is strictly below a lap:

- ``first_clean_lap``: any clean lap;
- ``beat_centre_bot``: faster than the follower bot on the centre line;
- ``beat_mincurv_bot``: faster than the follower on the min-curvature line (the best bot).

A run that learns from demonstrations beats a bot only when it also beats the bot that
demonstrated (its lap is ``summary.json``'s ``demos.lap_s``). A milestone is timed by the
round's ``cpu_s`` (``tests.parquet``: the run's CPU-seconds since training started when the round
ended); a missed one is None for a run, infinite in a median. Also per run: its best clean lap
over the reference limit, and its clean-start rate: the share of test rounds, from the round of
the first clean lap on, in which at least two thirds of the starts drove a lap without damage.

The report's time-to-competence table and ``benchmarks/time_to_competence.py`` both read their
figures from here.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from formula_tourney.results.folder import JobFolder
from formula_tourney.results.metrics import limit_ratio, model_table

MILESTONES = ("first_clean_lap", "beat_centre_bot", "beat_mincurv_bot")
MILESTONE_LABELS = {
    "first_clean_lap": "(a) first clean lap",
    "beat_centre_bot": "(b) beat follower, centre",
    "beat_mincurv_bot": "(c) beat follower, mincurv",
}


@dataclass(frozen=True)
class Bots:
    """The laps the milestones are set by: the follower's best lap on the centre and on the
    min-curvature line, and the track's reference limit, all in the runs' car."""

    centre_s: float
    mincurv_s: float
    reference_limit_s: float


def thresholds(bots: Bots, demo_lap_s: float | None = None) -> dict[str, float]:
    """The lap each milestone must get under; with demonstrations also the demonstrator's."""
    demo = math.inf if demo_lap_s is None or not math.isfinite(demo_lap_s) else float(demo_lap_s)
    return {
        "first_clean_lap": math.inf,
        "beat_centre_bot": min(float(bots.centre_s), demo),
        "beat_mincurv_bot": min(float(bots.mincurv_s), demo),
    }


def rounds(tests: pd.DataFrame, track: str) -> pd.DataFrame:
    """One row per test round on ``track``, in order: episode, env_steps, cpu_s, clean_lap_s."""
    frame = tests[tests["track"].astype(str) == track]
    if "job_id" not in frame.columns:
        frame = frame.assign(job_id="run")
    models = model_table(frame).sort_values("episode", kind="stable").reset_index(drop=True)
    if models.empty:
        return pd.DataFrame(columns=["episode", "env_steps", "cpu_s", "clean_lap_s"])
    cpu = pd.to_numeric(frame["cpu_s"], errors="coerce") if "cpu_s" in frame else math.nan
    by_round = frame.assign(cpu_s=cpu).groupby("episode")
    models["env_steps"] = models["episode"].map(by_round["env_steps"].max())
    models["cpu_s"] = models["episode"].map(by_round["cpu_s"].max())
    return models[["episode", "env_steps", "cpu_s", "clean_lap_s"]]


def milestones(tests: pd.DataFrame, track: str,
               limits: Mapping[str, float]) -> dict[str, dict[str, Any] | None]:  # fmt: skip
    """The first round reaching each milestone (episode, env_steps, lap_s, cpu_s), or None."""
    table = rounds(tests, track)
    out: dict[str, dict[str, Any] | None] = {}
    for name in MILESTONES:
        out[name] = None
        for row in table.itertuples(index=False):
            lap = float(row.clean_lap_s)
            if math.isfinite(lap) and lap < limits[name]:
                out[name] = {"episode": int(row.episode), "env_steps": int(row.env_steps),
                             "lap_s": lap, "cpu_s": float(row.cpu_s)}  # fmt: skip
                break
    return out


def best_clean_lap(tests: pd.DataFrame, track: str,
                   until_env_steps: float = math.inf) -> float:  # fmt: skip
    """The run's best lap: its fastest model clean lap on ``track`` (nan if none); with
    ``until_env_steps``, of the rounds held after at most that many env steps, so that runs
    are compared step for step, whatever each machine's speed."""
    held = rounds(tests, track)
    if math.isfinite(until_env_steps):
        held = held[held["env_steps"] <= until_env_steps]
    laps = pd.to_numeric(held["clean_lap_s"], errors="coerce").dropna()
    return float(laps.min()) if len(laps) else math.nan


def clean_start_rate(tests: pd.DataFrame, track: str, from_episode: int | None) -> float | None:
    """Share of test rounds from ``from_episode`` on (included) in which at least two thirds
    of the starts drove a lap with zero lap damage (finite ``best_lap_s``); None when there is
    no such round (no first clean lap)."""
    if from_episode is None:
        return None
    frame = tests[(tests["track"].astype(str) == track) & (tests["episode"] >= from_episode)]
    if frame.empty:
        return None
    clean = np.isfinite(pd.to_numeric(frame["best_lap_s"], errors="coerce").to_numpy(float))
    per_round = frame.assign(clean=clean).groupby("episode")["clean"].agg(["sum", "size"])
    needed = -(-2 * per_round["size"] // 3)  # ceil(2/3 of the starts): 2 of 3
    return float((per_round["sum"] >= needed).mean())


def learning_curve(tests: pd.DataFrame, track: str) -> list[dict[str, Any]]:
    """Per test round: episode, CPU-s then and its clean lap (None: no clean lap), so that a
    miss can be read off its curve (a run crawling towards the bot, or one never lapping)."""
    out = []
    for row in rounds(tests, track).itertuples(index=False):
        lap, cpu = float(row.clean_lap_s), float(row.cpu_s)
        out.append({"episode": int(row.episode),
                    "cpu_s": round(cpu, 1) if math.isfinite(cpu) else None,
                    "clean_lap_s": round(lap, 3) if math.isfinite(lap) else None})  # fmt: skip
    return out


def run_competence(tests: pd.DataFrame, track: str, bots: Bots,
                   demo_lap_s: float | None = None) -> dict[str, Any]:  # fmt: skip
    """One run's milestones from its tests table: CPU-s to each (None: missed), the rounds
    that reached them, its best clean lap and that lap over the limit, its clean-start rate
    and its learning curve."""
    limits = thresholds(bots, demo_lap_s)
    hits = milestones(tests, track, limits)
    best = best_clean_lap(tests, track)
    first = hits["first_clean_lap"]
    ratio = limit_ratio(best, bots.reference_limit_s)
    return {
        "cpu_s": {n: None if h is None else h["cpu_s"] for n, h in hits.items()},
        "milestones": hits,
        "limits_s": {n: v if math.isfinite(v) else None for n, v in limits.items()},
        "demo_lap_s": demo_lap_s if demo_lap_s is not None and math.isfinite(demo_lap_s)
        else None,
        "best_lap_s": best if math.isfinite(best) else None,
        "best_lap_to_limit": ratio if math.isfinite(ratio) else None,
        "clean_start_rate": clean_start_rate(tests, track, first and first["episode"]),
        "curve": learning_curve(tests, track),
    }  # fmt: skip


def timed(tests: pd.DataFrame) -> bool:
    """Whether a tests table records the CPU-seconds of its rounds (files written before the
    ``cpu_s`` column have none: no time to competence can be read from them)."""
    cpu = pd.to_numeric(tests["cpu_s"], errors="coerce") if "cpu_s" in tests.columns else None
    return cpu is not None and not tests.empty and bool(cpu.notna().all())


def job_competence(folder: JobFolder, track: str, bots: Bots) -> dict[str, Any]:
    """:func:`run_competence` of one job folder (its tests at its own grip, its demonstrator's
    lap from its summary), with the run's totals from its summary."""
    summary = folder.summary()
    demo_lap = (summary.get("demos") or {}).get("lap_s")
    out = run_competence(folder.tests(), track, bots, demo_lap)
    for key in ("cpu_s", "env_steps", "updates", "episodes", "stopped_by"):
        out[f"{key}_total" if key == "cpu_s" else key] = summary.get(key)
    return out


def median_inf(values: Iterable[float | None]) -> float:
    """Median with a miss (None or nan) counted as infinite; inf for no values."""
    xs = [math.inf if v is None or math.isnan(v) else float(v) for v in values]
    return float(statistics.median(xs)) if xs else math.inf


def _milestone_env_steps(run: Mapping[str, Any], name: str) -> float | None:
    """The env steps a run had trained when it reached milestone ``name`` (None: missed)."""
    hit = (run.get("milestones") or {}).get(name)
    return None if hit is None else float(hit["env_steps"])


def summarise(runs: list[Mapping[str, Any]]) -> dict[str, Any]:
    """Medians over one entrant's seeds: each milestone's CPU-s and env steps (miss = inf) and
    how many seeds reached it, best lap / limit (miss = inf) and clean-start rate (a seed
    without a clean lap counts 0). The env steps compare runs on machines (or hours of one
    machine) that buy a different number of steps per CPU-s; CPU-s is what a user pays."""
    out: dict[str, Any] = {"seeds": len(runs)}
    for name in MILESTONES:
        out[f"median_{name}_cpu_s"] = median_inf(r["cpu_s"].get(name) for r in runs)
        out[f"median_{name}_env_steps"] = median_inf(_milestone_env_steps(r, name) for r in runs)
        out[f"reached_{name}"] = sum(r["cpu_s"].get(name) is not None for r in runs)
    out["median_best_lap_to_limit"] = median_inf(r.get("best_lap_to_limit") for r in runs)
    speeds = [r["env_steps"] / r["cpu_s_total"] for r in runs
              if r.get("env_steps") and r.get("cpu_s_total")]  # fmt: skip
    out["median_env_steps_per_cpu_s"] = float(statistics.median(speeds)) if speeds else None
    rates = [r.get("clean_start_rate") or 0.0 for r in runs]
    out["median_clean_start_rate"] = float(statistics.median(rates)) if rates else 0.0
    return out

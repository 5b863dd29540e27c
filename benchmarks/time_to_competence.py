"""Time to competence: CPU-seconds until each entrant first laps cleanly, beats the follower bot
on the centre line and beats it on the minimum-curvature line, against Stable-Baselines3 SAC.

Entrants are ``VARIANT:PRESET`` pairs (``--entrants WIN1:fast,SAC:fast``), each an ordinary
``training.loop.train`` job built by ``training.spec.build_run_spec`` (``--set KEY=VALUE`` agent
overrides on top, for every entrant), trained on ``--track`` with ``--reference`` (and ``--lac``),
tested greedily every 5 episodes from 3 starts. Before the clock: the follower bot's best lap on
the centre line and on the min-curvature line, and the reference limit (the quasi-steady-state
lap on the min-curvature line). Per run, the CPU-seconds (``time.process_time`` of the run's own
process, from the start of training: updates, env steps, the tests, demonstrations and their
behaviour-cloning warm start) until the first test round with

  (a) a clean lap (the model's clean lap, ``results.metrics``: zero damage over all 3 starts),
  (b) a clean lap faster than the follower on the centre line,
  (c) a clean lap faster than the follower on the min-curvature line;

an entrant with demonstrations counts as beating a bot in (b) and (c) only when it also beats the
bot that demonstrated (the follower on ``demos.line``; its lap is ``summary["demos"]["lap_s"]``).
Also the run's best clean lap over the reference limit and its clean-start rate: the fraction of
test rounds, from the round of the first clean lap on (that round included), in which at least
2 of the 3 starts drive a lap with zero lap damage (from the job's tests.parquet). A run stops
at (c) or when its CPU budget is spent; with ``--to-budget`` only at the budget, so that the best
lap / limit is what the budget buys (stopped at (c), a run's best is its first lap past the bot).

The anchor, in the same run: Stable-Baselines3 SAC at its defaults (``SAC("MlpPolicy", env,
seed=seed)``, the ``bench`` extra) on the same env (FormulaRacing-v0 from
``RunEnvs(spec).make(track, test=False)``: same track, line, LAC, random starts and episode
length; the raw env reward, as an SB3 user sees it), budget and seeds, tested with the same
protocol. Ratios per milestone: our median CPU-s / SAC's (goal <= 0.5). Every (entrant, seed)
and every SAC seed runs in its own spawned process with one torch thread, ``--jobs`` at a time.

Medians are over seeds with a miss counted as infinite (printed "miss", null in the JSON).
Goals (issue 11): oval: (b) <= 60 CPU-s, (c) <= 300 CPU-s, best lap / limit <= 1.02;
technical (recorded + LAC): (a) <= 60 CPU-s with clean-start rate >= 2/3, (c) <= 3600 CPU-s,
best lap / limit <= 1.05. A table goes to stderr; the last line of stdout is one JSON object.

    .venv/bin/python benchmarks/time_to_competence.py [--track oval] [--reference centre] [--lac]
        [--entrants WIN1:fast,SAC:fast,PER1M:paper,WIN1:fast-demos] [--seeds 0,1,2,3]
        [--jobs 2] [--budget-cpu-s 600] [--set KEY=VALUE] [--no-sb3] [--out DIR]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from collections.abc import Iterable, Mapping  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

TEST_EVERY = 5
TEST_STARTS = 3
CLEAN_STARTS = 2  # of TEST_STARTS: a round counts as a clean start when this many lap cleanly
DEFAULT_ENTRANTS = "WIN1:fast,SAC:fast,PER1M:paper,WIN1:fast-demos"
MILESTONES = ("first_clean_lap", "beat_centre_bot", "beat_mincurv_bot")
MILESTONE_LABELS = {
    "first_clean_lap": "(a) first clean lap",
    "beat_centre_bot": "(b) beat follower, centre",
    "beat_mincurv_bot": "(c) beat follower, mincurv",
}
RATIO_GOAL = 0.5
GOALS: dict[str, dict[str, Any]] = {
    "oval": {"setup": "oval", "beat_centre_bot_cpu_s": 60.0, "beat_mincurv_bot_cpu_s": 300.0,
             "best_lap_to_limit": 1.02, "ratio_vs_sb3": RATIO_GOAL},
    "technical": {"setup": "technical (recorded + LAC)", "first_clean_lap_cpu_s": 60.0,
                  "clean_start_rate": 2.0 / 3.0, "beat_mincurv_bot_cpu_s": 3600.0,
                  "best_lap_to_limit": 1.05, "ratio_vs_sb3": RATIO_GOAL},
}  # fmt: skip
SB3_LABEL = "SB3 SAC (defaults)"


# --- pure functions (tests/test_bench_competence.py) -----------------------------------------
def parse_entrants(text: str) -> list[tuple[str, str]]:
    """``VARIANT:PRESET,...`` -> [(variant, preset)]; a pair without a preset is an error."""
    out: list[tuple[str, str]] = []
    for item in (x.strip() for x in text.split(",")):
        if not item:
            continue
        variant, sep, preset = item.partition(":")
        if not sep or not variant.strip() or not preset.strip():
            raise SystemExit(f"--entrants wants VARIANT:PRESET pairs, got {item!r}")
        pair = (variant.strip(), preset.strip())
        if pair in out:
            raise SystemExit(f"--entrants names {item!r} twice")
        out.append(pair)
    if not out:
        raise SystemExit("--entrants is empty")
    return out


def parse_overrides(pairs: Iterable[str]) -> dict[str, Any]:
    """``KEY=VALUE`` pairs; values parse as JSON (numbers, booleans), else stay strings."""
    out: dict[str, Any] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise SystemExit(f"--set wants KEY=VALUE, got {pair!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def thresholds(bot_centre_s: float, bot_mincurv_s: float,
               demo_lap_s: float | None = None) -> dict[str, float]:  # fmt: skip
    """The lap each milestone must beat: (a) any clean lap, (b) the follower on the centre line,
    (c) on the min-curvature line; with demonstrations also the demonstrator's lap."""
    demo = math.inf if demo_lap_s is None or not math.isfinite(demo_lap_s) else float(demo_lap_s)
    return {
        "first_clean_lap": math.inf,
        "beat_centre_bot": min(float(bot_centre_s), demo),
        "beat_mincurv_bot": min(float(bot_mincurv_s), demo),
    }


def _models(tests: Any, track: str) -> Any:
    """One row per test round on ``track`` (results.metrics' models), in round order."""
    from formula_tourney.results.metrics import model_table

    frame = tests[tests["track"] == track]
    if "job_id" not in frame.columns:
        frame = frame.assign(job_id="run")
    return model_table(frame).sort_values("episode", kind="stable").reset_index(drop=True)


def milestones(
    tests: Any, track: str, limits: Mapping[str, float], cpu_by_episode: Mapping[int, float],
    cpu_total: float,
) -> dict[str, dict[str, Any] | None]:  # fmt: skip
    """The first test round reaching each milestone: a clean lap strictly below its limit
    (``thresholds``). Each reached milestone has episode, env_steps, lap_s and cpu_s (the CPU
    clock read right after that round's tests; ``cpu_total`` for a round not in the map)."""
    models = _models(tests, track)
    env_steps = tests.groupby("episode")["env_steps"].max() if len(tests) else {}
    out: dict[str, dict[str, Any] | None] = {}
    for name in MILESTONES:
        limit = limits[name]
        hit = None
        for row in models.itertuples(index=False):
            lap = float(row.clean_lap_s)
            if math.isfinite(lap) and lap < limit:
                episode = int(row.episode)
                hit = {"episode": episode, "env_steps": int(env_steps[episode]), "lap_s": lap,
                       "cpu_s": float(cpu_by_episode.get(episode, cpu_total))}  # fmt: skip
                break
        out[name] = hit
    return out


def learning_curve(
    tests: Any, track: str, cpu_by_episode: Mapping[int, float], cpu_total: float,
) -> list[dict[str, Any]]:  # fmt: skip
    """Per test round: episode, CPU-s then and its clean lap (None: no start lapped cleanly).

    Kept in the JSON so a miss can be read off its curve (a run that crawls towards the bot
    differs from one that never laps twice), and drawn by ``--plot``."""
    out = []
    for row in _models(tests, track).itertuples(index=False):
        lap = float(row.clean_lap_s)
        episode = int(row.episode)
        cpu_s = float(cpu_by_episode.get(episode, cpu_total))
        out.append({"episode": episode, "cpu_s": round(cpu_s, 1),
                    "clean_lap_s": round(lap, 3) if math.isfinite(lap) else None})  # fmt: skip
    return out


def best_clean_lap(tests: Any, track: str) -> float:
    """The run's best lap: its fastest model clean lap on ``track`` (nan if none)."""
    laps = _models(tests, track)["clean_lap_s"].astype(float)
    laps = laps[laps.notna()]
    return float(laps.min()) if len(laps) else math.nan


def clean_start_rate(
    tests: Any, track: str, from_episode: int | None, min_clean: int = CLEAN_STARTS
) -> float | None:
    """Fraction of test rounds from ``from_episode`` on (included) in which at least
    ``min_clean`` starts drove a lap with zero lap damage (finite ``best_lap_s``); None when
    there is no such round (no first clean lap)."""
    if from_episode is None:
        return None
    frame = tests[(tests["track"] == track) & (tests["episode"] >= from_episode)]
    if frame.empty:
        return None
    import numpy as np

    clean = np.isfinite(frame["best_lap_s"].astype(float).to_numpy())
    per_round = frame.assign(clean=clean).groupby("episode")["clean"].sum()
    return float((per_round >= min_clean).mean())


def median_inf(values: Iterable[float | None]) -> float:
    """Median with a miss (None or nan) counted as infinite; inf for no values."""
    xs = [math.inf if v is None or math.isnan(v) else float(v) for v in values]
    return float(statistics.median(xs)) if xs else math.inf


def finite(x: float | None, ndigits: int = 1) -> float | None:
    """A JSON number, or None (null) for a miss."""
    return None if x is None or not math.isfinite(x) else round(float(x), ndigits)


def ratio(ours: float, anchor: float) -> float | None:
    """ours / anchor CPU-s; 0 when only the anchor missed, None when ours missed (or both)."""
    if not math.isfinite(ours):
        return None
    if not math.isfinite(anchor):
        return 0.0
    return ours / anchor if anchor > 0 else None


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Medians over one entrant's seeds: each milestone's CPU-s (miss = inf), best lap / limit
    (miss = inf) and clean-start rate (a seed without a clean lap counts 0)."""
    out: dict[str, Any] = {"seeds": len(runs)}
    for name in MILESTONES:
        out[f"median_{name}_cpu_s"] = median_inf(r["cpu_s"].get(name) for r in runs)
        out[f"reached_{name}"] = sum(r["cpu_s"].get(name) is not None for r in runs)
    out["median_best_lap_to_limit"] = median_inf(r.get("best_lap_to_limit") for r in runs)
    rates = [r.get("clean_start_rate") or 0.0 for r in runs]
    out["median_clean_start_rate"] = float(statistics.median(rates)) if rates else 0.0
    return out


def goal_flags(track: str, summary: Mapping[str, Any],
               ratios: Mapping[str, float | None] | None) -> dict[str, bool] | None:  # fmt: skip
    """Which of the issue's goals for ``track`` the entrant's medians meet (None: no goals)."""
    goals = GOALS.get(track)
    if goals is None:
        return None
    flags: dict[str, bool] = {}
    for name in MILESTONES:
        key = f"{name}_cpu_s"
        if key in goals:
            met = summary[f"median_{name}_cpu_s"] <= goals[key]
            if name == "first_clean_lap" and "clean_start_rate" in goals:
                met = met and summary["median_clean_start_rate"] >= goals["clean_start_rate"]
            flags[key] = bool(met)
    flags["best_lap_to_limit"] = bool(summary["median_best_lap_to_limit"]
                                      <= goals["best_lap_to_limit"])  # fmt: skip
    if ratios is not None:
        for name in MILESTONES:
            r = ratios.get(name)
            flags[f"ratio_{name}"] = r is not None and r <= goals["ratio_vs_sb3"]
    return flags


# --- what is measured before the clock (parent) ----------------------------------------------
def bot_figures(track_name: str, car_overrides: dict[str, Any] | None = None) -> dict[str, float]:
    """The follower's best lap on the centre and on the min-curvature line, and the limit, for
    the runs' own car (``--env-set car=...``): a bot in another car is no anchor."""
    from formula_tourney.bots.follower import drive
    from formula_tourney.bots.reference import reference_offsets
    from formula_tourney.lines.limit import reference_limit_s
    from formula_tourney.sim.car_params import CarParams
    from formula_tourney.sim.catalog import load_track

    track = load_track(track_name)
    car = CarParams(**(car_overrides or {}))
    laps = {kind: float(drive(track, reference_offsets(track, kind, car), laps=2,
                              car=car)["best_lap_s"])
            for kind in ("centre", "mincurv")}  # fmt: skip
    return {"centre_s": laps["centre"], "mincurv_s": laps["mincurv"],
            "reference_limit_s": float(reference_limit_s(track, car))}  # fmt: skip


def _warm_up(spec: Any) -> Any:
    """Build and step the run's env once before the clock (track, line and numba kernels load
    from their caches), so neither side pays it; returns the RunEnvs."""
    import numpy as np

    from formula_tourney.training.envs import RunEnvs

    envs = RunEnvs(spec)
    env = envs.make(spec.key_track, test=False)
    env.reset(seed=0)
    for _ in range(3):
        env.step(np.array([0.0, 0.5, 0.0], np.float32))
    env.close()
    return envs


def _say(label: str, seed: int, cpu: float, episode: int, env_steps: int,
         best: float | None) -> None:  # fmt: skip
    shown = "-" if best is None or not math.isfinite(best) else f"{best:.3f}"
    print(f"{label} seed {seed}: cpu {cpu:6.0f} s  episode {episode}  env steps {env_steps}  "
          f"best {shown}", file=sys.stderr, flush=True)  # fmt: skip


def _result(
    task: Mapping[str, Any], tests: Any, cpu_by_episode: dict[int, float], cpu_total: float,
    demo_lap_s: float | None, **extra: Any,
) -> dict[str, Any]:  # fmt: skip
    bots = task["bots"]
    track = task["track"]
    limits = thresholds(bots["centre_s"], bots["mincurv_s"], demo_lap_s)
    hits = milestones(tests, track, limits, cpu_by_episode, cpu_total)
    best = best_clean_lap(tests, track)
    first = hits["first_clean_lap"]
    return {
        "label": task["label"], "seed": task["seed"],
        "cpu_s": {n: (None if h is None else round(h["cpu_s"], 1)) for n, h in hits.items()},
        "milestones": hits,
        "limits_s": {n: finite(v, 3) for n, v in limits.items()},
        "demo_lap_s": finite(demo_lap_s, 3),
        "best_lap_s": finite(best, 3),
        "best_lap_to_limit": finite(best / bots["reference_limit_s"], 4),
        "clean_start_rate": clean_start_rate(tests, track, first and first["episode"]),
        "cpu_s_total": round(cpu_total, 1),
        "curve": learning_curve(tests, track, cpu_by_episode, cpu_total),
        **extra,
    }  # fmt: skip


# --- one (entrant, seed) run -------------------------------------------------------------------
def stop_lap_s(task: Mapping[str, Any], demo_lap_s: float | None = None) -> float:
    """The clean lap that ends a run early: (c)'s, or none (-inf) with ``--to-budget``, where
    every run spends its whole budget so that its best lap / limit is the budget's own (a run
    stopped at (c) keeps the first lap under the best bot as its best)."""
    if task.get("to_budget"):
        return -math.inf
    bots = task["bots"]
    return thresholds(bots["centre_s"], bots["mincurv_s"], demo_lap_s)["beat_mincurv_bot"]


def run_entrant(task: dict[str, Any]) -> dict[str, Any]:
    """One training run in this process; CPU-seconds are this process's own."""
    import numpy as np

    from formula_tourney.agents.core import configure_torch
    from formula_tourney.results.folder import JobFolder
    from formula_tourney.training.loop import train
    from formula_tourney.training.spec import RunSpec

    configure_torch(1)
    spec = RunSpec.from_json(task["spec"], "benchmark spec")
    envs = _warm_up(spec)
    predicted_demo = None
    if spec.demos is not None:
        # the demonstrator's lap decides when (c) is reached, so the stop rule needs it: the
        # demonstrations are deterministic in the seed, drive them once here, off the clock
        from formula_tourney.training.demos import collect_demonstrations

        env = envs.make(spec.key_track, test=False)
        obs_dim = int(np.prod(env.observation_space.shape))
        act_dim = int(np.prod(env.action_space.shape))
        env.close()
        seq = np.random.SeedSequence(spec.seed).spawn(4)[3]  # the loop's demonstration stream
        lap = collect_demonstrations(spec, envs, obs_dim, act_dim, seq).key_lap_s
        predicted_demo = lap if math.isfinite(lap) else None
    stop_at = stop_lap_s(task, predicted_demo)
    budget = float(task["budget_cpu_s"])
    cpu_by_episode: dict[int, float] = {}
    label, seed = task["label"], task["seed"]

    cpu0 = time.process_time()

    def progress(p: dict[str, Any]) -> bool:
        cpu = time.process_time() - cpu0
        best = p["best_lap_s"]
        if p["episode"] % TEST_EVERY == 0:
            cpu_by_episode[int(p["episode"])] = cpu
            _say(label, seed, cpu, p["episode"], p["env_steps"], best)
        reached = best is not None and best < stop_at
        return not reached and cpu < budget

    job = Path(task["job_dir"])
    summary = train(spec, job, progress)
    cpu_total = time.process_time() - cpu0
    demos = summary.get("demos")
    demo_lap = None if demos is None else demos.get("lap_s")
    tests = JobFolder(job).tests()
    return _result(
        task, tests, cpu_by_episode, cpu_total, demo_lap,
        demo_lap_predicted_s=finite(predicted_demo, 3), env_steps=summary["env_steps"],
        updates=summary["updates"], episodes=summary["episodes"], job=str(job),
    )  # fmt: skip


# --- one SB3 SAC seed --------------------------------------------------------------------------
class _Greedy:
    """SB3's deterministic ``predict`` in the shape ``evaluate.run_test_episode`` drives."""

    class cfg:  # noqa: N801 - read as ``agent.cfg.window``
        window = 1

    def __init__(self, model: Any) -> None:
        self.model = model

    def act(self, window: Any) -> Any:
        action, _ = self.model.predict(window[-1], deterministic=True)
        return action

    act_eval = act  # tests drive ``act_eval`` (our agents' averaged actor); SB3 keeps none


def run_sb3(task: dict[str, Any]) -> dict[str, Any]:
    """SB3 SAC at its defaults on the run's env, tested as our runs are; own CPU clock."""
    from stable_baselines3 import SAC
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.logger import Logger

    from formula_tourney.agents.core import configure_torch
    from formula_tourney.results.folder import JobFolder
    from formula_tourney.results.metrics import model_clean_lap_s
    from formula_tourney.training.evaluate import (
        laps_rows,
        run_test_episode,
        start_positions,
        tests_row,
    )
    from formula_tourney.training.spec import RunSpec

    configure_torch(1)
    spec = RunSpec.from_json(task["spec"], "benchmark spec")
    _warm_up(spec)
    stop_at = stop_lap_s(task)
    budget = float(task["budget_cpu_s"])
    label, seed, track = task["label"], task["seed"], spec.key_track
    cpu_by_episode: dict[int, float] = {}
    tests: list[dict[str, Any]] = []
    laps: list[dict[str, Any]] = []

    cpu0 = time.process_time()
    from formula_tourney.training.envs import RunEnvs

    envs = RunEnvs(spec)
    env = envs.make(track, test=False)
    test_env = envs.make(track, test=True)
    starts = start_positions(envs.tracks[track].length_m, TEST_STARTS)
    model = SAC("MlpPolicy", env, seed=seed, device="cpu")
    # SB3's default logger makes a /tmp/SB3-<date> folder per learn(); this one writes nothing
    model.set_logger(Logger(folder=None, output_formats=[]))
    greedy = _Greedy(model)

    class Tester(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.episodes = 0
            self.best = math.inf

        def _on_step(self) -> bool:
            ended = int(sum(bool(d) for d in self.locals["dones"]))
            if not ended:
                return True
            for _ in range(ended):
                self.episodes += 1
                if self.episodes % TEST_EVERY == 0:
                    drives = [run_test_episode(greedy, test_env, track, s0, seed=seed * 1000 + k,
                                               record_trace=False)
                              for k, s0 in enumerate(starts)]  # fmt: skip
                    steps = int(self.model.num_timesteps)
                    for d in drives:
                        tests.append(tests_row(d, self.episodes, steps, ""))
                        laps.extend(laps_rows(d, self.episodes))
                    lap = model_clean_lap_s([d.best_lap_s for d in drives],
                                            [d.damage for d in drives])  # fmt: skip
                    if math.isfinite(lap):
                        self.best = min(self.best, lap)
                    cpu = time.process_time() - cpu0
                    cpu_by_episode[self.episodes] = cpu
                    _say(label, seed, cpu, self.episodes, steps, self.best)
            cpu = time.process_time() - cpu0
            return not self.best < stop_at and cpu < budget

    tester = Tester()
    model.learn(total_timesteps=10**9, callback=tester)
    cpu_total = time.process_time() - cpu0
    env.close()
    test_env.close()
    job = JobFolder(task["job_dir"])
    job.path.mkdir(parents=True, exist_ok=True)
    job.write_tables([], tests, laps)
    return _result(
        task, job.tests(), cpu_by_episode, cpu_total, None, env_steps=int(model.num_timesteps),
        updates=int(getattr(model, "_n_updates", 0)), episodes=tester.episodes,
        job=str(job.path),
    )  # fmt: skip


def run_job(task: dict[str, Any]) -> dict[str, Any]:
    """A task in a worker; a crash is reported as a run that reached nothing."""
    try:
        return run_sb3(task) if task["kind"] == "sb3" else run_entrant(task)
    except Exception as err:  # noqa: BLE001 - one failed seed must not lose the others
        traceback.print_exc()
        return {"label": task["label"], "seed": task["seed"], "error": f"{type(err).__name__}: "
                f"{err}", "cpu_s": {n: None for n in MILESTONES}, "best_lap_s": None,
                "best_lap_to_limit": None, "clean_start_rate": None, "curve": []}  # fmt: skip


# --- output ------------------------------------------------------------------------------------
def _cell(x: float, reached: int | None = None, seeds: int | None = None) -> str:
    text = "miss" if not math.isfinite(x) else f"{x:.1f}"
    return text if reached is None else f"{text} ({reached}/{seeds})"


def _ratio_cell(r: float | None) -> str:
    if r is None:
        return "- (ours miss)"
    return "0 (SAC miss)" if r == 0.0 else f"{r:.2f}"


def render(result: Mapping[str, Any]) -> str:
    """The readable table (stderr)."""
    bots = result["bots"]
    lines = [
        f"time to competence on {result['track']} (reference {result['reference']}, "
        f"lac {result['lac']}), budget {result['budget_cpu_s']:.0f} CPU-s"
        f"{' (every run to the budget)' if result.get('to_budget') else ' (or until (c))'}, seeds "
        f"{','.join(map(str, result['seeds']))}, tests every {TEST_EVERY} episodes from "
        f"{TEST_STARTS} starts",
        f"follower: centre {bots['centre_s']:.3f} s, mincurv {bots['mincurv_s']:.3f} s; "
        f"reference limit {bots['reference_limit_s']:.3f} s",
        "median CPU-s to each milestone (seeds reaching it); best lap / limit; clean-start rate",
    ]
    head = ["entrant", *(MILESTONE_LABELS[n] for n in MILESTONES), "best/limit", "clean-start"]
    rows = []
    for e in [*result["entrants"], *([result["sb3"]] if result["sb3"] else [])]:
        s = e["summary"]
        rows.append([
            e["label"],
            *(_cell(s[f"median_{n}_cpu_s"], s[f"reached_{n}"], s["seeds"]) for n in MILESTONES),
            "miss" if not math.isfinite(s["median_best_lap_to_limit"])
            else f"{s['median_best_lap_to_limit']:.4f}",
            f"{s['median_clean_start_rate']:.2f}",
        ])  # fmt: skip
        if e.get("ratios_vs_sb3") is not None:
            rows.append(["  ours / SAC", *(_ratio_cell(e["ratios_vs_sb3"][n])
                                           for n in MILESTONES), "", ""])  # fmt: skip
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(len(head))]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    lines += [fmt.format(*head), fmt.format(*("-" * w for w in widths))]
    lines += [fmt.format(*r) for r in rows]
    goals = result["goals"]
    if goals:
        lines.append("goals (" + goals["setup"] + "): " + ", ".join(
            f"{k} <= {v:.3g}" if k != "clean_start_rate" else f"{k} >= {v:.3g}"
            for k, v in goals.items() if k != "setup"))  # fmt: skip
        for e in result["entrants"]:
            flags = e["goal_met"] or {}
            lines.append(f"  {e['label']}: " + ", ".join(
                f"{k} {'met' if v else 'NOT met'}" for k, v in flags.items()))  # fmt: skip
    else:
        lines.append(f"no goals for track {result['track']!r} (goals: {', '.join(GOALS)})")
    for e in [*result["entrants"], *([result["sb3"]] if result["sb3"] else [])]:
        for r in e["runs"]:
            if "error" in r:
                lines.append(f"  {e['label']} seed {r['seed']}: FAILED {r['error']}")
                continue
            cpu = ", ".join(f"{letter}={'miss' if r['cpu_s'][n] is None else r['cpu_s'][n]}"
                            for letter, n in zip("abc", MILESTONES, strict=True))  # fmt: skip
            lines.append(f"  {e['label']} seed {r['seed']}: CPU-s {cpu}; best {r['best_lap_s']} "
                         f"s, clean-start {r['clean_start_rate']}, {r['cpu_s_total']} CPU-s, "
                         f"{r['env_steps']} env steps")  # fmt: skip
    return "\n".join(lines)


def plot_curves(result: Mapping[str, Any], out_base: Path) -> list[Path]:
    """Each run's clean test laps (dots) and best lap so far (line) against CPU-s, one colour
    per entrant, with the two followers and the reference limit as horizontal lines."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    from formula_tourney.report.plots import save_figure

    fig, ax = plt.subplots(figsize=(8, 4.8))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    groups = [*result["entrants"], *([result["sb3"]] if result.get("sb3") else [])]
    laps_drawn = []
    for k, entrant in enumerate(groups):
        colour = colours[k % len(colours)]
        for n, run in enumerate(entrant["runs"]):
            points = [(c["cpu_s"], c["clean_lap_s"]) for c in run["curve"]
                      if c["clean_lap_s"] is not None]  # fmt: skip
            if not points:
                continue
            x = [p[0] for p in points]
            y = [p[1] for p in points]
            best = list(itertools.accumulate(y, min))
            laps_drawn += y
            ax.plot(x, y, ".", color=colour, alpha=0.35, ms=3)
            ax.step(x, best, where="post", color=colour, lw=1.2,
                    label=entrant["label"] if n == 0 else None)  # fmt: skip
    bots = result["bots"]
    for value, label, style in ((bots["centre_s"], "follower, centre", ":"),
                                (bots["mincurv_s"], "follower, min-curvature", "--"),
                                (bots["reference_limit_s"], "reference limit", "-")):  # fmt: skip
        ax.axhline(value, color="black", ls=style, lw=0.8, label=f"{label} {value:.2f} s")
    if laps_drawn:  # the slowest first laps would squash the interesting part
        ax.set_ylim(bots["reference_limit_s"] * 0.98,
                    min(max(laps_drawn), 2.0 * bots["reference_limit_s"]))  # fmt: skip
    ax.set_xlabel("training CPU-s")
    ax.set_ylabel("clean test lap (s)")
    ax.set_title(f"{result['track']} (reference {result['reference']}, LAC {result['lac']}), "
                 f"seeds {','.join(map(str, result['seeds']))}")  # fmt: skip
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return save_figure(fig, out_base)


def _json_summary(s: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(s)
    for n in MILESTONES:
        out[f"median_{n}_cpu_s"] = finite(s[f"median_{n}_cpu_s"])
    out["median_best_lap_to_limit"] = finite(s["median_best_lap_to_limit"], 4)
    out["median_clean_start_rate"] = round(s["median_clean_start_rate"], 4)
    return out


# --- main --------------------------------------------------------------------------------------
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--track", default="oval")
    ap.add_argument("--reference", default="centre", choices=["centre", "recorded", "mincurv"])
    ap.add_argument("--lac", action="store_true", help="look-ahead curvature in the observation")
    ap.add_argument("--entrants", default=DEFAULT_ENTRANTS, help="VARIANT:PRESET,...")
    ap.add_argument("--seeds", default="0,1,2,3", help="comma-separated seeds")
    ap.add_argument("--jobs", type=int, default=2, help="runs side by side (processes)")
    ap.add_argument("--budget-cpu-s", type=float, default=600.0)
    ap.add_argument("--max-steps", type=int, default=1000, help="steps per training episode")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="agent setting for every entrant, on top of its preset (repeatable)")
    ap.add_argument("--demos-set", action="append", default=[], metavar="KEY=VALUE",
                    help="demonstration setting (training.spec.DemoSettings) for every "
                    "entrant, on top of its preset's demos (repeatable; adds demos to a "
                    "preset without them)")
    ap.add_argument("--env-set", action="append", default=[], metavar="KEY=VALUE",
                    help="env setting (sim.config.EnvSettings, e.g. track_pos_weight=0) for "
                    "every entrant and the SB3 anchor alike (repeatable)")
    ap.add_argument("--schedule-set", action="append", default=[], metavar="KEY=VALUE",
                    help="schedule setting (training.spec.Schedule, e.g. cars=4) for every "
                    "entrant, on top of the benchmark's own (repeatable)")
    ap.add_argument("--no-sb3", action="store_true", help="skip the SB3 SAC anchor")
    ap.add_argument("--to-budget", action="store_true",
                    help="train every run for its whole budget instead of stopping at (c): "
                    "best lap / limit is then the budget's, not the first lap past the best bot")
    ap.add_argument("--out", default=None, help="folder for the job folders (default: temp)")
    ap.add_argument("--plot", default=None, metavar="FILE",
                    help="draw each run's clean test laps against CPU-s into FILE.png/.pdf")
    args = ap.parse_args()  # fmt: skip
    seeds = [int(x) for x in args.seeds.split(",") if x.strip()]
    if not seeds:
        raise SystemExit("--seeds is empty")
    entrants = parse_entrants(args.entrants)
    overrides = parse_overrides(args.set)
    demo_overrides = parse_overrides(args.demos_set)
    env_overrides = parse_overrides(args.env_set)
    schedule_overrides = parse_overrides(args.schedule_set)

    from formula_tourney.errors import UserInputError
    from formula_tourney.sim.config import EnvSettings
    from formula_tourney.training.spec import build_run_spec

    try:
        car_overrides = EnvSettings.model_validate(env_overrides).car
    except ValueError as err:
        raise SystemExit(f"--env-set: {err}") from None
    bots = bot_figures(args.track, car_overrides)
    print(f"follower on {args.track}: centre {bots['centre_s']:.3f} s, mincurv "
          f"{bots['mincurv_s']:.3f} s; reference limit {bots['reference_limit_s']:.3f} s",
          file=sys.stderr)  # fmt: skip
    control_period = 0.2
    test_max_steps = int(3 * max(bots["centre_s"], bots["mincurv_s"]) / control_period) + 100
    schedule = {"episodes": 10**7, "max_steps": args.max_steps,
                "test_every_episodes": TEST_EVERY, "test_starts": TEST_STARTS,
                "test_max_steps": test_max_steps}  # fmt: skip
    owned = sorted(set(schedule_overrides) & set(schedule))
    if owned:
        raise SystemExit(f"--schedule-set: {', '.join(owned)} belong to the benchmark's tests "
                         "and budget (--max-steps, --budget-cpu-s)")  # fmt: skip
    common = {"train_tracks": [args.track], "reference": args.reference, "lac": args.lac,
              "device": "cpu", "threads": 1}  # fmt: skip

    def spec_of(variant: str, preset: str, seed: int, extra: Mapping[str, Any],
                own_schedule: Mapping[str, Any]) -> Any:
        try:
            return build_run_spec(variant=variant, preset=preset, overrides=dict(extra),
                                  seed=seed, demos=demo_overrides or None,
                                  env_overrides=env_overrides or None,
                                  schedule={**schedule, **own_schedule},
                                  source=f"entrant {variant}:{preset}", **common)  # fmt: skip
        except UserInputError as err:
            raise SystemExit(f"error: {err}") from None

    out_root = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="ttc-"))
    print(f"job folders under {out_root}", file=sys.stderr)
    base = {"track": args.track, "bots": bots, "budget_cpu_s": args.budget_cpu_s,
            "to_budget": args.to_budget}  # fmt: skip
    tasks: list[dict[str, Any]] = []
    specs: dict[str, Any] = {}
    use_sb3 = not args.no_sb3
    if use_sb3 and importlib.util.find_spec("stable_baselines3") is None:
        print("stable-baselines3 is not installed (pip install -e '.[bench]'): skipping the SB3 "
              "SAC anchor", file=sys.stderr)  # fmt: skip
        use_sb3 = False
    for seed in seeds:
        for variant, preset in entrants:
            label = f"{variant}:{preset}"
            spec = spec_of(variant, preset, seed, overrides, schedule_overrides)
            specs[label] = spec
            tasks.append({**base, "kind": "ours", "label": label, "seed": seed,
                          "spec": spec.to_json(),
                          "job_dir": str(out_root / f"{variant}-{preset}" / f"seed-{seed}")})
        if use_sb3:  # the env of a plain spec with the same track, line, LAC and tests (one car)
            spec = spec_of("WIN1", "paper", seed, {}, {})
            tasks.append({**base, "kind": "sb3", "label": SB3_LABEL, "seed": seed,
                          "spec": spec.to_json(), "job_dir": str(out_root / "sb3-sac" /
                                                                 f"seed-{seed}")})  # fmt: skip

    if args.jobs > 1 and len(tasks) > 1:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        from formula_tourney.tourney.executors import die_with_parent

        # a run killed from the shell (kill, Ctrl-C of a hung parent) takes its workers with it:
        # orphans went on training and took the cores of the next benchmark
        with ProcessPoolExecutor(min(args.jobs, len(tasks)), mp.get_context("spawn"),
                                 initializer=die_with_parent,
                                 initargs=(os.getpid(),)) as pool:  # fmt: skip
            runs = list(pool.map(run_job, tasks))
    else:
        runs = [run_job(t) for t in tasks]

    sb3_runs = [r for r, t in zip(runs, tasks, strict=True) if t["kind"] == "sb3"]
    sb3 = None
    if use_sb3:
        sb3 = {"label": SB3_LABEL, "call": 'SAC("MlpPolicy", env, seed=seed, device="cpu")',
               "summary": summarise(sb3_runs), "runs": sorted(sb3_runs, key=lambda r: r["seed"])}
    goals = GOALS.get(args.track)
    if goals and args.track == "technical" and (args.reference != "recorded" or not args.lac):
        print("note: technical's goals are set for --reference recorded --lac", file=sys.stderr)
    results = []
    for variant, preset in entrants:
        label = f"{variant}:{preset}"
        mine = sorted((r for r in runs if r["label"] == label), key=lambda r: r["seed"])
        s = summarise(mine)
        ratios = None
        if sb3 is not None:
            ratios = {n: ratio(s[f"median_{n}_cpu_s"], sb3["summary"][f"median_{n}_cpu_s"])
                      for n in MILESTONES}  # fmt: skip
        spec = specs[label]
        results.append({
            "label": label, "variant": variant, "preset": preset,
            "demos": None if spec.demos is None else spec.demos.model_dump(),
            "beyond_paper": spec.beyond_paper(), "summary": s, "ratios_vs_sb3": ratios,
            "goal_met": goal_flags(args.track, s, ratios), "runs": mine,
        })  # fmt: skip
    result = {
        "benchmark": "time_to_competence", "track": args.track, "reference": args.reference,
        "lac": args.lac, "budget_cpu_s": args.budget_cpu_s, "to_budget": args.to_budget,
        "seeds": seeds,
        "max_steps": args.max_steps, "test_every_episodes": TEST_EVERY,
        "test_starts": TEST_STARTS, "test_max_steps": test_max_steps,
        "clean_start_min": CLEAN_STARTS, "overrides": overrides,
        "demo_overrides": demo_overrides, "env_overrides": env_overrides,
        "schedule_overrides": schedule_overrides, "bots": bots,
        "goals": goals, "entrants": results, "sb3": sb3, "out": str(out_root),
    }  # fmt: skip
    print(render(result), file=sys.stderr)
    if args.plot:
        for path in plot_curves(result, Path(args.plot)):
            print(f"wrote {path}", file=sys.stderr)
    for e in [*results, *([sb3] if sb3 else [])]:
        e["summary"] = _json_summary(e["summary"])
    print(json.dumps(result, default=_json_default, allow_nan=False))


def _json_default(x: Any) -> Any:
    if hasattr(x, "item"):
        return x.item()
    raise TypeError(f"not JSON: {type(x).__name__}")


if __name__ == "__main__":
    main()

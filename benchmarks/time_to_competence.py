"""Time to competence: CPU-seconds until each entrant first laps cleanly, beats the follower bot
on the centre line and beats it on the minimum-curvature line, against Stable-Baselines3 SAC.

Entrants are ``VARIANT:PRESET`` pairs (``--entrants WIN1:best,SAC:best``). The benchmark writes
one tournament (``<out>/time_to_competence.toml``, results in ``<out>/time-to-competence/``) with
one part per entrant, run by the product (``tourney.api.run_tournament``: its worker pool, one
process per seed, ``--jobs`` at a time, and its resume): each part trains its entrant on
``--track`` with ``--reference`` (and ``--lac``), ``--set KEY=VALUE`` agent overrides on top,
tested greedily every 5 episodes from 3 starts, with a CPU budget of ``--budget-cpu-s``
(schedule ``budget_cpu_s``) and ``stop_at = "best-bot"`` (a run ends once it beats the follower
on the min-curvature line; with ``--to-budget`` only at the budget, so that the best lap / limit
is what the budget buys), and races the follower on the centre and min-curvature lines as
baselines. The figures are the product's: the report's time-to-competence table
(``report.competence_table`` on ``results.competence``, docs/report.md), which defines the
milestones (a) first clean lap, (b) beat the follower on the centre line, (c) on the
min-curvature line, the best lap / reference limit and the clean-start rate.

The anchor, in the same run: Stable-Baselines3 SAC at its defaults (``SAC("MlpPolicy", env,
seed=seed)``, the ``bench`` extra) on the same env (FormulaRacing-v0 from
``RunEnvs(spec).make(track, test=False)``: same track, line, LAC, random starts and episode
length; the raw env reward, as an SB3 user sees it), budget and seeds, tested with the same
protocol, on the same CPU clock and stop rule (``training.budget``), its milestones read by
``results.competence`` from the tests table it writes. Each SAC seed runs in its own spawned
process, ``--jobs`` at a time, after the tournament. Ratios per milestone: our median CPU-s /
SAC's (goal <= 0.5).

Medians are over seeds with a miss counted as infinite (printed "miss", null in the JSON; a
failed seed counts as a run that reached nothing). Goals: oval: (b) <= 60 CPU-s, (c) <= 300
CPU-s, best lap / limit <= 1.02; technical (recorded + LAC): (a) <= 60 CPU-s with clean-start
rate >= 2/3, (c) <= 3600 CPU-s, best lap / limit <= 1.05. A table goes to stderr; the last line
of stdout is one JSON object. Seeds must be consecutive (a tournament's seeds are ``seed_base``
+ 0, 1, ...); ``--out`` reused with the same settings resumes (finished runs are kept).

    .venv/bin/python benchmarks/time_to_competence.py [--track oval] [--reference centre] [--lac]
        [--entrants WIN1:best,SAC:best,PER1M:paper,WIN1:best-demos] [--seeds 0,1,2,3]
        [--jobs 2] [--budget-cpu-s 600] [--to-budget] [--set KEY=VALUE] [--no-sb3] [--out DIR]
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
import sys  # noqa: E402
import tempfile  # noqa: E402
import traceback  # noqa: E402
from collections.abc import Iterable, Mapping  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

from formula_tourney.results.competence import (  # noqa: E402
    MILESTONE_LABELS,
    MILESTONES,
    Bots,
    run_competence,
    summarise,
    thresholds,
)

TEST_EVERY = 5
TEST_STARTS = 3
DEFAULT_ENTRANTS = "WIN1:best,SAC:best,PER1M:paper,WIN1:best-demos"
TOURNAMENT = "time-to-competence"
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


def parse_seeds(text: str) -> list[int]:
    """``0,1,2`` -> [0, 1, 2]; the seeds of a tournament are consecutive (seed_base + k)."""
    seeds = sorted({int(x) for x in text.split(",") if x.strip()})
    if not seeds:
        raise SystemExit("--seeds is empty")
    if seeds != list(range(seeds[0], seeds[0] + len(seeds))):
        raise SystemExit(f"--seeds must be consecutive (the tournament's seeds are seed_base + "
                         f"0, 1, ...), got {text!r}")  # fmt: skip
    return seeds


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


def goal_flags(track: str, summary: Mapping[str, Any],
               ratios: Mapping[str, float | None] | None) -> dict[str, bool] | None:  # fmt: skip
    """Which of the goals for ``track`` the entrant's medians meet (None: no goals)."""
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


def stop_lap_s(bots: Bots, to_budget: bool) -> float:
    """The clean lap that ends the anchor's run early, as ``stop_at = "best-bot"`` ends ours:
    (c)'s lap, or none (-inf) with ``--to-budget``."""
    return -math.inf if to_budget else thresholds(bots)["beat_mincurv_bot"]


def part_name(variant: str, preset: str) -> str:
    """The tournament part of one entrant (a folder name)."""
    return f"{variant}-{preset}"


def _toml(value: Any) -> str:
    """A TOML value: strings and numbers as JSON writes them, tables inline."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {_toml(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return json.dumps(value)


def tournament_toml(*, track: str, reference: str, lac: bool, entrants: list[tuple[str, str]],
                    seeds: list[int], defaults: Mapping[str, Any],
                    demos: Mapping[tuple[str, str], Mapping[str, Any]]) -> str:  # fmt: skip
    """The benchmark's tournament: one part per entrant, each racing the two followers."""
    lines = [f"name = {_toml(TOURNAMENT)}",
             f"description = {_toml(f'time to competence on {track}')}",
             f"seed_base = {seeds[0]}", "", "[defaults]", f"seeds = {len(seeds)}"]
    lines += [f"{key} = {_toml(value)}" for key, value in defaults.items()]
    for variant, preset in entrants:
        lines += ["", "[[parts]]", f"name = {_toml(part_name(variant, preset))}",
                  f"entrants = {_toml([variant])}", f"preset = {_toml(preset)}",
                  f"train_tracks = {_toml([track])}",
                  f"setups = {_toml([{'reference': reference, 'lac': lac}])}",
                  "baselines = " + _toml([{"bot": "follower", "reference": line}
                                          for line in ("centre", "mincurv")])]  # fmt: skip
        if (variant, preset) in demos:
            lines.append(f"demos = {_toml(demos[(variant, preset)])}")
    return "\n".join(lines) + "\n"


# --- what is measured before the clock (parent) ----------------------------------------------
def bot_figures(track_name: str, car_overrides: dict[str, Any] | None = None) -> Bots:
    """The follower's best lap on the centre and on the min-curvature line, and the limit, for
    the runs' own car (``--env-set car=...``): a bot in another car is no anchor. The parts'
    baselines drive the same laps; these set the tests' step cap and the anchor's stop."""
    from formula_tourney.lines.limit import reference_limit_s
    from formula_tourney.sim.car_params import CarParams
    from formula_tourney.sim.catalog import load_track
    from formula_tourney.training.budget import follower_lap_s

    car = CarParams(**(car_overrides or {}))
    return Bots(follower_lap_s(track_name, "centre", car),
                follower_lap_s(track_name, "mincurv", car),
                float(reference_limit_s(load_track(track_name), car)))


def _say(who: str, cpu: float, episode: int, env_steps: int, best: float | None) -> None:
    shown = "-" if best is None or not math.isfinite(best) else f"{best:.3f}"
    print(f"{who}: cpu {cpu:6.0f} s  episode {episode}  env steps {env_steps}  best {shown}",
          file=sys.stderr, flush=True)  # fmt: skip


def _run_record(label: str, run: Mapping[str, Any], **extra: Any) -> dict[str, Any]:
    """A run of ``results.competence`` as the benchmark's JSON shows it."""
    return {
        "label": label, "seed": run["seed"],
        "cpu_s": {n: finite(v) for n, v in run["cpu_s"].items()},
        "milestones": run["milestones"], "limits_s": run["limits_s"],
        "demo_lap_s": finite(run["demo_lap_s"], 3), "best_lap_s": finite(run["best_lap_s"], 3),
        "best_lap_to_limit": finite(run["best_lap_to_limit"], 4),
        "clean_start_rate": run["clean_start_rate"],
        "cpu_s_total": finite(run.get("cpu_s_total")), "curve": run["curve"],
        "env_steps": run.get("env_steps"), "updates": run.get("updates"),
        "episodes": run.get("episodes"), **extra,
    }  # fmt: skip


def _failed(label: str, seed: int, error: str) -> dict[str, Any]:
    """A seed whose run failed: it reached nothing."""
    return {"label": label, "seed": seed, "error": error, "cpu_s": dict.fromkeys(MILESTONES),
            "best_lap_s": None, "best_lap_to_limit": None, "clean_start_rate": None,
            "curve": []}  # fmt: skip


# --- our entrants: one tournament --------------------------------------------------------------
def run_entrants(toml_path: Path, out_root: Path, jobs: int,
                 entrants: list[tuple[str, str]]) -> dict[str, dict[str, Any]]:  # fmt: skip
    """Run the tournament through the product and read its time-to-competence table: per
    entrant label, its runs (failed seeds as misses), demos and beyond-paper labels."""
    from formula_tourney.errors import UserInputError
    from formula_tourney.report.competence_table import competence_table
    from formula_tourney.report.load import load_tournament
    from formula_tourney.report.paper_tables import Context
    from formula_tourney.results.folder import JobFolder
    from formula_tourney.tourney.api import run_tournament

    def on_event(event: Any) -> None:
        info = event.info
        if event.kind == "progress" and "cpu_s" in info and info["episode"] % TEST_EVERY == 0:
            _say(event.job_id, info["cpu_s"], info["episode"], info["env_steps"],
                 info["best_lap_s"])
        elif event.kind == "failed":
            print(f"{event.job_id}: FAILED {event.reason}", file=sys.stderr, flush=True)

    try:
        run_tournament(toml_path, workers=jobs, results_dir=out_root, on_event=on_event)
    except UserInputError as err:
        raise SystemExit(f"error: {err}") from None
    data = load_tournament(out_root / TOURNAMENT)
    table = competence_table(Context.build(data))
    by_part = {part_name(v, p): f"{v}:{p}" for v, p in entrants}
    out: dict[str, dict[str, Any]] = {label: {"runs": []} for label in by_part.values()}
    for record in table.records:
        label = by_part[record["part"]]
        out[label]["runs"] += [_run_record(label, r, job=str(data.job_dir(r["job_id"])))
                               for r in record["runs"]]  # fmt: skip
    for _, job in data.jobs.iterrows():
        label = by_part.get(str(job["part"]))
        if label is None:
            continue
        if job["status"] != "done":
            out[label]["runs"].append(_failed(label, int(job["seed"]),
                                              str(job["reason"] or job["status"])))
        elif "demos" not in out[label]:
            folder = JobFolder(data.job_dir(str(job["job_id"])))
            out[label]["demos"] = folder.config().get("demos")
            out[label]["beyond_paper"] = folder.beyond_paper()
    return out


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
    """SB3 SAC at its defaults on the run's env, tested as our runs are, on the same CPU clock
    and stop rule (``training.budget``); its milestones by ``results.competence``."""
    from formula_tourney.agents.core import configure_torch
    from formula_tourney.results.folder import JobFolder
    from formula_tourney.results.metrics import model_clean_lap_s
    from formula_tourney.training.budget import CpuClock, StopRule, warm_up
    from formula_tourney.training.envs import RunEnvs
    from formula_tourney.training.evaluate import (
        laps_rows,
        run_test_episode,
        start_positions,
        tests_row,
    )
    from formula_tourney.training.run_spec import RunSpec

    spec = RunSpec.from_json(task["spec"], "benchmark spec")
    from stable_baselines3 import SAC
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.logger import Logger

    configure_torch(1)
    warm_up(spec)
    bots = Bots(**task["bots"])
    stop = StopRule(float(task["budget_cpu_s"]), stop_lap_s(bots, bool(task.get("to_budget"))))
    label, seed, track = task["label"], task["seed"], spec.key_track
    tests: list[dict[str, Any]] = []
    laps: list[dict[str, Any]] = []

    clock = CpuClock()
    clock.start()
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
                    lap = model_clean_lap_s([d.best_lap_s for d in drives],
                                            [d.damage for d in drives])  # fmt: skip
                    if math.isfinite(lap):
                        self.best = min(self.best, lap)
                    cpu = clock.seconds()
                    for d in drives:
                        tests.append({**tests_row(d, self.episodes, steps, ""), "cpu_s": cpu})
                        laps.extend(laps_rows(d, self.episodes))
                    _say(f"{label} seed {seed}", cpu, self.episodes, steps, self.best)
            return stop.reason(self.best, clock.seconds()) is None

    tester = Tester()
    model.learn(total_timesteps=10**9, callback=tester)
    cpu_total = clock.seconds()
    env.close()
    test_env.close()
    job = JobFolder(task["job_dir"])
    job.path.mkdir(parents=True, exist_ok=True)
    job.write_tables([], tests, laps)
    run = run_competence(job.tests(), track, bots)
    return _run_record(label, {**run, "seed": seed, "cpu_s_total": cpu_total,
                               "env_steps": int(model.num_timesteps),
                               "updates": int(getattr(model, "_n_updates", 0)),
                               "episodes": tester.episodes}, job=str(job.path))  # fmt: skip


def run_job(task: dict[str, Any]) -> dict[str, Any]:
    """An anchor seed in a worker; a crash is reported as a run that reached nothing."""
    try:
        return run_sb3(task)
    except Exception as err:  # noqa: BLE001 - one failed seed must not lose the others
        traceback.print_exc()
        return _failed(task["label"], task["seed"], f"{type(err).__name__}: {err}")


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
    ap.add_argument("--seeds", default="0,1,2,3", help="comma-separated consecutive seeds")
    ap.add_argument("--jobs", type=int, default=2, help="runs side by side (processes)")
    ap.add_argument("--budget-cpu-s", type=float, default=600.0)
    ap.add_argument("--max-steps", type=int, default=1000, help="steps per training episode")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="agent setting for every entrant, on top of its preset (repeatable)")
    ap.add_argument("--demos-set", action="append", default=[], metavar="KEY=VALUE",
                    help="demonstration setting (training.run_spec.DemoSettings) for every "
                    "entrant, on top of its preset's demos (repeatable; adds demos to a "
                    "preset without them)")
    ap.add_argument("--env-set", action="append", default=[], metavar="KEY=VALUE",
                    help="env setting (sim.config.EnvSettings, e.g. track_pos_weight=0) for "
                    "every entrant and the SB3 anchor alike (repeatable)")
    ap.add_argument("--schedule-set", action="append", default=[], metavar="KEY=VALUE",
                    help="schedule setting (training.run_spec.Schedule, e.g. cars=4) for every "
                    "entrant, on top of the benchmark's own (repeatable)")
    ap.add_argument("--no-sb3", action="store_true", help="skip the SB3 SAC anchor")
    ap.add_argument("--to-budget", action="store_true",
                    help="train every run for its whole budget instead of stopping at (c): "
                    "best lap / limit is then the budget's, not the first lap past the best bot")
    ap.add_argument("--out", default=None, help="folder for the tournament (default: temp)")
    ap.add_argument("--plot", default=None, metavar="FILE",
                    help="draw each run's clean test laps against CPU-s into FILE.png/.pdf")
    args = ap.parse_args()  # fmt: skip
    seeds = parse_seeds(args.seeds)
    entrants = parse_entrants(args.entrants)
    overrides = parse_overrides(args.set)
    demo_overrides = parse_overrides(args.demos_set)
    env_overrides = parse_overrides(args.env_set)
    schedule_overrides = parse_overrides(args.schedule_set)

    from formula_tourney.errors import UserInputError
    from formula_tourney.sim.config import EnvSettings
    from formula_tourney.training.presets import get_preset
    from formula_tourney.training.run_spec import build_run_spec

    try:
        car_overrides = EnvSettings.model_validate(env_overrides).car
        preset_demos = {(v, p): get_preset(p).demos for v, p in entrants}
    except (ValueError, UserInputError) as err:
        raise SystemExit(f"error: {err}") from None
    bots = bot_figures(args.track, car_overrides)
    print(f"follower on {args.track}: centre {bots.centre_s:.3f} s, mincurv "
          f"{bots.mincurv_s:.3f} s; reference limit {bots.reference_limit_s:.3f} s",
          file=sys.stderr)  # fmt: skip
    control_period = 0.2
    test_max_steps = int(3 * max(bots.centre_s, bots.mincurv_s) / control_period) + 100
    schedule = {"episodes": 10**7, "max_steps": args.max_steps,
                "test_every_episodes": TEST_EVERY, "test_starts": TEST_STARTS,
                "test_max_steps": test_max_steps, "budget_cpu_s": args.budget_cpu_s,
                "stop_at": "none" if args.to_budget else "best-bot"}  # fmt: skip
    owned = sorted(set(schedule_overrides) & set(schedule))
    if owned:
        raise SystemExit(f"--schedule-set: {', '.join(owned)} belong to the benchmark's tests "
                         "and budget (--max-steps, --budget-cpu-s, --to-budget)")  # fmt: skip
    defaults = {**schedule, **schedule_overrides, "device": "cpu", "threads": 1,
                **({"env_overrides": env_overrides} if env_overrides else {}),
                **({"variant_overrides": overrides} if overrides else {})}  # fmt: skip
    # a preset's demonstrations under the user's keys, one by one (a part's demos replace them)
    demos = {pair: {**(preset_demos[pair] or {}), **demo_overrides}
             for pair in entrants if demo_overrides}  # fmt: skip

    out_root = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="ttc-"))
    out_root.mkdir(parents=True, exist_ok=True)
    toml_path = out_root / "time_to_competence.toml"
    toml_path.write_text(tournament_toml(
        track=args.track, reference=args.reference, lac=args.lac, entrants=entrants,
        seeds=seeds, defaults=defaults, demos=demos), encoding="utf-8")  # fmt: skip
    print(f"tournament {toml_path}, results under {out_root / TOURNAMENT}", file=sys.stderr)
    ours = run_entrants(toml_path, out_root, args.jobs, entrants)

    use_sb3 = not args.no_sb3
    if use_sb3 and importlib.util.find_spec("stable_baselines3") is None:
        print("stable-baselines3 is not installed (pip install -e '.[bench]'): skipping the SB3 "
              "SAC anchor", file=sys.stderr)  # fmt: skip
        use_sb3 = False
    sb3 = None
    if use_sb3:  # the env of a plain spec with the same track, line, LAC and tests (one car)
        tasks = []
        for seed in seeds:
            try:
                spec = build_run_spec(
                    variant="WIN1", preset="paper", seed=seed, train_tracks=[args.track],
                    reference=args.reference, lac=args.lac, device="cpu", threads=1,
                    env_overrides=env_overrides or None, schedule=schedule,
                    source="the SB3 anchor")  # fmt: skip
            except UserInputError as err:
                raise SystemExit(f"error: {err}") from None
            tasks.append({"label": SB3_LABEL, "seed": seed, "spec": spec.to_json(),
                          "bots": vars(bots), "budget_cpu_s": args.budget_cpu_s,
                          "to_budget": args.to_budget,
                          "job_dir": str(out_root / "sb3-sac" / f"seed-{seed}")})  # fmt: skip
        if args.jobs > 1 and len(tasks) > 1:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            from formula_tourney.tourney.executors import die_with_parent

            # a run killed from the shell takes its workers with it (orphans took the cores)
            with ProcessPoolExecutor(min(args.jobs, len(tasks)), mp.get_context("spawn"),
                                     initializer=die_with_parent,
                                     initargs=(os.getpid(),)) as pool:  # fmt: skip
                sb3_runs = list(pool.map(run_job, tasks))
        else:
            sb3_runs = [run_job(t) for t in tasks]
        sb3 = {"label": SB3_LABEL, "call": 'SAC("MlpPolicy", env, seed=seed, device="cpu")',
               "summary": summarise(sb3_runs), "runs": sorted(sb3_runs, key=lambda r: r["seed"])}
    goals = GOALS.get(args.track)
    if goals and args.track == "technical" and (args.reference != "recorded" or not args.lac):
        print("note: technical's goals are set for --reference recorded --lac", file=sys.stderr)
    results = []
    for variant, preset in entrants:
        label = f"{variant}:{preset}"
        mine = sorted(ours[label]["runs"], key=lambda r: r["seed"])
        s = summarise(mine)
        ratios = None
        if sb3 is not None:
            ratios = {n: ratio(s[f"median_{n}_cpu_s"], sb3["summary"][f"median_{n}_cpu_s"])
                      for n in MILESTONES}  # fmt: skip
        results.append({
            "label": label, "variant": variant, "preset": preset,
            "part": part_name(variant, preset),
            "demos": ours[label].get("demos"), "beyond_paper": ours[label].get("beyond_paper"),
            "summary": s, "ratios_vs_sb3": ratios,
            "goal_met": goal_flags(args.track, s, ratios), "runs": mine,
        })  # fmt: skip
    result = {
        "benchmark": "time_to_competence", "track": args.track, "reference": args.reference,
        "lac": args.lac, "budget_cpu_s": args.budget_cpu_s, "to_budget": args.to_budget,
        "seeds": seeds,
        "max_steps": args.max_steps, "test_every_episodes": TEST_EVERY,
        "test_starts": TEST_STARTS, "test_max_steps": test_max_steps,
        "overrides": overrides,
        "demo_overrides": demo_overrides, "env_overrides": env_overrides,
        "schedule_overrides": schedule_overrides, "bots": vars(bots),
        "goals": goals, "entrants": results, "sb3": sb3, "out": str(out_root),
        "tournament": str(toml_path),
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

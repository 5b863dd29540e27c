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

The anchors, in the same run: Stable-Baselines3 SAC and sb3-contrib CrossQ at their defaults
(``--anchors sb3:SAC,sb3_contrib:CrossQ``, the ``sb3`` extra), entered as outside entrants
(``agents/outside``, docs/entrants.md): one more part each in the same tournament, on the same
env (the first entrant's preset's env keys, e.g. the progress reward of ``best``, and
``--env-set``), budget, seeds, tests, CPU clock and stop rule, their milestones read from the
same table. Ratios per milestone: our median CPU-s / the anchor's (goal <= 0.25).

Under each entrant's CPU-s the table gives the median env steps to each milestone and the env
steps its runs bought per CPU-s: one machine can buy twice as many steps per CPU-s in one hour
as in another, so rows measured at different times compare in env steps (the CPU-s is what a
user pays). Medians are over seeds with a miss counted as infinite (printed "miss", null in the
JSON; a failed seed counts as a run that reached nothing). The goals (``GOALS``) are printed as
a table, figure by figure, with each entrant's value and whether it meets them; an entrant with
demonstrations is held to the demonstration goals. A table goes to stderr; the last line of
stdout is one JSON object. Seeds must be consecutive (a tournament's seeds are ``seed_base`` +
0, 1, ...); ``--out`` reused with the same settings resumes (finished runs are kept).

    .venv/bin/python benchmarks/time_to_competence.py [--track oval] [--reference centre] [--lac]
        [--entrants WIN1:best,SAC:best,PER1M:paper,WIN1:best-demos] [--seeds 0,1,2,3]
        [--jobs 2] [--budget-cpu-s 600] [--to-budget] [--set KEY=VALUE]
        [--anchors sb3:SAC,sb3_contrib:CrossQ | --no-sb3] [--out DIR] [--plot FILE]
    .venv/bin/python benchmarks/time_to_competence.py --replot RUN.json[=LABEL] ... --plot FILE
    .venv/bin/python benchmarks/time_to_competence.py --replot RUN.json ... --at-env-steps 100000
    .venv/bin/python benchmarks/time_to_competence.py --replot RUN.json ... --settled-from-cpu-s 200
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
from collections.abc import Callable, Iterable, Mapping, Sequence  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, NamedTuple  # noqa: E402

from formula_tourney.commands.model_options import parse_key_values  # noqa: E402
from formula_tourney.errors import UserInputError  # noqa: E402
from formula_tourney.results.competence import (  # noqa: E402
    MILESTONE_LABELS,
    MILESTONES,
    Bots,
    best_clean_lap,
    median_inf,
    summarise,
    thresholds,
)

TEST_EVERY = 5
TEST_STARTS = 3
DEFAULT_ENTRANTS = "WIN1:best,SAC:best,PER1M:paper,WIN1:best-demos"
TOURNAMENT = "time-to-competence"
RATIO_GOAL = 0.25
DEFAULT_ANCHORS = "sb3:SAC,sb3_contrib:CrossQ"
ANCHOR_LIBRARIES = {"sb3": "SB3", "sb3_contrib": "SB3C"}


class Goal(NamedTuple):
    """One figure of a track's goals: what is measured, its bound and whether every seed must
    reach it (a median alone lets one seed in four miss)."""

    figure: str
    key: str  # a milestone's "<name>_cpu_s", "best_lap_to_limit" or "clean_start_rate"
    bound: float
    all_seeds: bool = False


_RATIOS = Goal("each milestone against each anchor (ours / theirs)", "ratio", RATIO_GOAL)
GOALS: dict[str, dict[str, list[Goal]]] = {
    "oval": {"scratch": [
        Goal("CPU-s until it beats the best bot", "beat_mincurv_bot_cpu_s", 30.0),
        Goal("best lap / reference limit at the budget (300 CPU-s)", "best_lap_to_limit", 1.015),
        _RATIOS]},
    "technical": {
        "scratch": [
            Goal("CPU-s to a first clean lap", "first_clean_lap_cpu_s", 60.0, all_seeds=True),
            Goal("clean laps from >= 2 of 3 starts", "clean_start_rate", 2.0 / 3.0),
            Goal("CPU-s until it beats the best bot", "beat_mincurv_bot_cpu_s", 600.0,
                 all_seeds=True),
            Goal("best lap / reference limit at the budget (3 600 CPU-s)", "best_lap_to_limit",
                 1.045),
            _RATIOS],
        "demos": [
            Goal("CPU-s until it beats its demonstrator (the best bot)",
                 "beat_mincurv_bot_cpu_s", 240.0, all_seeds=True),
            Goal("best lap / reference limit at the budget (3 600 CPU-s)", "best_lap_to_limit",
                 1.045),
            _RATIOS]},
    "flowing": {"scratch": [
        Goal("CPU-s until it beats the best bot", "beat_mincurv_bot_cpu_s", 1200.0),
        _RATIOS]},
}  # fmt: skip
"""Per track, from scratch and with demonstrations: the figures the benchmark is held to."""


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


def parse_overrides(pairs: Iterable[str], what: str = "--set") -> dict[str, Any]:
    """``KEY=VALUE`` pairs (``commands.model_options.parse_key_values``); a bad pair ends the
    benchmark with its one-line message."""
    try:
        return parse_key_values(list(pairs), what)
    except UserInputError as err:
        raise SystemExit(str(err)) from None


def parse_env_steps(text: str) -> list[int]:
    """``100000,135000`` -> [100000, 135000]: positive whole numbers of env steps."""
    try:
        bounds = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise SystemExit(f"--at-env-steps wants whole numbers, got {text!r}") from None
    if not bounds or min(bounds) < 1:
        raise SystemExit(f"--at-env-steps wants numbers >= 1, got {text!r}")
    return bounds


def _job_tests(run: Mapping[str, Any]) -> Any:
    """The tests of a run's job folder (its JSON record's ``job``)."""
    from formula_tourney.results.folder import JobFolder

    if not run.get("job"):
        raise SystemExit(f"--at-env-steps: seed {run.get('seed')}'s record names no job folder")
    folder = JobFolder(Path(run["job"]))
    if not folder.config_path.is_file():  # moved or deleted: its laps are not a miss
        raise SystemExit(f"--at-env-steps: {folder.path}: not a job folder (no config.json)")
    return folder.tests()


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


def goal_value(goal: Goal, summary: Mapping[str, Any]) -> float:
    """The entrant's figure for ``goal``: a median (inf for a miss) or the clean-start rate."""
    if goal.key == "clean_start_rate":
        return float(summary["median_clean_start_rate"])
    if goal.key == "best_lap_to_limit":
        return float(summary["median_best_lap_to_limit"])
    return float(summary[f"median_{goal.key}"])


Ratios = Mapping[str, Mapping[str, float | None]]
"""Per anchor label, per milestone: our median CPU-s / the anchor's (``ratio``)."""


def goal_flags(track: str, summary: Mapping[str, Any], ratios: Ratios | None,
               demos: bool = False) -> dict[str, bool] | None:  # fmt: skip
    """Which of the goals for ``track`` the entrant's medians meet (None: no goals). A ratio
    goal is met per anchor and milestone where the anchor reached it (ours <= 0.25 x theirs;
    0 where only the anchor missed), and not met where ours missed."""
    goals = GOALS.get(track, {}).get("demos" if demos else "scratch")
    if goals is None:
        return None
    flags: dict[str, bool] = {}
    for goal in goals:
        if goal.key == "ratio":
            for anchor, by_milestone in (ratios or {}).items():
                for name, r in by_milestone.items():
                    flags[f"ratio_{name}_vs_{anchor}"] = r is not None and r <= goal.bound
            continue
        value = goal_value(goal, summary)
        met = value >= goal.bound if goal.key == "clean_start_rate" else value <= goal.bound
        if goal.all_seeds and goal.key.endswith("_cpu_s"):
            name = goal.key.removesuffix("_cpu_s")
            met = met and summary[f"reached_{name}"] == summary["seeds"]
        flags[goal.key] = bool(met)
    return flags


def parse_anchors(text: str) -> list[tuple[str, str]]:
    """``--anchors sb3:SAC,sb3_contrib:CrossQ`` -> [(library, algorithm), ...]."""
    out = []
    for item in (x.strip() for x in text.split(",")):
        if not item:
            continue
        library, _, algorithm = item.partition(":")
        if library not in ANCHOR_LIBRARIES or not algorithm:
            raise SystemExit(f"--anchors: {item!r} is not LIBRARY:ALGORITHM with LIBRARY one of "
                             f"{', '.join(ANCHOR_LIBRARIES)}")  # fmt: skip
        out.append((library, algorithm))
    return out


def anchor_variant(library: str, algorithm: str) -> str:
    """The tournament's variant name of an anchor (``SB3-SAC``, ``SB3C-CrossQ``)."""
    return f"{ANCHOR_LIBRARIES[library]}-{algorithm}"


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
                    demos: Mapping[tuple[str, str], Mapping[str, Any]],
                    anchors: list[tuple[str, str]] = ()) -> str:  # fmt: skip
    """The benchmark's tournament: one part per entrant, each racing the two followers; each
    anchor is an outside entrant (``[variants.SB3-SAC] sb3 = "SAC"``) with a part of its own,
    under the first entrant's preset (its env keys: the same reward; its agent settings do
    not reach an outside entrant)."""
    lines = [f"name = {_toml(TOURNAMENT)}",
             f"description = {_toml(f'time to competence on {track}')}",
             f"seed_base = {seeds[0]}", "", "[defaults]", f"seeds = {len(seeds)}"]
    lines += [f"{key} = {_toml(value)}" for key, value in defaults.items()]
    for library, algorithm in anchors:
        lines += ["", f"[variants.{anchor_variant(library, algorithm)}]",
                  f"{library} = {_toml(algorithm)}"]
    preset0 = entrants[0][1] if entrants else "paper"
    parts = [*entrants, *((anchor_variant(*a), preset0) for a in anchors)]
    for variant, preset in parts:
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
                 parts: dict[str, str]) -> dict[str, dict[str, Any]]:  # fmt: skip
    """Run the tournament through the product and read its time-to-competence table: per
    entrant label (``parts``: part name -> label), its runs (failed seeds as misses), demos and
    beyond-paper labels."""
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
    by_part = parts
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


# --- output ------------------------------------------------------------------------------------
def _cell(x: float, reached: int | None = None, seeds: int | None = None) -> str:
    text = "miss" if not math.isfinite(x) else f"{x:.1f}"
    return text if reached is None else f"{text} ({reached}/{seeds})"


def _steps_cell(x: float | None) -> str:
    """A median of env steps in thousands (a miss: inf, or None in the JSON)."""
    return "miss" if x is None or not math.isfinite(x) else f"{x / 1000:.1f}"


def _ratio_cell(r: float | None) -> str:
    if r is None:
        return "- (ours miss)"
    return "0 (anchor miss)" if r == 0.0 else f"{r:.2f}"


def _all(result: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    """Our entrants, then the anchors."""
    return [*result["entrants"], *result.get("anchors", [])]


def _goal_cell(goal: Goal, summary: Mapping[str, Any]) -> str:
    value = goal_value(goal, summary)
    if not math.isfinite(value):
        return "miss"
    text = f"{value:.4f}" if goal.key == "best_lap_to_limit" else (
        f"{value:.2f}" if goal.key == "clean_start_rate" else f"{value:.1f}")
    if goal.key.endswith("_cpu_s"):
        name = goal.key.removesuffix("_cpu_s")
        text += f" ({summary[f'reached_{name}']} of {summary['seeds']})"
    return text


def goals_table(result: Mapping[str, Any]) -> list[str]:
    """The track's goals, figure by figure: each entrant's value, the goal and met / NOT met."""
    lines = []
    for e in result["entrants"]:
        kind = "demos" if e.get("demos") else "scratch"
        goals = GOALS.get(result["track"], {}).get(kind)
        if goals is None:
            lines.append(f"{e['label']}: no goals for track {result['track']!r} ({kind})")
            continue
        flags = e["goal_met"] or {}
        how = "with demonstrations" if kind == "demos" else "from scratch"
        lines.append(f"goals of {e['label']} ({how}):")
        for goal in goals:
            if goal.key == "ratio":
                ratio_flags = {k: v for k, v in flags.items() if k.startswith("ratio_")}
                met = sum(ratio_flags.values())
                lines.append(f"  {goal.figure}: {met} of {len(ratio_flags)} <= {goal.bound:g}")
                continue
            sign = ">=" if goal.key == "clean_start_rate" else "<="
            every = ", every seed" if goal.all_seeds else ""
            lines.append(f"  {goal.figure}: {_goal_cell(goal, e['summary'])}; goal {sign} "
                         f"{goal.bound:.4g}{every}: {'met' if flags.get(goal.key) else 'NOT met'}")
    return lines


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
        "median CPU-s to each milestone (seeds reaching it), and under it the median env steps "
        "to it (a machine's speed varies; steps do not); best lap / limit; clean-start rate",
    ]
    head = ["entrant", *(MILESTONE_LABELS[n] for n in MILESTONES), "best/limit", "clean-start"]
    rows = []
    for e in _all(result):
        s = e["summary"]
        rows.append([
            e["label"],
            *(_cell(s[f"median_{n}_cpu_s"], s[f"reached_{n}"], s["seeds"]) for n in MILESTONES),
            "miss" if not math.isfinite(s["median_best_lap_to_limit"])
            else f"{s['median_best_lap_to_limit']:.4f}",
            f"{s['median_clean_start_rate']:.2f}",
        ])  # fmt: skip
        speed = s.get("median_env_steps_per_cpu_s")
        rows.append(["  env steps (k)",
                     *(_steps_cell(s.get(f"median_{n}_env_steps")) for n in MILESTONES),
                     "", "" if speed is None else f"{speed:.0f} steps/CPU-s"])  # fmt: skip
        for anchor, by_milestone in (e.get("ratios_vs_anchors") or {}).items():
            rows.append([f"  ours / {anchor}", *(_ratio_cell(by_milestone[n])
                                                 for n in MILESTONES), "", ""])  # fmt: skip
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(len(head))]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    lines += [fmt.format(*head), fmt.format(*("-" * w for w in widths))]
    lines += [fmt.format(*r) for r in rows]
    lines += goals_table(result)
    for e in _all(result):
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


def load_results(specs: Iterable[str]) -> dict[str, Any]:
    """Earlier runs of this benchmark as one result for :func:`plot_curves`, so that runs made
    apart (seeds 0-1 and 2-3, one setting against another) are drawn on one figure.

    Each spec is ``PATH`` or ``PATH=LABEL``: a file holding the benchmark's JSON line (its
    stdout, or a log with it; the last such line counts). ``LABEL`` names every entrant of that
    file, for runs whose labels say the same thing (``WIN1:best`` before and after a preset
    changed); entrants with one label pool their runs. The files must share a track, reference
    and LAC, or their laps are not comparable; the bots and the limit are the first file's.
    """
    merged: dict[str, Any] | None = None
    order: dict[str, dict[str, Any]] = {}
    for spec in specs:
        path, sep, label = spec.partition("=")
        try:
            lines = Path(path).read_text(encoding="utf-8").splitlines()
        except OSError as err:
            raise SystemExit(f"--replot: {path}: {err.strerror or err}") from None
        found = [x for x in lines if x.startswith('{"benchmark": "time_to_competence"')]
        if not found:
            raise SystemExit(f"--replot: {path}: no time_to_competence result line in it")
        try:
            result = json.loads(found[-1])
        except json.JSONDecodeError as err:
            raise SystemExit(f"--replot: {path}: its result line is not JSON ({err})") from None
        setup = ("track", "reference", "lac")
        try:
            if merged is None:
                merged = {**{k: result[k] for k in (*setup, "bots")},
                          "seeds": [], "entrants": [], "anchors": []}  # fmt: skip
            elif any(result.get(k) != merged[k] for k in setup):
                theirs = ", ".join(f"{k} {result.get(k)}" for k in setup)
                first = ", ".join(f"{k} {merged[k]}" for k in setup)
                raise SystemExit(f"--replot: {path} has {theirs}; the first file {first}")
            for entrant in _all(result):
                name = label if sep and label else entrant["label"]
                order.setdefault(name, {"label": name, "runs": []})["runs"] += entrant["runs"]
            merged["seeds"] = sorted({*merged["seeds"], *result.get("seeds", [])})
        except (KeyError, TypeError) as err:
            raise SystemExit(f"--replot: {path}: its result line lacks {err}") from None
    if merged is None:
        raise SystemExit("--replot: no file given")
    merged["entrants"] = list(order.values())
    return merged


TestsOf = Callable[[Mapping[str, Any]], Any]
"""A run's record -> its tests table (``_job_tests``: its job folder's)."""


def laps_at_env_steps(result: Mapping[str, Any], bounds: Sequence[int],
                      tests_of: TestsOf) -> list[dict[str, Any]]:
    """Per entrant of ``result`` (``load_results``) and per bound: each run's best clean lap
    after at most that many env steps (``results.competence.best_clean_lap`` on the tests
    ``tests_of(run)`` reads, None: no clean lap by then) and their median (a miss counted as
    infinite, None in the JSON). Runs measured when the machine bought fewer steps per CPU-s
    compare here step for step."""
    out = []
    for e in _all(result):
        row: dict[str, Any] = {"label": e["label"], "seeds": [r["seed"] for r in e["runs"]],
                               "laps_s": {}, "median_s": {}}  # fmt: skip
        for bound in bounds:
            laps = [math.inf if "error" in r else  # nan (no clean lap) is a miss as well
                    best_clean_lap(tests_of(r), result["track"], bound)
                    for r in e["runs"]]  # fmt: skip
            row["laps_s"][str(bound)] = [finite(x, 3) for x in laps]
            row["median_s"][str(bound)] = finite(median_inf(laps), 3)
        out.append(row)
    return out


def render_laps_at_env_steps(rows: Sequence[Mapping[str, Any]], track: str) -> str:
    """The ``--at-env-steps`` table (stderr)."""
    lines = [f"best clean lap on {track} after at most N env steps (each run, then the median)"]
    for row in rows:
        for bound, laps in row["laps_s"].items():
            shown = ", ".join("miss" if x is None else f"{x:.3f}" for x in laps)
            median = row["median_s"][bound]
            lines.append(f"  {row['label']} at {int(bound):,} env steps: {shown}; median "
                         f"{'miss' if median is None else f'{median:.3f}'} s")
    return "\n".join(lines)


def settled_laps(result: Mapping[str, Any], from_cpu_s: float) -> list[dict[str, Any]]:
    """Per entrant of ``result`` (``load_results``): each run's median clean test lap over the
    tests held at ``from_cpu_s`` CPU-s or later (its JSON ``curve``; None: no clean lap there)
    with their fastest and slowest, and the median over runs (a miss counted as infinite).
    The best lap is the fastest of hundreds of tests; this is where a run's tests settle."""
    out = []
    for e in _all(result):
        medians, spans = [], []
        for r in e["runs"]:
            laps = [c["clean_lap_s"] for c in r.get("curve", [])
                    if c["cpu_s"] >= from_cpu_s and c["clean_lap_s"] is not None]  # fmt: skip
            medians.append(float(statistics.median(laps)) if laps else math.inf)
            spans.append([round(min(laps), 3), round(max(laps), 3)] if laps else None)
        out.append({"label": e["label"], "seeds": [r["seed"] for r in e["runs"]],
                    "median_lap_s": [finite(x, 3) for x in medians], "span_s": spans,
                    "median_s": finite(median_inf(medians), 3)})  # fmt: skip
    return out


def render_settled_laps(rows: Sequence[Mapping[str, Any]], from_cpu_s: float) -> str:
    """The ``--settled-from-cpu-s`` table (stderr)."""
    lines = [f"median clean test lap from {from_cpu_s:g} CPU-s on (each run [fastest, "
             "slowest], then the median)"]  # fmt: skip
    for row in rows:
        shown = ", ".join("miss" if m is None else f"{m:.3f} [{span[0]:.3f}, {span[1]:.3f}]"
                          for m, span in zip(row["median_lap_s"], row["span_s"], strict=True))
        median = row["median_s"]
        lines.append(f"  {row['label']}: {shown}; median "
                     f"{'miss' if median is None else f'{median:.3f}'} s")
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
    groups = _all(result)
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
        out[f"median_{n}_env_steps"] = finite(s[f"median_{n}_env_steps"], 0)
    speed = s.get("median_env_steps_per_cpu_s")
    out["median_env_steps_per_cpu_s"] = None if speed is None else round(speed, 1)
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
                    "every entrant and the anchors alike (repeatable)")
    ap.add_argument("--schedule-set", action="append", default=[], metavar="KEY=VALUE",
                    help="schedule setting (training.run_spec.Schedule, e.g. cars=4) for every "
                    "entrant, on top of the benchmark's own (repeatable)")
    ap.add_argument("--anchors", default=DEFAULT_ANCHORS, metavar="LIB:ALGO,...",
                    help="outside entrants at their defaults in the same run (LIB: sb3 or "
                    "sb3_contrib; the sb3 extra)")
    ap.add_argument("--no-sb3", action="store_true", help="no anchors")
    ap.add_argument("--to-budget", action="store_true",
                    help="train every run for its whole budget instead of stopping at (c): "
                    "best lap / limit is then the budget's, not the first lap past the best bot")
    ap.add_argument("--out", default=None, help="folder for the tournament (default: temp)")
    ap.add_argument("--plot", default=None, metavar="FILE",
                    help="draw each run's clean test laps against CPU-s into FILE.png/.pdf")
    ap.add_argument("--replot", action="append", default=[], metavar="PATH[=LABEL]",
                    help="instead of running, draw earlier runs' curves (files holding this "
                    "benchmark's JSON line, e.g. its saved stdout) on one figure into --plot; "
                    "LABEL names the file's entrants (repeatable)")
    ap.add_argument("--at-env-steps", default=None, metavar="N[,N...]",
                    help="with --replot: each earlier run's best clean lap after at most N "
                    "env steps (read from its job folder's tests) and the median per entrant, "
                    "to compare runs step for step")
    ap.add_argument("--settled-from-cpu-s", type=float, default=None, metavar="S",
                    help="with --replot: each earlier run's median clean test lap over the "
                    "tests from S CPU-s on (where its tests settle) and the median per entrant")
    args = ap.parse_args()  # fmt: skip
    reads = (args.at_env_steps, args.settled_from_cpu_s)
    if any(x is not None for x in reads) and not args.replot:
        raise SystemExit("--at-env-steps and --settled-from-cpu-s read earlier runs: give them "
                         "with --replot")  # fmt: skip
    if args.replot:
        if not args.plot and all(x is None for x in reads):
            raise SystemExit("--replot draws into --plot FILE or reads --at-env-steps or "
                             "--settled-from-cpu-s: give one")  # fmt: skip
        result = load_results(args.replot)
        summary: dict[str, Any] = {"benchmark": "time_to_competence_replot",
                                   "replot": args.replot, "wrote": []}  # fmt: skip
        if args.at_env_steps is not None:
            rows = laps_at_env_steps(result, parse_env_steps(args.at_env_steps), _job_tests)
            print(render_laps_at_env_steps(rows, result["track"]), file=sys.stderr)
            summary["at_env_steps"] = rows
        if args.settled_from_cpu_s is not None:
            settled = settled_laps(result, args.settled_from_cpu_s)
            print(render_settled_laps(settled, args.settled_from_cpu_s), file=sys.stderr)
            summary["settled_from_cpu_s"] = {"from_cpu_s": args.settled_from_cpu_s,
                                             "entrants": settled}  # fmt: skip
        if args.plot:
            drawn = plot_curves(result, Path(args.plot))
            for path in drawn:
                print(f"wrote {path}", file=sys.stderr)
            summary["wrote"] = [str(p) for p in drawn]
        print(json.dumps(summary))
        return
    seeds = parse_seeds(args.seeds)
    entrants = parse_entrants(args.entrants)
    anchors = [] if args.no_sb3 else parse_anchors(args.anchors)
    if anchors and importlib.util.find_spec("stable_baselines3") is None:
        print("stable-baselines3 is not installed (pip install -e '.[sb3]'): no anchors",
              file=sys.stderr)  # fmt: skip
        anchors = []
    overrides = parse_overrides(args.set)
    demo_overrides = parse_overrides(args.demos_set)
    env_overrides = parse_overrides(args.env_set)
    schedule_overrides = parse_overrides(args.schedule_set)

    from formula_tourney.sim.config import EnvSettings
    from formula_tourney.training.presets import get_preset

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
        seeds=seeds, defaults=defaults, demos=demos, anchors=anchors),
        encoding="utf-8")  # fmt: skip
    print(f"tournament {toml_path}, results under {out_root / TOURNAMENT}", file=sys.stderr)
    labels = {part_name(v, p): f"{v}:{p}" for v, p in entrants}
    preset0 = entrants[0][1] if entrants else "paper"
    anchor_labels = {part_name(anchor_variant(*a), preset0): anchor_variant(*a) for a in anchors}
    ours = run_entrants(toml_path, out_root, args.jobs, {**labels, **anchor_labels})

    anchor_results = []
    for label in anchor_labels.values():
        runs = sorted(ours[label]["runs"], key=lambda r: r["seed"])
        anchor_results.append({"label": label, "summary": summarise(runs), "runs": runs})
    goals = GOALS.get(args.track)
    if goals and args.track == "technical" and (args.reference != "recorded" or not args.lac):
        print("note: technical's goals are set for --reference recorded --lac", file=sys.stderr)
    results = []
    for variant, preset in entrants:
        label = f"{variant}:{preset}"
        mine = sorted(ours[label]["runs"], key=lambda r: r["seed"])
        s = summarise(mine)
        ratios = {a["label"]: {n: ratio(s[f"median_{n}_cpu_s"], a["summary"][f"median_{n}_cpu_s"])
                               for n in MILESTONES} for a in anchor_results}  # fmt: skip
        results.append({
            "label": label, "variant": variant, "preset": preset,
            "part": part_name(variant, preset),
            "demos": ours[label].get("demos"), "beyond_paper": ours[label].get("beyond_paper"),
            "summary": s, "ratios_vs_anchors": ratios,
            "goal_met": goal_flags(args.track, s, ratios, bool(ours[label].get("demos"))),
            "runs": mine,
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
        "goals": {kind: [g._asdict() for g in gs] for kind, gs in (goals or {}).items()},
        "entrants": results, "anchors": anchor_results, "out": str(out_root),
        "tournament": str(toml_path),
    }  # fmt: skip
    print(render(result), file=sys.stderr)
    if args.plot:
        for path in plot_curves(result, Path(args.plot)):
            print(f"wrote {path}", file=sys.stderr)
    for e in [*results, *anchor_results]:
        e["summary"] = _json_summary(e["summary"])
    print(json.dumps(result, default=_json_default, allow_nan=False))


def _json_default(x: Any) -> Any:
    if hasattr(x, "item"):
        return x.item()
    raise TypeError(f"not JSON: {type(x).__name__}")


if __name__ == "__main__":
    main()

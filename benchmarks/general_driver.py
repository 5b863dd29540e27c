"""The general driver's goal figures from a finished (or running) tournament such as
tournaments/general.toml: per run, its general model's unseen tracks lapped cleanly and how many
of those laps are within a margin of the track's reference limit, at each CPU budget asked for.

    formula-tourney run tournaments/general.toml --workers 2 --results DIR
    .venv/bin/python benchmarks/general_driver.py DIR/general [--cpu-s 300,900] [--within 1.15]

Everything comes from the report's own definitions: the tournament is read by
``report.load.load_tournament``, a run's general model is ``results.metrics.general_model`` over
its tests up to the budget (a run trained longer is read as it stood then, so one long run gives
the figures of every shorter budget), and the limits and bots are those its baselines stored.
A miss (no general model) counts as 0 tracks. Per track it also gives the fastest clean lap of
any checkpoint of any run, and against the best bot. The last line is one JSON object with the
medians over the runs and the goal: every unseen track lapped, each within 15 % of its limit.
It also gives the training CPU-s and env steps each run had reached at its last test.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

import numpy as np
import pandas as pd

from formula_tourney.errors import UserInputError
from formula_tourney.report.competence_table import part_bots
from formula_tourney.report.load import load_tournament
from formula_tourney.report.paper_tables import reference_limits
from formula_tourney.results import metrics

GOAL_WITHIN = 1.15
"""The issue's margin: a general model's lap counts when it is within 15 % of the limit."""


def finite_or_none(value: Any) -> Any:
    """``value`` with every nan or infinite float replaced by None, so the line is strict JSON."""
    if isinstance(value, dict):
        return {k: finite_or_none(v) for k, v in value.items()}
    if isinstance(value, list):
        return [finite_or_none(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def run_at_budget(tests: pd.DataFrame, train_track: str, tracks: list[str], rate: float,
                  limits: dict[str, float], cpu_s: float, within: float) -> dict[str, Any]:
    """One run's figures from its tests up to ``cpu_s`` CPU-seconds of training."""
    # the whole run needs no CPU-s column (runs before it was stored have none)
    seen = (tests if math.isinf(cpu_s)
            else tests.loc[pd.to_numeric(tests["cpu_s"], errors="coerce") <= cpu_s])
    models = metrics.model_table(seen)
    pick = metrics.general_model(models, train_track, tracks, rate)
    unseen = [t for t in tracks if t != train_track]
    fastest = {}
    for track in unseen:
        laps = models.loc[models["track"] == track, "clean_lap_s"].dropna()
        fastest[track] = float(laps.min()) if not laps.empty else math.nan
    if pick is None:
        return {"episode": None, "lapped": 0, "within": 0, "ratios": {}, "fastest_s": fastest}
    ratios = {t: metrics.limit_ratio(pick["laps"][t], limits.get(t, math.nan)) for t in unseen
              if math.isfinite(pick["laps"][t])}  # fmt: skip
    return {"episode": pick["episode"], "lapped": int(pick["unseen_lapped"]),
            "within": sum(1 for r in ratios.values() if r <= within), "ratios": ratios,
            "fastest_s": fastest}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tournament", help="the tournament's folder, RESULTS/NAME")
    ap.add_argument("--part", default=None, help="one part of the tournament (default: all)")
    ap.add_argument("--cpu-s", default="",
                    help="budgets (CPU-s of training, comma-separated) to read each run at; "
                    "default: all of each run")
    ap.add_argument("--within", type=float, default=GOAL_WITHIN,
                    help="a lap counts as near the limit at most this times the limit")
    args = ap.parse_args()
    try:
        data = load_tournament(args.tournament, args.part)
        budgets = [float(b) for b in args.cpu_s.split(",") if b.strip()] or [math.inf]
    except (UserInputError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from exc
    limits = reference_limits(data.baselines)
    if not limits:
        print("note: no baseline has stored a reference limit yet (they run after the part's "
              "jobs), so no lap is counted within the margin", file=sys.stderr)
    tests = metrics.at_grip(data.tests, 1.0)
    out: dict[str, Any] = {"benchmark": "general_driver", "tournament": str(args.tournament),
                           "within": args.within, "budgets": []}
    for budget in budgets:
        runs = []
        fastest: dict[str, list[float]] = {}
        parts: list[str] = []
        for _, job in data.jobs.sort_values(["part", "seed"]).iterrows():
            rows = tests.loc[tests["job_id"] == job["job_id"]]
            if rows.empty:
                continue
            tracks = list(dict.fromkeys(rows["track"].astype(str)))
            train = job["train_tracks"][0] if job["train_tracks"] else ""
            rate = data.unseen_finish_rate([str(job["part"])])
            fig = run_at_budget(rows, train, tracks, rate, limits, budget, args.within)
            parts.append(str(job["part"]))
            last = {col: float(pd.to_numeric(rows[col], errors="coerce").max())
                    for col in ("cpu_s", "env_steps")}  # fmt: skip
            runs.append({"job": str(job["job_id"]), "seed": int(job["seed"]),
                         "cpu_s_at_last_test": last["cpu_s"],
                         "env_steps_at_last_test": last["env_steps"], **fig})
            for t, lap in fig["fastest_s"].items():
                fastest.setdefault(t, []).append(lap)
        label = "all" if math.isinf(budget) else f"{budget:g} CPU-s"
        print(f"== {label}", file=sys.stderr)
        for run in runs:
            laps = ", ".join(f"{t} {r:.3f}" for t, r in run["ratios"].items()) or "none"
            print(f"  seed {run['seed']}: {run['lapped']} lapped, {run['within']} within "
                  f"{args.within:g} x the limit (episode {run['episode']}): {laps}; "
                  f"{run['env_steps_at_last_test']:.0f} env steps at the run's last test",
                  file=sys.stderr)
        best_any = {}
        for t, laps in fastest.items():
            # the best bot as every benchmark has it: the follower on the min-curvature line
            bots = [b.mincurv_s for p in dict.fromkeys(parts)
                    if (b := part_bots(data.baselines, p, t)) is not None]  # fmt: skip
            lap = float(np.nanmin(laps)) if np.isfinite(laps).any() else math.nan
            best_any[t] = {"lap_s": lap, "ratio": metrics.limit_ratio(lap, limits.get(t, math.nan)),
                           "runs_lapping": int(np.isfinite(laps).sum()),
                           "best_bot_s": min(bots, default=math.nan)}
            shown = (f"fastest clean lap {lap:.2f} s ({best_any[t]['ratio']:.3f} x the limit)"
                     if math.isfinite(lap) else "no clean lap")
            print(f"  {t}: {shown}, by {best_any[t]['runs_lapping']} of {len(laps)} runs; "
                  f"best bot {best_any[t]['best_bot_s']:.2f} s", file=sys.stderr)
        print(f"  training CPU-s at the runs' last tests: "
              f"{sum(r['cpu_s_at_last_test'] for r in runs):.0f}", file=sys.stderr)
        lapped = [r["lapped"] for r in runs]
        within = [r["within"] for r in runs]
        out["budgets"].append({
            "cpu_s": None if math.isinf(budget) else budget, "runs": runs,
            "median_lapped": float(np.median(lapped)) if lapped else math.nan,
            "median_within": float(np.median(within)) if within else math.nan,
            "fastest_any": best_any,
            "goal_met": bool(runs) and bool(best_any) and all(
                len(r["ratios"]) == len(best_any) and max(r["ratios"].values()) <= GOAL_WITHIN
                for r in runs),
        })
    out["goal"] = (f"every run's general model laps every unseen track, each within "
                   f"{GOAL_WITHIN} x its limit")
    print(json.dumps(finite_or_none(out)))


if __name__ == "__main__":
    main()

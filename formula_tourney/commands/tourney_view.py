"""How ``run`` and ``tune`` look in a terminal: progress bars, result tables, the plan.

The tournament code reports progress through ``tourney.scheduler.RunProgress`` and returns plain
data; this module (the CLI layer) draws both with rich.
"""

from __future__ import annotations

import json
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from formula_tourney.commands.estimate_view import render_estimate
from formula_tourney.commands.output import stderr_console, styled


class ProgressView:
    """Rich progress of a run (``tourney.scheduler.RunProgress``): one bar per worker slot plus
    an overall bar, on stderr so that ``--json`` output stays one document."""

    def __init__(self) -> None:
        self._progress: Any = None
        self._overall: Any = None
        self._slots: list[Any] = []

    def start(self, workers: int) -> None:
        self._progress = Progress(
            TextColumn("{task.description}", style="bold"), BarColumn(), MofNCompleteColumn(),
            TextColumn("{task.fields[note]}"), TimeElapsedColumn(),
            console=stderr_console, transient=False,
        )
        self._overall = self._progress.add_task("all jobs", total=0, note="")
        self._slots = [
            self._progress.add_task(f"worker {i}", total=1, note="idle") for i in range(workers)
        ]
        self._progress.start()

    def stop(self) -> None:
        if self._progress is not None:
            self._progress.stop()

    def set_total(self, total: int, done: int) -> None:
        if self._progress is not None:
            self._progress.update(self._overall, total=total, completed=done)

    def job_started(self, slot: int, job_id: str, episodes: int) -> None:
        if self._progress is not None:
            self._progress.update(self._slots[slot], description=f"w{slot} {job_id}",
                                  total=episodes, completed=0, note="")

    def job_progress(self, slot: int, info: dict[str, Any]) -> None:
        if self._progress is None:
            return
        lap = info.get("best_lap_s")
        note = f"best {lap:.2f} s" if isinstance(lap, float) and lap == lap else ""
        self._progress.update(self._slots[slot], completed=info.get("episode", 0),
                              total=info.get("episodes") or None, note=note)

    def job_ended(self, slot: int, note: str) -> None:
        if self._progress is not None:
            self._progress.update(self._slots[slot], description=f"worker {slot}", note=note)


def render_results(console: Console, result: dict[str, Any]) -> None:
    """Rich tables of a run's result: per part, entrants ranked by aLT with bLT, the gap of bLT
    to the train track's reference limit, and the finish rate."""
    if result.get("dry_run"):
        render_plan(console, result["plan"], result["results"])
        if result.get("estimate"):
            render_estimate(console, result["estimate"])
        return
    for part in result["parts"]:
        if part.get("race") is not None:
            race = part["race"]
            console.print(styled(
                (part["part"], "bold"), f" ({part['study']}, race): {part['status']}"
                + (f" - {part['reason']}" if part.get("reason") else "")
                + (f"; series {race['status']}, {race['raced']}/{race['races']} "
                   f"races of {', '.join(race['entrants'])} in {race['path']}"
                   if race.get("path") else "; waiting for its entrants")))
            continue
        table = Table(title=f"{part['part']} ({part['study']}): {part['status']}"
                      + (f" - {part['reason']}" if part.get("reason") else ""))
        limit = part.get("reference_limit_s")
        for col in ("entrant", "family", "aLT s", "bLT s", "gap", "finished", "decision"):
            table.add_column(col, justify="right" if col.endswith(("s", "finished", "gap"))
                             else "left")
        for row in part["ranking"]:
            table.add_row(
                row["entrant"], row["family"], _fmt(row["aLT"]), _fmt(row["bLT"]),
                _gap(row["bLT"], limit),
                f"{row['finished_seeds']}/{row['seeds']}", row.get("decision") or "",
            )
        for base in part.get("baselines", []):
            table.add_row(f"{base['bot']} ({base['reference']}) @{base['track']}", "bot", "",
                          _fmt(base["best_lap_s"]),
                          _gap(base["best_lap_s"], base["reference_limit_s"]),
                          "yes" if base["finished"] else base["status"],
                          f"limit {_fmt(base['reference_limit_s'])}")
        console.print(table)
    for lost in result.get("lost") or []:
        console.print(styled(("lost", "yellow"),
                             f" {lost['job_id']}: done in the index, but {lost['reason']}; "
                             f"{lost['action']}"))
    for fail in result["failures"]:
        console.print(styled(("failed", "red"), f" {fail['job_id']}: {fail['reason']}"))
    if "wall_s" in result:
        run = result["this_run"]
        console.print(
            f"{result['results']}: {run['done']} jobs done, {run['failed']} failed, "
            f"{run['skipped']} already done"
            + (f", {run['recovered']} recovered from their folders" if run.get("recovered") else "")
            + (f", {run['reopened']} parts re-opened" if run.get("reopened") else "")
            + (f", {run['lost']} found lost (listed above)" if run.get("lost") else "")
            + f", in {result['wall_s']:.1f} s on "
            f"{result['workers']} {result['executor']} workers"
        )



def budget_text(env_steps: int | None) -> str:
    """The part's env-step budget, if it has one (an entrant's own is shown beside it)."""
    return "" if env_steps is None else f", at most {env_steps} env steps"

def render_plan(console: Console, plan: dict[str, Any], results: str) -> None:
    """The dry-run view: one short block per part (fits a narrow terminal)."""
    console.print(styled((f"plan of {plan['tournament']}", "bold"), f" -> {results}/"
                         f"  ({plan['known_jobs']} jobs known now; promoted parts add theirs "
                         "later)"))
    if plan.get("description"):
        console.print(f"  {plan['description']}")
    for part in plan["parts"]:
        if part.get("kind") == "race":
            _render_race_plan(console, part)
            continue
        if "entrants" in part:
            who = f"{len(part['entrants'])} entrants ({', '.join(part['entrants'])})"
            jobs = f"= {part['jobs']} jobs"
        else:
            who = f"promoted from {part['promoted_from']} ({part['rule']})"
            jobs = f"= {part['jobs_per_entrant']} jobs per promoted variant"
        console.print(styled((part["part"], "bold"), f" (study {part['study']}): {who}"))
        console.print(f"    x setups {', '.join(part['setups'])} x {part['seeds']} seeds {jobs}")
        console.print(
            f"    train {', '.join(part['train_tracks'])}; test {', '.join(part['test_tracks'])}"
            f" every {part['test_every_episodes']} episodes; "
            f"{part['episodes']} episodes x {part['max_steps']} steps"
            f"{budget_text(part.get('env_steps'))};"
            f" selection {part['selection']}"
        )
        for entrant, own in (part.get("entrant_settings") or {}).items():
            pairs = ", ".join(f"{k}={json.dumps(v)}" for k, v in own.items())
            console.print(f"    {entrant} sets {pairs} (its entry wins)")
        if part.get("env_overrides"):
            console.print(f"    env {json.dumps(part['env_overrides'])}")
        if part["baselines"]:
            console.print(f"    baselines {', '.join(part['baselines'])}")


def _render_race_plan(console: Console, part: dict[str, Any]) -> None:
    """A race part in the plan: who races (promoted entrants' best seeds, bots), how often and
    how long: one race job once its source part has promoted."""
    bots = part.get("race_bots") or []
    console.print(styled((part["part"], "bold"), f" (study {part['study']}, race): "
                         f"promoted from {part['promoted_from']} ({part['rule']})"
                         f" x setups {', '.join(part['setups'])}, each with its best seed's "
                         "model" + (f", + bots {', '.join(bots)}" if bots else "")))
    points = "-".join(f"{p:g}" for p in part.get("race_points") or [])
    console.print(
        f"    {part['races']} races x {part['race_laps']} laps of {part['train_tracks'][0]}; "
        f"{part['race_start']} start, grid by {part['race_grid']} (rotated each race); "
        f"points {points}; contact {'on' if part.get('race_contact') else 'off'}"
        "; = 1 race job after promotion"
    )


def _gap(lap_s: Any, limit_s: Any) -> str:
    """Gap of a lap to the track's reference limit (QSS lap on the min-curvature line)."""
    if lap_s is None or limit_s is None or lap_s != lap_s or not limit_s:
        return "-"
    return f"+{100.0 * (float(lap_s) / float(limit_s) - 1.0):.1f}%"


def _fmt(value: Any) -> str:
    if value is None:
        return "-"
    try:
        value = float(value)
    except (TypeError, ValueError):
        return str(value)
    return "-" if value != value else f"{value:.2f}"


def render_tune(console: Console, result: dict[str, Any]) -> None:
    """The trials of a study (state, objective, parameters) and the best one."""
    table = Table(title=f"{result['study']} ({result['storage']})")
    for col in ("trial", "state", "objective s", "params"):
        table.add_column(col)
    for row in result["trials"]:
        value = "-" if row["value"] is None else f"{row['value']:.2f}"
        table.add_row(str(row["number"]), row["state"], value, json.dumps(row["params"]))
    console.print(table)
    if result["best"]:
        console.print(f"best: trial {result['best']['number']} {result['best']['params']}")
    if result.get("written_to"):
        console.print(f"written to {result['written_to']}")

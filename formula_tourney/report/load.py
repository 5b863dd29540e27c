"""Read one tournament folder (index.sqlite + job folders) into frames, tolerating gaps.

The report reads files only, and only through the results layout's readers: the index through
``results.index.read_index`` and each job folder through ``results.folder.JobFolder`` (baseline
drives through ``BaselineFolder``), so it never imports the runner and a half-finished or partly
failed tournament still renders. Every gap (a failed job, a job still pending, a part with no
jobs, a file that cannot be read, a folder of another layout version) becomes a line in
``TournamentData.problems`` naming what is missing, instead of an exception.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from formula_tourney.errors import UserInputError
from formula_tourney.results import layout as L
from formula_tourney.results.folder import (
    BaselineFolder,
    CorruptResultError,
    JobFolder,
    OldSchemaError,
)
from formula_tourney.results.index import read_index, read_meta, rows_of_kind
from formula_tourney.tourney.kinds import BASELINE, TRAIN
from formula_tourney.tourney.spec import Selection

JOB_TABLE_NAMES = ("tests", "episodes", "laps")
GRIP_TESTS = "grip_tests"
"""The tests at every grip a run tested at (``schedule.test_grip_scales``); ``tests`` holds
those at the run's own grip, which every other table and figure reads."""
# Columns copied from the job index onto every row of a job's tables, so that one concatenated
# frame can be grouped by part/entrant/seed without joins.
JOB_KEYS = ["job_id", "part", "entrant", "variant", "family", "seed", "reference", "lac"]
DEFAULT_UNSEEN_FINISH_RATE = float(Selection.model_fields["min_unseen_finish_rate"].default)
"""The tournament spec's default share of starts a general model finishes on each unseen track,
used for parts whose stored spec does not say."""


@dataclass
class TournamentData:
    """Everything the report needs from one tournament, already concatenated over jobs."""

    root: Path
    name: str
    jobs: pd.DataFrame
    parts: pd.DataFrame
    baselines: pd.DataFrame
    tests: pd.DataFrame
    episodes: pd.DataFrame
    laps: pd.DataFrame
    general_models: pd.DataFrame = field(default_factory=lambda: pd.DataFrame(
        columns=L.INDEX_TABLES["general_models"]))
    grip_tests: pd.DataFrame = field(default_factory=lambda: pd.DataFrame(
        columns=L.JOB_TABLES["tests"]))
    """Tests at every grip a run tested at, each row with its grip and the limit there."""
    configs: dict[str, dict[str, Any]] = field(default_factory=dict)
    beyond_paper: dict[str, list[str]] = field(default_factory=dict)
    """Per job, what its run adds to the paper's setup (labelled in every table)."""
    """Run specification (config.json's ``run_spec``) per job id."""
    problems: list[str] = field(default_factory=list)
    unseen_finish_rates: dict[str, float] = field(default_factory=dict)
    """Per part, the tournament's ``selection.min_unseen_finish_rate`` (from the stored spec)."""

    def part_order(self) -> list[str]:
        """Parts in tournament order: the ``parts`` table's position, then any part seen in jobs."""
        order: list[str] = []
        if not self.parts.empty:
            ordered = self.parts.sort_values("position", kind="stable")
            order = [str(p) for p in ordered["part"]]
        for part in self.jobs["part"].astype(str):
            if part not in order:
                order.append(part)
        return order

    def job_dir(self, job_id: str) -> Path:
        """Folder of one job (the index's relative ``path``, else the layout's default)."""
        row = self.jobs.loc[self.jobs["job_id"] == job_id]
        rel = str(row["path"].iloc[0]) if not row.empty and _present(row["path"].iloc[0]) \
            else job_id
        return self.root / rel

    def read_trace(self, job_id: str, track: str) -> pd.DataFrame | None:
        """The best clean test lap's trace, or None when the job wrote none for this track (an
        unreadable one is a problem)."""
        try:
            return JobFolder(self.job_dir(job_id)).trace(track)
        except CorruptResultError as err:
            self.problems.append(f"{job_id}: {err}")
            return None

    def read_baseline_trace(self, rel_path: str) -> pd.DataFrame | None:
        """A baseline drive's lap trace (``baselines.path`` relative to the root), or None."""
        try:
            return BaselineFolder(self.root / rel_path).trace()
        except CorruptResultError as err:
            self.problems.append(f"baseline: {err}")
            return None

    def unseen_finish_rate(self, parts: Iterable[str]) -> float:
        """The general-model selection rule's finish rate of these parts (the strictest)."""
        rates = [self.unseen_finish_rates.get(str(p), DEFAULT_UNSEEN_FINISH_RATE) for p in parts]
        return max(rates, default=DEFAULT_UNSEEN_FINISH_RATE)


def resolve_tournament(tournament: str | None, results_dir: str | Path = "results") -> Path:
    """Turn ``--tournament NAME|PATH`` into a folder holding ``index.sqlite``.

    With no name, the only tournament under ``results_dir`` is taken, or the one written most
    recently, so that ``formula-tourney report`` right after ``run`` does what a user expects.
    """
    results = Path(results_dir)
    if tournament:
        as_path = Path(tournament)
        if (as_path / L.INDEX_FILE).is_file():
            return as_path
        if as_path.name == L.INDEX_FILE and as_path.is_file():
            return as_path.parent
        candidate = results / tournament
        if (candidate / L.INDEX_FILE).is_file():
            return candidate
        known = _known_tournaments(results)
        hint = f"; known under {results}: {', '.join(known)}" if known else ""
        raise UserInputError(
            f"no tournament {tournament!r}: neither {as_path} nor {candidate} holds an "
            f"index.sqlite{hint}"
        )
    known = _known_tournaments(results)
    if not known:
        raise UserInputError(
            f"no tournament results under {results}: run `formula-tourney run` first or pass "
            "--tournament PATH"
        )
    return max((results / k for k in known), key=lambda p: (p / L.INDEX_FILE).stat().st_mtime)


def _known_tournaments(results: Path) -> list[str]:
    if not results.is_dir():
        return []
    return sorted(p.name for p in results.iterdir() if (p / L.INDEX_FILE).is_file())


def _json_list(value: Any) -> list[Any]:
    if isinstance(value, list):
        return value
    if not _present(value):
        return []
    try:
        parsed = json.loads(str(value))
    except (TypeError, ValueError):
        return [str(value)] if str(value) else []
    return parsed if isinstance(parsed, list) else [parsed]


def _bool(value: Any) -> bool:
    if isinstance(value, str):
        return value.strip().lower() in {"1", "true", "yes"}
    try:
        return bool(value) and value == value
    except (TypeError, ValueError):
        return False


def _finish_rates(meta: dict[str, str]) -> dict[str, float]:
    """Each part's ``selection.min_unseen_finish_rate`` from the spec the tournament stored."""
    try:
        spec = json.loads(meta.get("spec") or "{}")
    except ValueError:
        return {}
    declared = spec.get("parts") if isinstance(spec, dict) else None
    rates: dict[str, float] = {}
    for part in declared if isinstance(declared, list) else []:
        if not isinstance(part, dict):
            continue
        rate = (part.get("selection") or {}).get("min_unseen_finish_rate")
        if isinstance(part.get("name"), str) and isinstance(rate, int | float):
            rates[part["name"]] = float(rate)
    return rates


def _read_job(folder: JobFolder, job_id: str, problems: list[str]
              ) -> tuple[dict[str, Any] | None, list[str], dict[str, pd.DataFrame]]:
    """A job folder's run spec, what it adds to the paper's setup and the tables it wrote; what
    cannot be read is a problem line.

    A folder of another layout version is not read at all: its columns may mean other things.
    """
    spec: dict[str, Any] | None = None
    beyond: list[str] = []
    try:
        spec = folder.config()
        beyond = folder.beyond_paper()
    except FileNotFoundError:
        pass  # not started yet, or failed before writing anything
    except OldSchemaError as err:
        problems.append(f"{job_id}: written by another version; cannot read ({err})")
        return None, [], {}
    except CorruptResultError as err:
        problems.append(f"{job_id}: {err}")
    tables: dict[str, pd.DataFrame] = {}
    for name in JOB_TABLE_NAMES:
        if not folder.table_path(name).is_file():
            continue
        try:
            tables[name] = folder.table(name)
            if name == "tests":  # every grip for the per-grip tables; the own grip elsewhere
                tables[GRIP_TESTS] = tables[name]
            if name in ("tests", "laps"):
                tables[name] = folder.at_own_grip(tables[name])
        except CorruptResultError as err:
            problems.append(f"{job_id}: {err}")
    return spec, beyond, tables


def load_tournament(root: str | Path, part: str | None = None) -> TournamentData:
    """Read a tournament folder: the index, then every job folder's tables that exist.

    ``part`` restricts jobs (and baselines) to one part; an unknown part is a UserInputError that
    lists the known ones. A missing index is a UserInputError, a garbage one a
    CorruptResultError naming the file. Jobs that failed, are pending, or are marked done but
    lack their files are listed in ``problems``; their partial tables (a failed job's tests so
    far) still count, because a report of what exists is more useful than none.
    """
    root = Path(root)
    problems: list[str] = []
    index = read_index(root, problems)
    rates = _finish_rates(read_meta(root))
    jobs = rows_of_kind(index["jobs"], TRAIN.name, TRAIN.columns)
    baselines = rows_of_kind(index["jobs"], BASELINE.name, BASELINE.columns)
    parts, general = index["parts"].copy(), index["general_models"].copy()
    general["chosen"] = general["chosen"].map(_bool).astype(bool)
    general["episode"] = pd.to_numeric(general["episode"], errors="coerce")
    general["train_lap_s"] = pd.to_numeric(general["train_lap_s"], errors="coerce")

    jobs["seed"] = pd.to_numeric(jobs["seed"], errors="coerce").fillna(-1).astype(int)
    jobs["lac"] = jobs["lac"].map(_bool).astype(bool)
    jobs["train_tracks"] = jobs["train_tracks"].map(_json_list)
    jobs["reference"] = jobs["reference"].fillna("centre").astype(str)
    jobs["variant"] = jobs["variant"].where(jobs["variant"].notna(), jobs["entrant"]).astype(str)
    jobs["family"] = jobs["family"].where(jobs["family"].notna(), jobs["variant"]).astype(str)
    jobs["part"] = jobs["part"].astype(str)
    jobs["status"] = jobs["status"].fillna("pending").astype(str)
    parts["entrants"] = parts["entrants"].map(_json_list)
    parts["promoted"] = parts["promoted"].map(_json_list)
    parts["position"] = pd.to_numeric(parts["position"], errors="coerce")
    parts["part"] = parts["part"].astype(str)
    for col in ("best_lap_s", "damage", "reference_limit_s"):
        baselines[col] = pd.to_numeric(baselines[col], errors="coerce")
    baselines["finished"] = baselines["finished"].map(_bool).astype(bool)
    baselines["part"] = baselines["part"].astype(str)

    known_parts = list(dict.fromkeys([*parts["part"].tolist(), *jobs["part"].tolist()]))
    if part is not None:
        if part not in known_parts:
            raise UserInputError(
                f"{root}: no part {part!r}; known parts: {', '.join(known_parts) or '(none)'}"
            )
        jobs = jobs.loc[jobs["part"] == part].reset_index(drop=True)
        parts = parts.loc[parts["part"] == part].reset_index(drop=True)
        baselines = baselines.loc[baselines["part"] == part].reset_index(drop=True)
        general = general.loc[general["part"].astype(str) == part].reset_index(drop=True)

    for _, prow in parts.iterrows():
        n_jobs = int((jobs["part"] == prow["part"]).sum())
        if prow["status"] == "failed":
            reason = prow["reason"] if _present(prow["reason"]) else "no reason recorded"
            problems.append(f"part {prow['part']}: failed ({reason})")
        elif n_jobs == 0:
            problems.append(
                f"part {prow['part']}: no jobs in the index (status {prow['status']}); "
                "nothing to report for it yet"
            )

    for _, brow in baselines.iterrows():
        if str(brow["status"]) in ("failed", "pending", "running"):
            reason = f" ({brow['reason']})" if _present(brow["reason"]) else ""
            problems.append(f"baseline {brow['bot']} on {brow['track']} ({brow['part']}): "
                            f"{brow['status']}{reason}")

    frames: dict[str, list[pd.DataFrame]] = {name: [] for name in (*JOB_TABLE_NAMES, GRIP_TESTS)}
    configs: dict[str, dict[str, Any]] = {}
    beyond: dict[str, list[str]] = {}
    for _, job in jobs.iterrows():
        job_id = str(job["job_id"])
        folder = JobFolder(root / (str(job["path"]) if _present(job["path"]) else job_id))
        status = job["status"]
        if status == "failed":
            reason = job["reason"] if _present(job["reason"]) else "no reason recorded"
            problems.append(f"{job_id}: failed ({reason}); partial results used if any")
        elif status in ("pending", "running"):
            problems.append(f"{job_id}: {status}; not finished")
        spec, beyond[job_id], tables = _read_job(folder, job_id, problems)
        if spec is not None:
            configs[job_id] = spec
        for name, frame in tables.items():
            frame = frame.copy()
            for key in JOB_KEYS:
                frame[key] = job[key]
            frames[name].append(frame)
        if status == "done" and not folder.table_path("tests").is_file():
            problems.append(f"{job_id}: marked done but {folder.path} has no tests.parquet "
                            "(missing)")

    def concat(name: str) -> pd.DataFrame:
        parts_ = [f for f in frames[name] if not f.empty]
        if not parts_:
            layout = L.JOB_TABLES["tests" if name == GRIP_TESTS else name]
            return pd.DataFrame(columns=[*layout, *JOB_KEYS])
        return pd.concat(parts_, ignore_index=True)

    def tests_frame(name: str) -> pd.DataFrame:
        frame = concat(name)
        for col in ("best_lap_s", "damage", "episode", "start_s_m", "distance_m", "grip_scale",
                    "reference_limit_s"):
            frame[col] = pd.to_numeric(frame[col], errors="coerce")
        frame["finished"] = frame["finished"].map(_bool).astype(bool)
        return frame

    tests = tests_frame("tests")
    grip_tests = tests_frame(GRIP_TESTS)
    episodes = concat("episodes")
    for col in ("episode", "reward", "best_lap_s", "damage", "env_steps"):
        episodes[col] = pd.to_numeric(episodes[col], errors="coerce")
    laps = concat("laps")
    return TournamentData(
        root=root, name=root.name, jobs=jobs, parts=parts, baselines=baselines, tests=tests,
        episodes=episodes, laps=laps, general_models=general, grip_tests=grip_tests,
        configs=configs,
        beyond_paper=beyond,
        problems=problems, unseen_finish_rates=rates,
    )


def _present(value: Any) -> bool:
    if value is None:
        return False
    if isinstance(value, float) and value != value:
        return False
    return str(value) != "" and value is not pd.NA

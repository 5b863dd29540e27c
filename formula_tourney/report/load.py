"""Read one tournament folder (index.sqlite + job folders) into frames, tolerating gaps.

The report reads files only (docs/CONTRACTS.md, "tourney store" and "training (one run)"): it
never imports the runner, so a half-finished or partly failed tournament still renders. Every gap
(a failed job, a job still pending, a part with no jobs, a table that cannot be read) becomes a
line in ``TournamentData.problems`` instead of an exception.
"""

from __future__ import annotations

import json
import re
import sqlite3
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from formula_tourney.errors import UserInputError

JOB_COLUMNS = [
    "job_id", "study", "part", "entrant", "variant", "family", "seed", "reference", "lac",
    "train_tracks", "status", "reason", "attempts", "path", "started_at", "finished_at", "wall_s",
]
PART_COLUMNS = ["part", "study", "position", "status", "entrants", "promoted", "reason"]
BASELINE_COLUMNS = [
    "part", "bot", "track", "reference", "best_lap_s", "damage", "finished", "reference_limit_s",
    "status", "reason", "path",
]
GENERAL_COLUMNS = [
    "part", "job_id", "entrant", "seed", "episode", "checkpoint", "train_track", "train_lap_s",
    "laps", "chosen",
]
TEST_COLUMNS = [
    "episode", "env_steps", "track", "start_s_m", "finished", "best_lap_s", "laps", "damage",
    "reward", "steps", "termination", "checkpoint",
]
EPISODE_COLUMNS = [
    "episode", "track", "reward", "steps", "env_steps", "updates", "laps", "best_lap_s", "damage",
    "termination", "epsilon", "seconds",
]
LAP_COLUMNS = ["episode", "track", "start_s_m", "lap_index", "lap_time_s", "lap_damage", "clean"]
# Columns copied from the job index onto every row of a job's tables, so that one concatenated
# frame can be grouped by part/entrant/seed without joins.
JOB_KEYS = ["job_id", "part", "entrant", "variant", "family", "seed", "reference", "lac"]


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
        columns=GENERAL_COLUMNS))
    configs: dict[str, dict[str, Any]] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)

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
        """Folder of one job (the index's relative ``path``, else the contract's default)."""
        row = self.jobs.loc[self.jobs["job_id"] == job_id]
        rel = str(row["path"].iloc[0]) if not row.empty and _present(row["path"].iloc[0]) \
            else job_id
        return self.root / rel

    def trace_path(self, job_id: str, track: str) -> Path:
        """Where the job's best clean test lap on ``track`` is stored (may not exist)."""
        # the same file-name rule as training.loop._trace_name (a track may be a path)
        name = re.sub(r"[^A-Za-z0-9_.+-]", "_", str(track))[:100] or "track"
        return self.job_dir(job_id) / "traces" / f"{name}.parquet"

    def read_trace(self, job_id: str, track: str) -> pd.DataFrame | None:
        """The best clean test lap's trace, or None when the job wrote none for this track."""
        path = self.trace_path(job_id, track)
        if not path.is_file():
            return None
        try:
            return pd.read_parquet(path)
        except Exception as exc:  # a corrupt file is a report problem, not a crash
            self.problems.append(f"{job_id}: cannot read {path.name} ({exc})")
            return None


def resolve_tournament(tournament: str | None, results_dir: str | Path = "results") -> Path:
    """Turn ``--tournament NAME|PATH`` into a folder holding ``index.sqlite``.

    With no name, the only tournament under ``results_dir`` is taken, or the one written most
    recently, so that ``formula-tourney report`` right after ``run`` does what a user expects.
    """
    results = Path(results_dir)
    if tournament:
        as_path = Path(tournament)
        if (as_path / "index.sqlite").is_file():
            return as_path
        if as_path.name == "index.sqlite" and as_path.is_file():
            return as_path.parent
        candidate = results / tournament
        if (candidate / "index.sqlite").is_file():
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
    return max((results / k for k in known), key=lambda p: (p / "index.sqlite").stat().st_mtime)


def _known_tournaments(results: Path) -> list[str]:
    if not results.is_dir():
        return []
    return sorted(p.name for p in results.iterdir() if (p / "index.sqlite").is_file())


def _read_sql_table(db: Path, table: str, columns: list[str], problems: list[str],
                    optional: bool = False) -> pd.DataFrame:
    """One table of the index, read-only; a missing table yields an empty frame and a problem
    (no problem for ``optional`` tables, which older or foreign stores may lack)."""
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    except sqlite3.Error as exc:
        raise UserInputError(f"{db}: cannot open the results index ({exc})") from exc
    try:
        frame = pd.read_sql_query(f"SELECT * FROM {table}", con)  # noqa: S608 (fixed names)
    except (sqlite3.Error, pd.errors.DatabaseError) as exc:
        if not optional:
            problems.append(f"index.sqlite: table {table!r} unreadable ({exc})")
        frame = pd.DataFrame(columns=columns)
    finally:
        con.close()
    for col in columns:
        if col not in frame.columns:
            frame[col] = pd.NA
    return frame


def _json_list(value: Any) -> list[Any]:
    if isinstance(value, list):
        return value
    if value is None or (isinstance(value, float) and value != value):
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


def _read_job_table(path: Path, columns: list[str], what: str, job_id: str,
                    problems: list[str]) -> pd.DataFrame | None:
    if not path.is_file():
        return None
    try:
        frame = pd.read_parquet(path)
    except Exception as exc:
        problems.append(f"{job_id}: cannot read {what} ({exc})")
        return None
    for col in columns:
        if col not in frame.columns:
            frame[col] = pd.NA
    return frame


def load_tournament(root: str | Path, part: str | None = None) -> TournamentData:
    """Read a tournament folder: the index, then every job's parquet files that exist.

    ``part`` restricts jobs (and baselines) to one part; an unknown part is a UserInputError that
    lists the known ones. Jobs that failed, are pending, or are marked done but lack their files
    are listed in ``problems``; their partial tables (a failed job's tests so far) still count,
    because a report of what exists is more useful than none.
    """
    root = Path(root)
    db = root / "index.sqlite"
    if not db.is_file():
        raise UserInputError(f"{root}: no index.sqlite (not a tournament results folder)")
    problems: list[str] = []
    jobs = _read_sql_table(db, "jobs", JOB_COLUMNS, problems)
    parts = _read_sql_table(db, "parts", PART_COLUMNS, problems)
    baselines = _read_sql_table(db, "baselines", BASELINE_COLUMNS, problems)
    general = _read_sql_table(db, "general_models", GENERAL_COLUMNS, problems, optional=True)
    general["chosen"] = general["chosen"].map(_bool).astype(bool)
    general["episode"] = pd.to_numeric(general["episode"], errors="coerce")

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

    tables: dict[str, list[pd.DataFrame]] = {"tests": [], "episodes": [], "laps": []}
    specs = {"tests": TEST_COLUMNS, "episodes": EPISODE_COLUMNS, "laps": LAP_COLUMNS}
    configs: dict[str, dict[str, Any]] = {}
    for _, job in jobs.iterrows():
        job_id = str(job["job_id"])
        job_dir = root / (str(job["path"]) if _present(job["path"]) else job_id)
        status = job["status"]
        if status == "failed":
            reason = job["reason"] if _present(job["reason"]) else "no reason recorded"
            problems.append(f"{job_id}: failed ({reason}); partial results used if any")
        elif status in ("pending", "running"):
            problems.append(f"{job_id}: {status}; not finished")
        config_path = job_dir / "config.json"
        if config_path.is_file():
            try:
                configs[job_id] = json.loads(config_path.read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                problems.append(f"{job_id}: cannot read config.json ({exc})")
        found_any = False
        for name, frames in tables.items():
            frame = _read_job_table(job_dir / f"{name}.parquet", specs[name], name, job_id,
                                    problems)
            if frame is None:
                continue
            found_any = True
            for key in JOB_KEYS:
                frame[key] = job[key]
            frames.append(frame)
        if status == "done" and not (job_dir / "tests.parquet").is_file():
            problems.append(f"{job_id}: marked done but {job_dir} has no tests.parquet (missing)")
        elif status == "done" and not found_any:
            problems.append(f"{job_id}: marked done but its folder has no results (missing)")

    def concat(name: str) -> pd.DataFrame:
        frames = [f for f in tables[name] if not f.empty]
        if not frames:
            return pd.DataFrame(columns=[*specs[name], *JOB_KEYS])
        return pd.concat(frames, ignore_index=True)

    tests = concat("tests")
    for col in ("best_lap_s", "damage", "episode", "start_s_m"):
        tests[col] = pd.to_numeric(tests[col], errors="coerce")
    tests["finished"] = tests["finished"].map(_bool).astype(bool)
    episodes = concat("episodes")
    for col in ("episode", "reward", "best_lap_s", "damage", "env_steps"):
        episodes[col] = pd.to_numeric(episodes[col], errors="coerce")
    laps = concat("laps")
    return TournamentData(
        root=root, name=root.name, jobs=jobs, parts=parts, baselines=baselines, tests=tests,
        episodes=episodes, laps=laps, general_models=general, configs=configs,
        problems=problems,
    )


def _present(value: Any) -> bool:
    if value is None:
        return False
    if isinstance(value, float) and value != value:
        return False
    return str(value) != "" and value is not pd.NA

"""File names, column lists, schema version and SQL schema of a results folder.

Layout::

    <tournament>/index.sqlite                          the index (written by the parent only)
    <tournament>/.lock                                 held by the running ``run``
    <tournament>/estimate.json                         the cost estimate of ``run --estimate``
    <tournament>/adaptive.json                         a sequential run's waves and decisions
    <tournament>/<part>/<entrant>/seed-<n>/            one training job (a job folder)
    <tournament>/<part>/_baselines/<bot>-<ref>-<track>/  one baseline drive
    <tournament>/<part>/_races/                        a race part's (or `race --races`) races
    <tournament>/optuna/<variant>.journal              tune studies
    <tournament>/_submitit/                            submitit's job files (--executor slurm)

A job folder: ``config.json`` (schema version + run spec), ``episodes.parquet``,
``tests.parquet``, ``laps.parquet``, ``traces/<track>.parquet``, ``checkpoints/``, ``tb/``,
``tourney.json`` (who the job is in its tournament), ``error.txt`` (a failed attempt's reason) and
``summary.json`` written last: its presence means finished.
"""

from __future__ import annotations

import re

SCHEMA_VERSION = 2
"""Version of the job-folder layout written into config.json. 1: the unversioned layout before
the run specification (flat TrainConfig, no distance_m in tests.parquet). A column added within
a version goes to :data:`ADDED_COLUMNS`: files written before it still read (the reader fills
it in), and older readers ignore it, so the version only moves when a column changes meaning."""

CONFIG_FILE = "config.json"
SUMMARY_FILE = "summary.json"
TOURNEY_META_FILE = "tourney.json"
ERROR_FILE = "error.txt"
TRACES_DIR = "traces"
CHECKPOINTS_DIR = "checkpoints"
TB_DIR = "tb"
BEST_CHECKPOINT = "best.pt"
LAST_CHECKPOINT = "last.pt"
RESUME_FILE = "resume.pt"
"""An unfinished training job's whole state (``training.resume``): a re-run continues from it,
a finished job deletes it."""

INDEX_FILE = "index.sqlite"
ESTIMATE_FILE = "estimate.json"
ADAPTIVE_FILE = "adaptive.json"
"""A sequential run's design, its waves (seeds per entrant, the claims as read) and why it
stopped (``tourney.adaptive``)."""
"""The cost estimate ``run --estimate`` measured before the tournament's first run (kept on
resume), which the report sets against the measured cost."""
LOCK_FILE = ".lock"
BASELINE_DIR = "_baselines"
BASELINE_RESULT_FILE = "result.json"
BASELINE_TRACE_FILE = "trace.parquet"
OPTUNA_DIR = "optuna"
SUBMITIT_DIR = "_submitit"
"""submitit's files of ``run --executor slurm``: each job's pickled call, its result, and the
Slurm log of each task (``<jobid>_0_log.out`` / ``.err``)."""
RACES_DIR = "_races"
"""A series of races (a race part, or ``race --races N --out DIR``): ``race-<k>.json`` per race
(``RaceResult.to_json``, k from 0), then ``series.json`` (track, settings, seed, entrants and
their checkpoints) written last: its presence means finished. The report's outputs beside them:
``standings.json`` and ``standings.md`` (``report.race_standings``) and
``figures/race-<k>-positions.png`` / ``-gaps.png`` (``report.race_figures``)."""
RACE_SERIES_FILE = "series.json"
RACE_QUALIFYING_FILE = "qualifying.json"
"""A tournament's race series: the qualifying laps and base grid, written before race 0 with
the race job's config hash, so a resumed series keeps its grid and its finished races (and a
series of other entrants or settings starts afresh)."""
RACE_STANDINGS_FILE = "standings.json"
RACE_STANDINGS_MD = "standings.md"
RACE_FIGURES_DIR = "figures"
RACE_FILE_RE = re.compile(r"^race-(\d+)\.json$")

JOB_TABLES: dict[str, list[str]] = {
    "episodes": [
        "episode", "track", "reward", "steps", "env_steps", "updates", "laps", "best_lap_s",
        "damage", "termination", "epsilon", "seconds",
    ],
    "tests": [
        "episode", "env_steps", "track", "start_s_m", "finished", "best_lap_s", "laps", "damage",
        "reward", "steps", "termination", "checkpoint", "distance_m", "grip_scale",
        "reference_limit_s", "cpu_s",
    ],
    "laps": [
        "episode", "track", "start_s_m", "lap_index", "lap_time_s", "lap_damage", "clean",
        "grip_scale",
    ],
}  # fmt: skip
"""Columns of each job table, in order (docs/CONTRACTS.md, "training (one run)")."""

ADDED_COLUMNS: dict[str, tuple[str, ...]] = {
    "tests": ("grip_scale", "reference_limit_s", "cpu_s"),
    "laps": ("grip_scale",),
}
"""Columns added within layout 2, which files written before them lack: a test then ran at its
run's env ``grip_scale`` (grip as an axis, docs/report.md), its reference limit was not stored
(nan), nor the CPU-seconds the run had spent when the test round ended (``cpu_s``, nan; time to
competence, ``results.competence``). ``results.folder.JobFolder`` fills them in when it reads
such a file."""

TRACE_COLUMNS = [
    "time_s", "distance_m", "s_m", "lateral_m", "x_m", "y_m", "speed_kmh", "steer", "throttle",
    "brake",
]  # fmt: skip

INDEX_TABLES: dict[str, list[str]] = {
    "jobs": [
        "job_id", "kind", "part", "position", "status", "reason", "attempts", "path",
        "started_at", "finished_at", "wall_s", "config_hash", "worker_pid", "attrs", "result",
    ],
    "parts": [
        "part", "study", "position", "status", "entrants", "promoted", "reason", "ranking",
        "source",
    ],
    "general_models": [
        "part", "job_id", "entrant", "seed", "episode", "checkpoint", "train_track",
        "train_lap_s", "laps", "chosen",
    ],
}  # fmt: skip
"""Columns of each index table. ``jobs`` holds every job of every kind (a training run, a
baseline drive, a race series, ...), one row per job id, like Optuna's trials table: the
columns every kind shares, ``kind`` naming its ``tourney.kinds`` object, and two JSON objects
whose keys that object declares: ``attrs`` (who the job is: entrant, seed, bot, track, ...) and
``result`` (what it recorded when it finished: best lap, damage, ...). Readers see ``attrs`` and
``result`` spread into columns (``results.index.read_index``)."""

JOB_JSON_COLUMNS = ("attrs", "result")
"""The ``jobs`` columns that hold a JSON object of kind-specific keys."""

INDEX_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS jobs (
    job_id TEXT PRIMARY KEY, kind TEXT NOT NULL, part TEXT, position INTEGER,
    status TEXT NOT NULL DEFAULT 'pending', reason TEXT, attempts INTEGER NOT NULL DEFAULT 0,
    path TEXT, started_at TEXT, finished_at TEXT, wall_s REAL, config_hash TEXT,
    worker_pid INTEGER, attrs TEXT NOT NULL DEFAULT '{}', result TEXT
);
CREATE INDEX IF NOT EXISTS jobs_by_part ON jobs (part, kind);
CREATE TABLE IF NOT EXISTS parts (
    part TEXT PRIMARY KEY, study TEXT, position INTEGER, status TEXT NOT NULL DEFAULT 'pending',
    entrants TEXT, promoted TEXT, reason TEXT, ranking TEXT, source TEXT
);
CREATE TABLE IF NOT EXISTS general_models (
    part TEXT, job_id TEXT PRIMARY KEY, entrant TEXT, seed INTEGER, episode INTEGER,
    checkpoint TEXT, train_track TEXT, train_lap_s REAL, laps TEXT, chosen INTEGER
);
"""

LEGACY_JOB_TABLES: dict[str, list[str]] = {
    "jobs": [
        "job_id", "study", "part", "entrant", "variant", "family", "seed", "reference", "lac",
        "train_tracks", "status", "reason", "attempts", "path", "started_at", "finished_at",
        "wall_s", "position", "config_hash", "worker_pid", "best_lap_s", "finished", "damage",
        "train_seconds", "test_distance_m",
    ],
    "baselines": [
        "part", "bot", "track", "reference", "best_lap_s", "damage", "finished",
        "reference_limit_s", "status", "reason", "path",
    ],
    "races": [
        "part", "track", "races", "entrants", "status", "reason", "attempts", "path",
        "started_at", "finished_at", "wall_s", "config_hash",
    ],
}  # fmt: skip
"""The index before the one ``jobs`` table: a table per job kind (training jobs in ``jobs``
without a ``kind`` column, ``baselines`` keyed by part, bot, track and reference, ``races`` by
part). ``results.index`` reads such an index as if it were the current one, and
``tourney.store.Store`` migrates it in place when a run resumes it."""

JOB_STATUSES = ("pending", "running", "done", "failed")


def job_rel_path(part: str, entrant: str, seed: int) -> str:
    """Job folder relative to the tournament root; equal to the job id."""
    return f"{part}/{entrant}/seed-{seed}"


def race_file_name(k: int) -> str:
    """File of race ``k`` (from 0) in a races folder."""
    return f"race-{int(k)}.json"


def races_rel_path(part: str) -> str:
    """A race part's races folder relative to the tournament root."""
    return f"{part}/{RACES_DIR}"


def baseline_rel_path(part: str, bot: str, reference: str, track: str) -> str:
    """Baseline folder relative to the tournament root."""
    return f"{part}/{BASELINE_DIR}/{bot}-{reference}-{trace_name(track)}"


def trace_name(track: str) -> str:
    """File-name stem for a track's trace (a track may be a path or a gen-<seed> name)."""
    return re.sub(r"[^A-Za-z0-9_.+-]", "_", str(track))[:100] or "track"

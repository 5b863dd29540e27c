"""Tournaments through submitit: on a real single-node Slurm (``slurm_fixture`` starts munged,
slurmctld and slurmd), and on submitit's local processes (``--executor slurm-local``, no
daemon). The job tables equal an uninterrupted run on the local pool. In the middle of their
jobs, one Slurm array task is signalled as at a time limit (submitit checkpoints and requeues
it: the same job continues under the same id, and the parent counts nothing) and the other is
cancelled with ``scancel`` (the parent submits it again and counts it once as retried);
nothing is lost. A job a killed earlier parent left in the queue is cancelled first."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cluster_fixtures import (
    REPO,
    digests,
    index_rows,
    reference_digests,
    slow_file,
    tiny_file,
)
from slurm_fixture import SlurmCluster, slurm_cluster  # noqa: F401  (the fixture)

from formula_tourney.errors import UserInputError
from formula_tourney.results.layout import SUBMITIT_DIR
from formula_tourney.tourney.api import run_tournament
from formula_tourney.tourney.runner import FAULTS_ENV
from formula_tourney.tourney.slurm_executor import RUNNING_LINE, SlurmSettings, job_name

pytest.importorskip("submitit")

SETTINGS = SlurmSettings(time_min=5, mem_gb=1, max_parallel=2)


def test_slurm_local_runs_the_same_jobs_without_slurm(tmp_path: Path) -> None:
    result = run_tournament(
        tiny_file(tmp_path), executor="slurm-local", slurm=SETTINGS, results_dir=tmp_path / "res"
    )
    assert result["executor"] == "slurm-local" and result["workers"] == 2
    jobs = index_rows(tmp_path / "res")
    assert [r["status"] for r in jobs.values()] == ["done", "done"]
    assert digests(tmp_path / "res") == reference_digests()
    assert list((tmp_path / "res" / "tiny" / SUBMITIT_DIR).glob("*_result.pkl"))


def test_a_job_past_its_time_limit_is_cancelled_and_failed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(FAULTS_ENV, json.dumps({"slow/*": "sleep:300"}))
    result = run_tournament(
        slow_file(tmp_path), executor="slurm-local", slurm=SETTINGS, job_timeout_s=3,
        results_dir=tmp_path / "res",
    )  # fmt: skip
    assert result["this_run"]["failed"] == 1 and result["this_run"]["retried"] == 0
    (row,) = index_rows(tmp_path / "res").values()
    assert (row["status"], row["reason"], row["attempts"]) == ("failed", "timed out after 3 s", 1)
    folder = str(tmp_path / "res" / "tiny" / SUBMITIT_DIR)
    # the job's processes end: within 30 s (they sleep 300 s), with room for a loaded machine
    # where the cancel's signals reach the job's process tree late
    deadline = time.monotonic() + 30
    while any(folder in " ".join(argv) for argv in _processes()):
        assert time.monotonic() < deadline, "the timed-out job's processes outlived its cancel"
        time.sleep(0.2)


def _processes() -> list[list[str]]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                found.append((entry / "cmdline").read_bytes().decode(errors="replace").split("\0"))
            except OSError:
                continue
    return found


def test_a_requeued_task_continues_and_a_cancelled_one_runs_again(
    slurm_cluster: SlurmCluster,  # noqa: F811
    tmp_path: Path,
) -> None:
    results = tmp_path / "res"
    name = job_name(results / "tiny")
    argv = ["run", str(tiny_file(tmp_path)), "--executor", "slurm", "--slurm-partition",
            slurm_cluster.partition, "--slurm-time-min", "5", "--slurm-mem-gb", "1",
            "--slurm-max-parallel", "2", "--results", str(results), "--json"]  # fmt: skip
    # a job of this folder that a killed earlier parent left running: the run cancels it first
    sbatch = ["sbatch", "--parsable", f"--job-name={name}", "--output=/dev/null"]
    leftover = subprocess.run(
        [*sbatch, "--wrap=sleep 300"], capture_output=True, text=True, check=True
    ).stdout.strip()
    proc = subprocess.Popen(
        [sys.executable, "-m", "formula_tourney.cli", *argv],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, FAULTS_ENV: json.dumps({"p1/*": "sleep:10"})},  # sbatch passes it on
    )
    try:
        deadline = time.monotonic() + 60
        while True:  # both tasks of the array run their job
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            logs = [p.read_text() for p in (results / "tiny" / SUBMITIT_DIR).glob("*_log.out")]
            if sum(RUNNING_LINE in log for log in logs) == 2:
                break
            time.sleep(0.2)
        tasks = slurm_cluster.squeue("--name", name)
        preempted, cancelled = sorted(task for task, state, _name in tasks if state == "RUNNING")
        assert "_" in cancelled  # an array task
        # USR2 is what Slurm sends before a time limit or a preemption: submitit checkpoints
        # the call and requeues the task under its id; the parent keeps following that id.
        subprocess.run(["scancel", "--signal=USR2", preempted], check=True)
        subprocess.run(["scancel", cancelled], check=True)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err[-2000:]
    result = json.loads(out)
    assert result["this_run"]["retried"] == 1 and result["this_run"]["failed"] == 0
    jobs = index_rows(results)
    assert sorted((r["status"], r["attempts"]) for r in jobs.values()) == [("done", 1), ("done", 2)]
    assert digests(results) == reference_digests()
    states = {task_id: state for task_id, state, _name in slurm_cluster.squeue("--name", name)}
    assert states[cancelled] == "CANCELLED" and list(states.values()).count("COMPLETED") == 2
    assert states[leftover] == "CANCELLED"
    shown = subprocess.run(["scontrol", "show", "job", preempted], capture_output=True,
                           text=True, check=True).stdout  # fmt: skip
    assert "Restarts=1" in shown and "JobState=COMPLETED" in shown


def test_an_unknown_partition_is_refused_before_anything_runs(
    slurm_cluster: SlurmCluster,  # noqa: F811
    tmp_path: Path,
) -> None:
    with pytest.raises(
        UserInputError, match="--slurm-partition 'gpu' does not exist; allowed values: debug"
    ):
        run_tournament(
            tiny_file(tmp_path),
            executor="slurm",
            slurm=SlurmSettings(partition="gpu"),
            results_dir=tmp_path / "res",
        )
    assert not (tmp_path / "res").exists()

"""A tournament on a real two-node Ray cluster (``ray start`` twice on this machine) survives
kill -9 of one node's raylet in the middle of a job: the job that node held runs again on the
other node, is counted once as retried (not failed), and the job tables equal an uninterrupted
run on the local pool. A task past ``--job-timeout-s`` is cancelled, its worker killed."""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
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

from formula_tourney.tourney.runner import FAULTS_ENV

pytestmark = pytest.mark.ray

RAY = Path(sys.executable).parent / "ray"
JOB_SLEEP_S = 4
"""Every job sleeps this long at its start (runner.FAULTS_ENV), so the kill lands mid-job."""


@dataclass
class RayCluster:
    address: str
    env: dict[str, str]
    temp_dir: Path

    def raylets(self) -> dict[int, str]:
        """pid -> raylet socket name of this cluster's raylets."""
        found = {}
        for pid, argv in _processes():
            if argv and argv[0].endswith("/raylet"):
                names = [a for a in argv if a.startswith("--raylet_socket_name=")]
                if names and str(self.temp_dir) in names[0]:
                    found[pid] = names[0]
        return found


def _processes() -> Iterator[tuple[int, list[str]]]:
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                raw = (entry / "cmdline").read_bytes()
            except OSError:
                continue
            yield int(entry.name), raw.decode(errors="replace").split("\0")


def _parent(pid: int) -> int:
    stat = Path(f"/proc/{pid}/stat").read_text()
    return int(stat.rsplit(")", 1)[1].split()[1])


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _ray_start(args: list[str], env: dict[str, str]) -> None:
    out = subprocess.run(
        [str(RAY), "start", *args], env=env, capture_output=True, text=True, timeout=90
    )
    if out.returncode != 0:
        lines = [ln for ln in (out.stderr + out.stdout).splitlines() if ln.strip()]
        pytest.skip(f"ray start failed: {lines[-1] if lines else out.returncode}")


def _stop(temp_dir: Path) -> None:
    """Kill this cluster's processes by pid: everything whose command line names its temp
    folder (``ray stop`` would stop every Ray instance of the machine, not only this one)."""
    for _round in range(2):
        for pid, argv in _processes():
            if pid != os.getpid() and any(str(temp_dir) in a for a in argv):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
        time.sleep(0.5)


@pytest.fixture(scope="module")
def ray_cluster() -> Iterator[RayCluster]:
    """A head node and a second node, one CPU each, in a private temp folder (a short path:
    Ray's unix sockets live under it). Token auth, as ``ray start --head`` enables by default."""
    if not RAY.exists():
        pytest.skip(f"no ray executable beside {sys.executable} (the optional [ray] extra)")
    temp_dir = Path(tempfile.mkdtemp(prefix="ftray-", dir="/tmp"))
    port = _free_port()
    env = {
        **os.environ,
        "RAY_AUTH_MODE": "token",
        "RAY_AUTH_TOKEN": secrets.token_hex(32),
        "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])),
        # read by the Ray workers: p1's jobs sleep a little, the part "slow" a long time
        FAULTS_ENV: json.dumps({"p1/*": f"sleep:{JOB_SLEEP_S}", "slow/*": "sleep:300"}),
    }
    common = [
        "--num-cpus",
        "1",
        "--node-ip-address",
        "127.0.0.1",
        "--disable-usage-stats",
        "--object-store-memory",
        str(100 * 1024 * 1024),
    ]
    try:
        _ray_start(
            [
                "--head",
                "--port",
                str(port),
                "--temp-dir",
                str(temp_dir),
                "--include-dashboard",
                "false",
                *common,
            ],
            env,
        )
        _ray_start(["--address", f"127.0.0.1:{port}", *common], env)
        yield RayCluster(f"127.0.0.1:{port}", env, temp_dir)
    finally:
        _stop(temp_dir)
        shutil.rmtree(temp_dir, ignore_errors=True)


def _run_cli(cluster: RayCluster, tournament: Path, results: Path, *extra: str) -> subprocess.Popen:
    argv = ["run", str(tournament), "--executor", "ray", "--address", cluster.address,
            "--results", str(results), "--json", *extra]  # fmt: skip
    return subprocess.Popen(
        [sys.executable, "-m", "formula_tourney.cli", *argv],
        cwd=REPO,
        env=cluster.env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _running_pids(results: Path, proc: subprocess.Popen, count: int) -> dict[str, int]:
    """Wait until ``count`` jobs run (their Ray worker's pid in the index)."""
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        try:
            running = {
                job_id: row["worker_pid"]
                for job_id, row in index_rows(results).items()
                if row["status"] == "running" and row["worker_pid"]
            }
        except sqlite3.OperationalError:  # not created yet
            running = {}
        if len(running) >= count:
            return running
        time.sleep(0.2)
    raise AssertionError("the jobs never ran on both nodes")


def test_killing_a_nodes_raylet_reruns_its_job_and_loses_nothing(
    ray_cluster: RayCluster, tmp_path: Path
) -> None:
    raylets = ray_cluster.raylets()
    assert len(raylets) == 2, raylets
    second = next(pid for pid, name in raylets.items() if name.endswith("raylet.1"))
    results = tmp_path / "res"
    proc = _run_cli(ray_cluster, tiny_file(tmp_path), results)  # 2 jobs: the cluster's CPUs
    try:
        running = _running_pids(results, proc, 2)  # one job on each node
        on_second = [job for job, pid in running.items() if _parent(pid) == second]
        assert len(on_second) == 1, (running, second)
        os.kill(second, signal.SIGKILL)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err[-2000:]
    result = json.loads(out)
    assert result["workers"] == 2  # the cluster's CPUs (--workers not given)
    assert result["this_run"]["retried"] == 1 and result["this_run"]["failed"] == 0
    jobs = index_rows(results)
    assert {j: r["status"] for j, r in jobs.items()} == dict.fromkeys(jobs, "done")
    assert {j: r["attempts"] for j, r in jobs.items()} == {
        j: 2 if j == on_second[0] else 1 for j in jobs
    }
    assert digests(results) == reference_digests()


def test_a_task_past_its_time_limit_is_cancelled_and_failed(
    ray_cluster: RayCluster, tmp_path: Path
) -> None:
    proc = _run_cli(
        ray_cluster, slow_file(tmp_path), tmp_path / "res", "--workers", "1", "--job-timeout-s", "3"
    )
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 3, err[-2000:]  # a job failed
    assert json.loads(out)["this_run"]["failed"] == 1
    (row,) = index_rows(tmp_path / "res").values()
    assert (row["status"], row["reason"], row["attempts"]) == ("failed", "timed out after 3 s", 1)
    assert 3.0 <= row["wall_s"] < 8.0
    deadline = time.monotonic() + 10
    while Path(f"/proc/{row['worker_pid']}").exists():  # ray.cancel(force=True) kills it
        assert time.monotonic() < deadline, "the task's worker process outlived its cancel"
        time.sleep(0.2)

"""A real single-node Slurm cluster for the tests: munged, slurmctld and slurmd started here.

:func:`slurm_cluster` (session scope) writes a minimal ``slurm.conf`` in a temp folder (private
ports, one node ``localhost`` with 2 CPUs, partition ``debug``), starts its own ``munged`` on a
private socket (writing a random ``/etc/munge/munge.key`` first when missing), then
``slurmctld`` and ``slurmd``, and waits until ``sinfo`` shows the node idle. ``SLURM_CONF``
points the clients (``sbatch``, ``squeue``, ``scancel``, submitit) at it for the session. At
teardown every job is cancelled and the three daemons are stopped by pid. When a daemon cannot
start (not root, the packages missing: ``apt-get install slurm-wlm munge``), the tests skip
with the reason.
"""

from __future__ import annotations

import os
import pwd
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

MUNGE_KEY = Path("/etc/munge/munge.key")
DAEMONS = ("munged", "slurmctld", "slurmd")
START_WAIT_S = 20.0

SLURM_CONF = """\
ClusterName=tourney
SlurmctldHost=localhost
SlurmctldPort={ctld_port}
SlurmdPort={slurmd_port}
NodeName=localhost CPUs=2 RealMemory={memory_mb} State=UNKNOWN
PartitionName=debug Nodes=localhost Default=YES MaxTime=INFINITE State=UP
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
SlurmdParameters=config_overrides
SlurmdSpoolDir={root}/spool
StateSaveLocation={root}/state
SlurmctldPidFile={root}/slurmctld.pid
SlurmdPidFile={root}/slurmd.pid
SlurmctldLogFile={root}/slurmctld.log
SlurmdLogFile={root}/slurmd.log
ReturnToService=2
JobRequeue=1
MpiDefault=none
SlurmUser=root
AuthType=auth/munge
AuthInfo=socket={root}/munge/munge.socket,cred_expire=10
CredType=cred/munge
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
KillWait=3
MinJobAge=300
"""


@dataclass
class SlurmCluster:
    """A started cluster: its config file and its one partition."""

    conf: Path
    partition: str = "debug"

    def squeue(self, *args: str) -> list[list[str]]:
        """``squeue -h -r --states=all -o '%i|%T|%j' ARGS``, one row per job or array task."""
        out = subprocess.run(
            ["squeue", "-h", "-r", "--states=all", "-o", "%i|%T|%j", *args],
            capture_output=True,
            text=True,
            check=False,
        )
        return [line.split("|") for line in out.stdout.splitlines() if line.strip()]


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _memory_mb() -> int:
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemTotal:"):
            return max(1024, int(line.split()[1]) // 1024 // 2)
    return 1024


def _first_log_line(path: Path, fallback: str) -> str:
    try:
        lines = [ln for ln in path.read_text(errors="replace").splitlines() if "error" in ln]
    except OSError:
        return fallback
    return lines[0] if lines else fallback


def _run(argv: list[str], what: str) -> None:
    out = subprocess.run(argv, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        first = out.stderr.strip() or out.stdout.strip() or f"exit {out.returncode}"
        pytest.skip(f"{what} did not start: {first.splitlines()[0]}")


def _stop(pid_file: Path) -> None:
    try:
        pid = int(pid_file.read_text().strip())
    except (OSError, ValueError):
        return
    for sig, wait_s in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 2.0)):
        try:
            os.kill(pid, sig)
        except ProcessLookupError:
            return
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                return
            time.sleep(0.1)


def _ensure_munge_key(munge: pwd.struct_passwd) -> None:
    """A random key, as ``mungekey --create`` writes it, when the machine has none."""
    if MUNGE_KEY.is_file():
        return
    MUNGE_KEY.parent.mkdir(parents=True, exist_ok=True)
    os.chown(MUNGE_KEY.parent, munge.pw_uid, munge.pw_gid)
    MUNGE_KEY.parent.chmod(0o700)
    MUNGE_KEY.write_bytes(os.urandom(128))
    os.chown(MUNGE_KEY, munge.pw_uid, munge.pw_gid)
    MUNGE_KEY.chmod(0o400)


def _start(root: Path) -> SlurmCluster:
    """Write the config and start the three daemons (skips the tests when one fails)."""
    if os.geteuid() != 0:
        pytest.skip("slurmd did not start: the Slurm tests start the daemons and need root")
    missing = [d for d in DAEMONS if shutil.which(d) is None and not Path("/usr/sbin", d).exists()]
    if missing:
        pytest.skip(f"{', '.join(missing)} not installed: apt-get install slurm-wlm munge")
    try:
        munge = pwd.getpwnam("munge")
    except KeyError:
        pytest.skip("munged did not start: no user 'munge' (apt-get install munge)")
    _ensure_munge_key(munge)
    sock_dir = root / "munge"
    sock_dir.mkdir()
    os.chown(sock_dir, munge.pw_uid, munge.pw_gid)
    sock_dir.chmod(0o755)
    _run(
        [
            "runuser",
            "-u",
            "munge",
            "--",
            "munged",
            f"--socket={sock_dir}/munge.socket",
            f"--pid-file={sock_dir}/munged.pid",
            f"--log-file={sock_dir}/munged.log",
            f"--seed-file={sock_dir}/munged.seed",
            f"--key-file={MUNGE_KEY}",
        ],
        "munged",
    )
    for sub in ("spool", "state"):
        (root / sub).mkdir()
    conf = root / "slurm.conf"
    conf.write_text(
        SLURM_CONF.format(
            root=root, ctld_port=_free_port(), slurmd_port=_free_port(), memory_mb=_memory_mb()
        )
    )
    os.environ["SLURM_CONF"] = str(conf)
    _run(["slurmctld", "-c", "-f", str(conf)], "slurmctld")
    _run(["slurmd", "-N", "localhost", "-f", str(conf)], "slurmd")
    cluster = SlurmCluster(conf)
    deadline = time.monotonic() + START_WAIT_S
    state = ""
    while time.monotonic() < deadline:
        out = subprocess.run(
            ["sinfo", "-h", "-N", "-o", "%T"], capture_output=True, text=True, check=False
        )
        state = out.stdout.strip()
        if state == "idle":
            return cluster
        time.sleep(0.5)
    log = _first_log_line(root / "slurmd.log", f"node state {state or 'unknown'!r}")
    pytest.skip(f"slurmd did not start: {log}")


def _teardown(root: Path) -> None:
    subprocess.run(
        ["scancel", "--user", pwd.getpwuid(os.geteuid()).pw_name], capture_output=True, check=False
    )
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        out = subprocess.run(
            ["squeue", "-h", "-o", "%i"], capture_output=True, text=True, check=False
        )
        if out.returncode != 0 or not out.stdout.strip():
            break
        time.sleep(0.5)
    _stop(root / "slurmd.pid")
    _stop(root / "slurmctld.pid")
    _stop(root / "munge" / "munged.pid")


@pytest.fixture(scope="session")
def slurm_cluster() -> Iterator[SlurmCluster]:
    """The started cluster (see the module's docstring); stopped at the end of the session."""
    root = Path(tempfile.mkdtemp(prefix="ftslurm-", dir="/tmp"))
    root.chmod(0o755)  # munged runs as the munge user
    before = os.environ.get("SLURM_CONF")
    try:
        yield _start(root)
    finally:
        _teardown(root)
        if before is None:
            os.environ.pop("SLURM_CONF", None)
        else:
            os.environ["SLURM_CONF"] = before
        shutil.rmtree(root, ignore_errors=True)

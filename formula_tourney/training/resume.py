"""Resuming a training job mid-run: its whole state in one file, on a schedule and on SIGTERM.

A training job writes ``resume.pt`` (``results.layout.RESUME_FILE``) into its folder every
``schedule.resume_every_cpu_s`` CPU-seconds and when it receives SIGTERM (a pool worker stopped,
a Slurm requeue, a Ray retry), at the next step boundary: the entrant's
``training_state()`` (weights, targets, optimisers, replay incl. demonstrations and PER
priorities, noise, RNG states, counters, update credit, epsilon) and the loop's own state (the
env stream's state at the current episode's start and the actions driven since, the counters,
the tables so far, the best laps, the CPU clock). The env itself is not pickled: a resumed run
resets the episode's env from the same draws and drives the recorded actions again (the
simulator is deterministic), which puts the car exactly where it was. Only runs of one car are
resumable (a vector env's cars are mid-episode at different steps); runs of several cars start
again.

The file is ``torch.save`` of plain tensors, numbers, strings, lists and dicts (numpy arrays and
scalars become tensors), loadable with ``weights_only=True``; it carries the run
specification's digest, and a file of another configuration, or one that cannot be read, is
ignored with a message naming it. A finished job deletes it.
"""

from __future__ import annotations

import contextlib
import io
import logging
import pickle
import signal
import threading
from collections.abc import Iterator
from typing import Any

import numpy as np
import torch

from formula_tourney.errors import UserInputError
from formula_tourney.results.folder import JobFolder
from formula_tourney.training.run_spec import RunSpec

log = logging.getLogger(__name__)

RESUME_FORMAT = "formula-tourney-resume"
RESUME_VERSION = 1
PREEMPTED = "preempted (resumable)"
"""The failure reason's text of a job stopped by SIGTERM after writing its resume file."""


class Preempted(RuntimeError):
    """SIGTERM stopped the job at a step boundary; its resume file holds where it was (or, for
    a run that cannot resume, it starts again when run again)."""


_sigterm = threading.Event()


def preemption_requested() -> bool:
    """Whether SIGTERM arrived while :func:`sigterm_checkpoints` was active."""
    return _sigterm.is_set()


@contextlib.contextmanager
def sigterm_checkpoints() -> Iterator[None]:
    """While the block runs, SIGTERM only sets a flag that the training loop reads at its next
    step boundary (write the resume file, raise :class:`Preempted`). A block that ends normally
    although SIGTERM came (the run finished before a step boundary saw it) passes the signal on
    to the previous handler afterwards: the request to end the process stands. Signal handlers
    can only be set in the main thread; elsewhere SIGTERM keeps its handler."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _sigterm.clear()
    previous = signal.signal(signal.SIGTERM, lambda _signum, _frame: _sigterm.set())
    pending = False
    try:
        yield
        pending = _sigterm.is_set()
    finally:
        signal.signal(signal.SIGTERM, previous)
        _sigterm.clear()
    if pending:
        signal.raise_signal(signal.SIGTERM)


def to_plain(obj: Any) -> Any:
    """``obj`` with numpy arrays and scalars turned into tensors (what ``weights_only`` loads);
    dicts, lists and tuples walked, everything else as it is."""
    if isinstance(obj, np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(obj))
    if isinstance(obj, np.generic):
        return torch.from_numpy(np.asarray(obj)) if obj.dtype.kind in "biuf" else obj.item()
    if isinstance(obj, dict):
        return {k: to_plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return type(obj)(to_plain(v) for v in obj)
    return obj


def rows_from_plain(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Table rows as they were: a 0-d tensor back to its numpy scalar (same dtype), so the
    resumed tables' columns are typed exactly as the uninterrupted run's."""
    return [{k: (v.numpy()[()] if isinstance(v, torch.Tensor) else v) for k, v in row.items()}
            for row in rows]  # fmt: skip


def write_resume(folder: JobFolder, spec: RunSpec, entrant: dict[str, Any],
                 loop: dict[str, Any]) -> int:  # fmt: skip
    """Write the resume file atomically; returns its size in bytes."""
    state = {
        "format": RESUME_FORMAT, "version": RESUME_VERSION, "config_hash": spec.digest(),
        "entrant": to_plain(entrant), "loop": to_plain(loop),
    }  # fmt: skip
    buf = io.BytesIO()
    torch.save(state, buf)
    data = buf.getvalue()
    folder.write_resume(data)
    return len(data)


def read_resume(folder: JobFolder, spec: RunSpec) -> dict[str, Any] | None:
    """The job's resume state if its file exists, reads and belongs to ``spec``; else None,
    with a logged message naming the file when one is there but refused."""
    path = folder.resume_path
    if not path.is_file():
        return None
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        log.warning("resume file %s holds objects other than tensors and plain values: "
                    "ignored, the job starts afresh", path)  # fmt: skip
        return None
    except Exception as err:  # truncated or foreign: torch's own text runs over many lines
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        log.warning("resume file %s cannot be read (%s): ignored, the job starts afresh",
                    path, first)  # fmt: skip
        return None
    if not isinstance(state, dict) or state.get("format") != RESUME_FORMAT:
        log.warning("resume file %s is not a formula-tourney resume file: ignored, the job "
                    "starts afresh", path)  # fmt: skip
        return None
    if state.get("version") != RESUME_VERSION:
        log.warning("resume file %s has version %s, this version reads %s: ignored, the job "
                    "starts afresh", path, state.get("version"), RESUME_VERSION)  # fmt: skip
        return None
    if state.get("config_hash") != spec.digest():
        log.warning("resume file %s was written by another configuration (hash %s, this run "
                    "%s): ignored, the job starts afresh", path, state.get("config_hash"),
                    spec.digest())  # fmt: skip
        return None
    loop = state.get("loop")
    if not isinstance(state.get("entrant"), dict) or not isinstance(loop, dict):
        log.warning("resume file %s is incomplete: ignored, the job starts afresh", path)
        return None
    log.info("resuming from %s: %s finished episodes, %s env steps", path, loop.get("episode"),
             loop.get("env_steps"))  # fmt: skip
    return state


def refuse(folder: JobFolder, err: Exception) -> UserInputError:
    """The error of a resume file that reads but does not fit its run (a damaged state)."""
    first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
    return UserInputError(
        f"resume file {folder.resume_path} does not fit this run ({first}); delete it to "
        "start the job afresh"
    )

"""One run per results folder: an ``fcntl.flock`` on ``<root>/.lock``.

The parent writes the index alone; two parents on one folder would start the same jobs into the
same folders. ``flock`` is released by the kernel when the holder dies (even by kill -9), so a
crashed run never leaves a stale lock behind, unlike a pid file. Spawned workers do not inherit
the descriptor (spawn starts a fresh interpreter), so an orphaned worker cannot hold it either.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from formula_tourney.errors import UserInputError
from formula_tourney.results.layout import LOCK_FILE
from formula_tourney.safeio import make_dirs


class RunLock:
    """Exclusive, non-blocking lock on a tournament folder; a context manager."""

    def __init__(self, root: str | Path, what: str = "run") -> None:
        self.root = Path(root)
        self.path = self.root / LOCK_FILE
        self.what = what
        self._fd: int | None = None

    def acquire(self) -> RunLock:
        """Take the lock or raise UserInputError naming the folder and the holder's pid."""
        make_dirs(self.root, "results folder")
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "?"
            os.close(fd)
            raise UserInputError(
                f"{self.root}: another run is using this results folder ({holder}); wait for "
                "it to finish or use --results DIR"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{self.what} pid {os.getpid()}".encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()

"""Safe names and atomic writes: the only way user-chosen names become paths on disk.

A tournament, entrant or track name from a user file ends up as a folder or file name, so it is
checked here (no separators, no ``..``); every file is written to a temporary sibling and then
renamed, so a crash never leaves a half-written file that a resume would trust.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from formula_tourney.errors import UserInputError

_SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,127}", re.ASCII)
"""Matched with ``fullmatch``: ``$`` would also match before a final newline, so ``"bt\n"``
passed; ASCII only, so no control, separator or look-alike Unicode character gets through."""


def is_safe_name(name: object) -> bool:
    """True if ``name`` can safely become one path component (see :func:`check_name`)."""
    return isinstance(name, str) and _SAFE_NAME.fullmatch(name) is not None and ".." not in name


def check_name(name: str, what: str = "name") -> str:
    """Return ``name`` if it can safely become one path component, else raise UserInputError."""
    if not is_safe_name(name):
        raise UserInputError(
            f"invalid {what} {name!r}: use letters, digits, '_', '-', '.', '+' "
            "(no path separators, no '..', no spaces or control characters, at most 128 "
            "characters, starting with a letter or digit)"
        )
    return name


def read_user_text(path: str | Path, what: str) -> str:
    """Text of a user's file, or a UserInputError naming it: one wording for every file kind."""
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserInputError(f"{path}: {what} file not found") from None
    except (OSError, UnicodeDecodeError) as err:
        raise UserInputError(f"{path}: cannot read {what} file ({err})") from None


def _blocking_file(path: Path) -> Path | None:
    """The nearest existing ancestor of ``path`` (or ``path`` itself) that is not a folder."""
    for candidate in (path, *path.parents):
        if candidate.exists():
            return None if candidate.is_dir() else candidate
    return None


def check_output_path(path: str | Path, what: str, folder: bool = False) -> Path:
    """Refuse an output path that cannot be written, before any work is done: one of its
    parents is a regular file, or (``folder``) it is a file itself, or it is a folder where a
    file is wanted. Nothing is created."""
    path = Path(path)
    blocker = _blocking_file(path.parent)
    if blocker is not None:
        raise UserInputError(f"{what} {path}: {blocker} is a file, not a folder")
    if folder and path.exists() and not path.is_dir():
        raise UserInputError(f"{what} {path}: is a file, not a folder")
    if not folder and path.is_dir():
        raise UserInputError(f"{what} {path}: is a folder, not a file name")
    return path


def make_dirs(path: str | Path, what: str = "folder") -> Path:
    """``mkdir -p``: every output folder is made here, so a parent that is a regular file, a
    full disk or a folder without write permission is one UserInputError naming the path."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        blocker = _blocking_file(path) or path
        raise UserInputError(f"{what} {path}: {blocker} is a file, not a folder") from None
    except OSError as err:
        raise UserInputError(f"{what} {path}: cannot create the folder ({err.strerror})") from None
    return path


def atomic_write(path: str | Path, write: Callable[[Path], None]) -> Path:
    """Call ``write(tmp_path)`` and rename the result onto ``path`` (same folder, so atomic)."""
    path = Path(path)
    make_dirs(path.parent)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        write(tmp_path)
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"))


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    return atomic_write(path, lambda p: p.write_bytes(data))


def atomic_write_json(path: str | Path, obj: Any) -> Path:
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n")


def atomic_write_parquet(path: str | Path, frame: Any) -> Path:
    """Write a pandas DataFrame as Parquet atomically."""
    return atomic_write(path, lambda p: frame.to_parquet(p, index=False))

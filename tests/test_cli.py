"""The command line's own contract: usage errors are one message and exit 2, never a traceback."""

from __future__ import annotations

import subprocess
import sys


def test_unknown_subcommand_is_a_usage_error_not_a_traceback() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "formula_tourney.cli", "lines", "bot"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2
    assert "No such command 'bot'" in done.stderr and "Traceback" not in done.stderr

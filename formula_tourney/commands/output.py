"""How commands print: rich for people, one JSON document on stdout with ``--json``.

With ``--json`` every message goes to stderr so that stdout holds exactly one parseable document.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from typing import Any

from rich.console import Console

stderr_console = Console(stderr=True)
stdout_console = Console()


def emit(data: Any, as_json: bool, render: Callable[[Console], None] | None = None) -> None:
    """Print ``data`` as one JSON document, or call ``render`` with a rich console."""
    if as_json:
        sys.stdout.write(json.dumps(data, default=_jsonable) + "\n")
        sys.stdout.flush()
    elif render is not None:
        render(stdout_console)
    else:
        stdout_console.print_json(json.dumps(data, default=_jsonable))


def message(text: str) -> None:
    """A progress or status message: always stderr, never mixed into JSON output."""
    stderr_console.print(text)


def _jsonable(obj: Any) -> Any:
    try:
        import numpy as np

        if isinstance(obj, np.generic):
            return obj.item()
        if isinstance(obj, np.ndarray):
            return obj.tolist()
    except ImportError:  # pragma: no cover
        pass
    return str(obj)

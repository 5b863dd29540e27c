"""How commands print: rich for people, one JSON document on stdout with ``--json``.

With ``--json`` every message goes to stderr so that stdout holds exactly one parseable document.

Text is text: descriptions, track paths and names come from user files, so no string printed
through these consoles (a message, a table cell, a title) is read as rich markup, and control
characters (terminal escape codes) are shown as ``\x1b``, never sent raw. Styles are given as
:func:`styled` pieces instead of markup, so the rule has no exception.
"""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Callable
from typing import Any

from rich.console import Console
from rich.text import Text

_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")
"""Control characters but newline and tab: ESC starts a terminal escape code."""


def printable(text: str) -> str:
    """``text`` with each control character written out (``\x1b``), so it cannot act."""
    return _CONTROL.sub(lambda m: f"\\x{ord(m.group(0)):02x}", text)


def styled(*pieces: str | tuple[str, str]) -> Text:
    """One line of plain and styled pieces (``("p1", "bold")``): how renderers style text,
    since strings are never read as markup."""
    return Text.assemble(*(
        (printable(p[0]), p[1]) if isinstance(p, tuple) else printable(p) for p in pieces
    ))


class TextConsole(Console):
    """A rich console that renders every string as plain text (see the module docstring)."""

    def render_str(self, text: str, **kwargs: Any) -> Text:
        kwargs.update(markup=False, emoji=False)
        return super().render_str(printable(text), **kwargs)


stderr_console = TextConsole(stderr=True)
stdout_console = TextConsole()


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
    """A progress or status message: always stderr, never mixed into JSON output, and one
    line however long (a terminal wraps it on screen; a log or a grep keeps the path whole)."""
    stderr_console.print(text, soft_wrap=True)


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

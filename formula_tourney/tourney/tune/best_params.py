"""``tune --write-best``: merge tuned hyperparameters into a tournament file's variant entry."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

from formula_tourney.errors import UserInputError
from formula_tourney.safeio import atomic_write_text
from formula_tourney.tourney.plan import Planner
from formula_tourney.tourney.spec import parse_spec, read_spec_text


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise UserInputError(f"cannot write {value!r} to TOML")


def write_best_params(path: Path, variant: str, params: dict[str, Any],
                      preset: str | None = None) -> None:  # fmt: skip
    """Merge ``params`` into ``[variants.<variant>] overrides`` of a tournament file.

    Edits the text (comments and layout elsewhere survive): an existing ``overrides`` line or
    ``[variants.X.overrides]`` table is replaced, else the entry is added. ``preset`` (the tune
    file's ``[train] preset``: the parameters were found on top of it and mean something else
    without it) is written as the entry's ``preset`` too. The result is validated as a
    tournament before it atomically replaces the file.
    """
    text = read_spec_text(path, "tournament")
    current = tomllib.loads(text).get("variants", {}).get(variant, {}).get("overrides", {})
    merged = {**current, **params}
    inline = "overrides = {" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in merged.items())
    inline += "}"
    lines = text.splitlines()
    header = f"[variants.{variant}]"
    sub = f"[variants.{variant}.overrides]"
    stripped = [ln.strip() for ln in lines]
    if sub in stripped:
        start = stripped.index(sub)
        end = start + 1
        while end < len(lines) and not stripped[end].startswith("["):
            end += 1
        body = [f"{k} = {_toml_value(v)}" for k, v in merged.items()]
        lines[start + 1:end] = body + [""]
    elif header in stripped:
        start = stripped.index(header)
        end = start + 1
        while end < len(lines) and not stripped[end].startswith("["):
            end += 1
        for i in range(start + 1, end):
            if stripped[i].startswith("overrides"):
                lines[i] = inline
                break
        else:
            lines.insert(start + 1, inline)
    else:
        lines += ["", header, inline]
    if preset is not None:
        _set_preset(lines, header, preset)
    new_text = "\n".join(lines).rstrip("\n") + "\n"
    # The merged file must plan: every job's run spec is built before the file is replaced.
    Planner(parse_spec(new_text, path), path, new_text, Path("results")).validate()
    atomic_write_text(path, new_text)


def _set_preset(lines: list[str], header: str, preset: str) -> None:
    """Set ``preset`` in the ``header`` table (after an existing ``[variants.X.overrides]``
    table the ``[variants.X]`` header is added at the end: TOML allows the parent after)."""
    entry = f"preset = {_toml_value(preset)}"
    stripped = [ln.strip() for ln in lines]
    if header not in stripped:
        lines += ["", header, entry]
        return
    start = stripped.index(header)
    end = start + 1
    while end < len(lines) and not stripped[end].startswith("["):
        end += 1
    for i in range(start + 1, end):
        if stripped[i].startswith("preset"):
            lines[i] = entry
            return
    lines.insert(start + 1, entry)

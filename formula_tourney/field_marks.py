"""Marks on a setting's pydantic Field that the run specification reads generically.

A setting says once, on the Field that declares it (``json_schema_extra``), what the run
specification (``training.run_spec``) needs to know about it beyond its value:

- ``added_in_layout``: the results layout version during which the setting was added. The run
  specification leaves such a setting out of its JSON while it is at its default, so a run that
  does not use it keeps the ``config.json`` and config hash it had before the setting existed
  (a resumed tournament still recognises its finished jobs).
- ``beyond_paper``: the setting belongs to a mechanism the Formula RL paper does not have; a run
  whose value differs from what its preset gives names it in the "beyond paper" label of every
  table.
"""

from __future__ import annotations

from typing import Any

from pydantic.fields import FieldInfo

ADDED_IN_LAYOUT = "added_in_layout"
BEYOND_PAPER = "beyond_paper"


def marks(*, added_in_layout: int | None = None, beyond_paper: bool = False) -> dict[str, Any]:
    """The ``json_schema_extra`` of a setting's Field (empty for an unmarked setting)."""
    out: dict[str, Any] = {}
    if added_in_layout is not None:
        out[ADDED_IN_LAYOUT] = added_in_layout
    if beyond_paper:
        out[BEYOND_PAPER] = True
    return out


def _extra(field: FieldInfo) -> dict[str, Any]:
    extra = field.json_schema_extra
    return extra if isinstance(extra, dict) else {}


def added_in_layout(field: FieldInfo) -> int | None:
    """The layout version a setting was added during; None for a setting as old as its layout."""
    value = _extra(field).get(ADDED_IN_LAYOUT)
    return int(value) if value is not None else None


def beyond_paper(field: FieldInfo) -> bool:
    """Whether a setting belongs to a mechanism beyond the paper."""
    return bool(_extra(field).get(BEYOND_PAPER, False))

"""Where a report's claims come from: ``--claims`` (a shipped set's name or a claims file), else
the ``[claims]`` table the tournament file declared (stored with its spec in the index), else
the paper's findings.

A claims file is validated whole before anything is evaluated, and its errors read like a
tournament file's: ``file:line: key: problem`` with the allowed keys or values (the locator of
``tourney.spec``), raised as ``UserInputError`` (exit 2).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from pydantic import ValidationError

from formula_tourney.claims.schema import SHIPPED_SETS, Claim, ClaimSet, shipped_set
from formula_tourney.errors import UserInputError
from formula_tourney.tourney.spec import describe_errors, parse_toml, read_spec_text

DEFAULT_SET = "paper"
"""The claims a report checks when neither ``--claims`` nor the tournament names any."""


def load_claims_file(path: str | Path) -> ClaimSet:
    """A claims file (``include = [...]`` and ``[[claim]]`` tables), validated whole."""
    path = Path(path)
    text = read_spec_text(path, "claims")
    raw = parse_toml(text, path)
    try:
        return ClaimSet.model_validate(raw)
    except ValidationError as err:
        raise UserInputError(describe_errors(err, path, text, ClaimSet)) from None


def claims_of_spec(meta: dict[str, str]) -> ClaimSet | None:
    """The ``[claims]`` table of the tournament spec stored in the index, None if it has none
    (or was stored by a version without claims)."""
    try:
        spec = json.loads(meta.get("spec") or "{}")
    except ValueError:
        return None
    raw = spec.get("claims") if isinstance(spec, dict) else None
    if not raw:
        return None
    try:
        return ClaimSet.model_validate(raw)
    except ValidationError as err:
        raise UserInputError(f"the tournament's stored [claims] table is not valid: {err}") \
            from None


def resolve_claims(sources: Sequence[str], meta: dict[str, str]) -> tuple[list[Claim], str]:
    """The claims to check and where they came from (for the report's caption).

    ``sources``: shipped set names or claims files, in order (a later claim of the same id
    replaces an earlier one); empty: the tournament's own ``[claims]``, else the paper's.
    """
    sets: list[tuple[ClaimSet, str]] = []
    for source in sources:
        if source in SHIPPED_SETS and not Path(source).is_file():
            sets.append((shipped_set(source), f"the shipped '{source}' set"))
        else:
            sets.append((load_claims_file(source), str(source)))
    if not sets:
        own = claims_of_spec(meta)
        if own is not None and (own.claim or own.include):
            sets.append((own, "the tournament file's [claims]"))
        else:
            sets.append((shipped_set(DEFAULT_SET), f"the shipped '{DEFAULT_SET}' set (default)"))
    merged: dict[str, Claim] = {}
    for claim_set, _ in sets:
        for claim in claim_set.resolved():
            merged.pop(claim.id, None)
            merged[claim.id] = claim
    return list(merged.values()), "; ".join(origin for _, origin in sets)

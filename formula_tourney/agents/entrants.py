"""Which entrant class trains a run: our families by default, outside kinds once registered.

The training loop asks :func:`resolve_entrant` for the class (an
:class:`~formula_tourney.agents.protocol.Entrant`) and the validated settings it builds a run's
entrant from. Without a registered kind that claims the run, that is
:class:`~formula_tourney.agents.family_entrant.FamilyEntrant` with the run's agent
configuration (``spec.agent``). Outside kinds (a class named ``"package.module:Class"``, an
entry point, a Stable-Baselines3 adapter) plug in with :func:`register_entrant_kind`: a resolver
that looks at the run specification and either claims it, returning ``(class, settings)``, or
returns None. Resolvers are asked newest first, so a later registration can refine an earlier
one. The run specification is read duck-typed (``agents`` knows no ``training``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pydantic

from formula_tourney.agents.family_entrant import FamilyEntrant
from formula_tourney.agents.protocol import Entrant

Resolver = Callable[[Any], "tuple[type[Entrant], pydantic.BaseModel] | None"]
"""``resolver(run_spec)``: the entrant class and its validated settings, or None (not mine)."""

_KINDS: dict[str, Resolver] = {}


def register_entrant_kind(name: str, resolver: Resolver) -> None:
    """Register (or replace) the entrant kind ``name``; see the module docstring."""
    _KINDS.pop(name, None)
    _KINDS[name] = resolver


def entrant_kinds() -> list[str]:
    """The registered kinds' names, oldest first."""
    return list(_KINDS)


def resolve_entrant(spec: Any) -> tuple[type[Entrant], pydantic.BaseModel]:
    """The class and settings a run's entrant is built from (``cls.build(settings, ...)``)."""
    for resolver in reversed(list(_KINDS.values())):
        found = resolver(spec)
        if found is not None:
            return found
    return FamilyEntrant, spec.agent


def entrant_class(spec: Any) -> type[Entrant]:
    """The entrant class that trains ``spec``: FamilyEntrant unless a registered kind claims it."""
    return resolve_entrant(spec)[0]

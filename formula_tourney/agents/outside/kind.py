"""The "outside" entrant kind: a run whose specification names an outside entrant trains it.

Importing this module registers the kind with ``agents.entrants.register_entrant_kind`` (the
loop's hook for entrant classes other than our families); ``training.run_spec`` imports
:class:`OutsideEntrant` from here, so every process that reads a run specification, a worker
included, has the kind registered before its first job. The resolver claims a run whose
``outside`` field is set and hands back the class and the settings its ``settings_model()``
validated (``agents.outside.check.entrant_class``, the same path the up-front check takes).
"""

from __future__ import annotations

from typing import Any

import pydantic

from formula_tourney.agents.entrants import register_entrant_kind
from formula_tourney.agents.outside.check import entrant_class
from formula_tourney.agents.outside.naming import OutsideEntrant

KIND = "outside"
"""The kind's name in ``agents.entrants``."""

__all__ = ["KIND", "OutsideEntrant", "outside_resolver"]


def outside_resolver(spec: Any) -> tuple[type, pydantic.BaseModel] | None:
    """(class, settings) of the run's outside entrant, or None for one of our families."""
    ref = getattr(spec, "outside", None)
    if ref is None:
        return None
    return entrant_class(ref, f"entrant {getattr(spec, 'variant', '?')}")


register_entrant_kind(KIND, outside_resolver)

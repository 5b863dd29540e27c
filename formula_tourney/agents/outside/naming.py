"""What names an outside entrant: ``impl``, an entry point, or an SB3 algorithm, and its class.

One model (:class:`OutsideEntrant`) holds the three forms, so a tournament file, ``train`` and a
job's ``config.json`` carry the same thing, and :func:`resolve` is the one place that turns it
into an entrant class and the settings that class validates:

- ``impl = "package.module:Class"`` with ``settings = {...}``: a class importable from the
  current folder or the installed packages (the current folder goes first on the import path,
  as ``python -m`` puts it, also for the ``formula-tourney`` script and its workers);
- ``entry = "name"`` with ``settings = {...}``: an entry point an installed package declares in
  the group ``formula_tourney.entrants`` (``importlib.metadata.entry_points``);
- ``sb3 = "SAC"`` or ``sb3_contrib = "CrossQ"`` with ``kwargs = {...}``: the SB3 adapter
  (``agents.outside.sb3``), its settings the library, algorithm and constructor keywords.

Every problem is a ``ValueError`` with the allowed values; callers prefix the file and entrant.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import os
import re
import sys
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from formula_tourney.agents.outside.sb3 import SB3Entrant, library_label

ENTRY_POINT_GROUP = "formula_tourney.entrants"
"""The entry-point group an installed package declares its entrant classes in."""

FORMS = ("impl", "entry", "sb3", "sb3_contrib")
"""The keys that name an outside entrant; exactly one is given."""

_IMPL = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*:[A-Za-z_][A-Za-z0-9_]*")


class OutsideEntrant(BaseModel):
    """An outside driver: exactly one of impl, entry, sb3, sb3_contrib, and its settings."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    impl: str | None = Field(
        None, description="The entrant class as \"package.module:Class\" (importable where the "
        "jobs run); it implements agents.protocol.Entrant.",
    )  # fmt: skip
    entry: str | None = Field(
        None, description=f"Name of an entry point in the group {ENTRY_POINT_GROUP!r} that an "
        "installed package declares (its value a \"package.module:Class\").",
    )  # fmt: skip
    sb3: str | None = Field(
        None, description="A Stable-Baselines3 algorithm by class name (SAC, TD3, DDPG, PPO, "
        "A2C), through the adapter (extra [sb3]).",
    )  # fmt: skip
    sb3_contrib: str | None = Field(
        None, description="An sb3-contrib algorithm by class name (CrossQ, TQC, TRPO), through "
        "the adapter (extra [sb3]).",
    )  # fmt: skip
    kwargs: dict[str, Any] = Field(
        default_factory=dict, description="sb3/sb3_contrib: keyword arguments of the "
        "algorithm's constructor, checked against its signature.",
    )  # fmt: skip
    settings: dict[str, Any] = Field(
        default_factory=dict, description="impl/entry: the entrant's settings, validated by "
        "its settings_model().",
    )  # fmt: skip

    @model_validator(mode="after")
    def _one_form(self) -> OutsideEntrant:
        given = [k for k in FORMS if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of {', '.join(FORMS)} (got "
                             f"{', '.join(given) or 'none'})")  # fmt: skip
        if self.kwargs and given[0] not in ("sb3", "sb3_contrib"):
            raise ValueError("kwargs are an SB3 algorithm's; an impl or entry entrant takes "
                             "settings = {...}")  # fmt: skip
        if self.settings and given[0] in ("sb3", "sb3_contrib"):
            raise ValueError("an SB3 entrant takes kwargs = {...} (the algorithm's constructor "
                             "arguments), not settings")  # fmt: skip
        if self.impl is not None and not _IMPL.fullmatch(self.impl):
            raise ValueError(f'impl {self.impl!r} is not "package.module:Class"')
        return self

    @property
    def form(self) -> str:
        """Which of :data:`FORMS` names this entrant."""
        return next(k for k in FORMS if getattr(self, k) is not None)

    def label(self) -> str:
        """What tables call it: ``sb3 2.9.2 SAC``, ``impl package.module:Class``, or the entry
        point's name with the distribution that declares it and its version."""
        if self.sb3 is not None:
            return library_label("sb3", self.sb3)
        if self.sb3_contrib is not None:
            return library_label("sb3_contrib", self.sb3_contrib)
        if self.impl is not None:
            return self.impl
        point = _entry_point(str(self.entry))
        dist = getattr(point, "dist", None)
        return f"{self.entry} ({dist.name} {dist.version})" if dist else str(self.entry)


def resolve(ref: OutsideEntrant) -> tuple[type, dict[str, Any]]:
    """(the entrant class, the settings its ``settings_model()`` validates); ValueError naming
    what could not be found."""
    if ref.sb3 is not None:
        return SB3Entrant, {"library": "sb3", "algorithm": ref.sb3, "kwargs": ref.kwargs}
    if ref.sb3_contrib is not None:
        return SB3Entrant, {"library": "sb3_contrib", "algorithm": ref.sb3_contrib,
                            "kwargs": ref.kwargs}  # fmt: skip
    if ref.impl is not None:
        return _import_impl(ref.impl), dict(ref.settings)
    try:
        found = _entry_point(str(ref.entry)).load()
    except Exception as err:  # noqa: BLE001 - outside code: any failure to import is the user's
        raise ValueError(f"entry point {ref.entry!r} failed to load: "
                         f"{type(err).__name__}: {err}") from None  # fmt: skip
    if not isinstance(found, type):
        raise ValueError(f"entry point {ref.entry!r} is {type(found).__name__}, not a class")
    return found, dict(ref.settings)


def _import_impl(impl: str) -> type:
    module_name, _, name = impl.partition(":")
    here = os.getcwd()
    if here not in sys.path:  # the console script, unlike ``python -m``, leaves it out
        sys.path.insert(0, here)
    try:
        module = importlib.import_module(module_name)
    except Exception as err:  # noqa: BLE001 - outside code: any failure to import is the user's
        raise ValueError(f"impl {impl!r}: cannot import module {module_name!r} "
                         f"({type(err).__name__}: {err})") from None  # fmt: skip
    found = getattr(module, name, None)
    if not isinstance(found, type):
        classes = sorted(n for n, v in vars(module).items()
                         if isinstance(v, type) and v.__module__ == module.__name__)  # fmt: skip
        raise ValueError(f"impl {impl!r}: module {module_name!r} has no class {name!r}; its "
                         f"classes: {', '.join(classes) or '(none)'}")  # fmt: skip
    return found


def _entry_point(name: str) -> Any:
    points = importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)
    for point in points:
        if point.name == name:
            return point
    known = sorted({p.name for p in points})
    raise ValueError(f"no entry point {name!r} in group {ENTRY_POINT_GROUP!r}; installed: "
                     f"{', '.join(known) or '(none)'}")  # fmt: skip

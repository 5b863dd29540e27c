"""Proof, before any job starts, that an outside entrant can run: class, settings, one action.

A tournament's up-front check, ``train`` and the planner call :func:`check_entrant` for each
outside entrant on the run's own spaces: the class is found and has every member of
``agents.protocol.Entrant``, its settings validate with its ``settings_model()``, and an entrant
built with a seed acts on an observation of zeros with a finite action of shape
``(cars, action_dim)``. Each failure is one ``UserInputError`` line naming the entrant (the
caller's ``source``) and what is allowed, so a broken driver costs a second, not a tournament.
What it cannot prove (a driver that fails later, returns NaN after an update, or hangs) the loop
and the executors contain per job.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pydantic

from formula_tourney.agents.outside.naming import OutsideEntrant, resolve
from formula_tourney.agents.protocol import Entrant, EntrantSpaces
from formula_tourney.errors import UserInputError

CLASS_METHODS = ("settings_model", "build", "load")
"""Protocol members called on the class."""
METHODS = ("act", "explore", "observe", "update", "episode_started", "save", "training_state",
           "restore_training_state")  # fmt: skip
"""Protocol members called on a built entrant."""


def entrant_class(ref: OutsideEntrant, source: str) -> tuple[type, pydantic.BaseModel]:
    """The entrant's class with every protocol member, and its validated settings."""
    try:
        cls, raw = resolve(ref)
    except ValueError as err:
        raise UserInputError(f"{source}: {err}") from None
    missing = [m for m in (*CLASS_METHODS, *METHODS) if not callable(getattr(cls, m, None))]
    if missing:
        raise UserInputError(f"{source}: {cls.__module__}.{cls.__qualname__} does not "
                             f"implement the entrant protocol (agents.protocol.Entrant): missing "
                             f"{', '.join(missing)}")  # fmt: skip
    try:
        model = cls.settings_model()
        if not (isinstance(model, type) and issubclass(model, pydantic.BaseModel)):
            raise TypeError(f"settings_model() returned {model!r}, not a pydantic model class")
        settings = model.model_validate(raw)
    except pydantic.ValidationError as err:
        raise UserInputError(f"{source}: settings: {_problems(err)}") from None
    except UserInputError as err:
        raise UserInputError(f"{source}: {err}") from None
    except Exception as err:  # noqa: BLE001 - outside code
        raise UserInputError(f"{source}: settings_model() failed: {type(err).__name__}: "
                             f"{err}") from None  # fmt: skip
    return cls, settings


def build_entrant(ref: OutsideEntrant, spaces: EntrantSpaces, seed: int, device: str,
                  source: str) -> Entrant:  # fmt: skip
    """A fresh entrant of ``ref`` on ``spaces`` (what the loop trains)."""
    cls, settings = entrant_class(ref, source)
    return cls.build(settings, spaces, seed, device)


def check_entrant(ref: OutsideEntrant, spaces: EntrantSpaces, seed: int, source: str) -> str:
    """Build ``ref`` on ``spaces`` and act once on zeros; returns its label. Every failure is
    one UserInputError line naming ``source``."""
    cls, settings = entrant_class(ref, source)
    try:
        entrant = cls.build(settings, spaces, seed, "cpu")
    except UserInputError as err:
        raise UserInputError(f"{source}: {err}") from None
    except Exception as err:  # noqa: BLE001 - outside code
        raise UserInputError(f"{source}: build() failed on {_spaces_text(spaces)}: "
                             f"{type(err).__name__}: {_one_line(err)}") from None  # fmt: skip
    if not isinstance(entrant, Entrant):
        missing = [m for m in ("label", "window") if not hasattr(entrant, m)]
        raise UserInputError(f"{source}: build() returned {type(entrant).__name__}, which does "
                             f"not implement the entrant protocol (missing "
                             f"{', '.join(missing) or 'members'})")  # fmt: skip
    window = getattr(entrant, "window", None)
    if not isinstance(window, int) or isinstance(window, bool) or window < 1:
        raise UserInputError(f"{source}: window is {window!r}; allowed: an int >= 1")
    zeros = np.zeros((spaces.cars, window, spaces.obs_dim), np.float32)
    try:
        action = np.asarray(entrant.act(zeros))
    except Exception as err:  # noqa: BLE001 - outside code
        raise UserInputError(f"{source}: act() on zeros failed: {type(err).__name__}: "
                             f"{_one_line(err)}") from None  # fmt: skip
    problem = action_problem(action, spaces)
    if problem:
        raise UserInputError(f"{source}: act() on zeros {problem}")
    return str(entrant.label)


def action_problem(action: Any, spaces: EntrantSpaces) -> str | None:
    """What is wrong with an entrant's ``(cars, action_dim)`` action array, or None."""
    want = (spaces.cars, spaces.action_dim)
    shape = getattr(action, "shape", None)
    if shape != want:
        return f"returned shape {shape}; allowed: {want} (cars, action_dim)"
    if not np.issubdtype(action.dtype, np.number) or not np.all(np.isfinite(action)):
        return "returned a non-finite action; allowed: finite numbers"
    return None


def _spaces_text(spaces: EntrantSpaces) -> str:
    return f"obs_dim {spaces.obs_dim}, action_dim {spaces.action_dim}, cars {spaces.cars}"


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split())
    return text[:300]


def _problems(err: pydantic.ValidationError) -> str:
    """Pydantic's errors as one line: ``key: problem`` joined by ``; ``."""
    out = []
    for e in err.errors():
        where = ".".join(str(x) for x in e["loc"])
        text = _one_line(e["msg"].removeprefix("Value error, "))
        out.append(f"{where}: {text}" if where else text)
    return "; ".join(out)

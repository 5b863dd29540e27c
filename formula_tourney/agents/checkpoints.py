"""Agent checkpoint files: written atomically, read back into the family their config names.

A checkpoint is :meth:`core.Agent.state_dict` (format 1, only tensors and plain types) saved
with ``torch.save``; reading it looks the family up by the config's ``algorithm``
(``families.py``) and checks the keys that family writes before any weight is loaded.
"""

from __future__ import annotations

import io
import pickle
from pathlib import Path
from typing import Any

import torch

from formula_tourney.agents.core import CHECKPOINT_FORMAT, CHECKPOINT_KEYS, Agent, resolve_device
from formula_tourney.agents.families import get_family
from formula_tourney.agents.variants import parse_config
from formula_tourney.errors import UserInputError
from formula_tourney.safeio import atomic_write_bytes

MAX_OBS_DIM = 100_000
"""Largest observation a checkpoint may declare (the richest observation here, window 8 with
LAC and opponents, is under 1 000 values); a bigger one is a damaged file, not an agent, and
would try to allocate its networks."""
MAX_ACTION_DIM = 16


def save_checkpoint(agent: Agent, path: str | Path, extra: dict[str, Any] | None = None) -> Path:
    """Write ``agent`` (and plain ``extra`` metadata) atomically to ``path``."""
    state = agent.state_dict()
    if extra:
        state["extra"] = extra
    buf = io.BytesIO()
    torch.save(state, buf)
    return atomic_write_bytes(path, buf.getvalue())


def load_checkpoint(path: str | Path, device: str = "cpu") -> tuple[Agent, dict[str, Any]]:
    """Rebuild the agent from a checkpoint with ``weights_only=True`` (no pickled code runs).

    Every way a file can be wrong (not a checkpoint, a missing key, a config this version does
    not accept, weights of another variant's shapes) is one UserInputError naming the file.
    """
    path = Path(path)
    if not path.is_file():
        raise UserInputError(f"checkpoint {path} does not exist")
    dev = resolve_device(device)
    try:
        state = torch.load(path, map_location=dev, weights_only=True)
    except pickle.UnpicklingError:
        # torch's text advises weights_only=False, which would run the file's code: never here
        raise UserInputError(
            f"checkpoint {path} cannot be read: it holds objects other than tensors and plain "
            "values, so it is not a formula-tourney checkpoint and is not loaded"
        ) from None
    except Exception as err:  # corrupt or foreign file; torch's own text runs over many lines
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise UserInputError(f"checkpoint {path} cannot be read: {first}") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise UserInputError(f"checkpoint {path} is not a formula-tourney agent checkpoint")
    missing = [k for k in CHECKPOINT_KEYS if k not in state]
    if missing:
        raise UserInputError(f"checkpoint {path} is incomplete: no {', '.join(missing)}")
    cfg = parse_config(state["config"], f"checkpoint {path} has a bad agent config")
    try:
        obs_dim, action_dim = int(state["obs_dim"]), int(state["action_dim"])
    except (ValueError, TypeError) as err:
        first = str(err).splitlines()[0]
        raise UserInputError(f"checkpoint {path} has bad sizes: {first}") from None
    if not (1 <= obs_dim <= MAX_OBS_DIM and 1 <= action_dim <= MAX_ACTION_DIM):
        raise UserInputError(
            f"checkpoint {path} has bad sizes {obs_dim} x {action_dim} (observation 1.."
            f"{MAX_OBS_DIM}, action 1..{MAX_ACTION_DIM})"
        )
    extra = state.get("extra", {})
    if not isinstance(extra, dict):
        raise UserInputError(
            f"checkpoint {path} has a bad 'extra': a {type(extra).__name__}, not a table"
        )
    family = get_family(cfg.algorithm)
    wanted = family.checkpoint_keys
    if cfg.eval_ema_updates:
        wanted += ("actor_eval",)
    if cfg.obs_norm:
        wanted += ("obs_norm",)
    missing = [k for k in wanted if k not in state]
    if missing:
        raise UserInputError(
            f"checkpoint {path} is incomplete for {cfg.algorithm}: no {', '.join(missing)}"
        )
    bad = _non_finite(state, CHECKPOINT_KEYS + wanted)
    if bad is not None:
        raise UserInputError(f"checkpoint {path}: its {bad} weights are not finite (NaN or "
                             "infinite): the run that wrote it diverged")
    agent = family(cfg, obs_dim, action_dim, device=str(dev))
    try:
        agent.load_state_dict(state)
    except (RuntimeError, KeyError, ValueError, TypeError) as err:
        first = str(err).strip().splitlines()[0]
        raise UserInputError(
            f"checkpoint {path}: its weights do not fit its config {cfg.name} ({first})"
        ) from None
    return agent, dict(extra)


def _non_finite(state: dict[str, Any], keys: tuple[str, ...]) -> str | None:
    """The first network (of ``keys``) holding a NaN or infinite weight, else None."""
    for key in keys:
        value = state.get(key)
        tensors = value.values() if isinstance(value, dict) else ()
        for tensor in tensors:
            if (isinstance(tensor, torch.Tensor) and tensor.is_floating_point()
                    and not bool(torch.isfinite(tensor).all())):
                return key
    return None

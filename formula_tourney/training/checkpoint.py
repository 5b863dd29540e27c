"""A run's checkpoint read back with the run specification it was trained under.

``eval`` and ``replay`` must rebuild the env exactly as training did (the observation depends
on the line, LAC and env settings), so a checkpoint carries its run spec; one without is from an
older layout and is refused with a message, never driven with guessed settings.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from formula_tourney.agents.checkpoints import load_checkpoint
from formula_tourney.agents.core import Agent
from formula_tourney.errors import UserInputError
from formula_tourney.training.run_spec import RunSpec


def load_run_checkpoint(path: str | Path, device: str = "cpu") -> tuple[Agent, RunSpec, dict]:
    """(agent, run spec, extra metadata) of a checkpoint written by ``training.loop.train``."""
    path = Path(path)
    agent, extra = load_checkpoint(path, device=device)
    data: Any = extra.get("run_spec")
    if not isinstance(data, dict):
        raise UserInputError(
            f"checkpoint {path} carries no run specification (written by an older version of "
            "formula-tourney, or not by a training run); retrain it to drive it here"
        )
    spec = RunSpec.from_json(data, f"checkpoint {path}")
    if spec.agent != agent.cfg:
        raise UserInputError(
            f"checkpoint {path}: its weights were made by another agent config than its run "
            "specification names"
        )
    return agent, spec, extra

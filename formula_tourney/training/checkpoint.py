"""A run's checkpoint read back with the run specification it was trained under.

``eval`` and ``replay`` must rebuild the env exactly as training did (the observation depends
on the line, LAC and env settings), so a checkpoint carries its run spec; one without is from an
older layout and is refused with a message, never driven with guessed settings.

An outside entrant's model (``agents.outside``) is its own file format and carries no run spec:
it is read only from a job folder (``<job>/checkpoints/<file>`` beside the job's
``config.json``), whose run spec names the entrant class that loads it. Anywhere else the file
is refused as not a formula-tourney checkpoint, so SB3's loader (which unpickles parts of its
zip) never reads a file a training run did not write into a results folder.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from formula_tourney.agents.checkpoints import load_checkpoint
from formula_tourney.agents.core import Agent
from formula_tourney.errors import UserInputError
from formula_tourney.results.folder import JobFolder
from formula_tourney.results.layout import CHECKPOINTS_DIR
from formula_tourney.training.outside import OutsideModel, load_outside_model
from formula_tourney.training.run_spec import RunSpec


def load_run_checkpoint(
    path: str | Path, device: str = "cpu"
) -> tuple[Agent | OutsideModel, RunSpec, dict]:
    """(agent, run spec, extra metadata) of a checkpoint written by ``training.loop.train``; an
    outside entrant's model in its job folder comes back as an ``OutsideModel`` (no metadata)."""
    path = Path(path)
    outside = _outside_job_spec(path)
    if outside is not None:
        return load_outside_model(path, outside, device), outside, {}
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


def _outside_job_spec(path: Path) -> RunSpec | None:
    """The run spec of the job folder holding ``path`` when that job trained an outside
    entrant; None for any other file."""
    if path.parent.name != CHECKPOINTS_DIR or not path.is_file():
        return None
    folder = JobFolder(path.parent.parent)
    if not folder.config_path.is_file():
        return None
    spec = RunSpec.from_json(folder.config(), str(folder.config_path))
    return spec if spec.outside is not None else None

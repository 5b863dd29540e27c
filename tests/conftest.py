"""Fixtures shared by the test files."""

from __future__ import annotations

import pytest
from training_fixtures import ring_track

from formula_tourney.training import envs as run_envs
from formula_tourney.training import run_spec


@pytest.fixture
def ring_tracks(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every track name loads a small ring, so training tests do not depend on the catalog."""
    monkeypatch.setattr(run_envs, "load_track", ring_track)
    monkeypatch.setattr(run_spec, "check_track_name", lambda name, base_dir=None: name)

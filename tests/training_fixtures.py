"""What the training tests share: small agent settings and small ring tracks under any name."""

from __future__ import annotations

import numpy as np

from formula_tourney.sim.track import Track

SMALL = {
    "hidden": [32, 32], "batch_size": 32, "learning_starts": 40, "buffer_size": 2000,
    "exploration_steps": 200,
}  # fmt: skip
"""Agent overrides that make an update cheap: each test run is seconds."""


def ring_track(name: str) -> Track:
    """A 500 m ring, 12 m wide, named ``name``."""
    a = np.linspace(0.0, 2 * np.pi, 400, endpoint=False)
    return Track.from_centreline(name, 80 * np.cos(a), 80 * np.sin(a), 6.0, 6.0)

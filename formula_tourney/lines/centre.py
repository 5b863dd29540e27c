"""The centre line (the paper's MOT, "middle of the track"): zero offset everywhere.

Kept as its own module so every line kind has one producer with the same signature
(``track -> offsets``), which the registry and the CLI dispatch on.
"""

from __future__ import annotations

import numpy as np

from formula_tourney.sim.track import Track


def centre_offsets(track: Track) -> np.ndarray:
    """Lateral offsets of the centre line: zeros, one per track sample."""
    return np.zeros(track.n, dtype=float)

"""Reference lines with the follower as their driver: the one call training, tournaments and the
CLI make for a line.

``lines.registry`` computes and caches every line but sits below ``bots`` (imports go downward), so
the recorded and genetic lines, which are made by driving, take their driver as an argument; this
module passes the follower in.
"""

from __future__ import annotations

import numpy as np

from formula_tourney.bots.follower import drive
from formula_tourney.lines import registry
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.track import Track


def reference_offsets(track: Track, kind: str, car: CarParams | None = None) -> np.ndarray:
    """Lateral offsets (one per track sample) of the line ``kind`` (centre | mincurv | recorded |
    genetic) on ``track`` for ``car``, cached on disk (``lines.registry``)."""
    return registry.reference_offsets(track, kind, car, driver=drive)

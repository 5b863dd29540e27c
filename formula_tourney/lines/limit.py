"""A track's reference limit: the quasi-steady-state lap time on its minimum-curvature line.

Every lap-time table shows the gap to it (docs/lines.md). It lives here, above
both ``speed_profile`` (the QSS lap) and ``registry`` (the cached min-curvature line), so that
neither of those imports the other.
"""

from __future__ import annotations

import numpy as np

from formula_tourney.lines.registry import reference_offsets
from formula_tourney.lines.speed_profile import SpeedProfile, speed_profile
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.track import Track


def reference_limit_profile(track: Track, car: CarParams | None = None,
                            grip_scale: float = 1.0) -> SpeedProfile:
    """The reference limit's lap: the QSS profile of the minimum-curvature line (cached), with
    every surface's friction times ``grip_scale`` (the env key). The line stays the one of grip
    1: minimum curvature is geometry, so at another grip only the speeds along it change."""
    car = car or CarParams()
    return speed_profile(track, reference_offsets(track, "mincurv", car), car,
                         grip_scale=grip_scale)


def reference_limit_s(track: Track, car: CarParams | None = None,
                      grip_scale: float = 1.0) -> float:
    """The track's reference limit: the lap time of :func:`reference_limit_profile`."""
    return reference_limit_profile(track, car, grip_scale).lap_time_s


def reference_limit_speeds_mps(track: Track, car: CarParams | None = None,
                               grip_scale: float = 1.0) -> np.ndarray:
    """The reference limit's speed (m/s) at each track sample, which the reward's overspeed
    crash term compares a car's speed with where it leaves the track."""
    return reference_limit_profile(track, car, grip_scale).speed_mps

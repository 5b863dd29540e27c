"""Start-state curriculum (beyond the paper): training starts spread before the braking zones.

Exploration rarely brakes long enough for a hairpin (docs/agents.md, "Acting and exploration"),
and a start drawn uniformly over the lap puts few episodes where braking is learned. With the
env setting ``start_curriculum = "braking"`` a share (``start_curriculum_share``) of training
episodes starts at one of the positions :func:`braking_starts` finds: every ``spacing_m`` from
``lead_m`` up to the braking point of each zone where the reference line's QSS speed profile
(``lines.speed_profile``) falls. The env draws among them (``curriculum_starts_m``).
"""

from __future__ import annotations

import numpy as np

from formula_tourney.lines.speed_profile import speed_profile
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.track import Track

LEAD_M = 150.0
"""How far before a braking point the earliest curriculum start lies."""
SPACING_M = 25.0
"""Distance between two curriculum starts before one braking point."""
MIN_DROP_MPS = 3.0
"""A zone counts when the profile's speed falls by at least this much within it: small dips
(a kink on a straight) need no braking to learn."""


def braking_zones(speed_mps: np.ndarray) -> list[tuple[int, int]]:
    """The braking zones of a closed lap's speed profile (one speed per sample): per zone the
    sample where the speed starts to fall and the one where it stops falling (modulo the
    sample count), for every fall of at least :data:`MIN_DROP_MPS`."""
    v = np.asarray(speed_mps, dtype=float)
    n = len(v)
    falling = np.roll(v, -1) < v  # the speed falls from sample i to i + 1
    zones = []
    for i in np.flatnonzero(falling & ~np.roll(falling, 1)):
        j = int(i)
        while falling[j % n] and j - i < n:
            j += 1
        if v[i] - v[j % n] >= MIN_DROP_MPS:
            zones.append((int(i), j % n))
    return zones


def braking_points_m(track: Track, offsets_m: np.ndarray | float, car: CarParams) -> np.ndarray:
    """Track positions (m along the centreline) where the QSS profile of the line with these
    offsets starts to decelerate, one per braking zone of at least :data:`MIN_DROP_MPS`."""
    v = speed_profile(track, offsets_m, car).speed_mps
    return np.asarray([float(track.s_m[i]) for i, _ in braking_zones(v)])


def braking_starts(
    track: Track,
    offsets_m: np.ndarray | float,
    car: CarParams,
    lead_m: float = LEAD_M,
    spacing_m: float = SPACING_M,
) -> tuple[float, ...]:
    """Curriculum starts: ``spacing_m``, 2 ``spacing_m``, ... up to ``lead_m`` before each
    braking point of :func:`braking_points_m`, modulo the track length, in ascending order."""
    leads = np.arange(spacing_m, lead_m + 1e-9, spacing_m)
    points = braking_points_m(track, offsets_m, car)
    starts = (points[:, None] - leads[None, :]) % track.length_m
    return tuple(float(s) for s in np.sort(starts.ravel()))

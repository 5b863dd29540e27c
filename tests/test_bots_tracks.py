"""The issue's acceptance checks on the real tracks: built-in and 20 generated ones.

Skipped only while the track catalog (``sim.catalog``) or the generator (``sim.generate``) has
not landed.
"""

from __future__ import annotations

import numpy as np
import pytest

from formula_tourney.bots.follower import drive
from formula_tourney.lines.mincurv import mincurv
from formula_tourney.lines.speed_profile import lap_time_s
from formula_tourney.sim.reference_line import ReferenceLine

catalog = pytest.importorskip("formula_tourney.sim.catalog")

BUILT_IN = ("oval", "technical", "flowing")
GENERATED = tuple(f"gen-{seed}" for seed in range(20))
_LINES: dict[str, tuple] = {}


def _lines(name: str):
    if name not in _LINES:
        track = catalog.load_track(name)
        _LINES[name] = (track, mincurv(track))
    return _LINES[name]


@pytest.mark.parametrize("name", BUILT_IN)
def test_mincurv_beats_centre_on_built_in_tracks(name):
    track, res = _lines(name)
    centre = ReferenceLine.from_offsets(track, 0.0)
    line = ReferenceLine.from_offsets(track, res.offsets_m)
    assert np.sum(line.curvature_1pm**2) < np.sum(centre.curvature_1pm**2)
    assert lap_time_s(track, res.offsets_m) < lap_time_s(track, 0.0)
    assert np.all(res.qp_offsets_m >= res.lower_m - 1e-6)
    assert np.all(res.qp_offsets_m <= res.upper_m + 1e-6)
    assert res.seconds < 10.0


@pytest.mark.parametrize("name", BUILT_IN)
def test_follower_clean_and_within_10pct_of_limit_on_built_in_tracks(name):
    track, res = _lines(name)
    limit = lap_time_s(track, res.offsets_m)
    for offsets in (np.zeros(track.n), res.offsets_m):
        result = drive(track, offsets, laps=2)
        assert result["finished"], (name, result["termination"])
        assert result["damage"] == 0.0
    assert result["best_lap_s"] < 1.10 * limit


@pytest.mark.parametrize("name", GENERATED)
def test_follower_clean_on_generated_tracks(name):
    pytest.importorskip("formula_tourney.sim.generate")
    track, res = _lines(name)
    # One flying lap each keeps the 40 drives under ~30 s (2 laps each: measured all clean).
    for offsets in (np.zeros(track.n), res.offsets_m):
        result = drive(track, offsets, laps=1)
        assert result["finished"], (name, result["termination"])
        assert result["damage"] == 0.0

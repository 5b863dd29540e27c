"""``replay --braking``: a line's braking zones and where a drive brakes for them.

The zones of ``technical`` are the real ones (its first hairpin: the centre line's QSS lap
brakes 132 m before it from 239 to 55 km/h); the drives are hand-made traces whose brake
points and speeds are known, so each figure the table prints is checked against the number it
must be.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.catalog import load_track
from formula_tourney.training.braking import (
    APPROACH_M,
    LineZone,
    braking_lines,
    drive_braking,
    line_braking_zones,
)
from formula_tourney.training.curriculum import braking_points_m, braking_zones


def test_a_zone_runs_from_where_the_speed_starts_falling_to_where_it_stops() -> None:
    v = np.array([50.0] * 5 + [45.0, 38.0, 30.0, 25.0] + [25.0, 40.0, 50.0]
                 + [49.0, 48.5] + [50.0] * 3)  # fmt: skip
    # the fall from sample 4 (50) to 8 (25) is a zone; the 1.5 m/s dip at 11-13 is not
    assert braking_zones(v) == [(4, 8)]
    # a zone across the lap's end wraps: the fall from the last sample to sample 2
    assert braking_zones(np.array([20.0, 15.0, 10.0, 30.0, 30.0, 25.0])) == [(4, 2)]


def test_technicals_first_hairpin_as_the_centre_line_brakes_for_it() -> None:
    track = load_track("technical")
    zones = line_braking_zones(track, 0.0, CarParams())
    first = zones[0]
    assert first.brake_s_m == pytest.approx(374.1, abs=0.5)
    assert first.apex_s_m == pytest.approx(528.1, abs=0.5)
    assert (round(first.brake_kmh), round(first.apex_kmh)) == (239, 55)
    assert all(z.apex_kmh < z.brake_kmh for z in zones)
    # on a wet track (grip 0.8, as a test at another grip drives) the line brakes 19 m sooner
    # for a slower apex; the curriculum finds the same braking point at grip 1
    wet = line_braking_zones(track, 0.0, CarParams(), grip_scale=0.8)[0]
    assert wet.brake_s_m == pytest.approx(355.1, abs=0.5) and round(wet.apex_kmh) == 50
    assert braking_points_m(track, 0.0, CarParams())[0] == first.brake_s_m


ZONES = [LineZone(400.0, 240.0, 500.0, 80.0), LineZone(700.0, 200.0, 850.0, 60.0)]
LENGTH_M = 1000.0


def _drive(start_s_m: float, brakes: list[tuple[float, float, float]],
           end_u: float) -> pd.DataFrame:  # fmt: skip
    """A drive every 5 m from ``start_s_m`` (unwrapped) to ``end_u`` at 200 km/h, but for
    each ``(from_u, to_u, floor_kmh)`` of ``brakes``: brake 1.0 from ``from_u`` up to
    ``to_u``, 40 km/h slower every 25 m down to ``floor_kmh``."""
    u = np.arange(start_s_m + 5.0, end_u + 1e-9, 5.0)
    kmh = np.full(len(u), 200.0)
    brake = np.zeros(len(u))
    for from_u, to_u, floor_kmh in brakes:
        braking = (u >= from_u) & (u < to_u)
        kmh[braking] = np.maximum(200.0 - 40.0 * (u[braking] - from_u) / 25.0, floor_kmh)
        brake[braking] = 1.0
    return pd.DataFrame({"distance_m": u - start_s_m, "speed_kmh": kmh, "brake": brake})


def test_a_late_brake_and_the_speeds_it_leaves_at_the_apex() -> None:
    steps = _drive(100.0, [(450.0, 560.0, 120.0), (690.0, 855.0, 60.0)], 1000.0)
    first, second = drive_braking(steps, 100.0, LENGTH_M, ZONES, "max_steps")
    assert first.brake_s_m == 450.0 and first.late_m == 50.0 and first.brake_kmh == 200.0
    assert first.at_line_brake_kmh == 200.0  # it had not braked yet where the line does
    assert first.apex_kmh == 120.0 and first.ended_by is None
    # 10 m before the limit: the first zone's press, held on to 560 m, is not the second's
    # (its approach starts after the first apex, 500 m, not 250 m before its point, 450 m)
    assert second.brake_s_m == 690.0 and second.late_m == -10.0 and second.apex_kmh == 60.0
    lines = braking_lines([first.as_dict(), second.as_dict()], "the centre line's QSS lap")
    assert lines[0].startswith("braking zones of the centre line's QSS lap, the drive's first")
    assert lines[1] == ("  zone 0: the line brakes at 400 m from 240 to 80 km/h at 500 m | "
                        "drive brakes at 450 m (+50 m late) at 200 km/h; 200 km/h at the "
                        "line's point; 120 km/h at the apex")


def test_a_drive_that_ends_in_a_zone_is_reported_there_and_stops_the_table() -> None:
    steps = _drive(100.0, [], 480.0)  # no brake, off the track 20 m before the apex
    (only,) = drive_braking(steps, 100.0, LENGTH_M, ZONES, "off_track")
    assert only.brake_s_m is None and only.apex_kmh is None
    assert (only.ended_by, only.ended_s_m, only.ended_kmh) == ("off_track", 480.0, 200.0)
    line = braking_lines([only.as_dict()], "the centre line's QSS lap")[1]
    assert "no brake in the approach" in line and "ended (off_track) at 480 m, 200 km/h" in line


def test_a_drive_that_ends_leaving_a_corner_is_reported_in_that_corner() -> None:
    steps = _drive(100.0, [(450.0, 560.0, 120.0)], 555.0)  # past the apex, still braking
    (only,) = drive_braking(steps, 100.0, LENGTH_M, ZONES, "backwards")
    assert only.zone == 0 and only.apex_kmh == 120.0
    assert (only.ended_by, only.ended_s_m, only.ended_kmh) == ("backwards", 555.0, 120.0)


def test_a_start_inside_an_approach_reads_that_zone_from_the_start() -> None:
    start = 400.0 - APPROACH_M / 2  # half-way into the first zone's approach
    steps = _drive(start, [(1450.0, 1505.0, 80.0)], 1600.0)  # it brakes only one lap on
    drives = drive_braking(steps, start, LENGTH_M, ZONES, "max_steps")
    assert [d.zone for d in drives] == [0, 1]  # this lap's, the first from its start on
    assert drives[0].brake_s_m is None and drives[0].apex_kmh == 200.0
    past_apex = 520.0  # a start past the first zone's apex reads it on the next lap
    drives = drive_braking(_drive(past_apex, [(1450.0, 1505.0, 80.0)], 1600.0), past_apex,
                           LENGTH_M, ZONES, "max_steps")  # fmt: skip
    assert [d.zone for d in drives] == [1, 0]
    assert drives[1].brake_s_m == 450.0 and drives[1].late_m == 50.0
    assert drive_braking(steps.iloc[:0], start, LENGTH_M, ZONES, "max_steps") == []

"""Race timing by hand: laps, positions, gaps and overtakes from scripted race distances."""

from __future__ import annotations

import math

import numpy as np
import pytest

from formula_tourney.race.timing import FINISHED, RETIRED, RaceTiming

LENGTH_M = 1000.0
DT_S = 0.2


def _run(speeds_mps: list[float], starts_m: list[float], steps: int, laps: int = 3,
         timing: RaceTiming | None = None) -> RaceTiming:
    """Cars at constant speeds from race distances ``starts_m``; crossings at k * LENGTH_M."""
    n = len(speeds_mps)
    timing = timing or RaceTiming([f"car{c}" for c in range(n)], LENGTH_M, laps)
    v = np.asarray(speeds_mps)
    d0 = np.asarray(starts_m)
    for k in range(1, steps + 1):
        t = k * DT_S
        d_prev, d = d0 + v * (t - DT_S), d0 + v * t
        for c in range(n):
            for lap in range(int(math.floor(d_prev[c] / LENGTH_M)) + 1,
                             int(math.floor(d[c] / LENGTH_M)) + 1):
                timing.crossing(c, (lap * LENGTH_M - d0[c]) / v[c])
        timing.step(t, d)
    return timing


def test_two_car_positions_and_gaps_follow_from_the_distances():
    # A at 50 m/s from 10 m behind the line, B at 40 m/s from 18 m behind.
    timing = _run([50.0, 40.0], [-10.0, -18.0], steps=100)
    t = 100 * DT_S
    d_a, d_b = -10.0 + 50.0 * t, -18.0 + 40.0 * t
    assert timing.positions == [1, 2]
    assert timing.gap_m(1) == pytest.approx(d_a - d_b, abs=1e-9)
    # B is at d_b now; A was there at (d_b + 10) / 50: gap = 0.2 t + 0.16 s.
    assert timing.gap_s(1) == pytest.approx(0.2 * t + 0.16, abs=1e-9)
    assert timing.gap_s(0) == 0.0
    a, b = timing.cars
    assert len(a.crossings_s) == 1 and a.laps_done == 0  # the first crossing starts lap 1
    assert a.crossings_s[0] == pytest.approx(10.0 / 50.0)
    assert timing.overtakes == []


def test_laps_are_timed_from_the_green_light_then_line_to_line():
    timing = _run([50.0], [-10.0], steps=250)  # 50 s: d = 2490 m, two laps done
    car = timing.cars[0]
    assert car.laps_done == 2
    # Lap 1 from the start (t = 0) to d = 1000 m: 1010 m at 50 m/s; lap 2 one lap: 20 s.
    assert car.lap_times_s() == pytest.approx([20.2, 20.0])


def test_a_faster_car_from_behind_overtakes_once():
    timing = _run([50.0, 60.0], [-10.0, -19.0], steps=10)
    # B reaches A when -19 + 60 t = -10 + 50 t: t = 0.9 s, seen at the end of the 1.0 s step.
    assert timing.positions == [2, 1]
    assert timing.overtakes == [{"t_s": pytest.approx(1.0), "lap": 1, "by": "car1",
                                 "on": "car0"}]
    # Gap of A behind B at t = 2 s: B was at A's 90 m at (90 + 19) / 60 s.
    assert timing.gap_s(0) == pytest.approx(2.0 - 109.0 / 60.0, abs=1e-9)


def test_finished_cars_lead_then_running_then_retired():
    timing = RaceTiming(["a", "b", "c"], LENGTH_M, 1)
    timing.step(0.2, np.array([10.0, 5.0, 0.0]))
    timing.retire(0, "stopped")  # the furthest car retires: classified last
    timing.step(0.4, np.array([10.0, 6.0, 3.0]))
    assert timing.order() == [1, 2, 0]
    timing.crossing(2, 0.5)
    timing.finish(2, 0.5)
    timing.step(0.6, np.array([10.0, 8.0, 3.0]))
    assert timing.order() == [2, 1, 0]
    assert timing.cars[2].status == FINISHED and timing.cars[0].status == RETIRED
    assert math.isnan(timing.gap_s(0))

"""Sector losses of a lap against a QSS profile (lines.lap_loss)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from formula_tourney.bots.follower import drive
from formula_tourney.bots.line_offsets import reference_offsets
from formula_tourney.errors import UserInputError
from formula_tourney.lines.lap_loss import driven_time_at, lap_loss, track_sectors
from formula_tourney.lines.speed_profile import speed_profile
from formula_tourney.report.plots import one_lap
from formula_tourney.sim.catalog import load_track
from formula_tourney.sim.track import Track

PERIOD_S = 0.2


def profile_lap(track: Track, stretch: float = 1.0, delay_at_m: float | None = None,
                delay_s: float = 0.0, phase_s: float = 0.097) -> tuple[dict, float, object]:
    """A trace that drives the QSS profile itself (times x ``stretch``, plus ``delay_s`` spent
    at station ``delay_at_m``), sampled every control step from ``phase_s`` after the line, as
    the env's best-lap traces are, the last row one step past the line."""
    prof = speed_profile(track, 0.0)
    st = np.concatenate([track.s_m, [track.length_m]])
    tt = np.concatenate([prof.time_s, [prof.lap_time_s]]) * stretch
    if delay_at_m is not None:
        tt = tt + delay_s * (st >= delay_at_m)
    lap = float(tt[-1])
    times = np.arange(phase_s, lap, PERIOD_S)
    times = np.append(times, times[-1] + PERIOD_S)  # the step that crossed the line
    s = np.interp(times, tt, st)
    s[-1] = np.interp(times[-1] - lap, tt, st)  # wrapped past the line
    speed = np.gradient(s[:-1], times[:-1]) * 3.6
    return {"time_s": times, "s_m": s, "speed_kmh": np.append(speed, speed[-1])}, lap, prof


@pytest.fixture(scope="module")
def oval() -> Track:
    return load_track("oval")


def test_sectors_are_the_tracks_segments_and_cover_the_lap(oval: Track) -> None:
    sectors = track_sectors(oval)
    assert [s.name for s in sectors][:2] == ["1 straight 150 m", "2 arc R500 24deg"]
    assert [s.kind for s in sectors] == [str(seg["type"]) for seg in oval.segments]
    assert len(sectors) == len(oval.segments) == 6
    assert sectors[0].s_start_m == 0.0 and sectors[-1].s_end_m == pytest.approx(oval.length_m)
    assert all(a.s_end_m == b.s_start_m for a, b in zip(sectors, sectors[1:], strict=False))


def test_a_track_without_segments_gets_equal_bins() -> None:
    a = np.linspace(0.0, 2.0 * np.pi, 400, endpoint=False)
    track = Track.from_centreline("ring", 300 * np.cos(a), 300 * np.sin(a), 6.0, 6.0)
    assert not track.segments  # a track made from a polyline has no segment list
    sectors = track_sectors(track, bin_m=250.0)
    assert len(sectors) == round(track.length_m / 250.0)
    widths = [s.s_end_m - s.s_start_m for s in sectors]
    assert sum(widths) == pytest.approx(track.length_m)
    assert {s.kind for s in sectors} == {"bin"}
    assert max(widths) - min(widths) < 1e-9
    with pytest.raises(UserInputError, match="sector length"):
        track_sectors(track, bin_m=0.0)


def test_the_profile_driven_loses_nothing_anywhere(oval: Track) -> None:
    trace, lap, prof = profile_lap(oval)
    losses = lap_loss(trace, lap, oval, prof, track_sectors(oval)).sectors
    assert lap == pytest.approx(prof.lap_time_s)
    assert max(abs(x.loss_s) for x in losses) < 0.005
    assert sum(x.driven_s for x in losses) == pytest.approx(lap)


def test_a_uniformly_slower_lap_loses_in_proportion(oval: Track) -> None:
    trace, lap, prof = profile_lap(oval, stretch=1.02)
    losses = lap_loss(trace, lap, oval, prof, track_sectors(oval)).sectors
    for x in losses:
        assert x.loss_s == pytest.approx(0.02 * x.profile_s, abs=0.005)
    assert sum(x.loss_s for x in losses) == pytest.approx(lap - prof.lap_time_s, abs=1e-9)


def test_a_delay_is_charged_to_its_sector_only(oval: Track) -> None:
    sectors = track_sectors(oval)
    at = 0.5 * (sectors[3].s_start_m + sectors[3].s_end_m)  # the middle of the first R250 arc
    trace, lap, prof = profile_lap(oval, delay_at_m=at, delay_s=1.0)
    losses = lap_loss(trace, lap, oval, prof, sectors).sectors
    assert losses[3].loss_s == pytest.approx(1.0, abs=0.01)
    assert max(abs(x.loss_s) for k, x in enumerate(losses) if k != 3) < 0.01


def test_the_crossings_come_from_the_rows_not_the_window_cut(oval: Track) -> None:
    # the same drive with its rows 0.03 s later and the lap's time given exactly
    trace, lap, _ = profile_lap(oval, phase_s=0.05)
    shifted = {**trace, "time_s": trace["time_s"] + 0.03}
    stations, times = driven_time_at(shifted["time_s"], shifted["s_m"], lap, oval.length_m)
    assert stations[0] == 0.0 and stations[-1] == oval.length_m
    assert times[0] == 0.0 and times[-1] == pytest.approx(lap)
    assert times[1] == pytest.approx(0.05, abs=0.002)


def test_the_followers_lap_adds_up_to_its_gap_and_misses_the_corner_speed(oval: Track) -> None:
    offsets = reference_offsets(oval, "mincurv")
    prof = speed_profile(oval, offsets)
    result = drive(oval, offsets, laps=2)
    frame = one_lap(pd.DataFrame(result["trace"]), result["lap_times_s"], result["lap_damage"])
    best = min(result["lap_times_s"])  # the flying lap
    lap_trace = {c: frame[c].to_numpy(float) for c in ("time_s", "s_m", "speed_kmh")}
    loss = lap_loss(lap_trace, best, oval, prof, track_sectors(oval))
    assert math.isclose(sum(x.loss_s for x in loss.sectors), best - prof.lap_time_s, abs_tol=1e-9)
    # the running loss the figure draws ends at the lap's gap, and the kinds split it
    assert loss.loss_s[-1] == pytest.approx(best - prof.lap_time_s, abs=1e-9)
    by_kind = loss.loss_by_kind()
    assert set(by_kind) == {"straight", "arc"}
    assert sum(by_kind.values()) == pytest.approx(best - prof.lap_time_s, abs=1e-9)
    arcs = [x for x in loss.sectors if "R250" in x.name]
    # flat out in the long arcs, the simulated car holds less than the QSS corner speed
    assert all(x.min_speed_kmh < x.profile_min_speed_kmh - 3.0 for x in arcs)
    assert all(x.loss_s > 0.1 for x in arcs)


def test_a_sectors_profile_minimum_is_the_profiles_own(oval: Track) -> None:
    trace, lap, prof = profile_lap(oval)
    sectors = track_sectors(oval)
    losses = lap_loss(trace, lap, oval, prof, sectors).sectors
    for sec, x in zip(sectors, losses, strict=True):
        inside = (oval.s_m >= sec.s_start_m) & (oval.s_m <= sec.s_end_m)
        assert x.profile_min_speed_kmh <= prof.speed_kmh[inside].min() + 1e-9
        assert x.profile_min_speed_kmh >= prof.speed_kmh.min() - 1e-9


def test_a_car_that_rolls_back_keeps_a_monotone_curve(oval: Track) -> None:
    times = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    s = np.array([100.0, 200.0, 190.0, 195.0, 300.0, 2300.0])
    stations, curve = driven_time_at(times, s, 6.0, oval.length_m)
    assert np.all(np.diff(stations) > 0) and np.all(np.diff(curve) >= 0)
    assert 190.0 not in stations and 195.0 not in stations


def test_a_profile_of_another_track_is_refused(oval: Track) -> None:
    trace, lap, _ = profile_lap(oval)
    other = speed_profile(load_track("technical"), 0.0)
    with pytest.raises(UserInputError, match="another track"):
        lap_loss(trace, lap, oval, other, track_sectors(oval))

"""The follower bot driving the simulator: clean laps, lap times near the QSS profile, traces."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_lines_support import hairpins, stadium, technical_like

from formula_tourney.bots.follower import Follower, FollowerConfig, drive
from formula_tourney.errors import UserInputError
from formula_tourney.lines.mincurv import mincurv_offsets
from formula_tourney.lines.recorded import recorded_offsets
from formula_tourney.lines.speed_profile import lap_time_s


@pytest.fixture(scope="module")
def lines():
    out = {}
    for track in (stadium(), hairpins()):
        out[track.name] = (track, np.zeros(track.n), mincurv_offsets(track))
    return out


@pytest.mark.parametrize("name", ["stadium", "hairpins"])
@pytest.mark.parametrize("kind", ["centre", "mincurv"])
def test_follower_laps_cleanly_near_the_profile(lines, name, kind):
    track, centre, mincurv = lines[name]
    offsets = centre if kind == "centre" else mincurv
    result = drive(track, offsets, laps=2)
    assert result["finished"], result["termination"]
    assert result["damage"] == 0.0
    assert len(result["lap_times_s"]) == 2
    profile = lap_time_s(track, offsets)
    # The QSS lap is a bound: the bot is slower, but within 15% of it (measured 7-9%).
    assert profile < result["best_lap_s"] < 1.15 * profile
    # Flying laps repeat: the second lap is within 3% of the first.
    first, second = result["lap_times_s"]
    assert abs(first - second) < 0.03 * first


def test_mincurv_line_is_faster_to_drive_than_centre(lines):
    track, centre, mincurv = lines["hairpins"]
    on_centre = drive(track, centre, laps=2)["best_lap_s"]
    on_mincurv = drive(track, mincurv, laps=2)["best_lap_s"]
    assert on_mincurv < 0.95 * on_centre


def test_trace_and_recorded_line(lines):
    track, _, mincurv = lines["hairpins"]
    result = drive(track, mincurv, laps=2)
    trace = result["trace"]
    n = result["steps"]
    for key in ("time_s", "distance_m", "s_m", "lateral_m", "x_m", "y_m", "speed_kmh", "steer",
                "throttle", "brake", "lap"):
        assert len(trace[key]) == n
    # 0 before the line, k during timed lap k, 3 once the second lap is done.
    assert trace["lap"][0] == 0 and max(trace["lap"]) == 3
    assert np.all(np.abs(trace["steer"]) <= 1.0)
    assert min(trace["throttle"]) >= 0.0 and max(trace["brake"]) <= 1.0
    # The line the bot drove (RC) stays near the line it was told to follow.
    rec = recorded_offsets(track, result)
    assert np.percentile(np.abs(rec - mincurv), 95) < 1.0
    assert lap_time_s(track, rec) < 1.05 * lap_time_s(track, mincurv)


def test_follower_targets_and_config_checks(lines):
    track, _, mincurv = lines["stadium"]
    bot = Follower(track, mincurv, config=FollowerConfig(speed_factor=0.9))
    i = track.n // 2
    assert bot.target_speed_mps(track.s_m[i]) == pytest.approx(bot.plan.speed_mps[i])
    # The margin is on corner speeds only; the slowest corner is planned at 90% of its limit.
    assert np.all(bot.target_mps <= 0.9 * bot.profile.corner_speed_mps + 1e-9)
    assert np.all(bot.target_mps <= bot.profile.speed_mps + 1e-9)
    assert bot.target_mps.min() < 0.95 * bot.profile.speed_mps.min()
    assert math.isclose(bot.profile.lap_time_s, lap_time_s(track, mincurv))
    with pytest.raises(UserInputError):
        FollowerConfig(speed_factor=-1.0).validate()
    with pytest.raises(UserInputError):
        Follower(track, mincurv[:10])
    with pytest.raises(UserInputError):
        drive(track, mincurv, laps=0)


def test_technical_track_clean_and_near_the_limit():
    track = technical_like()
    mincurv = mincurv_offsets(track)
    limit = lap_time_s(track, mincurv)
    on_centre = drive(track, np.zeros(track.n), laps=2)
    on_mincurv = drive(track, mincurv, laps=2)
    for result in (on_centre, on_mincurv):
        assert result["finished"] and result["damage"] == 0.0
    # Measured: 72.2 s against a 66.9 s limit (+7.9%); the centre line's QSS lap is 79.9 s.
    assert limit < on_mincurv["best_lap_s"] < 1.10 * limit
    assert on_centre["best_lap_s"] > lap_time_s(track, 0.0) > 1.1 * limit


def test_registry_recorded_and_genetic_lines_are_driven(tmp_path, monkeypatch):
    from formula_tourney.bots.line_offsets import reference_offsets
    from formula_tourney.lines import registry

    monkeypatch.setenv(registry.CACHE_ENV_VAR, str(tmp_path))
    track = stadium()
    mincurv = reference_offsets(track, "mincurv")
    recorded = reference_offsets(track, "recorded")
    # RC: the follower's own lap on the min-curvature line, close to it and as fast in QSS.
    assert np.percentile(np.abs(recorded - mincurv), 95) < 1.0
    assert lap_time_s(track, recorded) < 1.03 * lap_time_s(track, mincurv)
    genetic = reference_offsets(track, "genetic")
    assert lap_time_s(track, genetic) < lap_time_s(track, 0.0)
    driven = drive(track, genetic, laps=2)
    assert driven["finished"] and driven["damage"] == 0.0
    kinds = sorted(p.name.split("-")[-2] for p in (tmp_path / "lines").glob("*.npy"))
    assert kinds == ["genetic", "mincurv", "recorded"]

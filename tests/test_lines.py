"""Lines and the QSS speed profile: closed forms, QP constraints, caching, reproducibility."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_lines_support import circle, hairpins, stadium

from formula_tourney.errors import UserInputError
from formula_tourney.lines import registry
from formula_tourney.lines.genetic import genetic_line
from formula_tourney.lines.lac import lac
from formula_tourney.lines.mincurv import DEFAULT_MARGIN_M, mincurv
from formula_tourney.lines.recorded import recorded_offsets
from formula_tourney.lines.speed_profile import (
    corner_speed_mps,
    lap_time_s,
    speed_profile,
    straight_run,
    top_speed_mps,
)
from formula_tourney.sim.car_params import GRAVITY_MPS2, CarParams
from formula_tourney.sim.reference_line import ReferenceLine

G = GRAVITY_MPS2


def _flat_torque_car(force_n: float, **kw) -> CarParams:
    """One gear, flat torque: a constant tractive force ``force_n`` at every speed."""
    ratio, final, radius, eff = 1.0, 1.0, 0.5, 1.0
    torque = force_n * radius / (ratio * final * eff)
    return CarParams(
        gear_ratios=(ratio,), final_drive=final, wheel_radius_m=radius, drivetrain_efficiency=eff,
        engine_rpm_points=(0.0, 1e6), engine_torque_points_nm=(torque, torque),
        redline_rpm=1e6, upshift_rpm=9e5, downshift_rpm=1.0, **kw,
    )


# --- speed profile: closed forms -------------------------------------------------------------

STIFF = {"cornering_stiffness_front_n_per_rad": 1e12, "cornering_stiffness_rear_n_per_rad": 1e12}
"""Tyres that corner without slip: no cornering drag, so the textbook closed forms hold."""


def test_circle_no_drag_matches_textbook_corner_speed():
    car = CarParams(drag_coef_n_per_mps2=0.0, rolling_resistance=0.0, **STIFF)
    radius = 80.0
    expected_v = math.sqrt(car.mu * car.mass_kg * G * radius
                           / (car.mass_kg - car.mu * car.downforce_coef_n_per_mps2 * radius))
    assert corner_speed_mps(1 / radius, car) == pytest.approx(expected_v, rel=1e-12)
    prof = speed_profile(circle(radius), 0.0, car)
    assert prof.lap_time_s == pytest.approx(2 * math.pi * radius / expected_v, rel=5e-4)
    assert np.ptp(prof.speed_mps) < 0.01


def test_circle_holds_speed_against_drag():
    car = CarParams(**STIFF)
    radius = 100.0
    v = float(corner_speed_mps(1 / radius, car))
    normal = car.mass_kg * G + car.downforce_coef_n_per_mps2 * v * v
    lateral = car.mass_kg * v * v / radius
    longitudinal = car.drag_coef_n_per_mps2 * v * v + car.rolling_resistance * normal
    # At the limit speed the friction circle is exactly full.
    assert math.hypot(lateral, longitudinal) == pytest.approx(car.mu * normal, rel=1e-9)
    assert 42.0 < v < 45.0
    prof = speed_profile(circle(radius), 0.0, car)
    assert prof.lap_time_s == pytest.approx(2 * math.pi * radius / v, rel=5e-4)


def _fiala_drag(force, f_max, stiffness):
    """Independent check of the cornering drag: F tan(alpha) with F/Fmax = 1 - (1 - u)^3."""
    u = 1.0 - (1.0 - min(force / f_max, 1.0)) ** (1.0 / 3.0)
    return force * 3.0 * f_max * u / stiffness


def test_circle_default_car_settles_where_engine_meets_cornering_drag():
    car = CarParams()
    radius = 250.0
    m, g = car.mass_kg, G
    wb, lf, lr = car.wheelbase_m, car.cg_to_front_m, car.cg_to_rear_m

    def surplus(v):
        normal = m * g + car.downforce_coef_n_per_mps2 * v * v
        lat = m * v * v / radius
        load = normal / (m * g)
        cornering = (
            _fiala_drag(lat * lr / wb, car.mu * normal * lr / wb,
                        car.cornering_stiffness_front_n_per_rad * load)
            + _fiala_drag(lat * lf / wb, car.mu * normal * lf / wb,
                          car.cornering_stiffness_rear_n_per_rad * load))
        resist = car.drag_coef_n_per_mps2 * v * v + car.rolling_resistance * normal + cornering
        return float(car.max_drive_force_n(v)) - resist

    lo, hi = 10.0, float(corner_speed_mps(1 / radius, car))
    assert surplus(hi) < 0 < surplus(lo)  # at the friction limit the tyres drag too much
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if surplus(mid) > 0 else (lo, mid)
    prof = speed_profile(circle(radius), 0.0, car)
    assert np.median(prof.speed_mps) == pytest.approx(lo, rel=2e-3)
    assert prof.lap_time_s == pytest.approx(2 * math.pi * radius / lo, rel=2e-3)
    # Cornering drag costs several percent against the friction-limited speed.
    assert lo < 0.97 * corner_speed_mps(1 / radius, car)


def test_straight_constant_force_from_standstill():
    force = 6000.0
    car = _flat_torque_car(force, drag_coef_n_per_mps2=0.0, rolling_resistance=0.0, mu=5.0)
    length = 400.0
    t, v_end = straight_run(length, car)
    assert t == pytest.approx(math.sqrt(2 * length * car.mass_kg / force), rel=1e-6)
    assert v_end == pytest.approx(math.sqrt(2 * force / car.mass_kg * length), rel=1e-6)


def test_straight_grip_limited_launch_on_the_rear_axle():
    car = _flat_torque_car(1e6, drag_coef_n_per_mps2=0.0, rolling_resistance=0.0,
                           downforce_coef_n_per_mps2=0.0)
    # Rear axle at its grip limit with load transfer: a = mu g lf / (wb - mu h).
    accel = car.mu * G * car.cg_to_front_m / (car.wheelbase_m - car.mu * car.cg_height_m)
    t, _ = straight_run(100.0, car)
    assert t == pytest.approx(math.sqrt(2 * 100.0 / accel), rel=1e-6)


def test_straight_constant_force_against_drag():
    force, drag = 8000.0, 0.5
    car = _flat_torque_car(force, drag_coef_n_per_mps2=drag, rolling_resistance=0.0, mu=5.0)
    length, m = 600.0, car.mass_kg
    # x(t) = (m/k) ln cosh(t sqrt(F k) / m)  =>  t = m / sqrt(F k) * arccosh(exp(k x / m)).
    expected = m / math.sqrt(force * drag) * math.acosh(math.exp(drag * length / m))
    t, v_end = straight_run(length, car, spacing_m=0.5)
    assert t == pytest.approx(expected, rel=2e-4)
    v_expected = math.sqrt(force / drag * (1 - math.exp(-2 * drag * length / m)))
    assert v_end == pytest.approx(v_expected, rel=2e-4)


def test_default_car_top_speed_and_launch_are_plausible():
    car = CarParams()
    v_top = top_speed_mps(car)
    assert 280 / 3.6 < v_top < 320 / 3.6
    assert car.max_drive_force_n(v_top) == pytest.approx(
        car.drag_force_n(v_top) + car.rolling_resistance * car.normal_force_n(v_top), rel=0.01)
    t_1km, v_1km = straight_run(1000.0, car)
    assert 15.0 < t_1km < 25.0 and v_1km < v_top


def test_closed_lap_is_consistent_across_the_start_line():
    base = stadium()
    shift = base.n // 3
    rolled = type(base).from_centreline(
        "rolled", np.roll(base.x_m, -shift), np.roll(base.y_m, -shift), 6.0, 6.0)
    a = speed_profile(base, 0.0)
    b = speed_profile(rolled, 0.0)
    assert a.lap_time_s == pytest.approx(b.lap_time_s, rel=1e-3)
    # The speed entering sample 0 is the speed leaving the last sample (no jump).
    dv = abs(a.speed_mps[0] - a.speed_mps[-1])
    assert dv < 1.0


def test_profile_rejects_bad_input():
    with pytest.raises(UserInputError):
        straight_run(-1.0)
    with pytest.raises(UserInputError):
        speed_profile(stadium(), np.full(3, 0.0))


# --- min-curvature QP ------------------------------------------------------------------------

@pytest.mark.parametrize("make", [stadium, hairpins])
def test_mincurv_constraints_curvature_and_lap_time(make):
    track = make()
    res = mincurv(track)
    assert res.seconds < 10.0
    assert np.all(res.qp_offsets_m >= res.lower_m - 1e-6)
    assert np.all(res.qp_offsets_m <= res.upper_m + 1e-6)
    assert np.all(res.lower_m == pytest.approx(-track.width_right_m[res.qp_indices]
                                               + DEFAULT_MARGIN_M))
    half = 0.5 * DEFAULT_MARGIN_M
    assert np.all(res.offsets_m >= -track.width_right_m + half - 1e-9)
    assert np.all(res.offsets_m <= track.width_left_m - half + 1e-9)
    # The iteration converged: objective decreased and the last steps barely changed it.
    hist = res.objective_history
    assert hist[-1] < hist[0]
    assert abs(hist[-1] - hist[-2]) < 1e-3 * hist[-1]
    centre = ReferenceLine.from_offsets(track, 0.0)
    line = ReferenceLine.from_offsets(track, res.offsets_m)
    assert np.sum(line.curvature_1pm**2) < 0.9 * np.sum(centre.curvature_1pm**2)
    assert lap_time_s(track, res.offsets_m) < 0.97 * lap_time_s(track, 0.0)
    # Smooth curvature: no jumps at straight/arc joins (the centreline has them).
    assert np.max(np.abs(np.diff(line.curvature_1pm))) < 0.25 * np.max(
        np.abs(np.diff(centre.curvature_1pm)))


def test_mincurv_stadium_widens_the_half_circles():
    track = stadium(radius_m=60.0, width_m=12.0)
    offsets = mincurv(track).offsets_m
    line = ReferenceLine.from_offsets(track, offsets)
    # Left-hand half circles: the line runs on the right (outer) bound on the straights and at
    # mid-corner, and spreads the turn onto the straights (lower summed curvature^2).
    assert np.min(offsets) == pytest.approx(-6.0 + DEFAULT_MARGIN_M, abs=0.02)
    mid_arc = track.index_at(300.0 + math.pi * 60.0 / 2)
    assert offsets[mid_arc] == pytest.approx(-6.0 + DEFAULT_MARGIN_M, abs=0.05)
    on_straight = track.index_at(150.0)
    assert offsets[on_straight] == pytest.approx(-6.0 + DEFAULT_MARGIN_M, abs=0.05)
    turning = np.abs(line.curvature_1pm) > 1e-3
    assert turning.sum() > 1.2 * (np.abs(track.curvature_1pm) > 1e-3).sum()


def test_mincurv_rejects_negative_margin():
    with pytest.raises(UserInputError):
        mincurv(stadium(), margin_m=-1.0)


# --- LAC, recorded, genetic ------------------------------------------------------------------

def test_lac_on_circle_reads_one_over_radius():
    track = circle(50.0)
    values = lac(track, np.zeros(track.n), [0.0, 100.0])
    assert values.shape == (2, 4)
    assert np.allclose(values, 1 / 50.0, rtol=1e-3)
    with pytest.raises(UserInputError):
        lac(track, np.zeros(5), 0.0)


def test_recorded_line_recovers_a_driven_path():
    track = hairpins()
    truth = mincurv(track).offsets_m
    # A synthetic driven lap: points every ~9 m along the true line, with the lap counter the
    # follower writes (0 before the line, 1 during the first timed lap, 2 after it).
    s = np.arange(0.0, 3 * track.length_m, 9.0) - 50.0
    lap = (np.floor_divide(s, track.length_m) + 1).astype(int)
    noise = np.random.default_rng(0).normal(0.0, 0.05, s.size)
    lateral = np.interp(np.mod(s, track.length_m), track.s_m, truth) + noise
    x, y, _ = track.pose_at(s, lateral)
    result = {"trace": {"x_m": x, "y_m": y, "lap": lap}}
    rec = recorded_offsets(track, result)
    assert rec.shape == (track.n,)
    assert np.max(np.abs(rec - truth)) < 0.25
    assert abs(lap_time_s(track, rec) - lap_time_s(track, truth)) < 0.01 * lap_time_s(track, truth)
    with pytest.raises(UserInputError):
        recorded_offsets(track, {"trace": {"x_m": x[:5], "y_m": y[:5], "lap": [0, 0, 1, 1, 1]}})


def test_genetic_line_is_seeded_reproducible_and_improves():
    track = hairpins()
    kw = dict(population=12, generations=12, spacing_m=30.0)
    a = genetic_line(track, seed=3, **kw)
    b = genetic_line(track, seed=3, **kw)
    c = genetic_line(track, seed=4, **kw)
    assert np.array_equal(a.offsets_m, b.offsets_m)
    assert not np.array_equal(a.offsets_m, c.offsets_m)
    assert a.history_best_s[-1] < a.history_best_s[0]
    assert all(x >= y for x, y in zip(a.history_best_s, a.history_best_s[1:], strict=False))
    assert a.surrogate_lap_s < lap_time_s(track, 0.0)
    assert a.surrogate_lap_s == pytest.approx(lap_time_s(track, a.offsets_m), rel=1e-9)


def test_genetic_retimes_finalists_with_the_driver():
    track = hairpins()
    calls: list[float] = []

    def fake_driver(trk, offsets):
        lap = lap_time_s(trk, offsets) * 1.05 + 0.1 * len(calls)
        calls.append(lap)
        return {"finished": True, "damage": 0.0, "best_lap_s": lap}

    res = genetic_line(track, seed=0, population=8, generations=3, final_k=3, driver=fake_driver)
    assert len(calls) == 3
    assert res.driven_lap_s == pytest.approx(min(calls))


# --- registry / cache ------------------------------------------------------------------------

def test_registry_caches_on_disk_keyed_by_car(tmp_path, monkeypatch):
    monkeypatch.setenv(registry.CACHE_ENV_VAR, str(tmp_path))
    track = stadium()
    first = registry.reference_offsets(track, "mincurv")
    files = list((tmp_path / "lines").glob("*.npy"))
    assert len(files) == 1 and "mincurv" in files[0].name
    np.save(files[0], first + 0.0)
    again = registry.reference_offsets(track, "mincurv")
    assert np.array_equal(first, again)
    registry.reference_offsets(track, "mincurv", CarParams(mu=1.2))
    assert len(list((tmp_path / "lines").glob("*.npy"))) == 2
    assert np.all(registry.reference_offsets(track, "centre") == 0.0)
    with pytest.raises(UserInputError, match="known lines"):
        registry.reference_offsets(track, "fastest")
    # A damaged entry is recomputed, not trusted.
    files[0].write_bytes(b"garbage")
    assert np.allclose(registry.reference_offsets(track, "mincurv"), first)


def test_driven_lines_take_their_driver_as_an_argument(tmp_path, monkeypatch):
    """``lines`` sits below ``bots``: the recorded line is driven by the driver passed in (here a
    stand-in that drives the given line exactly), and without one it is a clear error."""
    monkeypatch.setenv(registry.CACHE_ENV_VAR, str(tmp_path))
    track = stadium()
    calls: list[dict] = []

    def exact_driver(trk, offsets, laps=2, car=None):
        calls.append({"laps": laps, "car": car, "offsets": np.asarray(offsets)})
        s = np.arange(0.0, 3 * trk.length_m, 4.0)  # run-up, two laps, 4 m per step
        lateral = np.interp(s % trk.length_m, trk.s_m, offsets, period=trk.length_m)
        x, y, _ = trk.pose_at(s % trk.length_m, lateral)
        return {"trace": {"lap": (s // trk.length_m).astype(int), "x_m": x, "y_m": y}}

    with pytest.raises(TypeError, match="bots.line_offsets.reference_offsets"):
        registry.reference_offsets(track, "recorded")
    with pytest.raises(TypeError, match="driver"):
        registry.reference_offsets(track, "genetic", use_cache=False)
    car = CarParams(mu=1.5)
    recorded = registry.reference_offsets(track, "recorded", car, exact_driver)
    mincurv = registry.reference_offsets(track, "mincurv", car)
    assert len(calls) == 1 and calls[0]["laps"] == 2 and calls[0]["car"] == car
    np.testing.assert_array_equal(calls[0]["offsets"], mincurv)
    assert np.percentile(np.abs(recorded - mincurv), 95) < 0.25  # the smoothing spline
    # cached: asked again, the driver is not called
    registry.reference_offsets(track, "recorded", car, exact_driver)
    assert len(calls) == 1


def test_bots_line_offsets_passes_the_follower(monkeypatch):
    from formula_tourney.bots import follower, line_offsets

    seen = []
    monkeypatch.setattr(registry, "reference_offsets",
                        lambda track, kind, car=None, driver=None: seen.append(driver) or kind)
    assert line_offsets.reference_offsets(stadium(), "genetic") == "genetic"
    assert seen == [follower.drive]


def test_reference_limit_is_the_qss_lap_on_the_mincurv_line(tmp_path, monkeypatch):
    from formula_tourney.lines.limit import reference_limit_s

    monkeypatch.setenv(registry.CACHE_ENV_VAR, str(tmp_path))
    track = stadium()
    car = CarParams(mu=1.4)
    offsets = registry.reference_offsets(track, "mincurv", car)
    assert reference_limit_s(track, car) == lap_time_s(track, offsets, car)
    assert reference_limit_s(track) < lap_time_s(track, 0.0)

"""The reference limit and the follower on 3-D tracks: banking raises a turn's
QSS limit, crests unload the car, slopes cost time uphill, grass and dirt slow the follower,
a section's grip factor slows it too, and the follower holds a 15 deg banked oval (the
b-speedway failure). Small self-written tracks only: torcs-data never enters the suite."""

from __future__ import annotations

import math

import numpy as np
import pytest

from formula_tourney.bots.follower import Follower, drive
from formula_tourney.errors import UserInputError
from formula_tourney.lines.registry import reference_offsets
from formula_tourney.lines.speed_profile import corner_speed_mps, lap_time_s, speed_profile
from formula_tourney.lines.surface import PathSurface, surface_forces
from formula_tourney.sim.car_params import GRAVITY_MPS2, CarParams
from formula_tourney.sim.segments import build_track, parse_spec, spec_to_toml

G = GRAVITY_MPS2
BARE_CAR = CarParams(downforce_coef_n_per_mps2=0.0, drag_coef_n_per_mps2=0.0,
                     rolling_resistance=0.0)
"""No aero, no drag, no rolling: the textbook banked turn and crest."""


@pytest.fixture(autouse=True)
def _private_dirs(tmp_path, monkeypatch):
    monkeypatch.setenv("FORMULA_TOURNEY_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.setenv("FORMULA_TOURNEY_CACHE_DIR", str(tmp_path / "cache"))


def oval(bank_turn_deg: float = 0.0, bank_straight_deg: float = 0.0, width_m: float = 16.0,
         radius_m: float = 150.0, road: str = "", grip: str = "", climb_m: float = 0.0) -> str:
    """An anticlockwise stadium: 400 m straights, two 180 deg left turns. The inside of a left
    turn is the left edge, so a bank that raises the outside is < 0 (TORCS' sign). ``climb_m``:
    the first straight climbs that much, the second comes back down."""
    surface = f'surface = "{road}"\n' if road else ""

    def seg(kind: str, bank: float, grip_line: str = "", z: str = "") -> str:
        body = ('type = "straight"\nlength_m = 400.0\n' if kind == "s"
                else f'type = "arc"\nradius_m = {radius_m}\nangle_deg = 180.0\n')
        banking = f"banking_deg = {bank}\n" if bank else ""
        return f"[[segment]]\n{body}{banking}{surface}{grip_line}{z}"

    up, down = (f"z_end_m = {climb_m}\n", "z_end_m = 0.0\n") if climb_m else ("", "")
    return (f'name = "oval3d"\nwidth_m = {width_m}\n' + seg("s", bank_straight_deg, z=up)
            + seg("a", bank_turn_deg, grip) + seg("s", bank_straight_deg, z=down)
            + seg("a", bank_turn_deg))


def track_of(text: str):
    return build_track(parse_spec(text, "t.toml"), "t.toml")


def surface_row(slope: float = 0.0, bank: float = 0.0, kv: float = 0.0) -> np.ndarray:
    one = np.ones(1)
    return PathSurface(one * slope, one * bank, one * kv, one, one * 0.0).packed()


# --- the QSS limit ----------------------------------------------------------------------------


@pytest.mark.parametrize("bank_deg", [5.0, 10.0, 20.0])
def test_banked_turn_corner_speed_is_the_closed_form_and_above_flat(bank_deg):
    radius, mu, b = 60.0, BARE_CAR.mu, math.radians(bank_deg)
    k = 1.0 / radius  # a left turn: the outside (right) edge raised is banking < 0
    banked = float(corner_speed_mps(np.array([k]), BARE_CAR, surface_row(bank=-b))[0])
    flat = float(corner_speed_mps(np.array([k]), BARE_CAR, surface_row())[0])
    closed = math.sqrt(radius * G * (math.sin(b) + mu * math.cos(b))
                       / (math.cos(b) - mu * math.sin(b)))
    assert banked == pytest.approx(closed, rel=1e-9)
    assert flat == pytest.approx(math.sqrt(mu * G * radius), rel=1e-9)
    assert banked > flat * (1.0 + 0.5 * math.tan(b))
    # banked the wrong way (inside edge raised) the limit falls
    adverse = float(corner_speed_mps(np.array([k]), BARE_CAR, surface_row(bank=b))[0])
    assert adverse < flat


def test_level_surface_gives_the_flat_corner_speed():
    k = np.array([0.0, 1 / 500, 1 / 60, -1 / 25])
    car = CarParams()
    flat = corner_speed_mps(k, car)
    level = corner_speed_mps(k, car, np.repeat(surface_row(), 4, axis=0))
    assert level == pytest.approx(flat, rel=1e-12)


def test_banked_oval_reference_limit_falls_and_turn_speed_rises():
    flat, banked = track_of(oval()), track_of(oval(bank_turn_deg=-15.0))
    assert not flat.has_surface and banked.has_surface
    p_flat, p_bank = speed_profile(flat, 0.0), speed_profile(banked, 0.0)
    i = int(flat.index_at(400.0 + 150.0 * math.pi / 2))  # apex of the first turn
    assert p_bank.corner_speed_mps[i] > 1.08 * p_flat.corner_speed_mps[i]
    assert p_bank.speed_mps[i] > 1.05 * p_flat.speed_mps[i]
    assert p_bank.lap_time_s < 0.97 * p_flat.lap_time_s
    # the flat track takes the flat arithmetic: exactly the profile of the plain call
    assert PathSurface.of_track(flat) is None
    assert lap_time_s(flat, 0.0) == p_flat.lap_time_s


def test_crest_unloads_the_car_and_lowers_its_corner_speed():
    m, v = BARE_CAR.mass_kg, 30.0
    kv = 1.0 / 200.0  # a crest of radius 200 m
    n_flat, _, _ = surface_forces(surface_row()[0], m, 0.0, v * v, 0.0)
    n_crest, _, _ = surface_forces(surface_row(kv=kv)[0], m, 0.0, v * v, 0.0)
    n_dip, _, _ = surface_forces(surface_row(kv=-kv)[0], m, 0.0, v * v, 0.0)
    assert n_flat == pytest.approx(m * G)
    assert n_crest == pytest.approx(m * (G - v * v * kv))  # 45 % lighter at 30 m/s
    assert n_crest < 0.6 * n_flat < n_flat < n_dip
    # a sharp crest at speed: the car would leave the road, its normal load stops at 0
    assert surface_forces(surface_row(kv=0.05)[0], m, 0.0, 900.0, 0.0)[0] == 0.0
    k = np.array([1 / 100.0])
    flat = float(corner_speed_mps(k, BARE_CAR, surface_row())[0])
    crest = float(corner_speed_mps(k, BARE_CAR, surface_row(kv=kv))[0])
    # v^2 k = mu (g - v^2 kv): v^2 = mu g / (k + mu kv)
    mu = BARE_CAR.mu
    assert crest == pytest.approx(math.sqrt(mu * G / (k[0] + mu * kv)), rel=1e-9)
    assert crest < 0.8 * flat


def test_a_climb_costs_more_than_the_descent_gives_back():
    hilly = track_of(oval(climb_m=24.0))  # a 6 % climb, then the same descent
    assert float(np.ptp(hilly.z_m)) == pytest.approx(24.0, abs=0.1)
    flat = track_of(oval())
    assert lap_time_s(hilly, 0.0) > lap_time_s(flat, 0.0) + 0.1


# --- surfaces and section grip ------------------------------------------------------------------


def test_section_grip_factor_is_validated_scales_friction_and_survives_the_toml():
    text = oval(grip="grip = 0.5\n")
    spec = parse_spec(text, "t.toml")
    assert spec.segments[1].grip == 0.5 and spec.segments[0].grip == 1.0
    tr = build_track(spec, "t.toml")
    turn = int(tr.index_at(400.0 + 100.0))
    assert tr.friction_road[turn] == 0.5 and tr.friction_road[10] == 1.0
    again = build_track(parse_spec(spec_to_toml(spec), "u.toml"), "u.toml")
    assert np.array_equal(again.friction_road, tr.friction_road)
    # the wet turn is slower in the reference limit
    assert lap_time_s(tr, 0.0) > lap_time_s(track_of(oval()), 0.0) + 1.0
    with pytest.raises(UserInputError, match=r"t.toml.*segment 2.*'grip'"):
        parse_spec(oval(grip="grip = 0.0\n"), "t.toml")
    with pytest.raises(UserInputError, match="'grip'"):
        parse_spec(oval(grip='grip = "wet"\n'), "t.toml")


@pytest.mark.parametrize("road", ["dirt", "grass"])
def test_dirt_and_grass_slow_the_follower_and_the_limit(road):
    asphalt, loose = track_of(oval()), track_of(oval(road=road))
    lap = {}
    for label, tr in (("asphalt", asphalt), (road, loose)):
        off = reference_offsets(tr, "mincurv")
        result = drive(tr, off, laps=2)
        assert result["finished"] and result["damage"] == 0.0, (label, result["termination"])
        lap[label] = (result["best_lap_s"], lap_time_s(tr, off))
    # dirt: friction 0.9 / 1.2 of asphalt's, grass 0.4 / 1.2, and more rolling resistance
    slower = {"dirt": 1.04, "grass": 1.3}[road]
    assert lap[road][0] > slower * lap["asphalt"][0]
    assert lap[road][1] > slower * lap["asphalt"][1]
    assert lap[road][0] > lap[road][1]  # the follower stays behind its own limit


def test_follower_plans_for_the_env_grip_scale():
    tr = track_of(oval(width_m=14.0, radius_m=80.0))
    off = reference_offsets(tr, "mincurv")
    full, low = Follower(tr, off), Follower(tr, off, grip_scale=0.7)
    assert low.profile.lap_time_s > full.profile.lap_time_s * 1.08
    result = drive(tr, off, laps=2, env_config={"grip_scale": 0.7})
    assert result["finished"] and result["damage"] == 0.0
    assert result["best_lap_s"] > drive(tr, off, laps=2)["best_lap_s"] * 1.05


# --- the follower on a banked oval (b-speedway's shape) ----------------------------------------


def test_follower_holds_a_15_deg_banked_oval_on_the_min_curvature_line():
    # Without the banking's feed-forward the follower left this track at the first apex, on
    # the low side (as on b-speedway); the flat copy it drove clean.
    tr = track_of(oval(bank_turn_deg=-16.0, bank_straight_deg=-15.0, width_m=16.0,
                       radius_m=300.0))
    off = reference_offsets(tr, "mincurv")
    result = drive(tr, off, laps=2)
    assert result["finished"] and result["damage"] == 0.0, result["termination"]
    limit = lap_time_s(tr, off)
    assert limit < lap_time_s(track_of(oval(width_m=16.0, radius_m=300.0)), off)
    assert limit < result["best_lap_s"] < 1.05 * limit

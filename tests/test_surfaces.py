"""Track surfaces: TORCS surface names to friction and rolling resistance, per
track sample for the road and the side; the env's ``grip_scale`` on top."""

from __future__ import annotations

import math

import numpy as np
import pytest
from simtracks import stadium

from formula_tourney.sim import kernels as K
from formula_tourney.sim.car import CarBatch
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.env import FormulaRacingEnv
from formula_tourney.sim.segments import parse_spec, spec_to_toml
from formula_tourney.sim.surfaces import TORCS_SURFACES, road_coefficients, side_coefficients
from formula_tourney.sim.torcs import load_torcs_track, read_torcs_spec

CAR = CarParams()
DIRT = TORCS_SURFACES["dirt"][0] / TORCS_SURFACES["asphalt"][0]  # 0.9 / 1.2

XML = """<?xml version="1.0" encoding="UTF-8"?>
<!DOCTYPE params SYSTEM "../../../src/libs/tgf/params.dtd" [
<!ENTITY default-surfaces SYSTEM "../../../data/tracks/surfaces.xml">
]>
<params name="test" type="param" mode="mw">
  <section name="Surfaces">&default-surfaces;</section>
  <section name="Main Track">
    {main}
    <attnum name="width" unit="m" val="12"/>
    <section name="Track Segments">
      <section name="s1"><attstr name="type" val="str"/><attnum name="lg" val="200"/>{seg}
      </section>
      <section name="t1"><attstr name="type" val="lft"/><attnum name="radius" val="60"/>
        <attnum name="arc" unit="deg" val="180"/></section>
      <section name="s2"><attstr name="type" val="str"/><attnum name="lg" val="200"/>{seg2}
      </section>
      <section name="t2"><attstr name="type" val="lft"/><attnum name="radius" val="60"/>
        <attnum name="arc" unit="deg" val="180"/></section>
    </section>
  </section>
</params>
"""


def write(tmp_path, main: str = "", seg: str = "", seg2: str = "", name: str = "surf.xml"):
    path = tmp_path / name
    path.write_text(XML.format(main=main, seg=seg, seg2=seg2))
    return path


def max_lateral_accel(speed_mps: float, grip: float) -> float:
    """Constant-speed steer ramp on an open plane: the largest 1 s mean lateral acceleration."""
    b = CarBatch(1)
    b.place(0, speed_mps=speed_mps)
    b.grip[0] = grip
    dt, steer, hist, best = 0.02, 0.0, [], 0.0
    for _ in range(int(100 / dt)):
        err = speed_mps - b.vx_mps[0]
        b.step([steer, float(np.clip(0.5 * err + 0.2, 0, 1)), float(np.clip(-0.3 * err, 0, 1))],
               dt)
        steer += 0.01 * dt
        hist.append(abs(b.lateral_accel_mps2[0]))
        if len(hist) >= 50:
            best = max(best, float(np.mean(hist[-50:])))
        if abs(b.vy_mps[0]) > 0.25 * abs(b.vx_mps[0]) or steer > 1.0:
            break
    return best


def test_names_map_to_torcs_numbers_and_families():
    assert road_coefficients("asphalt") == (1.0, 0.0)
    f, rr = road_coefficients("dirt")
    assert f == pytest.approx(0.75) and rr == pytest.approx(0.005)
    assert road_coefficients("dirtA") == road_coefficients("dirt")  # family by leading word
    assert road_coefficients("newdirt-d2") == road_coefficients("dirt")
    assert road_coefficients("sand")[0] == pytest.approx(0.5)
    assert math.isnan(side_coefficients("grass")[0]) and side_coefficients("grass")[1] == 0.0
    assert side_coefficients("asphalt") == (1.0, 0.0)  # a paved side grips like the road
    assert side_coefficients("sand")[1] == pytest.approx(0.09)
    f, rr = side_coefficients("grass6")  # a grass keeps the car's grass grip
    assert math.isnan(f) and rr == pytest.approx(0.005)


def test_unknown_surface_warns_naming_file_and_surface_and_drives_as_default(tmp_path):
    path = write(tmp_path, main='<attstr name="surface" val="moon-dust"/>', name="odd.xml")
    with pytest.warns(UserWarning, match=r"odd\.xml.*'moon-dust'"):
        track = load_torcs_track(path)
    assert np.all(track.friction_road == 1.0) and np.all(track.rolling_road == 0.0)


def test_default_tracks_carry_default_surfaces_and_geometry_columns(tmp_path):
    track = load_torcs_track(write(tmp_path))
    assert np.all(track.friction_road == 1.0) and np.all(np.isnan(track.friction_side))
    assert all("surface" not in s for s in track.segments)
    env = FormulaRacingEnv({"track": stadium()})
    g = env._b.geom
    assert np.all(g[:, K.G_MU_ROAD] == 1.0) and np.all(g[:, K.G_MU_SIDE] == 1.0)
    assert np.all(g[:, K.G_RR_ROAD] == 0.0) and np.all(g[:, K.G_RR_SIDE] == 0.0)


def test_torcs_surfaces_carry_over_per_segment_and_the_side_takes_the_lower_friction(tmp_path):
    path = write(
        tmp_path,
        main='<attstr name="surface" val="dirt"/><attstr name="lside surface" val="sand"/>'
             '<attstr name="rside surface" val="dirt-b"/>',
        seg2='<attstr name="surface" val="asphalt"/>'
             '<section name="Right Side"><attstr name="surface" val="grass"/></section>',
    )
    spec = read_torcs_spec(path)
    assert [s.surface for s in spec.segments] == ["dirt", "dirt", "asphalt", "asphalt"]
    assert [s.side_surface for s in spec.segments] == ["sand", "sand", "grass", "grass"]
    track = load_torcs_track(path)
    first = track.s_m < spec.segments[0].arc_length_m
    assert np.allclose(track.friction_road[first], DIRT)
    assert np.allclose(track.friction_side[first], 0.5)
    assert np.all(np.isnan(track.friction_side[~first & (track.s_m > 400 + 60 * math.pi)]))
    # The TOML written from an import drives the same.
    back = parse_spec(spec_to_toml(spec), "surf.toml")
    assert [s.surface for s in back.segments] == ["dirt", "dirt", "asphalt", "asphalt"]


def test_toml_surface_keys_are_validated():
    from formula_tourney.errors import UserInputError

    text = 'width_m = 12.0\n[[segment]]\ntype = "straight"\nlength_m = 10.0\nsurface = 3\n'
    with pytest.raises(UserInputError, match="surface"):
        parse_spec(text, "bad.toml")


def test_dirt_road_lowers_the_cornering_limit_in_the_ratio_of_the_frictions(tmp_path):
    track = load_torcs_track(write(tmp_path, main='<attstr name="surface" val="dirt"/>'))
    env = FormulaRacingEnv({"track": track})
    grip = float(env._b.geom[0, K.G_MU_ROAD])
    assert grip == pytest.approx(DIRT)
    asphalt = max_lateral_accel(30.0, 1.0)
    dirt = max_lateral_accel(30.0, grip)
    assert dirt / asphalt == pytest.approx(DIRT, rel=0.04), (dirt, asphalt)


def test_grip_scale_scales_every_surface_and_the_cornering_limit(tmp_path):
    track = load_torcs_track(write(tmp_path, main='<attstr name="surface" val="dirt"/>'
                                   '<attstr name="rside surface" val="sand"/>'
                                   '<attstr name="lside surface" val="sand"/>'))
    env = FormulaRacingEnv({"track": track, "grip_scale": 0.5})
    g = env._b.geom
    assert np.allclose(g[:, K.G_MU_ROAD], 0.5 * DIRT)
    assert np.allclose(g[:, K.G_MU_SIDE], 0.5 * 0.5 * CAR.mu / CAR.mu_grass)
    plain = FormulaRacingEnv({"track": stadium(), "grip_scale": 0.5})._b.geom
    assert np.all(plain[:, K.G_MU_ROAD] == 0.5) and np.all(plain[:, K.G_MU_SIDE] == 0.5)
    full = max_lateral_accel(30.0, 1.0)
    assert max_lateral_accel(30.0, 0.6) / full == pytest.approx(0.6, rel=0.05)


def _drive(track, steps: int, action, grip_scale: float = 1.0) -> np.ndarray:
    env = FormulaRacingEnv({"track": track, "grip_scale": grip_scale, "start_speed_mps": 30.0,
                            "terminate_off_track": False, "terminate_slow": False})
    env.reset(seed=0)
    rows = []
    for _ in range(steps):
        env.step(np.array(action, dtype=float))
        rows.append(env._b.state[0].copy())
    return np.array(rows)


def test_the_env_kernel_reads_the_surface_columns(tmp_path):
    asphalt = load_torcs_track(write(tmp_path, name="a.xml"))
    dirt = load_torcs_track(write(tmp_path, main='<attstr name="surface" val="dirt"/>',
                                  name="d.xml"))
    # Coasting down the straight: dirt's extra rolling resistance (0.005) slows the car more.
    coast_a = _drive(asphalt, 15, [0.0, 0.0, 0.0])[-1, K.ST_VX]
    coast_d = _drive(dirt, 15, [0.0, 0.0, 0.0])[-1, K.ST_VX]
    assert coast_d < coast_a - 0.01, (coast_d, coast_a)
    # Steering hard: the lateral acceleration is bounded by the scaled grip.
    full = np.abs(_drive(asphalt, 3, [0.6, 0.3, 0.0])[:, K.ST_AY]).max()
    low = np.abs(_drive(asphalt, 3, [0.6, 0.3, 0.0], grip_scale=0.3)[:, K.ST_AY]).max()
    assert low < 0.5 * full, (low, full)


def test_a_track_files_own_surfaces_override_the_table_and_survive_the_toml(tmp_path):
    own = ('<section name="Surfaces">&default-surfaces;<section name="mud-x">'
           '<attnum name="friction" val="0.6"/><attnum name="rolling resistance" val="0.03"/>'
           '</section></section>')
    text = XML.format(main='<attstr name="surface" val="mud-x"/>', seg="", seg2="")
    text = text.replace('<section name="Surfaces">&default-surfaces;</section>', own)
    path = tmp_path / "own.xml"
    path.write_text(text)
    spec = read_torcs_spec(path)
    assert spec.surfaces == {"mud-x": (0.6, 0.03)}
    track = load_torcs_track(path)
    assert np.allclose(track.friction_road, 0.5) and np.allclose(track.rolling_road, 0.029)
    back = parse_spec(spec_to_toml(spec), "own.toml")
    assert back.surfaces == spec.surfaces and back.segments == spec.segments


def test_toml_surfaces_table_is_validated():
    from formula_tourney.errors import UserInputError

    seg = '[[segment]]\ntype = "straight"\nlength_m = 10.0\n'
    bad = 'width_m = 12.0\n[surfaces.mud]\nfriction = 0.5\n' + seg
    with pytest.raises(UserInputError, match="rolling_resistance"):
        parse_spec(bad, "bad.toml")

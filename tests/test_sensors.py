"""Telemetry layout and values: range finders, trackPos, LAC."""

from __future__ import annotations

import math

import numpy as np
import pytest
from simtracks import stadium

from formula_tourney.sim import kernels as K
from formula_tourney.sim.env import FormulaRacingEnv
from formula_tourney.sim.reference_line import ReferenceLine
from formula_tourney.sim.sensors import (
    denormalise,
    observation_bounds,
    observation_names,
    track_geometry,
)

TRACK = stadium()  # 400 m straights, radius 80 m, 12 m wide


def _brute_ray(geom: np.ndarray, ox: float, oy: float, ang: float, rng_m: float = 200.0) -> float:
    """Nearest hit of a ray with every edge segment of the track (the slow reference)."""
    d = (math.cos(ang), math.sin(ang))
    best = rng_m
    for cx, cy in ((K.G_LX, K.G_LY), (K.G_RX, K.G_RY)):
        ax, ay = geom[:, cx], geom[:, cy]
        ex, ey = np.roll(ax, -1) - ax, np.roll(ay, -1) - ay
        den = d[0] * ey - d[1] * ex
        wx, wy = ax - ox, ay - oy
        with np.errstate(all="ignore"):
            t = (wx * ey - wy * ex) / den
            u = (wx * d[1] - wy * d[0]) / den
        ok = (np.abs(den) > 1e-12) & (u >= 0) & (u <= 1) & (t > 1e-9)
        if ok.any():
            best = min(best, float(t[ok].min()))
    return best


def test_names_and_bounds():
    names = observation_names(False)
    assert len(names) == 29 and names[0] == "angle" and names[1] == "track_-90"
    assert names[10] == "track_0" and names[19] == "track_90"
    assert names[20:29] == ["trackPos", "speedX", "speedY", "speedZ", "wheelSpinVel_FL",
                            "wheelSpinVel_FR", "wheelSpinVel_RL", "wheelSpinVel_RR", "rpm"]
    assert observation_names(True)[29:] == ["lac_20", "lac_40", "lac_60", "lac_80"]
    low, high = observation_bounds(True)
    assert low.shape == (33,) and low[1] == -1 and high[19] == 1 and high[0] == 1


@pytest.mark.parametrize("track", [TRACK, stadium(straight_m=60, radius_m=12, width_m=10,
                                                  step_m=1.0, name="hairpin")])
def test_corridor_walk_matches_brute_force(track):
    geom = track_geometry(track, ReferenceLine.centre(track))
    rng = np.random.default_rng(1)
    worst = 0.0
    for _ in range(300):
        s = rng.uniform(0, track.length_m)
        lat = rng.uniform(-0.98, 0.98) * track.width_left_m[0]
        x, y, h = (float(v) for v in track.pose_at(s, lat))
        _, _, i = K.project(geom, track.length_m, x, y, -1)
        ang = h + rng.uniform(-2.5, 2.5)
        worst = max(worst, abs(K.cast_ray(geom, i, x, y, ang, 200.0) - _brute_ray(geom, x, y, ang)))
    assert worst < 1e-6


def test_straight_ahead_side_rays_and_off_track():
    env = FormulaRacingEnv(config={"track": TRACK})
    obs, info = env.reset(seed=0, options={"start_s_m": 100.0})
    phys = denormalise(obs)
    track_m = phys["track_m"]
    assert track_m[9] == pytest.approx(200.0)  # 300 m of straight ahead, range 200 m
    assert track_m[0] == pytest.approx(6.0, abs=1e-6)  # right edge, half of 12 m
    assert track_m[18] == pytest.approx(6.0, abs=1e-6)
    assert track_m[6] == pytest.approx(6.0 / math.sin(math.radians(30)), abs=1e-6)  # -30 deg
    assert obs[K.OBS_TRACKPOS] == pytest.approx(0.0, abs=1e-9)
    assert obs[K.OBS_ANGLE] == pytest.approx(0.0, abs=1e-9)
    assert info["s_m"] == pytest.approx(100.0, abs=1e-6)
    # Move the car sideways onto the grass: every range finder reads -1, trackPos beyond 1.
    b = env._b
    b.state[0, K.ST_Y] += 7.5
    b.integrate[0] = 0
    b.run()
    assert np.all(b.obs[0, K.OBS_TRACK:K.OBS_TRACK + 19] == -1.0)
    assert b.obs[0, K.OBS_TRACKPOS] == pytest.approx(7.5 / 6.0, rel=1e-6)


def test_trackpos_and_angle_are_relative_to_the_reference_line():
    offsets = np.full(TRACK.n, 2.0)  # a line 2 m left of the centre
    env = FormulaRacingEnv(config={"track": TRACK, "reference_line": offsets})
    obs, info = env.reset(options={"start_s_m": 100.0})
    assert info["lateral_m"] == pytest.approx(2.0, abs=1e-6)  # starts on the line
    assert obs[K.OBS_TRACKPOS] == pytest.approx(0.0, abs=1e-6)
    b = env._b
    b.state[0, K.ST_Y] -= 3.0
    b.state[0, K.ST_PSI] += 0.1
    b.integrate[0] = 0
    b.run()
    assert b.obs[0, K.OBS_TRACKPOS] == pytest.approx(-3.0 / 6.0, abs=1e-6)
    assert b.obs[0, K.OBS_ANGLE] * math.pi == pytest.approx(0.1, abs=1e-6)


def test_lac_reads_reference_curvature_ahead():
    env = FormulaRacingEnv(config={"track": TRACK, "lac": True})
    # 390 m: the arc (radius 80 m, left) starts 10 m ahead; 20..80 m ahead are on it.
    obs, _ = env.reset(options={"start_s_m": 390.0})
    lac = denormalise(obs, lac=True)["lac_1pm"]
    assert obs.shape == (33,)
    np.testing.assert_allclose(lac, 1 / 80.0, rtol=0.02)
    obs, _ = env.reset(options={"start_s_m": 100.0})
    np.testing.assert_allclose(obs[29:], 0.0, atol=1e-9)


@pytest.mark.parametrize("track", [TRACK, stadium(straight_m=60, radius_m=12, width_m=10,
                                                  step_m=1.0, name="hairpin")])
def test_local_projection_matches_the_global_scan(track):
    """The kernel's hill-climb from the last index agrees with Track.project's full scan."""
    geom = track_geometry(track, ReferenceLine.centre(track))
    rng = np.random.default_rng(2)
    s, hint, worst = 0.0, -1, 0.0
    for _ in range(1500):
        s = (s + rng.uniform(-0.3, 1.0)) % track.length_m  # a car moves < 1 m per substep
        lat = rng.uniform(-1.0, 1.0) * (track.width_left_m[0] + 1.0)
        x, y, _ = (float(v) for v in track.pose_at(s, lat))
        s_k, lat_k, hint = K.project(geom, track.length_m, x, y, hint)
        s_g, lat_g, _ = track.project(x, y)
        ds = abs(s_k - s_g)
        worst = max(worst, min(ds, track.length_m - ds) + abs(lat_k - lat_g))
    assert worst < 2e-3

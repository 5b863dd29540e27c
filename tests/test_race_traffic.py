"""Traffic while training: a learner among bots, its observation, and its solo equivalence."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from simtracks import stadium

from formula_tourney.bots.traffic_env import TrafficEnv
from formula_tourney.sim import kernels as K
from formula_tourney.sim.env import FormulaRacingEnv
from formula_tourney.sim.multicar import lockstep_kernels as RK

TRACK = stadium()
CFG = {"track": TRACK, "start_speed_mps": 15.0, "max_steps": 400}


def test_traffic_env_passes_gymnasiums_checker_and_sees_the_bots():
    env = TrafficEnv(CFG, bots=3)
    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=4, options={"start_s_m": 100.0})
    assert obs.shape == (29 + RK.N_OPP,) and env.observation_space.contains(obs)
    opp = obs[29:]
    # Bots 1 and 3 ahead, bot 2 behind, 30-150 m apart along the straight: the sectors around
    # 0 deg (17, 18) and 180 deg (0, 35) see the nearest of each, nothing else within 200 m.
    ahead, behind = opp[[17, 18]].min(), opp[[0, 35]].min()
    assert 30.0 / 200.0 <= ahead <= 150.0 / 200.0 and 30.0 / 200.0 <= behind <= 150.0 / 200.0
    assert (np.delete(opp, [0, 17, 18, 35]) == 1.0).all()
    assert info["position"] == 3  # two bots ahead of it
    same, _ = TrafficEnv(CFG, bots=3).reset(seed=4, options={"start_s_m": 100.0})
    np.testing.assert_array_equal(obs, same)  # same seed, same traffic


def test_a_learner_that_drives_into_the_bot_ahead_makes_contact():
    # The bot 6 m ahead (1.5 m between the bodies); the learner keeps full throttle.
    env = TrafficEnv({**CFG, "start_speed_mps": 30.0}, bots=1, gap_m=(6.0, 6.0))
    env.reset(seed=0, options={"start_s_m": 50.0})
    energy = 0.0
    for _ in range(40):
        obs, reward, term, trunc, info = env.step(np.array([0.0, 1.0, 0.0], np.float32))
        energy += info["contact_kj"]
        if term or trunc:
            break
    assert energy > 1.0 and info["damage"] > 0.0
    assert info["position"] == 1  # it pushed its way past


def test_without_bots_the_learner_drives_as_the_single_env():
    env = TrafficEnv(CFG, bots=0, opponents=False)
    single = FormulaRacingEnv(config=CFG)
    obs_t, _ = env.reset(seed=1, options={"start_s_m": 200.0})
    obs_s, _ = single.reset(seed=1, options={"start_s_m": 200.0})
    np.testing.assert_array_equal(obs_t, obs_s)
    rng = np.random.default_rng(3)
    for _ in range(60):
        a = rng.uniform([-0.2, 0, 0], [0.2, 1, 0.1]).astype(np.float32)
        o1, r1, t1, tr1, i1 = env.step(a)
        o2, r2, t2, tr2, i2 = single.step(a)
        np.testing.assert_allclose(o1, o2, rtol=1e-6, atol=1e-7)
        assert abs(r1 - r2) <= 1e-9 * max(1.0, abs(r2)) and (t1, tr1) == (t2, tr2)
        assert i1["laps"] == i2["laps"] and abs(i1["distance_m"] - i2["distance_m"]) < 1e-9
        if t1 or tr1:
            break
    assert env.sim.state[0, K.ST_STEPS] == single._b.state[0, K.ST_STEPS]


def test_a_learner_with_the_overspeed_term_pays_it_among_bots_that_do_not():
    """The learner's overspeed crash term reads its own limit speeds (12 m/s here); the bots,
    whose reward nobody reads, leave the term out. Steered off the straight from 25 m/s, the
    learner's end pays -1 less 0.01 x (Vx^2 - 12^2), as alone."""
    cfg = {**CFG, "start_speed_mps": 25.0, "overspeed_crash_weight": 0.01,
           "limit_speeds_mps": (12.0,) * TRACK.n}
    env = TrafficEnv(cfg, bots=2, gap_m=(100.0, 150.0))
    assert all(b.config.overspeed_crash_weight == 0.0 for b in env._bots)
    env.reset(seed=0, options={"start_s_m": 100.0})
    term = False
    while not term:
        obs, reward, term, trunc, info = env.step(np.array([1.0, 0.0, 0.0], np.float32))
        assert not trunc
    vx = obs[K.OBS_VX] * K.SPEED_SCALE_MPS
    assert info["termination"] == "off_track" and vx > 12.0
    assert reward == pytest.approx(-1.0 - 0.01 * (vx * vx - 144.0), rel=1e-6)

"""The Gymnasium env: API, config, reward, episode ends, laps, walls, rendering."""

from __future__ import annotations

import math
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from simtracks import stadium

import formula_tourney  # noqa: F401  (registers FormulaRacing-v0)
from formula_tourney.errors import UserInputError
from formula_tourney.sim import kernels as K
from formula_tourney.sim.config import default_config
from formula_tourney.sim.env import FormulaRacingEnv

TRACK = stadium()  # 400 m straights, radius 80 m, 12 m wide; length ~1302.65 m
INFO_KEYS = {"lap_times_s", "lap_damage", "last_lap_s", "best_lap_s", "laps", "damage",
             "distance_m", "s_m", "lateral_m", "speed_mps", "off_track", "termination",
             "grip_scale", "rewards"}


def driver(obs: np.ndarray, target_mps: float = 24.0) -> np.ndarray:
    """A simple line follower on the telemetry: enough to lap the stadium cleanly."""
    angle = obs[K.OBS_ANGLE] * math.pi
    steer = np.clip(-2.0 * angle - 0.6 * obs[K.OBS_TRACKPOS], -1, 1)
    err = target_mps - obs[K.OBS_VX] * K.SPEED_SCALE_MPS
    return np.array([steer, np.clip(0.3 * err, 0, 1), np.clip(-0.2 * err, 0, 1)], np.float32)


def test_check_env_passes():
    env = gymnasium.make("FormulaRacing-v0", config={"track": TRACK, "random_start": True},
                         render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unbounded Box entries are deliberate (speeds, rpm)
        check_env(env.unwrapped, skip_render_check=False)
    assert env.unwrapped.observation_names[20] == "trackPos"


def test_same_seed_same_trajectory():
    def run(seed: int) -> tuple[np.ndarray, list[float]]:
        env = gymnasium.make("FormulaRacing-v0",
                             config={"track": TRACK, "random_start": True, "start_speed_mps": 20})
        obs, _ = env.reset(seed=seed)
        act_rng = np.random.default_rng(7)
        trace, rewards = [obs], []
        for _ in range(60):
            obs, r, term, trunc, _ = env.step(
                act_rng.uniform([-0.2, 0, 0], [0.2, 1, 0.2]).astype(np.float32))
            trace.append(obs)
            rewards.append(r)
            if term or trunc:
                obs, _ = env.reset()
                trace.append(obs)
        return np.array(trace), rewards

    a, ra = run(3)
    b, rb = run(3)
    c, _ = run(4)
    assert np.array_equal(a, b) and ra == rb
    assert not np.array_equal(a[0], c[0])  # another seed, another start


def test_config_is_checked():
    assert set(default_config()) >= {
        "track", "reference_line", "lac", "lac_distances_m", "control_period_s", "physics_hz",
        "max_steps", "terminate_off_track", "terminate_backwards", "terminate_slow",
        "slow_speed_kmh", "slow_patience_steps", "damage_weight", "random_start",
        "start_speed_mps", "car"}
    bad = [({"trak": "oval"}, "unknown config key .trak.; known keys: action_mode, car,"),
           ({"physics_hz": 50}, "physics_hz"), ({"max_steps": 0}, "max_steps"),
           ({"lac": "yes"}, "lac"),
           ({"reference_line": np.zeros(5)}, "reference_line"),
           ({"reference_line": "racing"}, "reference_line"), ({"car": {"mu": -1}}, "car"),
           ({"track": 3}, "track"), ({"lac_distances_m": []}, "lac_distances_m")]
    for extra, match in bad:
        cfg = {"track": TRACK, **extra}
        with pytest.raises(UserInputError, match=match):
            FormulaRacingEnv(config=cfg)
    env = FormulaRacingEnv(config={"track": TRACK})
    with pytest.raises(UserInputError, match="start_lap"):
        env.reset(options={"start_lap": 1})


def test_physics_rate_sets_the_substeps():
    env = FormulaRacingEnv(config={"track": TRACK, "physics_hz": 250, "control_period_s": 0.1})
    assert env._b.n_sub == 25
    assert env.metadata["render_fps"] == pytest.approx(10.0)


def test_default_start_and_flying_laps_with_interpolated_timing():
    env = FormulaRacingEnv(config={"track": TRACK, "max_steps": 2000})
    obs, info = env.reset(seed=0)
    assert set(info) == INFO_KEYS
    assert info["s_m"] == pytest.approx(TRACK.length_m - 50.0, abs=1e-6)
    assert info["speed_mps"] == 0.0 and math.isnan(info["best_lap_s"])
    laps_seen, t = [], 0
    while len(laps_seen) < 2:
        obs, r, term, trunc, info = env.step(driver(obs))
        t += 1
        assert not term and not trunc, info
        if info["laps"] > len(laps_seen):
            laps_seen.append(info["last_lap_s"])
    lap = laps_seen[1]
    # Flying laps of a ~1303 m loop at ~24 m/s: ~54 s, not a multiple of the 0.2 s step.
    assert 50.0 < lap < 60.0
    # Timed inside the substep: not a multiple of the 0.01 s physics step, and two laps at the
    # driver's steady state agree to well under one substep.
    assert abs(lap / 0.01 - round(lap / 0.01)) > 1e-3
    assert laps_seen[0] == pytest.approx(lap, abs=1e-3)
    assert info["lap_times_s"] == laps_seen and info["best_lap_s"] == min(laps_seen)
    assert info["lap_damage"] == [0.0, 0.0] and info["damage"] == 0.0
    assert info["distance_m"] == pytest.approx(50.0 + 2 * TRACK.length_m + info["s_m"],
                                               abs=1.0)


def test_lap_clock_interpolates_inside_the_substep():
    env = FormulaRacingEnv(config={"track": TRACK})
    # 0.5 m before the line at 20 m/s: the line is crossed 0.025 s in, inside substep 3.
    env.reset(options={"start_s_m": TRACK.length_m - 0.5, "start_speed_mps": 20.0})
    env.step(np.array([0, 0, 0], np.float32))
    assert env._b.state[0, K.ST_LAP_START] == pytest.approx(0.025, abs=2e-4)


def test_reward_is_the_papers_and_off_track_ends_with_minus_one():
    env = FormulaRacingEnv(config={"track": TRACK})
    obs, _ = env.reset(options={"start_s_m": 100.0, "start_speed_mps": 30.0})
    obs, r, term, trunc, info = env.step(np.array([0.0, 0.5, 0.0], np.float32))
    theta = obs[K.OBS_ANGLE] * math.pi
    vx = obs[K.OBS_VX] * K.SPEED_SCALE_MPS
    expect = vx * (math.cos(theta) - abs(math.sin(theta)) - abs(obs[K.OBS_TRACKPOS]))
    assert r == pytest.approx(expect, rel=1e-5) and 25 < r < 35
    for _ in range(30):
        obs, r, term, trunc, info = env.step(np.array([0.15, 0.5, 0.0], np.float32))
        if term:
            break
    assert term and not trunc and r == -1.0
    assert info["termination"] == "off_track" and info["off_track"]
    assert np.all(obs[K.OBS_TRACK:K.OBS_TRACK + 19] == -1.0)


def test_track_pos_weight_scales_only_the_lateral_term_and_one_is_the_papers():
    """Off the reference line (4 m left of the centre), weight 0 drops the -Vx |trackPos| term
    and weight 0.5 halves it; weight 1 gives the paper's reward bit for bit."""
    rewards = {}
    for weight in (None, 1.0, 0.5, 0.0):
        config = {"track": TRACK} | ({} if weight is None else {"track_pos_weight": weight})
        env = FormulaRacingEnv(config=config)
        env.reset(options={"start_s_m": 100.0, "start_speed_mps": 30.0})
        st = env._b.state[0]  # the bottom straight runs along +x: left of it is +y
        st[K.ST_Y] += 4.0
        st[K.ST_LAT] += 4.0
        obs, r, term, _, _ = env.step(np.array([0.0, 0.5, 0.0], np.float32))
        assert not term
        rewards[weight] = r
    theta = obs[K.OBS_ANGLE] * math.pi
    vx = obs[K.OBS_VX] * K.SPEED_SCALE_MPS
    track_pos = abs(obs[K.OBS_TRACKPOS])
    assert track_pos > 0.5  # the term is large here: a car 4 m off a 12 m track's centre
    assert rewards[1.0] == rewards[None]
    assert rewards[0.0] == pytest.approx(vx * (math.cos(theta) - abs(math.sin(theta))), rel=1e-5)
    assert rewards[0.5] == pytest.approx(rewards[0.0] - 0.5 * vx * track_pos, rel=1e-5)
    assert rewards[0.0] - rewards[1.0] == pytest.approx(vx * track_pos, rel=1e-5)


def _one_step_off_the_centre(config: dict, s_m: float,
                             lateral_m: float) -> tuple[float, dict, np.ndarray]:
    """Reward, info and observation of one straight-ahead step from ``lateral_m`` left of the
    centre at ``s_m``, at 30 m/s along the track's heading there."""
    env = FormulaRacingEnv(config={"track": TRACK, "track_pos_weight": 0.0} | config)
    env.reset(options={"start_s_m": s_m, "start_speed_mps": 30.0})
    st = env._b.state[0]
    st[K.ST_X] -= lateral_m * math.sin(st[K.ST_PSI])
    st[K.ST_Y] += lateral_m * math.cos(st[K.ST_PSI])
    st[K.ST_LAT] += lateral_m
    obs, r, term, _, info = env.step(np.array([0.0, 0.5, 0.0], np.float32))
    assert not term
    return r, info, obs


def test_progress_reward_pays_track_metres_and_the_inside_of_a_corner():
    """With ``progress_reward`` the speed term is the progress along the centreline in the step
    (m/s): on the stadium's R80 left turn a car 4 m inside earns ~10 % more than one 4 m outside
    at the same speed (1 / (1 -+ 4/80)), where the paper's Vx (cos - |sin|) pays both alike."""
    arc_s = 520.0  # mid first turn (400-651 m: the straights are 400 m)
    progress = {"progress_reward": True}
    inside, info_in, _ = _one_step_off_the_centre(progress, arc_s, 4.0)
    outside, info_out, _ = _one_step_off_the_centre(progress, arc_s, -4.0)
    straight, info0, _ = _one_step_off_the_centre(progress, 100.0, 0.0)
    # a reset's distance is 0, so one step's progress is its distance_m over the 0.2 s step
    assert straight == pytest.approx(info0["distance_m"] / 0.2, rel=1e-9)
    assert inside / outside == pytest.approx((1 + 4 / 80) / (1 - 4 / 80), rel=0.02)
    assert inside == pytest.approx(info_in["distance_m"] / 0.2, rel=1e-9)
    paper_in, _, _ = _one_step_off_the_centre({}, arc_s, 4.0)
    paper_out, _, _ = _one_step_off_the_centre({}, arc_s, -4.0)
    assert paper_in == pytest.approx(paper_out, rel=0.01)
    # the line term stays on top of it: w = 1 costs Vx |trackPos| as in the paper's reward
    lined, _, obs = _one_step_off_the_centre(progress | {"track_pos_weight": 1.0}, arc_s, 4.0)
    vx = obs[K.OBS_VX] * K.SPEED_SCALE_MPS
    assert lined == pytest.approx(inside - vx * abs(obs[K.OBS_TRACKPOS]), rel=1e-5)
    assert abs(obs[K.OBS_TRACKPOS]) > 0.5


def test_backwards_slow_and_max_steps_ends():
    env = FormulaRacingEnv(config={"track": TRACK})
    env.reset(options={"start_s_m": 100.0})
    env._b.state[0, K.ST_PSI] += math.pi
    _, r, term, _, info = env.step(np.zeros(3, np.float32))
    assert term and r == -1.0 and info["termination"] == "backwards"

    env = FormulaRacingEnv(config={"track": TRACK, "slow_patience_steps": 5,
                                   "slow_penalty": 50.0})
    env.reset(options={"start_s_m": 100.0})
    ends = [env.step(np.array([0, 0, 1], np.float32))[2] for _ in range(5)]
    assert ends == [False] * 4 + [True]
    _, r, term, _, info = env.step(np.array([0, 0, 1], np.float32))  # still slow: ends again
    assert term and r == -50.0 and info["termination"] == "slow"

    env = FormulaRacingEnv(config={"track": TRACK, "max_steps": 7, "terminate_slow": False})
    env.reset(options={"start_s_m": 100.0})
    for _ in range(7):
        _, _, term, trunc, info = env.step(np.zeros(3, np.float32))
    assert trunc and not term and info["termination"] == "max_steps"


def _paper_reward(obs: np.ndarray) -> float:
    theta = obs[K.OBS_ANGLE] * math.pi
    vx = obs[K.OBS_VX] * K.SPEED_SCALE_MPS
    return float(vx * (math.cos(theta) - abs(math.sin(theta)) - abs(obs[K.OBS_TRACKPOS])))


def test_wall_impulse_damage_is_proportional_to_impact_speed():
    env = FormulaRacingEnv(config={"track": TRACK, "grass_width_m": 5.0})
    env.reset(options={"start_s_m": 100.0})
    b, car = env._b, env.car
    for vn in (3.0, 6.0):
        st = np.zeros(K.N_STATE)
        # Straight along the bottom straight (heading +x), touching the left wall at y = 11 m,
        # moving 30 m/s along the track and vn towards the wall, no yaw rate.
        st[K.ST_X], st[K.ST_PSI], st[K.ST_IDX] = 100.0, 0.0, b.state[0, K.ST_IDX]
        st[K.ST_Y] = st[K.ST_LAT] = 11.0 - car.car_width_m / 2 + 0.01
        st[K.ST_VX], st[K.ST_VY] = 30.0, vn
        dmg = K.wall_contact(st, b.geom, b.params, 5.0)
        assert dmg == pytest.approx(car.wall_damage_per_mps * vn, rel=1e-9)
        assert st[K.ST_LAT] == pytest.approx(11.0 - car.car_width_m / 2, abs=1e-9)
        assert st[K.ST_VX] < 30.0 - 0.1 * vn  # friction along the wall scrubs speed
        assert st[K.ST_VY] < 0.8 * vn and st[K.ST_R] < 0.0  # pushed back, turned along the wall


def test_wall_hit_in_the_env_costs_speed_and_reward():
    damages = []
    for speed in (15.0, 30.0):
        env = FormulaRacingEnv(config={"track": TRACK, "terminate_off_track": False,
                                       "terminate_backwards": False, "damage_weight": 0.01})
        env.reset(options={"start_s_m": 100.0, "start_speed_mps": speed})
        env._b.state[0, K.ST_PSI] = math.radians(20)  # 20 deg towards the left wall
        hit = False
        for _ in range(15):
            prev_damage = env._b.state[0, K.ST_DAMAGE]
            obs, r, term, _, info = env.step(np.array([0, 0, 0], np.float32))
            assert info["lateral_m"] <= 6.0 + 5.0  # never through the wall
            if info["damage"] > prev_damage and not hit:
                hit = True
                assert info["speed_mps"] < 0.9 * speed
                assert r == pytest.approx(
                    _paper_reward(obs) - 0.01 * (info["damage"] - prev_damage), rel=1e-4)
        assert hit
        damages.append(info["damage"])
    assert damages[1] > 1.7 * damages[0]
    assert 300.0 < damages[0] < 3000.0


def test_render_rgb_array_shows_the_car():
    env = FormulaRacingEnv(config={"track": TRACK}, render_mode="rgb_array")
    env.reset(options={"start_s_m": 200.0})
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    r = env._renderer
    cx, cy = r.to_px(env._b.state[0, K.ST_X], env._b.state[0, K.ST_Y])
    assert tuple(frame[int(cy), int(cx)]) == (220, 30, 30)
    assert tuple(r.background[int(cy), int(cx)]) != (220, 30, 30)
    assert FormulaRacingEnv(config={"track": TRACK}).render() is None


BAD_ACTIONS = [
    (None, "shape"), (0.5, "shape"), ([0.0, 1.0], "shape"), (np.zeros(4, np.float32), "shape"),
    (np.zeros((1, 3), np.float32), "shape"), ([math.nan, 0.5, 0.0], "finite"),
    (np.array([0.0, math.inf, 0.0], np.float32), "finite"), ([0.0, 0.5, None], "finite"),
    (["a", "b", "c"], "action"), ("abc", "shape"), ({"steer": 0.0}, "action"),
]


@pytest.mark.parametrize(("action", "match"), BAD_ACTIONS)
def test_step_refuses_what_is_not_three_finite_numbers(action, match):
    """NumPy used to broadcast 0.5 into all three controls and turn None into NaN controls."""
    env = FormulaRacingEnv(config={"track": TRACK})
    env.reset(options={"start_s_m": 100.0, "start_speed_mps": 20.0})
    before = env._b.state.copy()
    with pytest.raises(ValueError, match=match) as err:
        env.step(action)
    assert isinstance(err.value, gymnasium.error.InvalidAction)
    assert "action" in str(err.value)
    np.testing.assert_array_equal(env._b.state, before)  # nothing was integrated
    # A plain list of three numbers is fine, and the env steps on normally after a refusal.
    obs, _, term, _, info = env.step([0.0, 0.5, 0.0])
    assert np.all(np.isfinite(obs)) and not term and info["speed_mps"] > 19.0


def test_refused_step_through_gymnasium_make_names_the_index():
    env = gymnasium.make("FormulaRacing-v0", config={"track": TRACK})
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"not finite at index \[\(1,\)\]"):
        env.step(np.array([0.0, math.nan, 0.0], np.float32))

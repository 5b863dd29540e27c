"""The vector env: make_vec entry point, next-step autoreset, agreement with the single env."""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import pytest
from simtracks import stadium

import formula_tourney  # noqa: F401  (registers FormulaRacing-v0)
from formula_tourney.errors import UserInputError
from formula_tourney.sim import kernels as K
from formula_tourney.sim.env import FormulaRacingEnv, FormulaRacingVectorEnv

TRACK = stadium()


def test_make_vec_uses_the_vector_entry_point():
    venv = gymnasium.make_vec("FormulaRacing-v0", num_envs=8,
                              vectorization_mode="vector_entry_point",
                              config={"track": TRACK, "random_start": True})
    assert isinstance(venv.unwrapped, FormulaRacingVectorEnv)
    obs, info = venv.reset(seed=1)
    assert obs.shape == (8, 29) and obs.dtype == np.float32
    assert venv.single_observation_space.contains(obs[0])
    assert len(set(np.round(info["s_m"], 6))) == 8  # random starts differ per car
    acts = venv.action_space.sample()
    obs, rew, term, trunc, info = venv.step(acts)
    assert rew.shape == (8,) and term.dtype == bool and trunc.dtype == bool
    assert info["damage"].shape == (8,) and info["_damage"].all()
    assert info["termination"].dtype == object


def test_cars_match_the_single_env():
    cfg = {"track": TRACK, "start_speed_mps": 15.0}
    venv = FormulaRacingVectorEnv(num_envs=3, config=cfg)
    venv.reset(seed=0, options={"start_s_m": 100.0})
    single = FormulaRacingEnv(config=cfg)
    obs1, _ = single.reset(seed=0, options={"start_s_m": 100.0})
    rng = np.random.default_rng(5)
    for _ in range(12):
        a = rng.uniform([-0.05, 0, 0], [0.05, 1, 0.1], size=(3, 3)).astype(np.float32)
        a[1] = a[0]
        obs_v, rew_v, *_ = venv.step(a)
        obs1, r1, term1, *_ = single.step(a[0])
        assert not term1
        np.testing.assert_array_equal(obs_v[0], obs1)
        np.testing.assert_array_equal(obs_v[1], obs1)  # same action, same trajectory
        assert rew_v[0] == r1
    assert not np.array_equal(obs_v[2], obs1)


def test_next_step_autoreset():
    venv = FormulaRacingVectorEnv(num_envs=2, config={"track": TRACK, "slow_patience_steps": 3,
                                                       "start_speed_mps": 0.0})
    first, _ = venv.reset(seed=0)
    go = np.array([[0, 1, 0], [0, 0, 1]], np.float32)  # car 0 drives, car 1 stays: slow end
    for _ in range(3):
        obs, rew, term, trunc, info = venv.step(go)
    assert term.tolist() == [False, True] and info["termination"][1] == "slow"
    assert rew[1] == -venv.config["slow_penalty"]
    obs, rew, term, trunc, info = venv.step(go)
    # The step after the end: car 1 is reset (its action ignored), reward 0, no flags.
    assert rew[1] == 0.0 and not term[1] and not trunc[1]
    np.testing.assert_array_equal(obs[1], first[1])
    assert info["termination"][1] is None and info["distance_m"][1] == 0.0
    assert info["distance_m"][0] > 0.0 and venv._b.state[0, K.ST_STEPS] == 4


def test_vector_env_arguments_are_checked():
    with pytest.raises(UserInputError, match="num_envs"):
        FormulaRacingVectorEnv(num_envs=0, config={"track": TRACK})
    with pytest.raises(UserInputError, match="unknown config key .speed."):
        FormulaRacingVectorEnv(num_envs=2, config={"track": TRACK, "speed": 1})
    venv = FormulaRacingVectorEnv(num_envs=2, config={"track": TRACK}, render_mode="rgb_array")
    venv.reset(seed=0)
    assert venv.render().shape[2] == 3


def test_batched_autoreset_places_cars_like_a_single_reset():
    venv = FormulaRacingVectorEnv(num_envs=3, config={"track": TRACK, "random_start": True,
                                                       "start_speed_mps": 12.0})
    venv.reset(seed=0)
    b = venv._b
    rng = np.random.default_rng(3)
    cars = np.array([0, 2])
    b.reset_cars(cars, rng)
    s = np.random.default_rng(3).uniform(0.0, TRACK.length_m, size=2)
    for c, s_c in zip(cars, s, strict=True):
        row = b.state[c].copy()
        b.reset_car(int(c), rng, {"start_s_m": float(s_c)})
        np.testing.assert_array_equal(row, b.state[c])


@pytest.mark.parametrize(
    ("actions", "match"),
    [
        (None, r"expected shape \(2, 3\)"),
        (0.5, r"expected shape \(2, 3\)"),
        (np.zeros(3, np.float32), r"got shape \(3,\)"),  # one car's action for two cars
        (np.zeros((2, 2), np.float32), r"got shape \(2, 2\)"),
        (np.zeros((3, 3), np.float32), r"got shape \(3, 3\)"),
        ([[0.0, 1.0, 0.0], [0.0, math.nan, 0.0]], r"not finite at index \[\(1, 1\)\]"),
        (np.array([[0, 1, 0], [-math.inf, 0, 0]], np.float32), r"index \[\(1, 0\)\]"),
        ([[0.0, 1.0, 0.0], [0.0, 1.0]], "action"),
    ],
)
def test_vector_step_refuses_bad_actions(actions, match):
    venv = FormulaRacingVectorEnv(num_envs=2, config={"track": TRACK})
    venv.reset(seed=0)
    before = venv._b.state.copy()
    with pytest.raises(ValueError, match=match) as err:
        venv.step(actions)
    assert isinstance(err.value, gymnasium.error.InvalidAction)
    np.testing.assert_array_equal(venv._b.state, before)
    obs, *_ = venv.step([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])  # nested lists are fine
    assert obs.shape == (2, 29) and np.all(np.isfinite(obs))

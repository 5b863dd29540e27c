"""sim.config.EnvConfig is the one owner of the env's config: the env validates with it, accepts
an instance, and still shows ``config`` as a plain dict (issue: one definition of env keys)."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from simtracks import stadium

import formula_tourney  # noqa: F401  (registers FormulaRacing-v0)
from formula_tourney.errors import UserInputError
from formula_tourney.sim import env as env_module
from formula_tourney.sim.config import EnvConfig, EnvSettings, ResetOptions, default_config
from formula_tourney.sim.env import FormulaRacingEnv, FormulaRacingVectorEnv

TRACK = stadium()  # ~1302.65 m


def rollout(config, steps: int = 40) -> tuple[np.ndarray, list[float]]:
    env = FormulaRacingEnv(config=config)
    obs, _ = env.reset(seed=11)
    rng = np.random.default_rng(2)
    trace, rewards = [obs], []
    for _ in range(steps):
        obs, r, term, trunc, _ = env.step(rng.uniform([-0.1, 0, 0], [0.1, 1, 0.1]))
        trace.append(obs)
        rewards.append(r)
        if term or trunc:
            break
    return np.array(trace), rewards


def test_env_accepts_an_env_config_instance_and_keeps_a_plain_dict():
    cfg = EnvConfig(track=TRACK, max_steps=7, random_start=True, car={"mu": 1.5})
    env = FormulaRacingEnv(config=cfg)
    assert env.env_config is cfg
    assert type(env.config) is dict and set(env.config) == set(default_config())
    assert env.config["max_steps"] == 7 and env.config["track"] is TRACK
    assert env.config["car"] == {"mu": 1.5} and env.car.mu == 1.5
    assert env._b.max_steps == 7 and env._b.random_start
    # The same settings as a dict give the bit-identical trajectory.
    as_dict = {"track": TRACK, "max_steps": 7, "random_start": True, "car": {"mu": 1.5}}
    a, ra = rollout(cfg)
    b, rb = rollout(as_dict)
    assert np.array_equal(a, b) and ra == rb
    venv = FormulaRacingVectorEnv(num_envs=2, config=cfg)
    assert venv.env_config is cfg and venv.config["max_steps"] == 7
    made = gymnasium.make("FormulaRacing-v0", config=cfg)
    assert made.unwrapped.config["car"] == {"mu": 1.5}


def test_env_settings_fill_in_over_the_defaults():
    settings = EnvSettings.parse({"slow_penalty": 5.0})
    env = FormulaRacingEnv(config=EnvConfig.parse(settings))
    assert env.config["slow_penalty"] == 5.0 and env.config["track"] == "oval"


def test_the_env_module_has_no_config_logic_of_its_own():
    for name in ("resolve_config", "_num", "_int", "_bool"):
        assert not hasattr(env_module, name), name
    assert FormulaRacingEnv.default_config() == default_config()
    assert default_config()["lac_distances_m"] == (20.0, 40.0, 60.0, 80.0)


def test_user_dict_is_merged_not_mutated():
    user = {"track": TRACK, "lac": True}
    env = FormulaRacingEnv(config=user)
    assert user == {"track": TRACK, "lac": True}
    env.config["max_steps"] = 3  # the dict handed out is a copy: the env is unaffected
    assert env._b.max_steps == 1000 and env.env_config.max_steps == 1000


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ({"lac_distances_m": [20.0, 2000.0]}, r"'lac_distances_m': \[2000.0\] not shorter than "
                                              r"the track \(1302.7 m\)"),
        ({"lac_distances_m": [-5.0]}, r"'lac_distances_m.0': Input should be greater than 0"),
        ({"track": {"name": "x"}}, r"config key 'track': expected a track name or a Track, "
                                   r"got dict"),
        ({"reference_line": object()}, r"config key 'reference_line': expected 'centre' or a "
                                       r"1-D array"),
        ({"control_period_s": True}, r"config key 'control_period_s': expected a number"),
        ({"slow_patience_steps": 2.5}, r"config key 'slow_patience_steps': expected an integer"),
        ({"car": {"wings": 3}}, r"config key 'car': invalid car parameters \(wings"),
        ({"reference_line": np.zeros(5)}, r"'reference_line': expected \d+ finite offsets"),
    ],
)
def test_config_errors_name_the_key(extra, match):
    with pytest.raises(UserInputError, match=match):
        FormulaRacingEnv(config={"track": TRACK, **extra})


def test_config_must_be_a_dict():
    with pytest.raises(UserInputError, match="config: expected a dict, got list"):
        FormulaRacingEnv(config=[("track", TRACK)])


def test_reset_options_are_validated_by_the_config_module():
    env = FormulaRacingEnv(config={"track": TRACK})
    with pytest.raises(UserInputError, match="reset options: unknown option 'start_lap'; known "
                                             "options: start_s_m, start_speed_mps"):
        env.reset(options={"start_lap": 1})
    with pytest.raises(UserInputError, match="reset options: option 'start_speed_mps': Input "
                                             "should be less than or equal to 100"):
        env.reset(options={"start_speed_mps": 150.0})
    with pytest.raises(UserInputError, match="option 'start_s_m': expected a finite number"):
        env.reset(options={"start_s_m": float("nan")})
    _, info = env.reset(options=ResetOptions(start_s_m=200.0, start_speed_mps=10.0))
    assert info["s_m"] == pytest.approx(200.0, abs=1e-6)
    assert info["speed_mps"] == pytest.approx(10.0)


def test_grip_scale_is_an_env_setting_with_a_range():
    assert EnvSettings().grip_scale == 1.0
    assert "friction" in EnvSettings.model_fields["grip_scale"].description
    assert EnvSettings.parse({"grip_scale": 0.6}).overrides() == {"grip_scale": 0.6}
    for bad in (0.1, 2.0, True, "1"):
        with pytest.raises(UserInputError, match="grip_scale"):
            EnvSettings.parse({"grip_scale": bad})
    assert FormulaRacingEnv({"track": TRACK, "grip_scale": 0.8}).config["grip_scale"] == 0.8

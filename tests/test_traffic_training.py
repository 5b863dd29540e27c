"""Traffic while training (schedule.traffic_bots): declared once, off = today's runs exactly."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from tourney_fixtures import TINY

from formula_tourney.bots.traffic_env import TrafficEnv
from formula_tourney.errors import UserInputError
from formula_tourney.race.entrants import model_entrant
from formula_tourney.sim.env import FormulaRacingEnv
from formula_tourney.sim.multicar import lockstep_kernels as RK
from formula_tourney.tourney.api import plan_tournament
from formula_tourney.training.envs import RunEnvs
from formula_tourney.training.loop import train
from formula_tourney.training.run_spec import RunSpec, build_run_spec

TINY_AGENT = {"hidden": [32, 32], "batch_size": 16, "learning_starts": 16}
SCHEDULE = {"episodes": 2, "max_steps": 40, "test_every_episodes": 2, "test_starts": 1,
            "test_max_steps": 40}


def _spec(**schedule) -> RunSpec:
    return build_run_spec(variant="WIN1", overrides=TINY_AGENT, train_tracks=["oval"],
                          schedule={**SCHEDULE, **schedule}, device="cpu")


def test_off_is_todays_spec_and_env():
    off, default = _spec(traffic_bots=0), _spec()
    assert "traffic_bots" not in off.to_json()["schedule"]
    assert off.to_json() == default.to_json() and off.digest() == default.digest()
    assert RunSpec.from_json(off.to_json(), "x").digest() == off.digest()
    env = RunEnvs(off).make("oval", test=False)
    assert type(env.unwrapped) is FormulaRacingEnv
    plain = gymnasium.make("FormulaRacing-v0", config=RunEnvs(off).config("oval", test=False),
                           disable_env_checker=True)
    o1, _ = env.reset(seed=3)
    o2, _ = plain.reset(seed=3)
    np.testing.assert_array_equal(o1, o2)
    for _ in range(20):
        a = np.array([0.05, 0.8, 0.0], np.float32)
        s1, s2 = env.step(a), plain.step(a)
        np.testing.assert_array_equal(s1[0], s2[0])
        assert s1[1:4] == s2[1:4]


def test_on_trains_among_n_bots_and_tests_alone_with_the_opponent_block():
    spec = _spec(traffic_bots=3)
    assert spec.to_json()["schedule"]["traffic_bots"] == 3 and spec.digest() != _spec().digest()
    assert "traffic (3 follower bots)" in spec.beyond_paper()
    envs = RunEnvs(spec)
    training = envs.make("oval", test=False).unwrapped
    testing = envs.make("oval", test=True).unwrapped
    assert isinstance(training, TrafficEnv) and training.n_bots == 3 and training.opponents
    assert isinstance(testing, TrafficEnv) and testing.n_bots == 0
    assert training.observation_space.shape == testing.observation_space.shape == (29 + RK.N_OPP,)
    obs, info = training.reset(seed=0)
    assert (obs[29:] < 1.0).any() and 1 <= info["position"] <= 4  # it sees the bots
    obs, _ = testing.reset(seed=0)
    assert (obs[29:] == 1.0).all()  # nobody there


@pytest.mark.parametrize("schedule, demos, text", [
    ({"traffic_bots": 2, "cars": 2}, None, "needs cars = 1"),
    ({"traffic_bots": 2}, {"laps": 1}, "no demos"),
    ({"traffic_bots": 20}, None, "traffic_bots"),
    ({"traffic_bots": -1}, None, "traffic_bots"),
])
def test_bad_traffic_settings_are_one_error(schedule, demos, text):
    with pytest.raises(UserInputError, match=text):
        build_run_spec(variant="WIN1", train_tracks=["oval"], schedule={**SCHEDULE, **schedule},
                       demos=demos)


def test_a_tournament_part_sets_traffic_and_its_jobs_get_it(tmp_path):
    path = tmp_path / "t.toml"
    path.write_text(TINY.format(entrants='["WIN1"]', p2="traffic_bots = 2\n"), encoding="utf-8")
    planner, planned, _root = plan_tournament(path, tmp_path / "res")
    (job,) = planned[0].jobs
    assert job.spec["schedule"]["traffic_bots"] == 2
    path.write_text(TINY.format(entrants='["WIN1"]', p2="traffic_bots = 99\n"), encoding="utf-8")
    with pytest.raises(UserInputError, match="t.toml:.*traffic_bots"):
        plan_tournament(path, tmp_path / "res")


def test_a_model_trained_in_traffic_races_seeing_the_others(tmp_path):
    summary = train(_spec(traffic_bots=2), tmp_path / "run")
    assert summary["episodes"] == 2
    entrant = model_entrant(tmp_path / "run" / "checkpoints" / "last.pt", "oval", "tr")
    assert entrant.sees_opponents

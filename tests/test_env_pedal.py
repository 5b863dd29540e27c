"""The pedal action mode (beyond the paper): (steer, pedal) with throttle above 0 and brake below,
on a real env step, in the vector env, in exploration, in the agents and in a training run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from simtracks import stadium
from training_fixtures import SMALL

from formula_tourney.agents.buffers import ReplayBuffer
from formula_tourney.agents.families import make_agent
from formula_tourney.agents.noise import BrakeExplorationNoise
from formula_tourney.agents.variants import get_variant
from formula_tourney.errors import UserInputError
from formula_tourney.sim.env import (
    FormulaRacingEnv,
    FormulaRacingVectorEnv,
    InvalidActionError,
    pedal_action,
)
from formula_tourney.training import loop
from formula_tourney.training.budget import warm_up
from formula_tourney.training.run_spec import build_run_spec

torch.set_num_threads(1)
TRACK = stadium()


def _env(mode: str) -> FormulaRacingEnv:
    env = FormulaRacingEnv(config={"track": TRACK, "action_mode": mode, "start_speed_mps": 20.0})
    env.reset(seed=0)
    return env


@pytest.mark.parametrize(("pedal", "throttle", "brake"), [(-0.5, 0.0, 0.5), (0.3, 0.3, 0.0)])
def test_a_pedal_step_applies_throttle_above_zero_and_brake_below(
    pedal: float, throttle: float, brake: float
) -> None:
    env, paper = _env("pedal"), _env("paper")
    assert env.action_space.shape == (2,) and paper.action_space.shape == (3,)
    for _ in range(3):
        got = env.step(np.array([0.1, pedal], np.float32))
        np.testing.assert_allclose(env.applied_controls, [0.1, throttle, brake], rtol=1e-6)
        # the car moves exactly as the three-axis action of the same controls moves it
        want = paper.step(np.array([0.1, throttle, brake], np.float32))
        np.testing.assert_array_equal(got[0], want[0])
        assert got[1:4] == want[1:4]
    assert got[4]["speed_mps"] != pytest.approx(20.0, abs=0.5)  # it did brake or accelerate


def test_the_vector_env_maps_every_cars_pedal() -> None:
    venv = FormulaRacingVectorEnv(2, config={"track": TRACK, "action_mode": "pedal"})
    venv.reset(seed=0)
    assert venv.single_action_space.shape == (2,)
    venv.step(np.array([[0.0, -0.5], [0.2, 0.3]], np.float32))
    np.testing.assert_allclose(venv._b.actions, [[0.0, 0.0, 0.5], [0.2, 0.3, 0.0]], rtol=1e-6)
    with pytest.raises(InvalidActionError, match=r"shape \(2, 2\) \(steer, pedal per car\)"):
        venv.step(np.zeros((2, 3)))


def test_a_bad_action_mode_and_a_three_axis_action_in_pedal_mode_are_clear_errors() -> None:
    with pytest.raises(UserInputError, match="action_mode"):
        FormulaRacingEnv(config={"track": TRACK, "action_mode": "joystick"})
    with pytest.raises(InvalidActionError, match=r"expected shape \(2,\) \(steer, pedal\)"):
        _env("pedal").step(np.zeros(3))


def test_a_bots_demonstration_is_written_as_throttle_minus_brake() -> None:
    np.testing.assert_allclose(
        pedal_action(np.array([[0.2, 0.7, 0.0], [-0.1, 0.0, 0.4]])), [[0.2, 0.7], [-0.1, -0.4]],
        rtol=1e-6,
    )


def test_brake_exploration_pushes_the_pedal_below_zero() -> None:
    noise = BrakeExplorationNoise(np.random.default_rng(0), noise_prob=0.0, brake_prob=1.0,
                                  brake_mean=0.5, brake_sigma=0.0, action_dim=2)  # fmt: skip
    out, event = noise(np.array([0.0, 0.6], np.float32), epsilon=1.0)
    assert event.brake_explored and event.mask.shape == (2,)
    np.testing.assert_allclose(out, [0.0, -0.5])  # epsilon 1: the drawn brake pressure, fully
    out, _ = noise(np.array([0.0, 0.6], np.float32), epsilon=0.5)
    np.testing.assert_allclose(out, [0.0, 0.05], atol=1e-7)  # halfway from 0.6 towards -0.5


@pytest.mark.parametrize("variant", ["WIN1", "TD3", "SAC", "CrossQ"])
def test_every_family_acts_inside_the_pedal_box_and_learns(variant: str) -> None:
    agent = make_agent(get_variant(variant, {"hidden": (16, 12)}), 4, action_dim=2, seed=0)
    act = agent.act(np.zeros((1, 4), np.float32))
    assert act.shape == (2,) and act[1] > 0.5  # the pedal starts on the throttle side
    buf = ReplayBuffer(1000, 4, 2, seed=0)
    rng = np.random.default_rng(0)
    for _ in range(40):
        buf.add(rng.normal(size=4), rng.uniform(-1, 1, 2), rng.normal(), rng.normal(size=4),
                terminated=False, truncated=False)  # fmt: skip
    for _ in range(4):
        assert all(np.isfinite(v) for v in agent.update(buf.sample(8)))
    acts = agent.actor(torch.randn(64, 1, 4) * 10).detach().numpy()
    assert (acts >= -1).all() and (acts <= 1).all()


def test_the_hand_written_ddpg_update_matches_autograd_in_pedal_mode() -> None:
    cfg = get_variant("WIN1", {"hidden": (16, 12), "buffer_size": 1000})
    manual, reference = (make_agent(cfg, 4, action_dim=2, seed=4) for _ in range(2))
    assert manual._mlp_update is not None
    buf = ReplayBuffer(1000, 4, 2, seed=5)
    rng = np.random.default_rng(1)
    for _ in range(40):
        buf.add(rng.normal(size=4), rng.uniform(-1, 1, 2), rng.normal(), rng.normal(size=4),
                terminated=False, truncated=False)  # fmt: skip
    for _ in range(4):
        batch = buf.sample(16)
        np.testing.assert_allclose(manual.update(batch), reference._update_autograd(batch),
                                   rtol=1e-4, atol=1e-6)  # fmt: skip
    for m, r in zip(manual.actor.parameters(), reference.actor.parameters(), strict=True):
        torch.testing.assert_close(m, r, atol=1e-5, rtol=1e-4)


def test_a_pedal_run_trains_and_tests_with_two_axis_actions_labelled_beyond_paper(
    tmp_path: Path, ring_tracks
) -> None:
    spec = build_run_spec(
        variant="WIN1", overrides={**SMALL, "learning_starts": 20}, train_tracks=["ringA"],
        device="cpu", seed=1, env_overrides={"action_mode": "pedal"},
        schedule=dict(episodes=3, max_steps=60, test_every_episodes=3, test_starts=1,
                      test_max_steps=60),
    )  # fmt: skip
    assert spec.beyond_paper() == ["action_mode pedal"]
    assert "action_mode" not in build_run_spec(variant="WIN1", train_tracks=["ringA"]).to_json()[
        "env"
    ]
    loop.train(spec, tmp_path / "job")
    eps = pd.read_parquet(tmp_path / "job" / "episodes.parquet")
    assert len(eps) == 3 and eps.updates.iloc[-1] > 0
    assert len(pd.read_parquet(tmp_path / "job" / "tests.parquet")) == 1


def test_the_budget_warm_up_steps_a_pedal_env(ring_tracks) -> None:
    spec = build_run_spec(variant="WIN1", train_tracks=["ringA"],
                          env_overrides={"action_mode": "pedal"})  # fmt: skip
    warm_up(spec)  # its half throttle as (steer 0, pedal 0.5), not a three-axis action

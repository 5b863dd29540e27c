"""The tests' averaged actor (``eval_ema_updates``, beyond the paper), with numbers.

After each actor step the average moves 1/N of the way to the online actor's weights; tests and
races drive it while exploration keeps the online actor; checkpoints carry it; a warm start
copies the actor into it; the paper's 0 keeps none and drives the online actor.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from training_fixtures import SMALL, ring_track

from formula_tourney.agents.buffers import make_buffer
from formula_tourney.agents.checkpoints import load_checkpoint, save_checkpoint
from formula_tourney.agents.families import make_agent
from formula_tourney.agents.variants import AgentConfig, get_variant
from formula_tourney.errors import UserInputError
from formula_tourney.sim.env import FormulaRacingEnv
from formula_tourney.training.evaluate import greedy_windows, run_test_episode
from formula_tourney.training.run_spec import build_run_spec

torch.set_num_threads(1)
D = 6


def _filled_buffer(cfg: AgentConfig, n: int = 200):  # noqa: ANN202 - a ReplayBuffer
    buf = make_buffer(500, D, 3, prioritized=cfg.prioritized, gamma=cfg.gamma, n_step=cfg.n_step,
                      window=cfg.window, bootstrap_on_truncation=True, seed=0)  # fmt: skip
    rng = np.random.default_rng(0)
    for t in range(n):
        buf.add(rng.normal(size=D), rng.random(3), rng.normal(), rng.normal(size=D),
                terminated=t % 50 == 24, truncated=t % 50 == 49)  # fmt: skip
    return buf


def _flat(module: torch.nn.Module) -> np.ndarray:
    return np.concatenate([p.detach().double().numpy().ravel() for p in module.parameters()])


@pytest.mark.parametrize(("name", "actor_steps"), [("WIN1", [1, 1, 1, 1]), ("TD3", [0, 1, 0, 1])])
def test_the_average_moves_a_1_over_n_step_towards_the_actor_after_each_actor_step(
    name: str, actor_steps: list[int]
) -> None:
    """WIN1 (the hand-written update, an actor step every update) and TD3 (autograd, the actor
    stepping every second update): e_k = e_{k-1} + (a_k - e_{k-1}) / 4 in float64 by hand."""
    cfg = get_variant(name, {"hidden": (32, 24), "batch_size": 16, "eval_ema_updates": 4})
    agent = make_agent(cfg, D, seed=0)
    buf = _filled_buffer(cfg)
    expected = _flat(agent.actor)
    np.testing.assert_array_equal(_flat(agent.actor_eval), expected)  # starts as the actor
    for stepped in actor_steps:
        before = _flat(agent.actor)
        agent.update(buf.sample(16))
        after = _flat(agent.actor)
        assert (not np.array_equal(before, after)) == bool(stepped)
        if stepped:
            expected = expected + (after - expected) / 4.0
        np.testing.assert_allclose(_flat(agent.actor_eval), expected, rtol=0, atol=1e-6)
    assert not np.allclose(_flat(agent.actor_eval), _flat(agent.actor), atol=1e-6)


def test_act_eval_is_the_average_and_act_the_online_actor() -> None:
    window = np.random.default_rng(1).normal(size=(1, D)).astype(np.float32)
    plain = make_agent(get_variant("WIN1", {"hidden": (32, 24), "batch_size": 16}), D, seed=0)
    assert plain.actor_eval is None and "actor_eval" not in plain.state_dict()
    averaged = make_agent(get_variant("WIN1", {"hidden": (32, 24), "batch_size": 16,
                                              "eval_ema_updates": 3}), D, seed=0)  # fmt: skip
    buf = _filled_buffer(averaged.cfg)
    for _ in range(5):
        plain.update(buf.sample(16))
        averaged.update(buf.sample(16))
    np.testing.assert_array_equal(plain.act_eval(window), plain.act(window))
    with torch.no_grad():
        by_module = averaged.actor_eval(torch.as_tensor(window).reshape(1, 1, D))[0].numpy()
    np.testing.assert_allclose(averaged.act_eval(window), by_module, atol=1e-6)
    assert not np.allclose(averaged.act_eval(window), averaged.act(window), atol=1e-6)


def test_a_test_drive_takes_the_averaged_actors_actions() -> None:
    """An average set to brake fully leaves the car at rest (the slow-progress end), while the
    online actor, set to full throttle, drives away: the test is the average's."""
    cfg = get_variant("WIN1", {"hidden": (32, 24), "eval_ema_updates": 100})
    agent = make_agent(cfg, 29, seed=0)
    with torch.no_grad():
        for actor, throttle in ((agent.actor, 20.0), (agent.actor_eval, -20.0)):
            actor.out.weight.zero_()
            actor.out.bias.copy_(torch.tensor([0.0, throttle, -throttle]))
    env = FormulaRacingEnv({"track": ring_track("ring"), "max_steps": 60, "random_start": False})
    drive = run_test_episode(agent, env, "ring", 0.0, seed=0)
    assert drive.distance_m < 1.0 and drive.termination == "slow"
    np.testing.assert_allclose(agent.act(np.zeros((1, 29), np.float32))[1:], [1.0, 0.0], atol=1e-6)


def test_checkpoints_carry_the_average_and_refuse_one_without_it(tmp_path: Path) -> None:
    cfg = get_variant("WIN1", {"hidden": (32, 24), "batch_size": 16, "eval_ema_updates": 5})
    agent = make_agent(cfg, D, seed=0)
    buf = _filled_buffer(cfg)
    for _ in range(4):
        agent.update(buf.sample(16))
    loaded, _ = load_checkpoint(save_checkpoint(agent, tmp_path / "a.pt"))
    np.testing.assert_array_equal(_flat(loaded.actor_eval), _flat(agent.actor_eval))
    batch = buf.sample(16)
    agent.update(batch)
    loaded.update(batch)
    np.testing.assert_array_equal(_flat(loaded.actor_eval), _flat(agent.actor_eval))
    state = agent.state_dict()
    state.pop("actor_eval")
    torch.save(state, tmp_path / "old.pt")
    with pytest.raises(UserInputError, match="incomplete for ddpg: no actor_eval"):
        load_checkpoint(tmp_path / "old.pt")


def test_a_warm_start_copies_the_actor_into_the_average() -> None:
    agent = make_agent(get_variant("WIN1", {"hidden": (32, 24), "eval_ema_updates": 50}), D, seed=0)
    with torch.no_grad():
        agent.actor.out.bias.add_(1.0)  # what behaviour cloning does: the actor moves alone
    assert not np.array_equal(_flat(agent.actor_eval), _flat(agent.actor))
    agent.sync_actor_copies()
    np.testing.assert_array_equal(_flat(agent.actor_eval), _flat(agent.actor))
    np.testing.assert_array_equal(_flat(agent.actor_target), _flat(agent.actor))


def test_the_setting_is_beyond_paper_and_left_out_of_config_at_zero(ring_tracks) -> None:
    spec = build_run_spec(variant="WIN1", train_tracks=["ringA"], overrides={**SMALL})
    assert "eval_ema_updates" not in spec.to_json()["agent"] and spec.beyond_paper() == []
    averaged = build_run_spec(variant="WIN1", train_tracks=["ringA"],
                              overrides={**SMALL, "eval_ema_updates": 2000})  # fmt: skip
    assert averaged.to_json()["agent"]["eval_ema_updates"] == 2000
    assert averaged.beyond_paper() == ["eval_ema_updates 2000"]
    with pytest.raises(UserInputError, match="eval_ema_updates"):
        build_run_spec(variant="WIN1", train_tracks=["ringA"], overrides={"eval_ema_updates": -1})


def test_greedy_windows_is_the_drive_a_test_takes() -> None:
    """The per-step drive the benchmarks read the networks along is the test's own: the same
    actions, steps and end as ``run_test_episode`` from the same start."""
    cfg = get_variant("WIN4", {"hidden": (32, 24)})
    agent = make_agent(cfg, 29, seed=0)
    env = FormulaRacingEnv({"track": ring_track("ring"), "max_steps": 60, "random_start": False})
    drive = run_test_episode(agent, env, "ring", 0.0, seed=0, keep_steps=True)
    steps = list(greedy_windows(agent, env, 0.0, seed=0))
    assert len(steps) == drive.steps == 17 and drive.termination == "off_track"
    assert steps[-1][2]["termination"] == "off_track"
    assert steps[0][0].shape == (4, 29)  # the WIN4 window, as the actor reads it
    throttle = np.array([action[1] for _, action, _ in steps])
    np.testing.assert_allclose(throttle, drive.steps_trace["throttle"], rtol=1e-6)

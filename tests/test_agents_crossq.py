"""CrossQ: the batch-norm critics see the joint batch of (s, a) and (s', a'), no target network
moves, Adam runs with beta1 0.5, updates stay finite, checkpoints round-trip, a run completes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from training_fixtures import SMALL

from formula_tourney.agents.buffers import ReplayBuffer
from formula_tourney.agents.checkpoints import load_checkpoint, save_checkpoint
from formula_tourney.agents.crossq import CrossQAgent
from formula_tourney.agents.families import make_agent
from formula_tourney.agents.variants import get_variant
from formula_tourney.training import loop
from formula_tourney.training.run_spec import build_run_spec

torch.set_num_threads(1)
D, B = 4, 8


def _agent(seed: int = 0) -> CrossQAgent:
    agent = make_agent(get_variant("CrossQ", {"hidden": (16, 12), "batch_size": B}), D, seed=seed)
    assert isinstance(agent, CrossQAgent)
    return agent


def _batch(seed: int = 0):  # type: ignore[no-untyped-def]
    buf = ReplayBuffer(1000, D, 3, seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(50):
        buf.add(rng.normal(size=D), rng.random(3), rng.normal(), rng.normal(size=D) + 5.0,
                terminated=False, truncated=False)  # fmt: skip
    return buf.sample(B)


def test_the_bn_forward_pass_normalises_the_joint_batch_of_current_and_next_states() -> None:
    agent = _agent()
    batch = _batch()
    seen: list[torch.Tensor] = []
    bn = agent.critic.q1.bn_in
    hook = bn.register_forward_hook(lambda m, args, out: seen.append(args[0].detach().clone()))
    mean_before = bn.running_mean.clone()
    agent._policy_delay = 10**6  # the critic's pass alone
    agent.update(batch)
    hook.remove()
    assert len(seen) == 1  # one pass: (s, a) and (s', a') together
    joint = seen[0]
    assert joint.shape == (2 * B, D + 3)
    np.testing.assert_array_equal(joint[:B, :D].numpy(), batch.observations[:, -1])
    np.testing.assert_array_equal(joint[B:, :D].numpy(), batch.next_observations[:, -1])
    np.testing.assert_array_equal(joint[:B, D:].numpy(), batch.actions)
    # the running mean moved by momentum 0.01 towards the JOINT batch's mean (next states sit
    # 5 higher: a pass over the current half alone would move it ~2.5 less)
    want = 0.99 * mean_before + 0.01 * joint.mean(0)
    torch.testing.assert_close(bn.running_mean, want)
    assert not agent.critic.training  # back in eval mode for the actor and acting


def test_no_target_network_moves_and_adam_runs_with_beta1_half() -> None:
    agent = _agent()
    target_before = agent.critic_target.state_dict()["q1.l1.weight"].clone()
    for opt in (agent.actor_opt, agent.critic_opt, agent.alpha_opt):
        assert opt.betas == (0.5, 0.999)
    for seed in range(6):
        info = agent.update(_batch(seed))
        assert all(np.isfinite(v) for v in info)
    assert agent.updates == 6 and agent._policy_delay == 3
    torch.testing.assert_close(agent.critic_target.state_dict()["q1.l1.weight"], target_before)
    assert not torch.equal(agent.critic.q1.l1.weight, target_before)


def test_the_target_bootstraps_from_the_online_critic_on_the_joint_pass() -> None:
    """The reported critic loss is the mean squared TD error against y built from the online
    critics' own Q(s', a'), with the generator's a' ~ pi(.|s')."""
    agent = _agent(3)
    batch = _batch(2)
    t = agent._tensors(batch, agent._MLP_FIELDS)
    probe = _agent(3)
    probe.load_state_dict(agent.state_dict())
    with torch.no_grad():
        a_next, logp = probe.actor.sample(t["next_observations"], probe._generator)
        probe.critic.train()
        q_all = probe.critic(torch.cat([t["observations"], t["next_observations"]]),
                             torch.cat([t["actions"], a_next]))  # fmt: skip
        q, q_next = q_all[:, :B], q_all[:, B:]
        y = t["rewards"] + t["discounts"] * (q_next.amin(0) - logp)  # alpha starts at 1
        expected = float(((y - q) ** 2).mean())
    assert agent.update(batch).critic_loss == pytest.approx(expected, rel=1e-5)


def test_a_checkpoint_round_trips_with_the_bn_statistics(tmp_path: Path) -> None:
    agent = _agent(1)
    for seed in range(4):
        agent.update(_batch(seed))
    path = save_checkpoint(agent, tmp_path / "c.pt", extra={})
    loaded, _ = load_checkpoint(path)
    assert type(loaded) is CrossQAgent
    torch.testing.assert_close(loaded.critic.q2.bn2.running_var, agent.critic.q2.bn2.running_var)
    window = np.ones((1, D), np.float32)
    np.testing.assert_array_equal(agent.act(window), loaded.act(window))
    batch = _batch(9)
    assert agent.update(batch) == loaded.update(batch)


def test_a_tiny_crossq_run_completes(tmp_path: Path, ring_tracks) -> None:
    spec = build_run_spec(
        variant="CrossQ", overrides=SMALL, train_tracks=["ringA"], device="cpu", seed=2,
        schedule=dict(episodes=3, max_steps=60, test_every_episodes=3, test_starts=1,
                      test_max_steps=60),
    )  # fmt: skip
    assert spec.beyond_paper() == ["CrossQ"]
    assert "bn_momentum" not in spec.to_json()["agent"]  # default-valued new settings left out
    summary = loop.train(spec, tmp_path / "job")
    eps = pd.read_parquet(tmp_path / "job" / "episodes.parquet")
    assert len(eps) == 3 and summary["updates"] > 0 and np.isfinite(eps.reward).all()

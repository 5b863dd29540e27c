"""Behaviour cloning in the actor's loss (``DemoSettings.bc_weight``): the Q-filtered MSE to the
demonstrated actions, its hand-written gradient against autograd's, and its pull on the actor."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from formula_tourney.agents.buffers import DemoMix, ReplayBuffer, make_buffer
from formula_tourney.agents.families import make_agent
from formula_tourney.agents.mlp_update import BCLoss
from formula_tourney.agents.variants import AgentConfig, get_variant
from formula_tourney.errors import UserInputError
from formula_tourney.training.run_spec import DemoSettings, build_run_spec

D = 6
SMALL = {"hidden": (32, 24), "batch_size": 16, "buffer_size": 1000}


def _filled(
    cfg: AgentConfig, seed: int, *, prioritized: bool, n: int = 200, driver: bool = False
) -> ReplayBuffer:
    """Random transitions; ``driver``: the actions are a smooth function of the observation,
    as a bot's are (something an actor can fit)."""
    kw = {"alpha": cfg.per_alpha, "lambda3": cfg.per_lambda3} if prioritized else {}
    buf = make_buffer(
        500, D, 3, prioritized=prioritized, gamma=cfg.gamma, n_step=cfg.n_step,
        window=cfg.window, bootstrap_on_truncation=cfg.adopted_target, seed=seed, **kw,
    )  # fmt: skip
    rng = np.random.default_rng(seed)
    for t in range(n):
        obs = rng.normal(size=D)
        action = 1.0 / (1.0 + np.exp(-obs[:3])) if driver else rng.random(3)
        buf.add(obs, action, 1.0 + rng.normal(), rng.normal(size=D),  # progress: Q > 0
                terminated=t % 50 == 24, truncated=t % 50 == 49)  # fmt: skip
    return buf


def _mix(cfg: AgentConfig, demo_rows: int = 6) -> DemoMix:
    return DemoMix(_filled(cfg, 5, prioritized=cfg.prioritized),
                   _filled(cfg, 7, prioritized=False, n=120, driver=True), demo_rows)  # fmt: skip


@pytest.mark.parametrize("q_filter", [True, False])
def test_the_actor_loss_gains_the_q_filtered_mse_to_the_demonstrated_actions(
    q_filter: bool,
) -> None:
    """The reported actor loss is -mean Q(s, mu(s)) + w mean|Q(s, mu(s))| / k sum over the k
    demonstration rows of m_i ||mu(s_i) - a_i||^2, computed here by hand from the networks as
    they were before the step; the batch has rows the filter keeps and rows it drops."""
    cfg = get_variant("WIN1", SMALL)
    agent = make_agent(cfg, D, seed=4)
    mix = _mix(cfg)
    batch = mix.sample(16)
    assert batch.from_demos is not None and batch.from_demos.sum() == 6
    obs, a = torch.from_numpy(batch.observations), torch.from_numpy(batch.actions)
    with torch.no_grad():
        mu = agent.actor(obs)
        q, q_mu = agent.critic(obs, a).view(-1), agent.critic(obs, mu).view(-1)
    demo = torch.from_numpy(batch.from_demos)
    keep = demo & (q > q_mu) if q_filter else demo
    if q_filter:
        assert 0 < int(keep.sum()) < 6, "the check needs rows kept and rows filtered out"
    mse = ((mu - a) ** 2).sum(1)
    expected = -q_mu.mean() + 0.7 * q_mu.abs().mean() / 6 * (mse * keep).sum()
    info = agent.update(batch, None, BCLoss(0.7, 6, q_filter))
    assert info.actor_loss == pytest.approx(float(expected), rel=1e-5)
    plain = make_agent(cfg, D, seed=4).update(batch, None)
    assert plain.actor_loss == pytest.approx(float(-q_mu.mean()), rel=1e-5)
    assert info.actor_loss > plain.actor_loss  # the term is there, and positive


@pytest.mark.parametrize("name", ["WIN1", "WIN4", "PER40k"])
def test_the_hand_written_cloning_gradient_matches_autograd(name: str) -> None:
    cfg = get_variant(name, SMALL)
    manual, reference = make_agent(cfg, D, seed=4), make_agent(cfg, D, seed=4)
    assert manual._mlp_update is not None
    mix_m, mix_r = _mix(cfg), _mix(cfg)
    bc = BCLoss(0.7, 6)
    for _ in range(5):
        info_m = manual.update(mix_m.sample(16), mix_m.priorities(16), bc)
        info_r = reference._update_autograd(mix_r.sample(16), mix_r.priorities(16), bc)
        np.testing.assert_allclose(info_m, info_r, rtol=1e-4, atol=1e-6)
    for key in ("actor", "critic"):
        sm, sr = getattr(manual, key).state_dict(), getattr(reference, key).state_dict()
        for k in sm:
            assert torch.allclose(sm[k], sr[k], atol=1e-5, rtol=1e-4), f"{key}.{k}"


@pytest.mark.parametrize("name", ["WIN1", "TD3", "SAC"])
def test_cloning_pulls_the_actor_towards_the_demonstrated_actions(name: str) -> None:
    """Unfiltered, a strong cloning term brings mu(s) close to the demonstrations' actions,
    which 300 updates of the critic's gradient alone do not (TD3 and SAC: the autograd path);
    at the paper's actor lr (1e-4) 300 Adam steps move a weight by 0.03 at most, so 1e-3."""
    cfg = get_variant(name, {**SMALL, "actor_lr": 1e-3})
    mix = _mix(cfg, demo_rows=8)
    demos = mix.demos.sample(120)
    obs, a = torch.from_numpy(demos.observations), torch.from_numpy(demos.actions)

    def mse_after(bc: BCLoss | None) -> float:
        agent = make_agent(cfg, D, seed=1)
        for _ in range(300):
            agent.update(mix.sample(16), None, bc)
        with torch.no_grad():
            mu = agent.actor(obs)  # SAC: its greedy action, the squashed mean
        return float(((mu - a) ** 2).sum(1).mean())

    cloned, free = mse_after(BCLoss(50.0, 8, q_filter=False)), mse_after(None)
    assert cloned < 0.5 * free, (cloned, free)


def test_cloning_needs_demonstration_rows_in_every_batch(ring_tracks) -> None:
    """A weight with no demonstration rows to clone is refused, also where the fraction rounds
    to no row at the run's batch size."""
    for fraction, batch in ((0.0, 64), (0.01, 16)):
        with pytest.raises(UserInputError, match="bc_weight 0.5 clones"):
            build_run_spec(variant="WIN1", train_tracks=["ringA"], overrides={"batch_size": batch},
                           demos={"batch_fraction": fraction, "bc_weight": 0.5})  # fmt: skip
    assert DemoSettings(batch_fraction=0.0, bc_steps=10).bc_weight == 0.0


def test_a_demos_setting_changes_one_key_of_the_presets_demonstrations(ring_tracks) -> None:
    """The caller's demos keys win over the preset's one by one, as agent and schedule keys do:
    `tuned-bc` with another weight keeps its 10 laps and its quarter of the batch."""
    spec = build_run_spec(variant="WIN1", train_tracks=["ringA"], preset="tuned-bc",
                          demos={"bc_weight": 0.5})  # fmt: skip
    assert (spec.demos.laps, spec.demos.batch_fraction, spec.demos.bc_weight) == (10, 0.25, 0.5)
    plain = build_run_spec(variant="WIN1", train_tracks=["ringA"], demos={"laps": 2})
    assert plain.demos.bc_weight == 0.0 and plain.demos.laps == 2

"""The classification critic (``critic_bins``, beyond the paper), with numbers.

Its target histogram has the target's mean and 0.75 bin widths of spread; its Q is the softmax's
mean of the bin centres; it learns a regression target by cross-entropy through the
hand-written update (``tests/test_agents.py`` holds it to autograd's); checkpoints round-trip;
0 keeps the paper's critic and its digests.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from formula_tourney.agents.buffers import make_buffer
from formula_tourney.agents.checkpoints import load_checkpoint, save_checkpoint
from formula_tourney.agents.families import make_agent
from formula_tourney.agents.networks import HL_GAUSS_SIGMA_BINS, MLPCritic, hl_gauss_targets
from formula_tourney.agents.variants import get_variant
from formula_tourney.errors import UserInputError
from formula_tourney.training.run_spec import build_run_spec

torch.set_num_threads(1)
D = 6
SMALL = {"hidden": (32, 24), "batch_size": 32}


def test_the_target_histogram_has_the_targets_mean_and_spread() -> None:
    edges = torch.linspace(-10.0, 10.0, 41, dtype=torch.float64)  # 40 bins of 0.5
    centres = 0.5 * (edges[1:] + edges[:-1])
    sigma = 0.5 * HL_GAUSS_SIGMA_BINS
    y = torch.tensor([-3.3, 0.0, 0.26, 7.9], dtype=torch.float64)
    p = hl_gauss_targets(y, edges)
    np.testing.assert_allclose(p.sum(1).numpy(), 1.0, atol=1e-12)
    np.testing.assert_allclose((p @ centres).numpy(), y.numpy(), atol=1e-5)
    spread = ((p * (centres[None] - y[:, None]) ** 2).sum(1)).sqrt()
    # a normal of sd 0.375 binned at 0.5: sd^2 + width^2 / 12 (Sheppard's correction)
    np.testing.assert_allclose(spread.numpy(), (sigma**2 + 0.5**2 / 12) ** 0.5, rtol=1e-3)
    far = hl_gauss_targets(torch.tensor([50.0], dtype=torch.float64), edges)
    # clipped to the span's top edge: the top bin takes most of the mass, Q near the top
    assert float(far[0, -1]) > 0.8 and float(far[0] @ centres) > 9.5


def test_a_wider_target_spreads_its_mass_over_more_bins() -> None:
    """``critic_sigma_bins`` sets the target's spread in bin widths, from the settings to the
    loss: 2 bin widths put ~20 % of the mass in the target's own bin (0.75: ~50 %)."""
    edges = torch.linspace(-10.0, 10.0, 41, dtype=torch.float64)  # 40 bins of 0.5
    centres = 0.5 * (edges[1:] + edges[:-1])
    y = torch.tensor([0.25], dtype=torch.float64)  # the middle of the bin [0, 0.5]
    narrow, wide = hl_gauss_targets(y, edges), hl_gauss_targets(y, edges, 2.0)
    own = 20  # the bin [0, 0.5]
    # the normal's mass within +-0.5 / sigma standard deviations: erf(0.5 / (sigma sqrt 2))
    assert float(narrow[0, own]) == pytest.approx(0.4950, abs=1e-3)
    assert float(wide[0, own]) == pytest.approx(0.1974, abs=1e-3)
    np.testing.assert_allclose(float(wide[0] @ centres), 0.25, atol=1e-9)
    cfg = get_variant("WIN1", {**SMALL, "critic_bins": 41, "critic_value_range": (-10.0, 10.0),
                               "critic_sigma_bins": 2.0})  # fmt: skip
    agent = make_agent(cfg, D, seed=0)
    assert agent.critic.sigma_bins == 2.0


def test_the_target_narrows_over_its_warm_up_in_both_updates() -> None:
    """``critic_sigma_start_bins`` 3 over ``critic_sigma_warmup_updates`` 4 to 0.75: 3, 2.4375,
    1.875, 1.3125, then 0.75 for good, read by the hand-written update and autograd's alike."""
    over = {**SMALL, "critic_bins": 11, "critic_value_range": (-0.5, 0.5),
            "critic_sigma_start_bins": 3.0, "critic_sigma_warmup_updates": 4}  # fmt: skip
    cfg = get_variant("WIN1", over)
    manual, reference = make_agent(cfg, D, seed=1), make_agent(cfg, D, seed=1)
    buf = _constant_target_buffer(0.2)
    widths = []
    for _ in range(6):
        widths.append(manual.target_sigma_bins())
        batch = buf.sample(16)
        info_m = manual.update(batch)
        reference.critic.sigma_bins = reference.target_sigma_bins()
        info_r = reference._update_autograd(batch)
        reference.updates = manual.updates
        np.testing.assert_allclose(info_m, info_r, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(widths, [3.0, 2.4375, 1.875, 1.3125, 0.75, 0.75])
    assert manual.critic.sigma_bins == 0.75
    for bad in ({"critic_bins": 11, "critic_sigma_start_bins": 3.0},
                {"critic_bins": 11, "critic_sigma_warmup_updates": 4}):  # fmt: skip
        with pytest.raises(UserInputError, match="both or neither"):
            get_variant("WIN1", bad)
    with pytest.raises(UserInputError, match="needs critic_bins"):
        get_variant("WIN1", {"critic_sigma_start_bins": 3.0, "critic_sigma_warmup_updates": 4})


def test_q_is_the_softmax_mean_of_the_bin_centres() -> None:
    critic = MLPCritic(D, 3, 1, (16, 8), bins=5, value_range=(-10.0, 10.0))
    np.testing.assert_allclose(critic.centres.numpy(), [-8.0, -4.0, 0.0, 4.0, 8.0])
    with torch.no_grad():
        critic.out.weight.zero_()
        critic.out.bias.copy_(torch.tensor([0.0, 0.0, 0.0, 0.0, np.log(6.0)]))
    obs, act = torch.zeros(2, 1, D), torch.zeros(2, 3)
    # probabilities 1/10 x 4 and 6/10: Q = (-8 - 4 + 0 + 4) / 10 + 8 x 0.6
    np.testing.assert_allclose(critic(obs, act).detach().numpy(), [4.0, 4.0], atol=1e-5)
    q, q_pi = critic.q_pair(obs, act, act)
    np.testing.assert_allclose(q.detach().numpy(), q_pi.detach().numpy())


def _constant_target_buffer(reward: float):  # noqa: ANN202 - a ReplayBuffer
    buf = make_buffer(500, D, 3, prioritized=False, gamma=0.99, n_step=1, window=1,
                      bootstrap_on_truncation=True, seed=0)  # fmt: skip
    rng = np.random.default_rng(0)
    for _ in range(300):  # every transition terminal: y = r
        buf.add(rng.normal(size=D), rng.random(3), reward, rng.normal(size=D),
                terminated=True, truncated=False)  # fmt: skip
    return buf


def test_the_critic_learns_a_target_by_cross_entropy() -> None:
    cfg = get_variant("WIN1", {**SMALL, "critic_bins": 51, "critic_value_range": (-20.0, 20.0),
                               "critic_lr": 3e-3})  # fmt: skip
    agent = make_agent(cfg, D, seed=0)
    assert agent._mlp_update is not None  # the hand-written update runs it
    buf = _constant_target_buffer(7.3)
    first = agent.update(buf.sample(32))
    for _ in range(300):
        info = agent.update(buf.sample(32))
    assert abs(first.q_mean) < 1.0  # an untrained head is near uniform: Q near the span's middle
    assert info.q_mean == pytest.approx(7.3, abs=0.2)
    assert info.critic_loss < first.critic_loss  # the cross-entropy fell


def test_checkpoints_round_trip_and_settings_are_checked(tmp_path: Path) -> None:
    cfg = get_variant("WIN1", {**SMALL, "critic_bins": 11})
    agent = make_agent(cfg, D, seed=0)
    buf = _constant_target_buffer(1.0)
    for _ in range(3):
        agent.update(buf.sample(32))
    loaded, _ = load_checkpoint(save_checkpoint(agent, tmp_path / "a.pt"))
    obs, act = torch.randn(4, 1, D), torch.rand(4, 3)
    with torch.no_grad():
        q_loaded, q_saved = loaded.critic(obs, act), agent.critic(obs, act)
    np.testing.assert_array_equal(q_loaded.numpy(), q_saved.numpy())
    for bad, words in (({"critic_bins": 1}, "not 1"),
                       ({"critic_bins": 11, "critic_value_range": (5.0, 5.0)}, "must be below"),
                       ({"critic_bins": 11, "lstm_critic": True}, "not lstm_critic"),
                       ({"critic_value_range": (-5.0, 5.0)}, "needs critic_bins"),
                       ({"critic_sigma_bins": 1.5}, "needs critic_bins"),
                       ({"critic_bins": 11, "critic_sigma_bins": 0.0}, "greater than 0"),
                       ):  # fmt: skip
        with pytest.raises(UserInputError, match=words):
            get_variant("WIN1", bad)
    with pytest.raises(UserInputError, match="critic_bins apply to algorithm ddpg only"):
        get_variant("TD3", {"critic_bins": 11})


def test_zero_bins_keep_the_papers_critic_and_the_setting_is_beyond_paper(ring_tracks) -> None:
    """One output, the hand-written backend, no bins; a run spec labels the setting and leaves
    it out of its config at 0."""
    plain = make_agent(get_variant("WIN1", SMALL), D, seed=0)
    assert plain._mlp_update is not None and plain.critic.out.out_features == 1
    assert not hasattr(plain.critic, "centres")
    spec = build_run_spec(variant="WIN1", train_tracks=["ringA"], overrides={})
    assert "critic_bins" not in spec.to_json()["agent"] and spec.beyond_paper() == []
    binned = build_run_spec(variant="WIN1", train_tracks=["ringA"],
                            overrides={"critic_bins": 51})  # fmt: skip
    assert binned.to_json()["agent"]["critic_bins"] == 51
    assert binned.beyond_paper() == ["critic_bins 51"]


def test_the_squared_error_of_q_joins_the_cross_entropy() -> None:
    """``critic_mse_weight`` w: the critic's loss is the cross-entropy plus w times the paper's
    squared error of Q (the softmax's mean) to y, both read at the update's own weights; the
    setting is refused without bins."""
    weight = 0.5
    cfg = get_variant("WIN1", {**SMALL, "critic_bins": 21, "critic_value_range": (-10.0, 10.0),
                               "critic_mse_weight": weight})  # fmt: skip
    agent = make_agent(cfg, D, seed=2)
    assert agent._mlp_update is not None and agent._mlp_update.mse_weight == weight
    batch = _constant_target_buffer(7.3).sample(32)  # every row terminal: y = 7.3
    obs, actions = torch.from_numpy(batch.observations), torch.from_numpy(batch.actions)
    with torch.no_grad():
        logits, _ = agent.critic.logits_pair(obs, actions, actions)
        q = agent.critic.value(logits)
        y = torch.full_like(q, 7.3)
        target = hl_gauss_targets(y, agent.critic.edges, agent.critic.sigma_bins)
        cross_entropy = float(-(target * torch.log_softmax(logits, 1)).sum(1).mean())
        squared = float((y - q).square().mean())
    assert squared > 40.0  # an untrained head reads Q near 0: the term is far from nothing
    info = agent.update(batch)
    assert info.critic_loss == pytest.approx(cross_entropy + weight * squared, rel=1e-5)
    with pytest.raises(UserInputError, match="needs critic_bins"):
        get_variant("WIN1", {"critic_mse_weight": 0.5})

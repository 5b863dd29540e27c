"""Running observation normalisation (``obs_norm``, beyond the paper), with numbers.

The statistics are those of every counted observation whatever the chunking; acting, tests and
updates read the observations through the same map; checkpoints carry the statistics; the
entrant counts each stored transition's observation once; off, nothing changes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from training_fixtures import SMALL

from formula_tourney.agents.buffers import make_buffer
from formula_tourney.agents.checkpoints import load_checkpoint, save_checkpoint
from formula_tourney.agents.families import make_agent
from formula_tourney.agents.family_entrant import FamilyEntrant
from formula_tourney.agents.obs_norm import CLIP, RunningObsNorm
from formula_tourney.agents.protocol import EntrantSpaces, Transition
from formula_tourney.agents.variants import AgentConfig, get_variant
from formula_tourney.errors import UserInputError
from formula_tourney.training.run_spec import build_run_spec

torch.set_num_threads(1)
D = 5
SCALES = np.array([0.01, 0.1, 1.0, 10.0, 3.0])
OFFSETS = np.array([0.5, -2.0, 0.0, 40.0, 1.0])


def _observations(n: int, seed: int = 0) -> np.ndarray:
    """Values whose spreads differ by 1 000x, as the sensors' raw ranges do."""
    return (np.random.default_rng(seed).normal(size=(n, D)) * SCALES + OFFSETS).astype(np.float32)


def _filled_buffer(cfg: AgentConfig, obs: np.ndarray):  # noqa: ANN202 - a ReplayBuffer
    buf = make_buffer(500, D, 3, prioritized=False, gamma=cfg.gamma, n_step=cfg.n_step,
                      window=cfg.window, bootstrap_on_truncation=True, seed=0)  # fmt: skip
    rng = np.random.default_rng(1)
    for t in range(len(obs) - 1):
        buf.add(obs[t], rng.random(3), rng.normal(), obs[t + 1], terminated=t % 50 == 24,
                truncated=t % 50 == 49)  # fmt: skip
    return buf


def _flat(module: torch.nn.Module) -> np.ndarray:
    return np.concatenate([p.detach().double().numpy().ravel() for p in module.parameters()])


def test_the_statistics_are_those_of_every_observation_whatever_the_chunks() -> None:
    obs = _observations(1000)
    norm = RunningObsNorm(D, torch.device("cpu"))
    for chunk in np.array_split(obs, [1, 2, 50, 51, 400, 999]):
        norm.update(chunk)
    assert norm.count == 1000
    np.testing.assert_allclose(norm.mean, obs.astype(np.float64).mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(norm.std, obs.astype(np.float64).std(axis=0), rtol=1e-9)
    z = norm.apply(torch.from_numpy(obs)).numpy()
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=1e-5)
    np.testing.assert_allclose(z.std(axis=0), 1.0, atol=1e-4)
    np.testing.assert_allclose(norm.apply_np(obs), z, atol=1e-6)  # NumPy and torch agree


def test_the_map_is_the_identity_before_any_count_and_clips_far_values() -> None:
    norm = RunningObsNorm(D, torch.device("cpu"))
    x = _observations(4)
    np.testing.assert_array_equal(norm.apply_np(x), x)
    norm.update(np.zeros((10, D)))  # nothing moved: centred, divided by the floor
    far = np.full((1, D), 1.0, np.float32)
    np.testing.assert_array_equal(norm.apply_np(far), np.full((1, D), CLIP, np.float32))
    # a window (w, obs_dim) and a flattened one map value by value alike
    norm.update(_observations(50))
    window = _observations(3, seed=2)
    np.testing.assert_allclose(norm.apply_np(window.reshape(1, -1)).reshape(3, D),
                               norm.apply_np(window), atol=0)  # fmt: skip


def _pair(window: int = 1) -> tuple:
    """A normalising agent and a plain one with the same weights."""
    overrides = {"hidden": (32, 24), "batch_size": 16, "window": window}
    normed = make_agent(get_variant("WIN1", {**overrides, "obs_norm": True}), D, seed=0)
    plain = make_agent(get_variant("WIN1", overrides), D, seed=0)
    np.testing.assert_array_equal(_flat(normed.actor), _flat(plain.actor))
    return normed, plain


def test_acting_reads_the_normalised_window() -> None:
    normed, plain = _pair(window=4)
    obs = _observations(300)
    normed.count_observations(obs)
    window = _observations(4, seed=3)
    z = normed.obs_norm.apply_np(window)
    np.testing.assert_allclose(normed.act(window), plain.act(z), atol=1e-6)
    np.testing.assert_allclose(normed.act_eval(window), plain.act_eval(z), atol=1e-6)
    np.testing.assert_allclose(normed.act_batch(window[None]), plain.act_batch(z[None]),
                               atol=1e-6)  # fmt: skip
    assert not np.allclose(normed.act(window), plain.act(window), atol=1e-3)


@pytest.mark.parametrize("name", ["WIN1", "TD3"])
def test_an_update_reads_the_batch_through_the_statistics_of_the_moment(name: str) -> None:
    """The same update as a plain agent given the batch normalised by hand: the hand-written
    backend (WIN1) and autograd (TD3) alike."""
    overrides = {"hidden": (32, 24), "batch_size": 16}
    normed = make_agent(get_variant(name, {**overrides, "obs_norm": True}), D, seed=0)
    plain = make_agent(get_variant(name, overrides), D, seed=0)
    obs = _observations(301)
    buf = _filled_buffer(normed.cfg, obs)
    normed.count_observations(obs[:300])
    for _ in range(3):
        batch = buf.sample(16)
        by_hand = batch._replace(
            observations=normed.obs_norm.apply_np(batch.observations),
            next_observations=normed.obs_norm.apply_np(batch.next_observations),
        )
        a, b = normed.update(batch), plain.update(by_hand)
        assert a.critic_loss == pytest.approx(b.critic_loss, rel=1e-5)
    np.testing.assert_allclose(_flat(normed.critic), _flat(plain.critic), atol=1e-6)
    np.testing.assert_allclose(_flat(normed.actor), _flat(plain.actor), atol=1e-6)


def test_checkpoints_carry_the_statistics_and_refuse_a_file_without_them(tmp_path: Path) -> None:
    normed, _ = _pair()
    normed.count_observations(_observations(200))
    loaded, _ = load_checkpoint(save_checkpoint(normed, tmp_path / "a.pt"))
    assert loaded.obs_norm.count == 200
    np.testing.assert_array_equal(loaded.obs_norm.mean, normed.obs_norm.mean)
    window = _observations(1, seed=4)
    np.testing.assert_array_equal(loaded.act_eval(window), normed.act_eval(window))
    state = normed.state_dict()
    state.pop("obs_norm")
    torch.save(state, tmp_path / "old.pt")
    with pytest.raises(UserInputError, match="incomplete for ddpg: no obs_norm"):
        load_checkpoint(tmp_path / "old.pt")


def test_the_entrant_counts_each_stored_observation_once() -> None:
    cfg = get_variant("WIN1", {**SMALL, "obs_norm": True})
    spaces = EntrantSpaces(D, 3, np.zeros(3, np.float32), np.ones(3, np.float32), 2)
    entrant = FamilyEntrant.build(cfg, spaces, 0, "cpu")
    obs = _observations(40)
    for t in range(0, 40, 2):  # two cars a step
        entrant.observe([Transition(car, obs[t + car], np.zeros(3, np.float32), 0.0,
                                    obs[t + car], False, False) for car in (0, 1)])  # fmt: skip
    norm = entrant.agent.obs_norm
    assert norm.count == 40
    np.testing.assert_allclose(norm.mean, obs.astype(np.float64).mean(axis=0), rtol=1e-12)


def test_off_it_keeps_no_statistics_and_the_setting_is_beyond_paper(ring_tracks) -> None:
    plain = make_agent(get_variant("WIN1", {"hidden": (32, 24)}), D, seed=0)
    assert plain.obs_norm is None and "obs_norm" not in plain.state_dict()
    x = torch.from_numpy(_observations(3))
    assert plain.normalise(x) is x
    spec = build_run_spec(variant="WIN1", train_tracks=["ringA"], overrides={**SMALL})
    assert "obs_norm" not in spec.to_json()["agent"] and spec.beyond_paper() == []
    normed = build_run_spec(variant="WIN1", train_tracks=["ringA"],
                            overrides={**SMALL, "obs_norm": True})  # fmt: skip
    assert normed.beyond_paper() == ["obs_norm"]

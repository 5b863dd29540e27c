"""The TD3 and SAC families: targets and log-probs by hand, delay, temperature,
learning, checkpoints and copies, the paper's ten unchanged, and "all+beyond" entrants."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from formula_tourney.agents.buffers import ReplayBuffer, make_buffer
from formula_tourney.agents.checkpoints import load_checkpoint, save_checkpoint
from formula_tourney.agents.families import make_agent
from formula_tourney.agents.variants import (
    ALL_VARIANTS,
    BEYOND_PAPER_VARIANTS,
    VARIANTS,
    AgentConfig,
    get_variant,
)
from formula_tourney.errors import UserInputError
from formula_tourney.tourney.plan import part_variants
from formula_tourney.tourney.spec import default_family, load_spec

torch.set_num_threads(1)
D = 6
SMALL = {"hidden": (32, 24), "batch_size": 16}
BOX_LOW, BOX_HIGH = np.array([-1.0, 0.0, 0.0]), np.array([1.0, 1.0, 1.0])
CENTRE, SCALE = np.array([0.0, 0.5, 0.5]), np.array([1.0, 0.5, 0.5])


def _buffer_for(cfg: AgentConfig, n: int = 200, seed: int = 0, **kw) -> ReplayBuffer:
    buf = make_buffer(
        500, D, 3, prioritized=cfg.prioritized, gamma=cfg.gamma, n_step=cfg.n_step,
        window=cfg.window, bootstrap_on_truncation=cfg.adopted_target, seed=seed, **kw,
    )  # fmt: skip
    rng = np.random.default_rng(seed)
    for t in range(n):
        buf.add(
            rng.normal(size=D), rng.random(3), rng.normal(), rng.normal(size=D),
            terminated=t % 50 == 24, truncated=t % 50 == 49,
        )  # fmt: skip
    return buf


# --- the networks by hand, in float64 NumPy from the modules' weights ---------------------------
def _weights(module: torch.nn.Module) -> dict[str, np.ndarray]:
    return {k: v.detach().double().numpy() for k, v in module.state_dict().items()}


def _dense(w: dict[str, np.ndarray], name: str, x: np.ndarray) -> np.ndarray:
    out = x @ w[f"{name}.weight"].T
    return out + w[f"{name}.bias"] if f"{name}.bias" in w else out


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0)


def _q(w: dict[str, np.ndarray], prefix: str, x: np.ndarray, a: np.ndarray) -> np.ndarray:
    """MLPCritic: relu(W2h relu(W1 x + b1) + b2 + W2a a) -> Q."""
    h1 = _relu(_dense(w, f"{prefix}l1", x))
    h2 = _relu(_dense(w, f"{prefix}l2", h1) + _dense(w, f"{prefix}l2_action", a))
    return _dense(w, f"{prefix}out", h2)[:, 0]


def _mu(w: dict[str, np.ndarray], x: np.ndarray) -> np.ndarray:
    """Actor: tanh steer, sigmoid pedals."""
    z = _dense(w, "out", _relu(_dense(w, "l2", _relu(_dense(w, "l1", x)))))
    return np.concatenate([np.tanh(z[:, :1]), 1.0 / (1.0 + np.exp(-z[:, 1:]))], axis=1)


def _gaussian(w: dict[str, np.ndarray], x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """SquashedGaussianActor's (mean, clamped log std)."""
    h = _relu(_dense(w, "l2", _relu(_dense(w, "l1", x))))
    return _dense(w, "mean", h), np.clip(_dense(w, "log_std", h), -20.0, 2.0)


def _log_prob_by_hand(u: np.ndarray, mean: np.ndarray, log_std: np.ndarray) -> np.ndarray:
    """log N(u; m, s) - sum log |d a / d u| with a = c + k tanh(u): the naive formula."""
    std = np.exp(log_std)
    gauss = -0.5 * ((u - mean) / std) ** 2 - np.log(std) - 0.5 * np.log(2 * np.pi)
    jacobian = SCALE * (1.0 - np.tanh(u) ** 2)
    return (gauss - np.log(jacobian)).sum(-1)


def _normal_draws(generator: torch.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """The next standard normal draws of a generator, without moving it."""
    g = torch.Generator()
    g.set_state(generator.get_state())
    return torch.randn(shape, generator=g).double().numpy()


def _mirror(critic: torch.nn.Module, x: np.ndarray, a: np.ndarray) -> None:
    """Known weights for the twin critics at ``(x, a)``: Q1's final layer x300 (its outputs
    spread beyond the initial +-3e-3), and Q2 = 2 median(Q1) - Q1, so each critic is the smaller
    on some rows."""
    with torch.no_grad():
        critic.q1.out.weight.mul_(300.0)
        q1 = _q(_weights(critic), "q1.", x, a)
        critic.q2.load_state_dict(critic.q1.state_dict())
        critic.q2.out.weight.neg_()
        critic.q2.out.bias.copy_(2.0 * np.median(q1) - critic.q1.out.bias)


def _tiny_batch(b: int = 5, seed: int = 0) -> tuple[torch.Tensor, ...]:
    rng = np.random.default_rng(seed)
    rewards = torch.tensor(rng.normal(size=b), dtype=torch.float32)
    discounts = torch.tensor([0.99, 0.0, 0.99**3, 0.99, 0.5], dtype=torch.float32)[:b]
    next_obs = torch.tensor(rng.normal(size=(b, 1, D)) * 2, dtype=torch.float32)
    return rewards, discounts, next_obs, torch.zeros(b, 0, 3)


# --- targets ------------------------------------------------------------------------------------
def test_td3_target_is_clipped_double_q_at_the_smoothed_target_action() -> None:
    """y = r + d min_j Q'_j(s', clip(mu'(s') + clip(N(0, s), -c, c), box)), computed by hand."""
    cfg = get_variant("TD3", {**SMALL, "policy_noise": 0.4, "noise_clip": 0.3})
    agent = make_agent(cfg, D, seed=0)
    with torch.no_grad():  # a target actor at full throttle, so the smoothing leaves the box
        agent.actor_target.out.bias[1] += 6.0
    rewards, discounts, next_obs, windows = _tiny_batch()
    x = next_obs.reshape(5, -1).double().numpy()
    eps = _normal_draws(agent._generator, (5, 3))
    noise = np.clip(0.4 * eps, -0.3, 0.3)
    mu = _mu(_weights(agent.actor_target), x)
    a_next = np.clip(mu + noise, BOX_LOW, BOX_HIGH)
    assert np.any(np.abs(noise) == 0.3) and np.any(a_next[:, 1] == 1.0)  # both clips at work
    _mirror(agent.critic_target, x, a_next)
    y = agent.target(rewards, discounts, next_obs, windows).double().numpy()

    w = _weights(agent.critic_target)
    q1, q2 = _q(w, "q1.", x, a_next), _q(w, "q2.", x, a_next)
    assert np.any(q1 < q2) and np.any(q2 < q1)  # the min picks from both critics
    expected = rewards.double().numpy() + discounts.double().numpy() * np.minimum(q1, q2)
    np.testing.assert_allclose(y, expected, rtol=1e-5, atol=1e-6)
    assert y[1] == pytest.approx(float(rewards[1]), abs=1e-7)  # d = 0: y = r


def test_sac_target_is_soft_clipped_double_q_at_a_policy_sample() -> None:
    """y = r + d (min_j Q'_j(s', a') - alpha log pi(a'|s')), a' ~ pi(.|s'), by hand."""
    cfg = get_variant("SAC", {**SMALL, "alpha_init": 0.3})
    agent = make_agent(cfg, D, seed=1)
    assert agent.actor_target is None
    rewards, discounts, next_obs, windows = _tiny_batch(seed=1)
    x = next_obs.reshape(5, -1).double().numpy()
    eps = _normal_draws(agent._generator, (5, 3))
    mean, log_std = _gaussian(_weights(agent.actor), x)
    u = mean + np.exp(log_std) * eps
    a_next = CENTRE + SCALE * np.tanh(u)
    log_pi = _log_prob_by_hand(u, mean, log_std)
    _mirror(agent.critic_target, x, a_next)
    y = agent.target(rewards, discounts, next_obs, windows).double().numpy()

    w = _weights(agent.critic_target)
    q1, q2 = _q(w, "q1.", x, a_next), _q(w, "q2.", x, a_next)
    assert np.any(q1 < q2) and np.any(q2 < q1)
    soft_q = np.minimum(q1, q2) - 0.3 * log_pi
    expected = rewards.double().numpy() + discounts.double().numpy() * soft_q
    np.testing.assert_allclose(y, expected, rtol=1e-5, atol=1e-6)
    assert y[1] == pytest.approx(float(rewards[1]), abs=1e-7)


def test_sac_log_prob_carries_the_squash_and_the_affine_correction() -> None:
    actor = make_agent(get_variant("SAC", SMALL), D, seed=2).actor
    rng = np.random.default_rng(0)
    mean, log_std = rng.normal(size=(64, 3)), rng.uniform(-1.5, 0.5, (64, 3))
    u = mean + np.exp(log_std) * rng.normal(size=(64, 3)) * 2
    got = actor.log_prob(*(torch.tensor(v, dtype=torch.float64) for v in (u, mean, log_std)))
    np.testing.assert_allclose(got.numpy(), _log_prob_by_hand(u, mean, log_std), rtol=1e-9)
    # pi is a density on the box [-1, 1] x [0, 1]^2: it integrates to 1 (without the affine
    # factor k = (1, 1/2, 1/2) it would integrate to 1/4); midpoint rule, 120^3 points
    n = 120
    mid = (np.arange(n) + 0.5) / n
    axes = [lo + (hi - lo) * mid for lo, hi in zip(BOX_LOW, BOX_HIGH, strict=True)]
    a = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    u_grid = np.arctanh((a - CENTRE) / SCALE)
    m, s = np.array([[0.3, -0.4, 0.8]]), np.array([[-0.2, 0.1, -0.5]])
    lp = actor.log_prob(*(torch.tensor(v, dtype=torch.float64) for v in (u_grid, m, s)))
    cell = np.prod((BOX_HIGH - BOX_LOW) / n)
    assert float(lp.exp().sum()) * cell == pytest.approx(1.0, abs=1e-2)
    # a sample's log-prob is that of its own pre-squash value, inside the box
    obs = torch.randn(256, 1, D)
    g = torch.Generator().manual_seed(3)
    eps = _normal_draws(g, (256, 3))
    a_s, lp_s = actor.sample(obs, g)
    m_s, s_s = (v.detach().double().numpy() for v in actor.distribution(obs))
    u_s = m_s + np.exp(s_s) * eps
    np.testing.assert_allclose(a_s.detach().numpy(), CENTRE + SCALE * np.tanh(u_s), atol=1e-6)
    np.testing.assert_allclose(lp_s.detach().numpy(), _log_prob_by_hand(u_s, m_s, s_s), rtol=1e-4)
    assert a_s.min(0).values.tolist() >= BOX_LOW.tolist()
    assert (a_s <= torch.tensor(BOX_HIGH, dtype=torch.float32)).all()


# --- update mechanics ---------------------------------------------------------------------------
def test_td3_steps_actor_and_targets_every_policy_delay_th_update() -> None:
    cfg = get_variant("TD3", {**SMALL, "policy_delay": 3, "buffer_size": 1000})
    agent = make_agent(cfg, D, seed=0)
    buf = _buffer_for(cfg)

    def snapshot() -> dict[str, list[torch.Tensor]]:
        nets = ("actor", "critic", "actor_target", "critic_target")
        return {n: [p.detach().clone() for p in getattr(agent, n).parameters()] for n in nets}

    moved = {n: [] for n in ("actor", "critic", "actor_target", "critic_target")}
    for _ in range(7):
        before = snapshot()
        info = agent.update(buf.sample(16))
        assert math.isfinite(info.actor_loss) and math.isfinite(info.critic_loss)
        after = snapshot()
        for n in moved:
            pairs = zip(before[n], after[n], strict=True)
            moved[n].append(any(not torch.equal(p, q) for p, q in pairs))
    assert moved["critic"] == [True] * 7
    for n in ("actor", "actor_target", "critic_target"):
        assert moved[n] == [False, False, True, False, False, True, False], n


def test_sac_temperature_moves_toward_the_target_entropy() -> None:
    """alpha falls while the policy's entropy is above the target and rises while below."""
    buf = _buffer_for(get_variant("SAC", SMALL))
    obs = torch.from_numpy(buf.sample(256).observations)
    for target_entropy, direction in ((-8.0, -1.0), (6.0, 1.0)):
        agent = make_agent(get_variant("SAC", {**SMALL, "target_entropy": target_entropy}), D,
                          seed=0)  # fmt: skip
        with torch.no_grad():
            entropy = -float(agent.actor.sample(obs, torch.Generator().manual_seed(0))[1].mean())
        assert np.sign(entropy - target_entropy) == -direction  # the initial policy's side
        alphas = [float(agent.alpha)]
        for _ in range(20):
            agent.update(buf.sample(16))
            alphas.append(float(agent.alpha))
        steps = np.diff(alphas)
        assert np.all(steps * direction > 0), alphas
        # Adam's first steps move log alpha by about its learning rate each
        assert math.log(alphas[-1] / alphas[0]) == pytest.approx(direction * 20 * 3e-4, rel=0.05)
    assert get_variant("SAC").entropy_target(3) == -3.0  # default: -action_dim


@pytest.mark.parametrize("name", ["TD3", "SAC"])
def test_per_weights_and_priorities_use_the_papers_rule_on_the_first_critic(name: str) -> None:
    cfg = get_variant(name, {**SMALL, "prioritized": True, "buffer_size": 1000,
                             "per_lambda3": 0.3, "per_eps": 1e-2})  # fmt: skip
    agent = make_agent(cfg, D, seed=1)
    buf = _buffer_for(cfg, alpha=cfg.per_alpha, lambda3=cfg.per_lambda3, eps=cfg.per_eps)
    agent.update(buf.sample(64), buf)  # priorities now differ, so importance weights do
    batch = buf.sample(16)
    assert not np.allclose(batch.weights, 1.0)
    before = copy.deepcopy(agent)  # same weights and the same noise stream
    info = agent.update(batch, buf)
    fields = ("observations", "rewards", "discounts", "next_observations", "next_action_windows")
    t = {k: torch.from_numpy(getattr(batch, k)) for k in fields}
    y = before.target(t["rewards"], t["discounts"], t["next_observations"],
                      t["next_action_windows"])  # fmt: skip
    a = torch.from_numpy(batch.actions).requires_grad_(True)
    q1 = before.critic.q1(t["observations"], a)
    (g,) = torch.autograd.grad(q1.sum(), a)
    p = (y - q1).detach().numpy() ** 2 + 0.3 * (g.numpy() ** 2).sum(1) + 1e-2
    np.testing.assert_allclose(agent.last_priorities, p, rtol=1e-4)
    # the reported critic loss is the mean of the twins' importance-weighted losses
    with torch.no_grad():
        q = before.critic(t["observations"], a)
    loss = (batch.weights * (y - q).numpy() ** 2).mean()
    assert info.critic_loss == pytest.approx(float(loss), rel=1e-5)


# --- acting and exploring -----------------------------------------------------------------------
def test_explore_samples_for_sac_and_is_act_for_ddpg_and_td3() -> None:
    window = np.random.default_rng(0).normal(size=(1, D)).astype(np.float32)
    for name in ("WIN1", "TD3"):
        agent = make_agent(get_variant(name, SMALL), D, seed=0)
        assert agent.cfg.uses_action_noise
        np.testing.assert_array_equal(agent.explore(window), agent.act(window))
    sac = make_agent(get_variant("SAC", SMALL), D, seed=0)
    assert not sac.cfg.uses_action_noise
    greedy = sac.act(window)
    assert np.array_equal(greedy, sac.act(window))  # act is deterministic
    with torch.no_grad():
        mean = sac.actor.distribution(torch.from_numpy(window)[None])[0][0].double().numpy()
    np.testing.assert_allclose(greedy, CENTRE + SCALE * np.tanh(mean), rtol=1e-6, atol=1e-7)
    # the untrained mean starts at the deterministic actor's pedals (throttle 0.73, brake 0.05)
    assert greedy[1] == pytest.approx(0.73, abs=0.02) and greedy[2] == pytest.approx(0.05, abs=0.01)
    samples = np.stack([sac.explore(window) for _ in range(500)])
    assert np.all(samples >= BOX_LOW) and np.all(samples <= BOX_HIGH)
    assert samples.std(0).min() > 0.05  # it explores in every dimension
    np.testing.assert_allclose(np.median(samples, 0), greedy, atol=0.1)  # tanh keeps the median


@pytest.mark.parametrize(("name", "updates"), [("TD3", 2500), ("SAC", 2000)])
def test_td3_and_sac_learn_a_contextual_bandit(name: str, updates: int) -> None:
    """test_agents.py's bandit for DDPG: one-step episodes, steer to +-0.5 by the sign of s_0
    (TD3 moves its actor every other update, so it gets more updates)."""
    overrides = {"hidden": (64, 64), "batch_size": 64, "actor_lr": 1e-3, "critic_lr": 3e-3}
    if name == "SAC":
        overrides["alpha_lr"] = 3e-3
    agent = make_agent(get_variant(name, overrides), 2, seed=0)
    buf = ReplayBuffer(5000, 2, 3, seed=0)
    rng = np.random.default_rng(0)
    for _ in range(2000):
        s = rng.uniform(-1, 1, 2).astype(np.float32)
        a = np.array([rng.uniform(-1, 1), rng.random(), rng.random()], np.float32)
        r = -((a[0] - 0.5 * np.sign(s[0])) ** 2)
        buf.add(s, a, r, s, terminated=True, truncated=False)
    for _ in range(updates):
        agent.update(buf.sample(64))
    test = np.array([[0.8, 0.0], [-0.8, 0.0], [0.3, 0.5], [-0.3, -0.5]], np.float32)
    steer = [agent.act(t[None])[0] for t in test]
    np.testing.assert_allclose(steer, [0.5, -0.5, 0.5, -0.5], atol=0.15)


# --- checkpoints and copies ---------------------------------------------------------------------
@pytest.mark.parametrize("name", ["TD3", "SAC"])
def test_checkpoint_round_trip_carries_networks_alpha_and_noise(name: str, tmp_path: Path) -> None:
    cfg = get_variant(name, {**SMALL, "buffer_size": 1000})
    agent = make_agent(cfg, D, seed=0)
    buf = _buffer_for(cfg)
    for _ in range(3):
        agent.update(buf.sample(16))
    path = save_checkpoint(agent, tmp_path / "a.pt", extra={"episode": 3})
    loaded, extra = load_checkpoint(path)
    assert extra == {"episode": 3} and loaded.cfg == cfg and loaded.updates == 3
    window = np.random.default_rng(0).normal(size=(1, D)).astype(np.float32)
    np.testing.assert_array_equal(agent.act(window), loaded.act(window))
    if name == "SAC":
        assert torch.equal(agent.alpha, loaded.alpha) and float(agent.alpha) != 1.0
    batch = buf.sample(16)  # the next update (noise included) is the same on both
    assert agent.update(batch) == loaded.update(batch)
    np.testing.assert_array_equal(agent.explore(window), loaded.explore(window))
    state = agent.state_dict()
    key = {"TD3": "generator", "SAC": "log_alpha"}[name]
    state.pop(key)
    torch.save(state, tmp_path / "nokey.pt")
    with pytest.raises(UserInputError, match=f"incomplete for {name.lower()}: no {key}"):
        load_checkpoint(tmp_path / "nokey.pt")


# --- configuration ------------------------------------------------------------------------------
NEW_FIELDS = {
    "algorithm": "ddpg", "policy_noise": 0.2, "noise_clip": 0.5, "policy_delay": 2,
    "alpha_init": 1.0, "alpha_lr": 3e-4, "target_entropy": None, "brake_explore_hold_steps": 1,
    "crash_penalty": 0.0, "epsilon_floor": 0.0, "eval_ema_updates": 0,
    "bn_momentum": 0.01, "crossq_adam_beta1": 0.5, "crossq_policy_delay": 3,
    "critic_layer_norm": False, "crash_penalty_decay_steps": 0, "preact_penalty": 0.0,
    "preact_bound": [6.0, 6.0], "obs_norm": False, "critic_bins": 0,
    "critic_value_range": [-100.0, 100.0], "critic_sigma_bins": 0.75,
    "critic_sigma_start_bins": 0.0, "critic_sigma_warmup_updates": 0, "critic_mse_weight": 0.0,
    "lr_decay_updates": 0, "lr_final_fraction": 0.1,
}  # fmt: skip
# AgentConfig().model_dump(mode="json") and each paper variant's changes from it, before
# TD3 and SAC existed
DEFAULTS_BEFORE = {
    "name": "WIN1", "family": "DDPG", "window": 1, "lstm_critic": False, "lstm_hidden": 64,
    "lstm_state_units": 128, "n_step": 1, "prioritized": False, "buffer_size": 1000000,
    "per_alpha": 0.6, "per_beta0": 0.4, "per_beta_steps": 200000, "per_lambda3": 1.0,
    "per_eps": 0.001, "gamma": 0.99, "reward_scale": 0.02, "tau": 0.005, "actor_lr": 0.0001,
    "critic_lr": 0.001, "batch_size": 256, "hidden": [400, 300], "learning_starts": 1000,
    "updates_per_step": 1.0, "adopted_target": True, "brake_bias_init": -3.0,
    "throttle_bias_init": 1.0, "exploration_steps": 100000, "noise_prob": 0.1,
    "ou_theta": [0.15, 0.15, 0.15], "ou_sigma": [0.3, 0.3, 0.1], "brake_explore_prob": 0.1,
    "brake_explore_mean": 0.5, "brake_explore_sigma": 0.2,
}  # fmt: skip
CHANGES_BEFORE = {
    "WIN1": {},
    "WIN4": {"name": "WIN4", "window": 4},
    "WIN8": {"name": "WIN8", "window": 8},
    "LSTM4": {"name": "LSTM4", "family": "LSTM", "window": 4, "lstm_critic": True},
    "LSTM8": {"name": "LSTM8", "family": "LSTM", "window": 8, "lstm_critic": True},
    "MS2": {"name": "MS2", "family": "MS", "n_step": 2},
    "MS3": {"name": "MS3", "family": "MS", "n_step": 3},
    "MS4": {"name": "MS4", "family": "MS", "n_step": 4},
    "PER40k": {"name": "PER40k", "family": "PER", "prioritized": True, "buffer_size": 40000},
    "PER1M": {"name": "PER1M", "family": "PER", "prioritized": True},
}


def test_the_papers_ten_configs_are_unchanged() -> None:
    assert list(VARIANTS) == list(CHANGES_BEFORE)
    for name, cfg in VARIANTS.items():
        dump = cfg.model_dump(mode="json")
        assert {k: dump.pop(k) for k in NEW_FIELDS} == NEW_FIELDS, name
        assert dump == {**DEFAULTS_BEFORE, **CHANGES_BEFORE[name]}, name
        assert not cfg.beyond_paper and cfg.uses_action_noise and not cfg.twin_critics


def test_td3_and_sac_are_registered_beyond_the_paper() -> None:
    assert list(BEYOND_PAPER_VARIANTS) == ["TD3", "SAC", "CrossQ"]
    assert list(ALL_VARIANTS) == [*VARIANTS, "TD3", "SAC", "CrossQ"]
    td3, sac = get_variant("TD3"), get_variant("SAC")
    assert (td3.family, td3.algorithm, sac.family, sac.algorithm) == ("TD3", "td3", "SAC", "sac")
    assert td3.beyond_paper and sac.beyond_paper and td3.twin_critics and sac.twin_critics
    assert (td3.policy_noise, td3.noise_clip, td3.policy_delay) == (0.2, 0.5, 2)
    lrs = (sac.actor_lr, sac.critic_lr, sac.alpha_lr)
    assert lrs == (3e-4, 3e-4, 3e-4) and (sac.batch_size, sac.tau) == (256, 0.005)
    assert sac.hidden == (256, 256) and not sac.uses_action_noise and td3.uses_action_noise
    assert td3.window == sac.window == 1 and not (td3.lstm_critic or sac.lstm_critic)
    assert get_variant("TD3", {"window": 4}).window == 4
    assert AgentConfig.model_fields["policy_delay"].description  # every new field is described
    assert all(AgentConfig.model_fields[k].description for k in NEW_FIELDS)


@pytest.mark.parametrize(
    ("name", "overrides", "message"),
    [
        ("TD3", {"lstm_critic": True}, "lstm_critic apply to algorithm ddpg only"),
        ("SAC", {"lstm_critic": True}, "lstm_critic apply to algorithm ddpg only"),
        ("WIN1", {"policy_delay": 3}, "policy_delay apply to algorithm td3 only"),
        ("SAC", {"policy_noise": 0.1}, "policy_noise apply to algorithm td3 only"),
        ("TD3", {"alpha_init": 0.5}, "alpha_init apply to algorithm sac only"),
        ("WIN4", {"algorithm": "td3"}, "may not change"),
        ("TD3", {"policy_delay": 0}, "policy_delay"),
    ],
)  # fmt: skip
def test_settings_an_algorithm_would_ignore_are_errors(name, overrides, message) -> None:
    with pytest.raises(UserInputError, match=message):
        get_variant(name, overrides)


def test_family_must_fit_the_algorithm() -> None:
    with pytest.raises(ValueError, match="family DDPG does not fit algorithm td3"):
        AgentConfig(algorithm="td3")
    with pytest.raises(ValueError, match="family SAC does not fit algorithm ddpg"):
        AgentConfig(family="SAC")


# --- tournaments: "all" stays the paper's ten, "all+beyond" adds TD3 and SAC ---------------------
SPEC = """\
name = "t1"

[variants.FAST4]
base = "WIN4"

[variants.SAC4]
base = "SAC"
overrides = {{ window = 4 }}

[[parts]]
name = "p1"
entrants = {entrants}
train_tracks = ["oval"]
"""


@pytest.mark.parametrize(
    ("entrants", "expected"),
    [
        ('"all"', ["FAST4", "SAC4", *VARIANTS]),
        ('"all+beyond"', ["FAST4", "SAC4", *VARIANTS, "TD3", "SAC", "CrossQ"]),
        ('["TD3", "SAC4"]', ["TD3", "SAC4"]),
    ],
)
def test_all_is_the_papers_ten_and_all_plus_beyond_adds_td3_and_sac(
    tmp_path: Path, entrants: str, expected: list[str]
) -> None:
    path = tmp_path / "t.toml"
    path.write_text(SPEC.format(entrants=entrants), encoding="utf-8")
    spec, _ = load_spec(path)
    assert part_variants(spec, spec.parts[0]) == expected
    assert default_family("TD3") == "TD3" and default_family("SAC") == "SAC"


def test_unknown_entrant_lists_all_plus_beyond(tmp_path: Path) -> None:
    path = tmp_path / "t.toml"
    path.write_text(SPEC.format(entrants='["TD4"]'), encoding="utf-8")
    with pytest.raises(UserInputError, match=r"unknown variant 'TD4'.*TD3, SAC.*all\+beyond"):
        load_spec(path)

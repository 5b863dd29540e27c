"""DDPG agent: the adopted target, PER priorities, exploration rule, determinism, learning."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from formula_tourney.agents.buffers import ReplayBuffer, make_buffer
from formula_tourney.agents.checkpoints import load_checkpoint, save_checkpoint
from formula_tourney.agents.core import Agent
from formula_tourney.agents.families import make_agent
from formula_tourney.agents.noise import BrakeExplorationNoise, linear_epsilon
from formula_tourney.agents.variants import VARIANTS, get_variant
from formula_tourney.errors import UserInputError

torch.set_num_threads(1)
D = 6
SMALL = {"hidden": (32, 24), "batch_size": 16, "lstm_state_units": 16, "lstm_hidden": 8}


def _small(name: str) -> dict:
    """SMALL for variant ``name``: the LSTM critic's sizes are the DDPG family's settings only."""
    if get_variant(name).algorithm == "ddpg":
        return SMALL
    return {k: v for k, v in SMALL.items() if not k.startswith("lstm_")}


def _buffer_for(cfg, n: int = 200, seed: int = 0, **kw) -> ReplayBuffer:
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


def test_registry_has_the_papers_ten_variants() -> None:
    assert list(VARIANTS) == [
        "WIN1", "WIN4", "WIN8", "LSTM4", "LSTM8", "MS2", "MS3", "MS4", "PER40k", "PER1M",
    ]  # fmt: skip
    assert {v.family for v in VARIANTS.values()} == {"DDPG", "LSTM", "MS", "PER"}
    assert get_variant("PER40k").buffer_size == 40_000 and get_variant("MS3").n_step == 3
    assert get_variant("LSTM8").lstm_critic and get_variant("LSTM8").window == 8
    with pytest.raises(UserInputError, match="known: WIN1"):
        get_variant("WIN2")
    with pytest.raises(UserInputError, match="gamma"):
        get_variant("WIN1", {"gamma": 2.0})
    with pytest.raises(UserInputError, match="bogus"):
        get_variant("WIN1", {"bogus": 1})


def test_adopted_target_bootstraps_on_truncation_not_termination() -> None:
    cfg = get_variant("WIN1", SMALL)
    agent = make_agent(cfg, D, seed=0)
    buf = ReplayBuffer(10, D, 3, gamma=0.9)
    s = [np.full(D, v, np.float32) for v in (0.1, 0.2, 0.3, 0.4)]
    buf.add(s[0], np.zeros(3), 1.0, s[1], terminated=True, truncated=False)
    buf.add(s[2], np.zeros(3), 2.0, s[3], terminated=False, truncated=True)
    b = buf.gather(np.array([0, 1]), np.ones(2))
    t = {k: torch.from_numpy(v) for k, v in b._asdict().items() if v is not None}
    y = agent.target(t["rewards"], t["discounts"], t["next_observations"], t["next_action_windows"])
    with torch.no_grad():
        s3 = torch.from_numpy(s[3])[None, None]
        q_boot = agent.critic_target(s3, agent.actor_target(s3)).item()
    assert q_boot != 0.0
    assert y[0].item() == pytest.approx(1.0, abs=1e-7)  # y = r on a premature end
    assert y[1].item() == pytest.approx(2.0 + 0.9 * q_boot, rel=1e-6)  # full target at max-steps


def test_per_update_writes_the_papers_priority() -> None:
    cfg = get_variant("PER40k", {**SMALL, "per_lambda3": 0.3, "per_eps": 1e-2, "per_alpha": 0.5})
    agent = make_agent(cfg, D, seed=1)
    buf = _buffer_for(cfg, alpha=cfg.per_alpha, lambda3=cfg.per_lambda3, eps=cfg.per_eps)
    batch = buf.sample(16)
    before = copy.deepcopy(agent)
    agent.update(batch, buf)
    # recompute delta and grad_a Q(s_i, a_i) with the critic as it was before the step
    obs = torch.from_numpy(batch.observations)
    a = torch.from_numpy(batch.actions).requires_grad_(True)
    y = before.target(
        torch.from_numpy(batch.rewards), torch.from_numpy(batch.discounts),
        torch.from_numpy(batch.next_observations), torch.from_numpy(batch.next_action_windows),
    )  # fmt: skip
    q = before.critic(obs, a)
    (g,) = torch.autograd.grad(q.sum(), a)
    delta = (y - q).detach().numpy()
    p = delta**2 + 0.3 * (g.numpy() ** 2).sum(1) + 1e-2
    np.testing.assert_allclose(agent.last_priorities, p, rtol=1e-4)
    last_write = {i: k for k, i in enumerate(batch.indices)}  # duplicates: last write wins
    idx = np.array(list(last_write))
    np.testing.assert_allclose(buf.tree.values(idx), p[list(last_write.values())] ** 0.5, rtol=1e-4)


def test_brake_exploration_never_presses_both_pedals_beyond_the_rule() -> None:
    rng = np.random.default_rng(0)
    noise = BrakeExplorationNoise(np.random.default_rng(1), noise_prob=0.1, brake_prob=0.2)
    fired = 0
    n = 4000
    for _ in range(n):
        a = np.array([rng.uniform(-1, 1), rng.uniform(0, 1), rng.uniform(0, 0.2)], np.float32)
        eps = float(rng.uniform(0.05, 1.0))
        out, ev = noise(a, eps)
        assert np.all(out >= [-1, 0, 0]) and np.all(out <= 1)
        if ev.brake_explored:
            fired += 1
            # throttle only goes down, by exactly the factor (1 - epsilon), and gets no noise
            assert out[1] == pytest.approx(a[1] * (1 - eps), abs=1e-6)
            assert not ev.mask[1]
        elif not ev.mask[1]:
            assert out[1] == pytest.approx(a[1], abs=1e-7)
    # the rule fires with its probability (binomial, 5 sigma)
    assert abs(fired - 0.2 * n) < 5 * np.sqrt(n * 0.2 * 0.8)
    # at epsilon = 0 the action is untouched; at epsilon = 1 brake exploration releases throttle
    a = np.array([0.3, 0.9, 0.0], np.float32)
    assert np.array_equal(noise(a, 0.0)[0], a)
    full = BrakeExplorationNoise(np.random.default_rng(2), brake_prob=1.0)
    out, ev = full(a, 1.0)
    assert ev.brake_explored and out[1] == 0.0


def test_epsilon_anneals_linearly_to_zero() -> None:
    assert [linear_epsilon(s, 100) for s in (0, 25, 100, 500)] == [1.0, 0.75, 0.0, 0.0]


def test_epsilon_floor_clips_the_papers_line_from_below() -> None:
    """Above the floor epsilon is the paper's line; from where the line meets it, the floor."""
    steps = (0, 25, 70, 80, 100, 500)
    assert [linear_epsilon(s, 100, 0.25) for s in steps] == pytest.approx(
        [1.0, 0.75, 0.3, 0.25, 0.25, 0.25], abs=1e-12)


@pytest.mark.parametrize(
    ("name", "extra"),
    [("WIN4", {}), ("LSTM4", {}), ("MS3", {}), ("PER1M", {}),
     ("TD3", {"window": 4, "n_step": 3}), ("SAC", {"window": 4, "n_step": 3})],
)  # fmt: skip
def test_same_seed_same_weights_after_updates(name: str, extra: dict) -> None:
    """Every family, windows and n-step included for TD3 and SAC: same seed, same weights."""
    cfg = get_variant(name, {**_small(name), "buffer_size": 1000, **extra})

    def run(seed: int) -> Agent:
        agent = make_agent(cfg, D, seed=seed)
        buf = _buffer_for(cfg, seed=seed)
        for _ in range(10):
            agent.update(buf.sample(cfg.batch_size), buf)
        return agent

    a, b, c = run(7), run(7), run(8)
    for key in ("actor", "critic", "critic_target"):
        sa, sb, sc = (getattr(x, key).state_dict() for x in (a, b, c))
        assert all(torch.equal(sa[k], sb[k]) for k in sa)
        assert not all(torch.equal(sa[k], sc[k]) for k in sa)
    window = np.random.default_rng(0).normal(size=(cfg.window, D)).astype(np.float32)
    assert a.act(window).shape == (3,) and np.array_equal(a.act(window), b.act(window))


def test_actor_ranges_and_lstm_critic_reads_past_actions() -> None:
    cfg = get_variant("LSTM4", SMALL)
    agent = make_agent(cfg, D, seed=0)
    obs = torch.randn(64, 4, D) * 10
    act = agent.actor(obs)
    assert act.shape == (64, 3)
    assert act[:, 0].abs().max() <= 1 and act[:, 1:].min() >= 0 and act[:, 1:].max() <= 1
    past = torch.rand(64, 3, 3)
    q1 = agent.critic(obs, act, past)
    q2 = agent.critic(obs, act, torch.rand(64, 3, 3))
    assert not torch.allclose(q1, q2)
    # untrained actor leaves the brake nearly released (sigmoid(-3) ~ 0.05)
    assert float(act[:, 2].mean().detach()) < 0.15


def test_checkpoint_round_trip_weights_only(tmp_path) -> None:
    cfg = get_variant("WIN4", SMALL)
    agent = make_agent(cfg, D, seed=0)
    path = save_checkpoint(agent, tmp_path / "a.pt", extra={"episode": 3})
    loaded, extra = load_checkpoint(path)
    assert extra == {"episode": 3} and loaded.cfg == cfg
    x = np.random.default_rng(0).normal(size=(4, D)).astype(np.float32)
    np.testing.assert_array_equal(agent.act(x), loaded.act(x))
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(UserInputError, match="bad.pt"):
        load_checkpoint(tmp_path / "bad.pt")


def _tampered(tmp_path, name: str, change) -> object:
    state = make_agent(get_variant("WIN1", SMALL), D, seed=0).state_dict()
    change(state)
    torch.save(state, tmp_path / name)
    return tmp_path / name


@pytest.mark.parametrize(
    ("name", "change", "message"),
    [
        ("shapes.pt", lambda s: s.update(config=get_variant("WIN4", SMALL).model_dump(mode="json")),
         "do not fit its config WIN4"),
        ("nokey.pt", lambda s: s.pop("critic"), "incomplete: no critic"),
        ("badcfg.pt", lambda s: s["config"].update(batch_size="many"), "bad agent config"),
        ("unknown.pt", lambda s: s["config"].update(colour="red"), "bad agent config"),
        ("dims.pt", lambda s: s.update(obs_dim=0), "bad sizes"),
    ],
)  # fmt: skip
def test_bad_checkpoints_give_one_line_errors(tmp_path, name, change, message) -> None:
    """Another variant's shapes, a missing key or a bad config once gave tracebacks from eval and
    replay: each is one line naming the checkpoint."""
    with pytest.raises(UserInputError, match=message) as err:
        load_checkpoint(_tampered(tmp_path, name, change))
    assert name in str(err.value) and "\n" not in str(err.value)


def test_ddpg_learns_a_contextual_bandit() -> None:
    """One-step episodes (y = r): the actor must steer to +-0.5 by the sign of s_0."""
    cfg = get_variant(
        "WIN1", {"hidden": (64, 64), "batch_size": 64, "actor_lr": 1e-3, "critic_lr": 3e-3}
    )
    agent = make_agent(cfg, 2, seed=0)
    buf = ReplayBuffer(5000, 2, 3, seed=0)
    rng = np.random.default_rng(0)
    for _ in range(2000):
        s = rng.uniform(-1, 1, 2).astype(np.float32)
        a = np.array([rng.uniform(-1, 1), rng.random(), rng.random()], np.float32)
        r = -((a[0] - 0.5 * np.sign(s[0])) ** 2)
        buf.add(s, a, r, s, terminated=True, truncated=False)
    for _ in range(1500):
        agent.update(buf.sample(64))
    test = np.array([[0.8, 0.0], [-0.8, 0.0], [0.3, 0.5], [-0.3, -0.5]], np.float32)
    steer = [agent.act(t[None])[0] for t in test]
    np.testing.assert_allclose(steer, [0.5, -0.5, 0.5, -0.5], atol=0.15)


def _saturated_steer_after(updates: int, **extra: float) -> float:
    """The greedy steer of an actor whose steer pre-activation starts at +30 (full lock, where
    tanh's gradient is 0 in float32), after ``updates`` on one-step episodes that pay
    -steer^2: the critic soon says "steer less", and only a gradient at z can act on it."""
    cfg = get_variant("WIN1", {"hidden": (64, 64), "batch_size": 64, "actor_lr": 1e-3,
                               "critic_lr": 3e-3, **extra})  # fmt: skip
    agent = make_agent(cfg, 2, seed=0)
    with torch.no_grad():
        agent.actor.out.bias[0] += 30.0
    buf = ReplayBuffer(5000, 2, 3, seed=0)
    rng = np.random.default_rng(0)
    for _ in range(2000):
        s = rng.uniform(-1, 1, 2).astype(np.float32)
        a = np.array([rng.uniform(-1, 1), rng.random(), rng.random()], np.float32)
        buf.add(s, a, -float(a[0]) ** 2, s, terminated=True, truncated=False)
    for _ in range(updates):
        agent.update(buf.sample(64))
    return float(agent.act(np.array([[0.3, -0.2]], np.float32))[0])


def test_saturation_term_frees_an_actor_stuck_at_full_lock() -> None:
    """The paper's loss leaves a saturated steer at full lock; the saturation term pulls its
    pre-activation back inside the bound, where the critic's gradient steers it to 0."""
    assert _saturated_steer_after(2000) == 1.0
    assert abs(_saturated_steer_after(2000, preact_penalty=1.0)) < 0.25


@pytest.mark.parametrize("extra", [{}, {"eval_ema_updates": 50}])
def test_eval_preactivation_is_what_the_tested_actor_squashes(extra: dict) -> None:
    """The pre-activations a benchmark reads are the driven actor's: squashed, they give
    act_eval's action, also when the tests drive an average that has moved off the online
    actor."""
    cfg = get_variant("WIN1", {**SMALL, "buffer_size": 1000, **extra})
    agent = make_agent(cfg, D, seed=2)
    buf = _buffer_for(cfg, seed=2)
    for _ in range(20):
        agent.update(buf.sample(16), buf)
    window = np.random.default_rng(0).standard_normal((1, D)).astype(np.float32)
    z = agent.eval_preactivation(window)
    squashed = agent._eval_actor.squash(torch.as_tensor(z)[None])[0].numpy()
    np.testing.assert_allclose(squashed, agent.act_eval(window), rtol=1e-5, atol=1e-6)
    with torch.no_grad():
        online = agent.actor.preactivation(torch.as_tensor(window)[None])[0].numpy()
    if extra:  # the average lags the online actor: a read of the online one would differ
        assert np.abs(online - z).max() > 1e-4
    else:
        np.testing.assert_allclose(online, z, rtol=1e-6)


def test_eval_q_reads_the_critic_through_the_observation_statistics() -> None:
    """The Q a benchmark reads along a drive is the update's: the window goes through the
    running statistics (``obs_norm``) first, so a read of the raw window would differ."""
    cfg = get_variant("WIN1", {**SMALL, "buffer_size": 1000, "obs_norm": True})
    agent = make_agent(cfg, D, seed=2)
    rng = np.random.default_rng(0)
    agent.count_observations((3.0 + 5.0 * rng.standard_normal((200, D))).astype(np.float32))
    window = rng.standard_normal((1, D)).astype(np.float32)
    action = agent.act_eval(window)
    x, a = torch.as_tensor(window)[None], torch.as_tensor(action)[None]
    with torch.no_grad():
        seen, raw = float(agent.critic(agent.normalise(x), a)[0]), float(agent.critic(x, a)[0])
    assert agent.eval_q(window, action) == pytest.approx(seen, rel=1e-6)
    assert abs(raw - seen) > 1e-4
    with pytest.raises(TypeError, match="not a LSTMCritic"):
        make_agent(get_variant("LSTM4", _small("LSTM4")), D, seed=2).eval_q(
            np.zeros((4, D), np.float32), np.zeros(3, np.float32))


@pytest.mark.parametrize("name", ["WIN4", "LSTM4"])
def test_q_pair_equals_two_critic_evaluations(name: str) -> None:
    """The shared-state-path evaluation gives exactly Q(s, a) and Q(s, mu(s))."""
    agent = make_agent(get_variant(name, _small(name)), D, seed=3)
    obs = torch.randn(32, 4, D)
    a, past = torch.rand(32, 3), torch.rand(32, 3, 3)
    with torch.no_grad():
        pi = agent.actor(obs)
        q, q_pi = agent.critic.q_pair(obs, a, pi, past)
        torch.testing.assert_close(q, agent.critic(obs, a, past))
        torch.testing.assert_close(q_pi, agent.critic(obs, pi, past))


@pytest.mark.parametrize(
    ("name", "extra"),
    [("WIN1", {}), ("WIN4", {}), ("MS3", {}), ("PER40k", {}),
     # a bound this small puts most pre-activations of a fresh actor beyond it
     ("WIN1", {"preact_penalty": 0.5, "preact_bound": (0.02, 0.05)}),
     # a classification critic whose span the targets cross, with PER's grad_a too
     ("WIN1", {"critic_bins": 11, "critic_value_range": (-0.5, 0.5)}),
     ("PER40k", {"critic_bins": 7, "critic_value_range": (-1.0, 2.0)}),
     # a wider target (critic_sigma_bins) reaches the same loss through both updates
     ("WIN1", {"critic_bins": 11, "critic_value_range": (-0.5, 0.5), "critic_sigma_bins": 2.5}),
     # the squared error of Q beside the cross-entropy (critic_mse_weight), with PER's grad_a
     ("WIN1", {"critic_bins": 11, "critic_value_range": (-0.5, 0.5), "critic_mse_weight": 2.0}),
     ("PER40k", {"critic_bins": 7, "critic_value_range": (-1.0, 2.0), "critic_mse_weight": 0.5}),
     # both at once, the term on the steer alone (the shape of `best`'s DDPG family): a fresh
     # actor's steer z lies beyond 0.001 in ~4 of 5 rows, its pedals' (~3) within 50
     ("WIN1", {"critic_bins": 11, "critic_value_range": (-0.5, 0.5), "preact_penalty": 0.5,
               "preact_bound": (0.001, 50.0)})],
)  # fmt: skip
def test_hand_written_update_matches_autograd(name: str, extra: dict) -> None:
    """The MLP critic's autograd-free update gives the autograd update's weights and priorities
    (also across a change of batch size, which reallocates its buffers), with the saturation
    term and a classification critic too."""
    cfg = get_variant(name, {**_small(name), "buffer_size": 1000, **extra})
    manual, reference = make_agent(cfg, D, seed=4), make_agent(cfg, D, seed=4)
    assert manual._mlp_update is not None
    kw = {"alpha": cfg.per_alpha, "lambda3": cfg.per_lambda3} if cfg.prioritized else {}
    buf_m, buf_r = _buffer_for(cfg, seed=5, **kw), _buffer_for(cfg, seed=5, **kw)
    for batch_size in (16, 16, 8, 16, 16):
        info_m = manual.update(buf_m.sample(batch_size), buf_m)
        info_r = reference._update_autograd(buf_r.sample(batch_size), buf_r)
        np.testing.assert_allclose(info_m, info_r, rtol=1e-4, atol=1e-6)
        if cfg.prioritized:
            np.testing.assert_allclose(manual.last_priorities, reference.last_priorities, rtol=1e-4)
    fresh = make_agent(cfg, D, seed=4)
    for key in ("actor", "critic", "actor_target", "critic_target"):
        sm, sr = getattr(manual, key).state_dict(), getattr(reference, key).state_dict()
        s0 = getattr(fresh, key).state_dict()
        weights = dict(getattr(manual, key).named_parameters())
        for k in sm:
            assert torch.allclose(sm[k], sr[k], atol=1e-5, rtol=1e-4), f"{key}.{k}"
            if k in weights:  # a real comparison (bin edges are buffers, fixed)
                assert not torch.equal(sm[k], s0[k]), f"{key}.{k} never moved"
    for opt in ("actor_opt", "critic_opt"):
        om, orf = getattr(manual, opt).state_dict(), getattr(reference, opt).state_dict()
        pairs = zip(
            om["exp_avg"] + om["exp_avg_sq"], orf["exp_avg"] + orf["exp_avg_sq"], strict=True
        )
        for a, b in pairs:
            assert torch.allclose(a, b, atol=1e-6, rtol=1e-3)


@pytest.mark.parametrize("name", ["WIN4", "LSTM4"])
def test_act_equals_the_actor_module(name: str) -> None:
    agent = make_agent(get_variant(name, _small(name)), D, seed=2)
    window = np.random.default_rng(0).normal(size=(4, D)).astype(np.float32)
    with torch.no_grad():
        expected = agent.actor(torch.from_numpy(window)[None])[0].numpy()
    np.testing.assert_allclose(agent.act(window), expected, rtol=1e-6, atol=1e-7)


def test_device_is_chosen_at_run_time() -> None:
    from formula_tourney.agents.core import resolve_device

    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    if not torch.cuda.is_available():
        with pytest.raises(UserInputError, match="cuda"):
            resolve_device("cuda")


@pytest.mark.parametrize("name", ["WIN1", "LSTM4", "TD3", "SAC"])
def test_deepcopy_is_an_independent_agent_that_keeps_learning(name: str) -> None:
    """The copy keeps learning on its own networks (SAC has no target actor: the critic's
    target is the one checked, for every family)."""
    cfg = get_variant(name, _small(name))
    agent = make_agent(cfg, D, seed=3)
    buf = _buffer_for(cfg)
    batch = buf.sample(16)
    agent.update(batch, buf)
    rng_before = torch.get_rng_state()
    clone = copy.deepcopy(agent)
    assert torch.equal(torch.get_rng_state(), rng_before)  # copying drew no random numbers
    # the same next update on both gives the same weights, targets included (the clone's
    # soft update and Adam step reach its networks), and the original is left untouched
    before = [p.detach().clone() for p in agent.critic_target.parameters()]
    clone.update(batch, buf)
    for p, q in zip(agent.critic_target.parameters(), before, strict=True):
        assert torch.equal(p, q)
    agent.update(batch, buf)
    nets = [n for n in ("actor", "critic", "actor_target", "critic_target")
            if getattr(agent, n) is not None]  # fmt: skip
    for net in nets:
        for p, q in zip(getattr(agent, net).parameters(), getattr(clone, net).parameters(),
                        strict=True):  # fmt: skip
            torch.testing.assert_close(p, q)
    assert any(not torch.equal(p, q) for p, q in
               zip(clone.critic_target.parameters(), before, strict=True))  # fmt: skip


def test_held_brake_exploration_brakes_for_a_hairpins_length() -> None:
    """Beyond the paper: brake_explore_hold_steps > 1 holds a fired brake exploration (with one
    drawn pressure) for up to that many steps; 1 is the paper's rule, stream for stream."""
    actor = np.array([0.0, 0.9, 0.05])

    def run(**kw: int) -> tuple[np.ndarray, np.ndarray]:
        noise = BrakeExplorationNoise(np.random.default_rng(4), **kw)
        out = [noise(actor, 1.0) for _ in range(3000)]
        return np.array([o[0] for o in out]), np.array([o[1].brake_explored for o in out])

    paper, paper_events = run()
    same, _ = run(brake_hold_steps=1)
    np.testing.assert_array_equal(paper, same)
    held, events = run(brake_hold_steps=15)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], events.astype(int), [0]])))
    lengths = edges[1::2] - edges[::2]
    paper_edges = np.flatnonzero(np.diff(np.concatenate([[0], paper_events.astype(int), [0]])))
    assert (paper_edges[1::2] - paper_edges[::2]).max() <= 4  # independent 0.1 draws
    assert lengths.max() >= 13
    start, stop = edges[0], edges[1]
    assert np.ptp(held[start:stop, 2]) < 1e-6 and np.all(held[start:stop, 1] == 0.0)


@pytest.mark.parametrize("name", ["WIN1", "TD3"])  # the hand-written update and autograd's
def test_learning_rates_decay_linearly_to_their_final_fraction(name: str) -> None:
    """``lr_decay_updates`` 4 to ``lr_final_fraction`` 0.25: the Adam steps of updates 1-6 run
    at 1, 0.8125, 0.625, 0.4375, 0.25, 0.25 x the set rates; the first update is the
    undecayed one's to the bit, the second is not."""
    over = {**_small(name), "buffer_size": 1000}
    cfg = get_variant(name, {**over, "lr_decay_updates": 4, "lr_final_fraction": 0.25})
    plain_cfg = get_variant(name, over)
    agent, plain = make_agent(cfg, D, seed=4), make_agent(plain_cfg, D, seed=4)
    buf, plain_buf = _buffer_for(cfg, seed=5), _buffer_for(plain_cfg, seed=5)
    factors = []
    for k in range(6):
        agent.update(buf.sample(16))
        plain.update(plain_buf.sample(16))
        factors.append((agent.actor_opt.lr / cfg.actor_lr, agent.critic_opt.lr / cfg.critic_lr))
        same = torch.equal(agent._online_flat, plain._online_flat)
        assert same == (k == 0), k
    np.testing.assert_allclose(factors, [[f, f] for f in (1, 0.8125, 0.625, 0.4375, 0.25, 0.25)])
    assert plain.actor_opt.lr == plain_cfg.actor_lr and plain.lr_factor() == 1.0

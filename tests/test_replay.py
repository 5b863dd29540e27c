"""Replay buffers: n-step sums, the adopted target's discounts, windows, prioritized sampling."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from formula_tourney.agents.buffers import (
    ObservationWindow,
    PrioritizedReplayBuffer,
    ReplayBuffer,
    SumTree,
    make_buffer,
)

D = 2


def _obs(v: float) -> np.ndarray:
    return np.array([v, -v], np.float32)


def _fill(buf: ReplayBuffer, episodes: list[tuple[list[float], list[float], str]]) -> None:
    """Each episode: observation values o_0..o_T, rewards r_0..r_{T-1}, end kind."""
    for obs_values, rewards, end in episodes:
        for t, r in enumerate(rewards):
            last = t == len(rewards) - 1
            buf.add(
                _obs(obs_values[t]),
                np.array([0.1 * t, 0.5, 0.0]),
                r,
                _obs(obs_values[t + 1]),
                terminated=last and end == "terminated",
                truncated=last and end == "truncated",
            )


def test_n_step_target_matches_hand_computed_sum() -> None:
    g = 0.9
    buf = ReplayBuffer(100, D, 3, gamma=g, n_step=3)
    # episode A terminates after 5 steps, episode B is truncated after 4
    _fill(
        buf,
        [
            ([0, 1, 2, 3, 4, 5], [1, 2, 3, 4, 5], "terminated"),
            ([10, 11, 12, 13, 14], [10, 20, 30, 40], "truncated"),
        ],
    )
    b = buf.gather(np.arange(9), np.ones(9))
    expected_r = [
        1 + g * 2 + g * g * 3,  # 5.23, bootstraps from o_3
        2 + g * 3 + g * g * 4,
        3 + g * 4 + g * g * 5,
        4 + g * 5,  # stops at the termination: m = 2
        5.0,
        10 + g * 20 + g * g * 30,
        20 + g * 30 + g * g * 40,
        30 + g * 40,  # stops at the truncation, never crosses into another episode
        40.0,
    ]
    np.testing.assert_allclose(b.rewards, expected_r, rtol=1e-6)
    np.testing.assert_array_equal(b.n_steps, [3, 3, 3, 2, 1, 3, 3, 2, 1])
    # terminal ends: y = r (discount 0); truncated ends bootstrap with gamma^m (adopted target)
    np.testing.assert_allclose(b.discounts, [g**3, g**3, 0, 0, 0, g**3, g**3, g**2, g], rtol=1e-6)
    # bootstrap state s_{t+m}
    np.testing.assert_allclose(b.next_observations[:, 0, 0], [3, 4, 5, 5, 5, 13, 14, 14, 14])


def test_adopted_target_switch_off_cuts_bootstrap_on_truncation() -> None:
    for flag, expected in ((True, 0.99), (False, 0.0)):
        buf = ReplayBuffer(10, D, 3, gamma=0.99, bootstrap_on_truncation=flag)
        _fill(buf, [([0, 1, 2], [1, 1], "truncated"), ([5, 6], [7], "terminated")])
        b = buf.gather(np.array([0, 1, 2]), np.ones(3))
        np.testing.assert_allclose(b.discounts, [0.99, expected, 0.0], rtol=1e-6)


def test_n_step_stops_at_newest_step_of_running_episode() -> None:
    buf = ReplayBuffer(10, D, 3, gamma=0.5, n_step=4)
    _fill(buf, [([0, 1, 2], [1, 1], "running")])
    b = buf.gather(np.array([0, 1]), np.ones(2))
    np.testing.assert_allclose(b.rewards, [1.5, 1.0])
    np.testing.assert_allclose(b.discounts, [0.25, 0.5])
    np.testing.assert_allclose(b.next_observations[:, 0, 0], [2, 2])


def test_windows_pad_at_episode_start_and_never_mix_episodes() -> None:
    buf = ReplayBuffer(100, D, 3, window=4)
    _fill(
        buf,
        [([10, 11, 12, 13], [0, 0, 0], "terminated"), ([20, 21, 22, 23, 24], [0] * 4, "truncated")],
    )
    b = buf.gather(np.array([0, 2, 3, 4, 6]), np.ones(5))
    np.testing.assert_array_equal(
        b.observations[:, :, 0],
        [[10, 10, 10, 10], [10, 10, 11, 12], [20, 20, 20, 20], [20, 20, 20, 21], [20, 21, 22, 23]],
    )
    np.testing.assert_array_equal(
        b.next_observations[:, :, 0],
        [[10, 10, 10, 11], [10, 11, 12, 13], [20, 20, 20, 21], [20, 20, 21, 22], [21, 22, 23, 24]],
    )
    # actions pad the same way (first step repeated); past actions of the bootstrap window
    np.testing.assert_allclose(b.action_windows[1, :, 0], [0.0, 0.0, 0.1, 0.2], atol=1e-7)
    np.testing.assert_allclose(b.next_action_windows[4, :, 0], [0.1, 0.2, 0.3], atol=1e-7)
    # the acting-time window builds the same padded stack
    win = ObservationWindow(4)
    win.reset(_obs(20))
    np.testing.assert_array_equal(win.push(_obs(21))[:, 0], [20, 20, 20, 21])


def test_windows_pad_with_earliest_surviving_step_after_wraparound() -> None:
    buf = ReplayBuffer(5, D, 3, window=3)
    _fill(buf, [([0, 1, 2, 3, 4, 5, 6, 7], [0] * 7, "truncated")])  # slots 0,1 overwritten
    # slot 2 holds step 2 (o=2), whose predecessors were overwritten by steps 5, 6
    b = buf.gather(np.array([2, 3]), np.ones(2))
    np.testing.assert_array_equal(b.observations[:, :, 0], [[2, 2, 2], [2, 2, 3]])


def test_sum_tree_totals_and_search() -> None:
    tree = SumTree(5)
    tree.update(np.arange(5), np.array([1.0, 0.0, 2.0, 3.0, 4.0]))
    assert tree.total == pytest.approx(10.0)
    np.testing.assert_array_equal(
        tree.find(np.array([0.0, 0.99, 1.0, 2.99, 3.0, 9.999])), [0, 0, 2, 2, 3, 4]
    )
    tree.update(np.array([4, 4]), np.array([1.0, 1.0]))  # duplicate indices: same value
    assert tree.total == pytest.approx(7.0)


def test_per_samples_in_proportion_to_p_alpha() -> None:
    n, alpha = 20, 0.7
    buf = PrioritizedReplayBuffer(32, D, 3, alpha=alpha, beta=0.5, lambda3=0.5, eps=1e-3, seed=3)
    _fill(buf, [(list(range(n + 1)), [0.0] * n, "truncated")])
    rng = np.random.default_rng(0)
    td = rng.uniform(0.0, 3.0, n)
    grads = rng.normal(size=(n, 3))
    p = buf.update_priorities(np.arange(n), td, grads)
    # the paper's priority, stored as p^alpha
    np.testing.assert_allclose(p, td**2 + 0.5 * (grads**2).sum(1) + 1e-3)
    np.testing.assert_allclose(buf.tree.values(np.arange(n)), p**alpha)
    counts = np.zeros(n)
    for _ in range(200):
        b = buf.sample(256)
        counts += np.bincount(b.indices, minlength=n)
    expected = p**alpha / (p**alpha).sum() * counts.sum()
    assert stats.chisquare(counts, expected).pvalue > 1e-3
    # the test has power: uniform sampling would be rejected outright
    assert stats.chisquare(counts, np.full(n, counts.sum() / n)).pvalue < 1e-12
    # importance weights (N P(i))^-beta normalised by the batch maximum
    b = buf.sample(64)
    w = (n * buf.probabilities(b.indices)) ** -0.5
    np.testing.assert_allclose(b.weights, w / w.max(), rtol=1e-5)


def test_per_new_transitions_get_max_priority() -> None:
    buf = PrioritizedReplayBuffer(16, D, 3, alpha=1.0, seed=0)
    _fill(buf, [([0, 1, 2], [0, 0], "truncated")])
    buf.update_priorities(np.array([0]), np.array([3.0]), np.zeros((1, 3)))
    _fill(buf, [([5, 6], [0], "terminated")])
    assert buf.tree.values(np.array([2]))[0] == pytest.approx(9.0 + buf.eps)


def test_laned_buffer_samples_only_stored_slots_and_per_gives_new_rows_max_priority() -> None:
    buf = make_buffer(40, 2, 3, prioritized=False, gamma=0.99, n_step=1, window=1,
                      bootstrap_on_truncation=True, seed=0, lanes=4)  # fmt: skip
    lanes = np.array([0, 2])  # lanes 1 and 3 stay empty
    for k in range(3):
        buf.add_cars(lanes, np.full((2, 2), k), np.zeros((2, 3)), np.ones(2), np.zeros((2, 2)),
                     np.zeros(2, bool), np.zeros(2, bool))  # fmt: skip
    assert len(buf) == 6
    assert set(buf.sample(500).indices.tolist()) == {0, 1, 2, 20, 21, 22}
    per = PrioritizedReplayBuffer(40, 2, 3, lanes=4, alpha=1.0, seed=0)
    per.add_cars(np.array([1, 3]), np.zeros((2, 2)), np.zeros((2, 3)), np.ones(2),
                 np.zeros((2, 2)), np.zeros(2, bool), np.zeros(2, bool))  # fmt: skip
    np.testing.assert_array_equal(per.tree.values(np.array([10, 30, 0])), [1.0, 1.0, 0.0])
    assert set(per.sample(64).indices.tolist()) == {10, 30}

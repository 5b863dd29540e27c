"""Replay buffers: uniform and prioritized, with n-step returns and episode-safe windows.

Transitions are stored raw, one slot per environment step, with their episode id and step index.
Everything a variant needs is assembled at sample time by vectorised gathers:

* **n-step returns** (MS variants): ``R = sum_{k<m} gamma^k r_{t+k}`` where ``m <= n`` stops at the
  episode's end (and at the newest stored step of a running episode); the batch carries the
  bootstrap state ``s_{t+m}`` and its discount ``gamma^m``, or 0 for a terminal end.
* **The adopted target** (paper, "Episode termination"): a max-steps end (Gymnasium
  ``truncated``) bootstraps like a normal step; only premature ends (``terminated``) use y = r.
  With ``bootstrap_on_truncation=False`` every end uses y = r (the paper's ablation).
* **Windows** (WIN and LSTM variants): the last ``w`` observations (and actions) up to a step,
  never mixing two episodes: positions before the episode's first stored step repeat that step
  (edge padding), exactly like :class:`ObservationWindow` builds them while acting.
* **Prioritized replay** (PER variants): a vectorised NumPy sum tree holds ``p_i^alpha``; batches
  are drawn stratified, carry importance weights ``(N P(i))^-beta`` (normalised by the batch
  maximum) and their slot indices, and :meth:`PrioritizedReplayBuffer.update_priorities` applies
  the paper's ``p_i = delta_i^2 + lambda3 |grad_a Q(s_i, a_i)|^2 + eps``. Sampling 256 of 1M took
  ~0.85 ms here against a ~16 ms update, so NumPy is enough (torchrl's compiled PER fails to load
  with torch 2.13; cpprb's n-step returns a wrong next observation after time-limit ends).
"""

from __future__ import annotations

import math
from collections import deque
from typing import NamedTuple

import numpy as np


class ReplayBatch(NamedTuple):
    """One sampled minibatch (NumPy; the agent moves it to its device).

    ``observations`` and ``next_observations`` are windows ``(B, w, obs_dim)`` (``w = 1`` for
    plain DDPG). ``rewards`` is the (n-step) discounted reward sum, ``discounts`` is
    ``gamma^m`` for a bootstrapped target and 0 where the target is y = r.
    """

    observations: np.ndarray  # (B, w, D) float32, window ending at s_t
    actions: np.ndarray  # (B, A) float32, a_t
    rewards: np.ndarray  # (B,) float32, sum_{k<m} gamma^k r_{t+k}
    next_observations: np.ndarray  # (B, w, D) float32, window ending at s_{t+m}
    discounts: np.ndarray  # (B,) float32, gamma^m, or 0 when the target is y = r
    weights: np.ndarray  # (B,) float32, importance weights (ones when uniform)
    indices: np.ndarray  # (B,) int64, buffer slots (for priority updates)
    action_windows: np.ndarray  # (B, w, A) float32, a_{t-w+1..t} (LSTM critic)
    next_action_windows: np.ndarray  # (B, w-1, A) float32, a_{t+m-w+1..t+m-1}
    n_steps: np.ndarray  # (B,) int64, m: rewards actually summed


class ReplayBuffer:
    """Uniform replay over a circular buffer of raw transitions."""

    def __init__(
        self,
        capacity: int,
        obs_dim: int,
        action_dim: int,
        *,
        gamma: float = 0.99,
        n_step: int = 1,
        window: int = 1,
        bootstrap_on_truncation: bool = True,
        seed: int | None = None,
    ) -> None:
        if capacity < 1 or n_step < 1 or window < 1:
            raise ValueError("capacity, n_step and window must be >= 1")
        self.capacity = int(capacity)
        self.obs_dim = int(obs_dim)
        self.action_dim = int(action_dim)
        self.gamma = float(gamma)
        self.n_step = int(n_step)
        self.window = int(window)
        self.bootstrap_on_truncation = bool(bootstrap_on_truncation)
        self.rng = np.random.default_rng(seed)
        c = self.capacity
        self.obs = np.zeros((c, obs_dim), np.float32)
        self.next_obs = np.zeros((c, obs_dim), np.float32)
        self.actions = np.zeros((c, action_dim), np.float32)
        self.rewards = np.zeros(c, np.float32)
        self.terminated = np.zeros(c, bool)
        self.truncated = np.zeros(c, bool)
        self.episode = np.full(c, -1, np.int64)
        self.step_in_episode = np.zeros(c, np.int64)
        self.pos = 0
        self.size = 0
        self._episode_id = 0
        self._episode_step = 0
        self._gamma_pows = self.gamma ** np.arange(self.n_step + 1)

    def __len__(self) -> int:
        return self.size

    def add(
        self,
        obs: np.ndarray,
        action: np.ndarray,
        reward: float,
        next_obs: np.ndarray,
        terminated: bool,
        truncated: bool,
    ) -> int:
        """Store one transition (an end closes its episode); returns its slot."""
        i = self.pos
        self.obs[i] = obs
        self.actions[i] = action
        self.rewards[i] = reward
        self.next_obs[i] = next_obs
        self.terminated[i] = terminated
        self.truncated[i] = truncated
        self.episode[i] = self._episode_id
        self.step_in_episode[i] = self._episode_step
        self.pos = (i + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)
        self._episode_step += 1
        if terminated or truncated:
            self.end_episode()
        return i

    def end_episode(self) -> None:
        """Start a new episode id (the env was reset without a terminal flag, e.g. a test)."""
        if self._episode_step > 0:
            self._episode_id += 1
            self._episode_step = 0

    # --- sampling -------------------------------------------------------------------------------
    def _sample_indices(self, batch_size: int) -> tuple[np.ndarray, np.ndarray]:
        idx = self.rng.integers(0, self.size, batch_size)
        return idx, np.ones(batch_size, np.float32)

    def sample(self, batch_size: int) -> ReplayBatch:
        """Draw ``batch_size`` transitions with n-step targets and windows assembled."""
        if self.size == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        idx, weights = self._sample_indices(batch_size)
        return self.gather(idx, weights)

    def _same_episode(
        self, start: np.ndarray, slots: np.ndarray, offsets: np.ndarray
    ) -> np.ndarray:
        """True where ``slots`` hold the step ``offsets`` away from ``start`` in its episode."""
        return (self.episode[slots] == self.episode[start][:, None]) & (
            self.step_in_episode[slots] == self.step_in_episode[start][:, None] + offsets
        )

    def _window_slots(self, end: np.ndarray) -> np.ndarray:
        """Slots (B, w) of the window ending at ``end``, edge-padded at the episode's start."""
        w = self.window
        if w == 1:
            return end[:, None]
        back = np.arange(w - 1, -1, -1)  # chronological: oldest first, `end` last
        slots = (end[:, None] - back) % self.capacity
        same = self._same_episode(end, slots, -back)
        # valid positions form a suffix; count it from the newest step backwards
        n_valid = np.logical_and.accumulate(same[:, ::-1], axis=1).sum(axis=1)
        first = w - n_valid
        cols = np.maximum(np.arange(w)[None, :], first[:, None])
        return np.take_along_axis(slots, cols, axis=1)

    def gather(self, idx: np.ndarray, weights: np.ndarray) -> ReplayBatch:
        """Assemble the batch for slots ``idx`` (exposed for tests with scripted slots)."""
        idx = np.asarray(idx, np.int64)
        n = self.n_step
        if n == 1:
            m = np.ones(len(idx), np.int64)
            returns = self.rewards[idx].astype(np.float64)
            last = idx
        else:
            ks = np.arange(n)
            slots = (idx[:, None] + ks) % self.capacity
            same = self._same_episode(idx, slots, ks)
            ended = self.terminated[slots] | self.truncated[slots]
            # step k is summed only if no earlier step of the lookahead ended the episode
            open_before = np.ones_like(same)
            open_before[:, 1:] = ~ended[:, :-1]
            included = np.logical_and.accumulate(same & open_before, axis=1)
            m = included.sum(axis=1)
            returns = (included * self._gamma_pows[:n] * self.rewards[slots]).sum(axis=1)
            last = (idx + m - 1) % self.capacity
        # The adopted target: only a premature end (terminated) cuts the bootstrap; a max-steps
        # end (truncated) bootstraps like any step unless the ablation switch is off.
        if self.bootstrap_on_truncation:
            no_bootstrap = self.terminated[last]
        else:
            no_bootstrap = self.terminated[last] | self.truncated[last]
        discounts = np.where(no_bootstrap, 0.0, self._gamma_pows[m])

        win = self._window_slots(idx)
        obs = self.obs[win]
        action_windows = self.actions[win]
        if self.window == 1:
            next_obs = self.next_obs[last][:, None, :]
            next_action_windows = np.zeros((len(idx), 0, self.action_dim), np.float32)
        else:
            win_last = self._window_slots(last)
            next_obs = np.concatenate(
                [self.obs[win_last[:, 1:]], self.next_obs[last][:, None, :]], axis=1
            )
            next_action_windows = self.actions[win_last[:, 1:]]
        return ReplayBatch(
            observations=obs,
            actions=self.actions[idx],
            rewards=returns.astype(np.float32),
            next_observations=next_obs,
            discounts=discounts.astype(np.float32),
            weights=np.asarray(weights, np.float32),
            indices=idx,
            action_windows=action_windows,
            next_action_windows=next_action_windows,
            n_steps=m.astype(np.int64),
        )


class SumTree:
    """A complete binary tree of sums over ``capacity`` leaves, updated and searched vectorised.

    Leaves hold p_i^alpha; each level of an update or a search is one NumPy operation over the
    whole batch, so cost is O(B log C) in ~20 array calls rather than B*20 Python steps.
    """

    def __init__(self, capacity: int) -> None:
        self.leaves = 1 << max(0, math.ceil(math.log2(max(1, capacity))))
        self.depth = int(math.log2(self.leaves))
        self.tree = np.zeros(2 * self.leaves, np.float64)

    @property
    def total(self) -> float:
        return float(self.tree[1])

    def values(self, idx: np.ndarray) -> np.ndarray:
        return self.tree[np.asarray(idx) + self.leaves]

    def update(self, idx: np.ndarray, values: np.ndarray) -> None:
        """Set leaves ``idx`` to ``values`` (last write wins on duplicates) and refresh sums."""
        node = np.asarray(idx, np.int64) + self.leaves
        self.tree[node] = values
        for _ in range(self.depth):
            node = node >> 1  # duplicates recompute the same sum: harmless, cheaper than unique
            self.tree[node] = self.tree[2 * node] + self.tree[2 * node + 1]

    def find(self, mass: np.ndarray) -> np.ndarray:
        """Leaf index whose cumulative-sum interval holds each ``mass`` in [0, total)."""
        mass = np.asarray(mass, np.float64).copy()
        node = np.ones(len(mass), np.int64)
        for _ in range(self.depth):
            left = 2 * node
            left_sum = self.tree[left]
            # never step into an empty subtree, even when rounding pushes mass past the last leaf
            go_right = (mass >= left_sum) & (self.tree[left + 1] > 0.0)
            mass = np.where(go_right, mass - left_sum, mass)
            node = left + go_right
        return node - self.leaves


class PrioritizedReplayBuffer(ReplayBuffer):
    """Proportional prioritized replay (Schaul et al.) with the paper's DDPGfD-style priority."""

    def __init__(
        self,
        capacity: int,
        obs_dim: int,
        action_dim: int,
        *,
        alpha: float = 0.6,
        beta: float = 0.4,
        lambda3: float = 1.0,
        eps: float = 1e-3,
        **kwargs: object,
    ) -> None:
        super().__init__(capacity, obs_dim, action_dim, **kwargs)  # type: ignore[arg-type]
        self.alpha = float(alpha)
        self.beta = float(beta)
        self.lambda3 = float(lambda3)
        self.eps = float(eps)
        self.tree = SumTree(self.capacity)
        self.max_priority = 1.0  # new transitions get the largest p seen, so each is tried once

    def add(self, *args: object, **kwargs: object) -> int:  # type: ignore[override]
        i = super().add(*args, **kwargs)  # type: ignore[arg-type]
        self.tree.update(np.array([i]), np.array([self.max_priority**self.alpha]))
        return i

    def priority(self, td_errors: np.ndarray, action_grads: np.ndarray) -> np.ndarray:
        """The paper's p_i = delta_i^2 + lambda3 |grad_a Q(s_i, a_i)|^2 + eps."""
        td_errors = np.asarray(td_errors, np.float64)
        action_grads = np.asarray(action_grads, np.float64).reshape(len(td_errors), -1)
        return td_errors**2 + self.lambda3 * np.sum(action_grads**2, axis=1) + self.eps

    def update_priorities(
        self, indices: np.ndarray, td_errors: np.ndarray, action_grads: np.ndarray
    ) -> np.ndarray:
        """Store new priorities for sampled slots; returns the raw priorities p_i."""
        p = self.priority(td_errors, action_grads)
        self.tree.update(np.asarray(indices, np.int64), p**self.alpha)
        self.max_priority = max(self.max_priority, float(p.max()))
        return p

    def probabilities(self, indices: np.ndarray) -> np.ndarray:
        """P(i) = p_i^alpha / sum_k p_k^alpha."""
        return self.tree.values(indices) / self.tree.total

    def _sample_indices(self, batch_size: int) -> tuple[np.ndarray, np.ndarray]:
        total = self.tree.total
        # stratified: one draw in each of batch_size equal slices of the total mass
        mass = (np.arange(batch_size) + self.rng.random(batch_size)) * (total / batch_size)
        idx = np.minimum(self.tree.find(np.minimum(mass, np.nextafter(total, 0.0))), self.size - 1)
        probs = self.tree.values(idx) / total
        weights = (self.size * probs) ** (-self.beta)
        weights /= weights.max()
        return idx, weights.astype(np.float32)


class ObservationWindow:
    """The acting-time twin of the buffer's windows: the last ``w`` observations, edge-padded.

    ``reset(obs)`` fills the window with the first observation, as the buffer pads an episode's
    first steps, so the actor sees at test time exactly what it was trained on.
    """

    def __init__(self, window: int) -> None:
        self.window = int(window)
        self._frames: deque[np.ndarray] = deque(maxlen=self.window)

    def reset(self, obs: np.ndarray) -> np.ndarray:
        self._frames.clear()
        for _ in range(self.window):
            self._frames.append(np.asarray(obs, np.float32))
        return self.array()

    def push(self, obs: np.ndarray) -> np.ndarray:
        self._frames.append(np.asarray(obs, np.float32))
        return self.array()

    def array(self) -> np.ndarray:
        """(w, obs_dim) oldest first."""
        return np.stack(self._frames)


def make_buffer(
    capacity: int,
    obs_dim: int,
    action_dim: int,
    *,
    prioritized: bool,
    gamma: float,
    n_step: int,
    window: int,
    bootstrap_on_truncation: bool,
    seed: int | None,
    alpha: float = 0.6,
    beta: float = 0.4,
    lambda3: float = 1.0,
    eps: float = 1e-3,
) -> ReplayBuffer:
    """The buffer a variant's configuration asks for."""
    common = dict(
        gamma=gamma,
        n_step=n_step,
        window=window,
        bootstrap_on_truncation=bootstrap_on_truncation,
        seed=seed,
    )
    if prioritized:
        return PrioritizedReplayBuffer(
            capacity,
            obs_dim,
            action_dim,
            alpha=alpha,
            beta=beta,
            lambda3=lambda3,
            eps=eps,
            **common,
        )
    return ReplayBuffer(capacity, obs_dim, action_dim, **common)  # type: ignore[arg-type]

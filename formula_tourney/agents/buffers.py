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
* **Lanes** (N cars per learner): a buffer made with ``lanes=N`` is N circular buffers of
  ``capacity // N`` slots side by side, one per car; :meth:`ReplayBuffer.add_cars` stores one
  step of several cars at once. n-step lookahead and windows wrap inside a lane and compare
  episode ids (unique over all lanes), so a transition's n-step sum and window never mix cars
  or episodes; uniform sampling draws over every stored slot of every lane. ``lanes=1`` is the
  one-car buffer, with the same arithmetic as before lanes existed.
* **Demonstrations** (RLPD, Ball et al. 2023): :class:`DemoMix` draws a fixed number of each
  batch's rows from a second buffer of demonstration transitions (``ReplayBatch.from_demos``
  marks them). Under PER only the online rows carry priorities and importance weights; the
  demonstration rows are drawn uniformly with weight 1 (:class:`OnlinePriorities`).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, NamedTuple

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
    from_demos: np.ndarray | None = None  # (B,) bool, rows from the demonstrations (DemoMix)


class ReplayBuffer:
    """Uniform replay over a circular buffer of raw transitions (``lanes`` of them, one per car).

    With ``lanes > 1`` the capacity is rounded down to a multiple of ``lanes``; lane ``l`` holds
    slots ``[l * C, (l + 1) * C)`` with ``C = capacity // lanes`` and is written by
    :meth:`add_cars` only.
    """

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
        lanes: int = 1,
    ) -> None:
        if capacity < 1 or n_step < 1 or window < 1 or lanes < 1:
            raise ValueError("capacity, n_step, window and lanes must be >= 1")
        if capacity < lanes:
            raise ValueError(f"capacity {capacity} holds less than one slot per lane ({lanes})")
        self.lanes = int(lanes)
        self.lane_capacity = int(capacity) // self.lanes
        self.capacity = self.lane_capacity * self.lanes
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
        # per-lane write position, fill, running episode id and step (lanes > 1 only)
        self._lane_pos = np.zeros(self.lanes, np.int64)
        self._lane_size = np.zeros(self.lanes, np.int64)
        self._lane_episode = np.arange(self.lanes, dtype=np.int64)
        self._lane_step = np.zeros(self.lanes, np.int64)
        self._lane_base = np.arange(self.lanes, dtype=np.int64) * self.lane_capacity
        self._next_episode = self.lanes

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
        """Store one transition (an end closes its episode); returns its slot. One lane only."""
        if self.lanes != 1:
            raise ValueError("a buffer with lanes is written by add_cars")
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

    def add_cars(
        self,
        lanes: np.ndarray,
        obs: np.ndarray,
        actions: np.ndarray,
        rewards: np.ndarray,
        next_obs: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
    ) -> np.ndarray:
        """Store one step of the cars ``lanes`` (distinct lane numbers, one row each); an end
        closes that car's episode and the next step of its lane starts a new one. Returns the
        slots written."""
        lanes = np.asarray(lanes, np.int64)
        if self.lanes == 1:  # one car: the one-lane path, transition by transition
            return np.array([self.add(obs[k], actions[k], float(rewards[k]), next_obs[k],
                                      bool(terminated[k]), bool(truncated[k]))
                             for k in range(len(lanes))], np.int64)  # fmt: skip
        slots = self._lane_base[lanes] + self._lane_pos[lanes]
        self.obs[slots] = obs
        self.actions[slots] = actions
        self.rewards[slots] = rewards
        self.next_obs[slots] = next_obs
        self.terminated[slots] = terminated
        self.truncated[slots] = truncated
        self.episode[slots] = self._lane_episode[lanes]
        self.step_in_episode[slots] = self._lane_step[lanes]
        self._lane_pos[lanes] = (self._lane_pos[lanes] + 1) % self.lane_capacity
        self._lane_size[lanes] = np.minimum(self._lane_size[lanes] + 1, self.lane_capacity)
        self.size = int(self._lane_size.sum())
        self._lane_step[lanes] += 1
        ended = lanes[np.asarray(terminated, bool) | np.asarray(truncated, bool)]
        if len(ended):
            self.end_lane_episodes(ended)
        return slots

    def end_lane_episodes(self, lanes: np.ndarray) -> None:
        """New episode ids for ``lanes`` (unique over all lanes); lanes with no step yet keep
        theirs."""
        lanes = np.asarray(lanes, np.int64)
        lanes = lanes[self._lane_step[lanes] > 0]
        k = len(lanes)
        self._lane_episode[lanes] = np.arange(self._next_episode, self._next_episode + k)
        self._next_episode += k
        self._lane_step[lanes] = 0

    # --- state --------------------------------------------------------------------------------
    _SLOT_ARRAYS = ("obs", "next_obs", "actions", "rewards", "terminated", "truncated",
                    "episode", "step_in_episode")  # fmt: skip
    _LANE_ARRAYS = ("_lane_pos", "_lane_size", "_lane_episode", "_lane_step")
    _STATE_NUMBERS = ("pos", "size", "_episode_id", "_episode_step", "_next_episode")

    def state_dict(self) -> dict[str, Any]:
        """Everything sampling depends on, to resume a run bit-identically: the stored slots
        (a lane's filled ones only), the counters and the sampling generator's state (plain
        arrays, ints and dicts)."""
        slots = self._filled_slots()
        state: dict[str, Any] = {name: getattr(self, name)[slots] for name in self._SLOT_ARRAYS}
        state.update({name: getattr(self, name).copy() for name in self._LANE_ARRAYS})
        state.update({name: int(getattr(self, name)) for name in self._STATE_NUMBERS})
        state["capacity"] = self.capacity
        state["rng"] = self.rng.bit_generator.state
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Continue from :meth:`state_dict` of a buffer built with the same arguments."""
        if int(state["capacity"]) != self.capacity:
            raise ValueError(f"buffer state of capacity {state['capacity']}, not {self.capacity}")
        for name in self._LANE_ARRAYS:
            getattr(self, name)[:] = np.asarray(state[name])
        for name in self._STATE_NUMBERS:
            setattr(self, name, int(state[name]))
        slots = self._filled_slots()
        for name in self._SLOT_ARRAYS:
            getattr(self, name)[slots] = np.asarray(state[name])
        self.rng.bit_generator.state = state["rng"]

    def stored_observations(self) -> np.ndarray:
        """Every stored transition's observation ``(len, obs_dim)``, in slot order."""
        return self.obs[self._filled_slots()]

    def _filled_slots(self) -> np.ndarray:
        """The slots holding a transition: a prefix of a filling one-lane buffer, each lane's
        own prefix with lanes (lanes fill from their base)."""
        if self.lanes == 1 or self.size == self.capacity:
            return np.arange(self.size)
        return np.concatenate([base + np.arange(n) for base, n in zip(
            self._lane_base, self._lane_size, strict=True)])  # fmt: skip

    # --- sampling -------------------------------------------------------------------------------
    def _sample_indices(self, batch_size: int) -> tuple[np.ndarray, np.ndarray]:
        idx = self.rng.integers(0, self.size, batch_size)
        if self.lanes != 1:
            idx = self._stored_slot(idx)
        return idx, np.ones(batch_size, np.float32)

    def _stored_slot(self, rank: np.ndarray) -> np.ndarray:
        """The ``rank``-th stored slot counted lane by lane (lanes fill at their own pace)."""
        if self.size == self.capacity:
            return rank
        ends = np.cumsum(self._lane_size)
        lane = np.searchsorted(ends, rank, side="right")
        return self._lane_base[lane] + rank - (ends[lane] - self._lane_size[lane])

    def _shift(self, slots: np.ndarray, offsets: np.ndarray | int) -> np.ndarray:
        """Slots ``offsets`` steps after ``slots`` in the same lane (circular)."""
        if self.lanes == 1:
            return (slots + offsets) % self.capacity
        c = self.lane_capacity
        local = slots % c
        return slots - local + (local + offsets) % c

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
        slots = self._shift(end[:, None], -back)
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
            slots = self._shift(idx[:, None], ks)
            same = self._same_episode(idx, slots, ks)
            ended = self.terminated[slots] | self.truncated[slots]
            # step k is summed only if no earlier step of the lookahead ended the episode
            open_before = np.ones_like(same)
            open_before[:, 1:] = ~ended[:, :-1]
            included = np.logical_and.accumulate(same & open_before, axis=1)
            m = included.sum(axis=1)
            returns = (included * self._gamma_pows[:n] * self.rewards[slots]).sum(axis=1)
            last = self._shift(idx, m - 1)
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

    def add_cars(self, *args: object, **kwargs: object) -> np.ndarray:  # type: ignore[override]
        if self.lanes == 1:  # add() sets each slot's priority
            return super().add_cars(*args, **kwargs)  # type: ignore[arg-type]
        slots = super().add_cars(*args, **kwargs)  # type: ignore[arg-type]
        self.tree.update(slots, np.full(len(slots), self.max_priority**self.alpha))
        return slots

    def state_dict(self) -> dict[str, Any]:
        """The uniform buffer's state plus the stored slots' leaves of the sum tree (every inner
        node is the exact sum of its children, so the leaves rebuild it bit for bit), the
        largest priority and beta."""
        state = super().state_dict()
        leaves = self.tree.values(self._filled_slots())
        state.update(leaves=leaves, max_priority=self.max_priority, beta=self.beta)
        return state

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.tree.tree[:] = 0.0
        self.tree.update(self._filled_slots(), np.asarray(state["leaves"], np.float64))
        self.max_priority = float(state["max_priority"])
        self.beta = float(state["beta"])

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
        idx = self.tree.find(np.minimum(mass, np.nextafter(total, 0.0)))
        if self.lanes == 1:  # with lanes, stored slots are not a prefix; find never picks p = 0
            idx = np.minimum(idx, self.size - 1)
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


class OnlinePriorities:
    """The priority sink of a mixed batch: the first ``rows`` rows are the online buffer's."""

    def __init__(self, buffer: PrioritizedReplayBuffer, rows: int) -> None:
        self.buffer = buffer
        self.rows = int(rows)

    def update_priorities(
        self, indices: np.ndarray, td_errors: np.ndarray, action_grads: np.ndarray
    ) -> np.ndarray:
        """The online rows' new priorities (demonstration rows keep none)."""
        r = self.rows
        return self.buffer.update_priorities(indices[:r], td_errors[:r], action_grads[:r])


class DemoMix:
    """Batches of ``batch - demo_rows`` online rows followed by ``demo_rows`` demonstration
    rows (RLPD's symmetric sampling at ``demo_rows = batch / 2``).

    Both parts are assembled by their own buffer (same n-step, window and target rules), then
    concatenated; ``from_demos`` marks the demonstration rows, ``indices`` are each part's own
    slots. Under PER the online part is drawn by priority with its importance weights and
    ``priorities`` passes only those rows' new priorities on; demonstration rows are uniform,
    weight 1.
    """

    def __init__(self, online: ReplayBuffer, demos: ReplayBuffer, demo_rows: int) -> None:
        if len(demos) == 0:
            raise ValueError("the demonstration buffer is empty")
        self.online = online
        self.demos = demos
        self.demo_rows = int(demo_rows)
        self._flags: dict[int, np.ndarray] = {}

    def sample(self, batch_size: int) -> ReplayBatch:
        k = self.demo_rows
        online_rows = batch_size - k
        if k == 0:
            return self.online.sample(batch_size)
        if online_rows <= 0:
            raise ValueError(f"batch {batch_size} leaves no online rows beside {k} demo rows")
        a = self.online.sample(online_rows)
        b = self.demos.sample(k)
        flags = self._flags.get(batch_size)
        if flags is None:
            flags = self._flags[batch_size] = np.arange(batch_size) >= online_rows
        fields = {f: np.concatenate([x, y]) for f, x, y in zip(
            ReplayBatch._fields[:-1], a[:-1], b[:-1], strict=True)}  # fmt: skip
        return ReplayBatch(**fields, from_demos=flags)

    def priorities(self, batch_size: int) -> OnlinePriorities | None:
        """What ``agent.update`` gets as ``per_buffer``: None for a uniform online buffer."""
        if not isinstance(self.online, PrioritizedReplayBuffer):
            return None
        return OnlinePriorities(self.online, batch_size - self.demo_rows)


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
    lanes: int = 1,
) -> ReplayBuffer:
    """The buffer a variant's configuration asks for (``lanes``: one per car driven into it)."""
    common = dict(
        gamma=gamma,
        n_step=n_step,
        window=window,
        bootstrap_on_truncation=bootstrap_on_truncation,
        seed=seed,
        lanes=lanes,
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

"""Driving cars into the replay buffer: one car (FormulaRacing-v0) or N cars (the vector env).

Both collectors take one action per car, step their env(s), make each car's
:class:`~formula_tourney.agents.protocol.Transition` of the step (``transitions``) with the
reward the reward model's :class:`sim.reward.RewardRule` makes of the env's (its crash penalty
and scale), keep each car's observation window (edge-padded at its episode's start, exactly as
``agents.buffers.ObservationWindow`` and the buffer build it), and hand back the car-episodes
that ended. The training loop hands the transitions to its entrant (``Entrant.observe``) and owns
acting, exploration and learning (and closes the envs); given a ``buffer``, a collector stores
them there itself, as an entrant of ours does (``family_entrant.store_transitions``: a test or
a calibration that drives scripted actions through the same ``step``).

* :class:`SingleCarCollector` is the paper's loop: one env per train track, a track and a reset
  seed drawn per episode. It keeps the generator's state at the episode's start and the
  actions driven since, from which :meth:`SingleCarCollector.replay` puts a resumed run's car
  back where it was (``training.resume``).
* :class:`VectorCollector` drives ``N`` cars of ``FormulaRacingVectorEnv`` (one vector env per
  train track, the cars split as evenly as possible). The vector env's next-step autoreset
  returns a car's first observation on the step after its episode ended and ignores that car's
  action then: that step stores no transition for the car (``stored`` counts the transitions of
  a step), and the car's window restarts from the returned observation.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from formula_tourney.agents.buffers import ObservationWindow, ReplayBuffer
from formula_tourney.agents.family_entrant import store_transitions
from formula_tourney.agents.protocol import Transition
from formula_tourney.sim.reward import RewardRule


@dataclass
class CarEpisode:
    """One finished car-episode: what its ``episodes.parquet`` row is made of."""

    car: int
    track: str
    reward: float  # sum of the env's (unscaled) rewards
    steps: int
    laps: int
    best_lap_s: float
    damage: float
    termination: str


def split_cars(cars: int, tracks: Sequence[str]) -> list[tuple[str, int]]:
    """``(track, cars on it)`` for each distinct train track: as even as possible, the first
    tracks take the remainder; cars are numbered track by track."""
    names = list(dict.fromkeys(tracks))
    share, extra = divmod(cars, len(names))
    return [(name, share + (k < extra)) for k, name in enumerate(names) if share + (k < extra)]


class SingleCarCollector:
    """One car; a track is drawn from ``train_tracks`` and the env reset with a drawn seed at
    each episode start (draws from ``rng``, in that order)."""

    cars = 1

    def __init__(
        self,
        envs: Mapping[str, Any],
        train_tracks: Sequence[str],
        rng: np.random.Generator,
        buffer: ReplayBuffer | None,
        window: int,
        reward_rule: RewardRule,
    ) -> None:
        self.envs = envs
        self.train_tracks = list(train_tracks)
        self.rng = rng
        self.buffer = buffer
        self.reward_rule = reward_rule
        self.window = ObservationWindow(window)
        self.stored = 0
        self.transitions: list[Transition] = []  # the last step's
        self.started = [0]  # cars whose episode began at the last reset or step
        self._start()

    def _start(self) -> None:
        rng = self.rng
        self.start_rng_state = rng.bit_generator.state  # what a resumed run starts from
        self.episode_actions: list[np.ndarray] = []  # driven since the episode's start
        self.track = self.train_tracks[int(rng.integers(len(self.train_tracks)))]
        self.env = self.envs[self.track]
        self.obs, _ = self.env.reset(seed=int(rng.integers(2**31 - 1)))
        self.stack = self.window.reset(self.obs)
        self.reward, self.steps = 0.0, 0

    @property
    def windows(self) -> list[np.ndarray]:
        """Each car's window ``(w, obs_dim)``, oldest first."""
        return [self.stack]

    def step(self, actions: Sequence[np.ndarray]) -> list[CarEpisode]:
        """Apply ``actions[0]``, make (and store) the transition, start a new episode after an
        end."""
        action = actions[0]
        next_obs, reward, terminated, truncated, info = self.env.step(action)
        self.episode_actions.append(np.array(action))
        stored = self.reward_rule(float(reward), bool(terminated))
        self.transitions = [Transition(0, self.obs, action, stored, next_obs, bool(terminated),
                                       bool(truncated))]  # fmt: skip
        if self.buffer is not None:
            store_transitions(self.buffer, self.transitions)
        self.stored = 1
        self.steps += 1
        self.reward += float(reward)
        if not (terminated or truncated):
            self.obs = next_obs
            self.stack = self.window.push(next_obs)
            self.started = []
            return []
        done = CarEpisode(
            car=0, track=self.track, reward=self.reward, steps=self.steps,
            laps=int(info.get("laps", 0)), best_lap_s=float(info.get("best_lap_s", np.nan)),
            damage=float(info.get("damage", 0.0)), termination=str(info.get("termination") or ""),
        )  # fmt: skip
        self._start()
        self.started = [0]
        return [done]

    def replay(self, actions: Sequence[np.ndarray]) -> None:
        """Drive the current episode's first ``actions`` again, storing nothing: a resumed run
        (``training.resume``) puts the car where it was, its window, reward and step count too.
        The env must not end the episode on the way (it did not when they were recorded)."""
        for action in actions:
            next_obs, reward, terminated, truncated, _info = self.env.step(action)
            if terminated or truncated:
                raise ValueError("the replayed actions end the episode: not the recorded drive")
            self.episode_actions.append(np.array(action))
            self.steps += 1
            self.reward += float(reward)
            self.obs = next_obs
            self.stack = self.window.push(next_obs)
        self.started = [] if self.steps else [0]


class VectorCollector:
    """``N`` cars in one vector env per train track, car ``c`` in lane ``c`` of the buffer."""

    def __init__(
        self,
        groups: Sequence[tuple[str, Any]],
        seeds: Sequence[int],
        buffer: ReplayBuffer | None,
        window: int,
        reward_rule: RewardRule,
    ) -> None:
        self.groups = list(groups)
        self.buffer = buffer
        self.reward_rule = reward_rule
        sizes = [env.num_envs for _, env in self.groups]
        self.cars = n = int(sum(sizes))
        if buffer is not None and buffer.lanes != n:
            raise ValueError(f"{n} cars need a buffer with {n} lanes, got {buffer.lanes}")
        bounds = np.cumsum([0, *sizes])
        self._slices = [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
        self.car_tracks = [name for name, env in self.groups for _ in range(env.num_envs)]
        self._lanes = np.arange(n, dtype=np.int64)
        obs = [env.reset(seed=int(seed))[0] for (_, env), seed in zip(self.groups, seeds,
                                                                         strict=True)]  # fmt: skip
        self.obs = np.concatenate(obs).astype(np.float32)
        self._windows = np.repeat(self.obs[:, None, :], window, axis=1)
        self.reward = np.zeros(n)
        self.steps = np.zeros(n, np.int64)
        self.needs_reset = np.zeros(n, bool)  # the env resets these cars on the next step
        self.stored = 0
        self.transitions: list[Transition] = []  # the last step's, in car order
        self.started = list(range(n))

    @property
    def windows(self) -> np.ndarray:
        """Each car's window ``(N, w, obs_dim)``, oldest first (one row per car)."""
        return self._windows

    def step(self, actions: Sequence[np.ndarray] | np.ndarray) -> list[CarEpisode]:
        """Apply one action per car, make (and store) the live cars' transitions, return ended
        episodes in car order."""
        actions = np.asarray(actions, np.float32)
        outs = [env.step(actions[sl]) for (_, env), sl in zip(self.groups, self._slices,
                                                              strict=True)]  # fmt: skip
        if len(outs) == 1:
            next_obs, reward, terminated, truncated, info = outs[0]
            infos = [info]
        else:
            next_obs = np.concatenate([o[0] for o in outs])
            reward, terminated, truncated = (np.concatenate([o[k] for o in outs])
                                             for k in (1, 2, 3))  # fmt: skip
            infos = [o[4] for o in outs]
        live = ~self.needs_reset
        stored = self.reward_rule(reward, terminated)
        lanes = self._lanes if live.all() else live.nonzero()[0]
        obs = self.obs
        self.transitions = [
            Transition(c, obs[c], actions[c], float(stored[c]), next_obs[c], bool(terminated[c]),
                       bool(truncated[c]))
            for c in lanes.tolist()
        ]  # fmt: skip
        if self.buffer is not None:
            store_transitions(self.buffer, self.transitions)
        self.stored = len(lanes)
        self.reward[lanes] += reward[lanes]
        self.steps[lanes] += 1
        ended = (terminated | truncated) & live
        finished = [self._episode(int(c), infos) for c in ended.nonzero()[0]]
        # windows: live cars push their new observation; cars the env just reset start over
        win = self._windows
        if win.shape[1] > 1:
            win[:, :-1] = win[:, 1:]
        win[:, -1] = next_obs
        reset = self.needs_reset.nonzero()[0]
        if len(reset):
            win[reset] = next_obs[reset, None, :]
            self.reward[reset] = 0.0
            self.steps[reset] = 0
        self.started = reset.tolist()
        self.needs_reset = ended
        self.obs = next_obs
        return finished

    def _episode(self, car: int, infos: list[dict[str, Any]]) -> CarEpisode:
        g = next(k for k, sl in enumerate(self._slices) if sl.start <= car < sl.stop)
        info, i = infos[g], car - self._slices[g].start
        best = float(info["best_lap_s"][i])
        return CarEpisode(
            car=car, track=self.car_tracks[car], reward=float(self.reward[car]),
            steps=int(self.steps[car]), laps=int(info["laps"][i]), best_lap_s=best,
            damage=float(info["damage"][i]), termination=str(info["termination"][i] or ""),
        )  # fmt: skip

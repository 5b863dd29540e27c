"""Our algorithm families as entrants: an ``Agent`` with its replay, exploration and update credit.

:class:`FamilyEntrant` is the :class:`~formula_tourney.agents.protocol.Entrant` of every family
registered in ``agents.families`` (DDPG and its variants, TD3, SAC, CrossQ). It owns what the
training loop used to hold beside the agent, so the loop can drive any entrant alike:

* the replay buffer (uniform or prioritized, n-step, windows, one lane per car), filled by
  :meth:`observe` exactly as the collectors stored transitions (:func:`store_transitions`);
* with demonstrations, the second buffer every batch draws its share of rows from
  (``buffers.DemoMix``) and the cloning term of the actor's loss (``mlp_update.BCLoss``);
* one exploration noise per car (``noise.BrakeExplorationNoise``) and the annealed epsilon;
* the update credit: ``updates_per_step`` updates earned per stored transition once learning
  has started (``learning_starts``, a batch stored), spent at once.

Random streams: the agent's weights come from ``torch.manual_seed(seed)``; the noises and the
buffer draw from children 1 and 2 of ``SeedSequence(seed).spawn(4)`` (child 0 is the loop's env
stream, child 3 its demonstration stream), so a run is the same whoever builds the pieces.
``save`` writes today's agent checkpoint (``checkpoints.save_checkpoint``), which races,
replays and ``eval`` load unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch

from formula_tourney.agents.buffers import DemoMix, ReplayBuffer, make_buffer
from formula_tourney.agents.checkpoints import load_checkpoint, save_checkpoint
from formula_tourney.agents.core import Agent, UpdateInfo
from formula_tourney.agents.families import make_agent
from formula_tourney.agents.mlp_update import BCLoss
from formula_tourney.agents.noise import BrakeExplorationNoise, linear_epsilon
from formula_tourney.agents.protocol import EntrantSpaces, Transition
from formula_tourney.agents.variants import AgentConfig

TB_EVERY_UPDATES = 250
"""The loop logs an update's losses to TensorBoard when the count of updates passes a multiple
of this (``update`` returns the last update's losses and the count)."""


def store_transitions(buffer: ReplayBuffer, transitions: Sequence[Transition]) -> None:
    """Store one loop step's transitions: one by one in a one-lane buffer, as one
    ``add_cars`` call of the step's cars (in car order) in a buffer with lanes."""
    if buffer.lanes == 1:
        for t in transitions:
            buffer.add(t.obs, t.action, t.reward, t.next_obs, t.terminated, t.truncated)
        return
    if not transitions:
        return
    buffer.add_cars(
        np.array([t.car for t in transitions], np.int64),
        np.stack([t.obs for t in transitions]),
        np.stack([t.action for t in transitions]),
        np.array([t.reward for t in transitions]),
        np.stack([t.next_obs for t in transitions]),
        np.array([t.terminated for t in transitions]),
        np.array([t.truncated for t in transitions]),
    )


def _losses(info: UpdateInfo, updates: int) -> dict[str, float]:
    return {
        "critic_loss": info.critic_loss,
        "actor_loss": info.actor_loss,
        "q_mean": info.q_mean,
        "td_abs_mean": info.td_abs_mean,
        "updates": float(updates),
    }


class FamilyEntrant:
    """One of our families, trained and driven through the entrant protocol."""

    saves_metadata: ClassVar[bool] = True
    """``save`` takes ``extra``: the plain metadata (episode, run spec, best lap) that a
    checkpoint of a training run carries for ``eval`` and ``replay``."""

    def __init__(
        self,
        agent: Agent,
        buffer: ReplayBuffer | None = None,
        noises: list[BrakeExplorationNoise] | None = None,
    ) -> None:
        """An entrant around ``agent``; without ``buffer`` and ``noises`` it only drives (a
        loaded checkpoint)."""
        self.agent = agent
        self.cfg: AgentConfig = agent.cfg
        self.buffer = buffer
        self.noises = noises or []
        self.cars = max(1, len(self.noises))
        self.label = f"{self.cfg.name} ({self.cfg.algorithm})"
        self.window = int(self.cfg.window)
        self.epsilon = 1.0
        self.update_credit = 0.0
        # learning starts at the transition that reaches learning_starts with a batch stored
        self._learn_from = max(self.cfg.learning_starts, self.cfg.batch_size)
        self._samples_its_policy = not self.cfg.uses_action_noise  # SAC samples its policy
        self._stored = 0  # transitions of the current loop step
        self._sampler: Any = buffer  # what batches are drawn from
        self._priority_sink: Any = buffer  # what agent.update hands PER priorities to
        self._bc: BCLoss | None = None
        self._demos: ReplayBuffer | None = None
        self._demo_settings: dict[str, Any] | None = None

    # --- building and files -----------------------------------------------------------------------
    @classmethod
    def settings_model(cls) -> type[AgentConfig]:
        return AgentConfig

    @classmethod
    def build(
        cls, settings: AgentConfig, spaces: EntrantSpaces, seed: int, device: str
    ) -> FamilyEntrant:
        cfg = settings
        obs_dim, action_dim, cars = spaces.obs_dim, spaces.action_dim, spaces.cars
        agent = make_agent(cfg, obs_dim, action_dim, device=device, seed=seed)
        # children 1 and 2 of the run's spawn(4) (module docstring); spawn is deterministic
        _, noise_seq, buf_seq, _ = np.random.SeedSequence(seed).spawn(4)
        buffer = make_buffer(
            cfg.buffer_size, obs_dim, action_dim, prioritized=cfg.prioritized,
            gamma=cfg.gamma, n_step=cfg.n_step, window=cfg.window,
            bootstrap_on_truncation=cfg.adopted_target, seed=buf_seq,  # type: ignore[arg-type]
            alpha=cfg.per_alpha, beta=cfg.per_beta0, lambda3=cfg.per_lambda3,
            eps=cfg.per_eps, lanes=cars,
        )  # fmt: skip
        noise_seeds = [noise_seq] if cars == 1 else noise_seq.spawn(cars)
        noises = [
            BrakeExplorationNoise(
                np.random.default_rng(seq), cfg.ou_theta, cfg.ou_sigma, cfg.noise_prob,
                cfg.brake_explore_prob, cfg.brake_explore_mean, cfg.brake_explore_sigma,
                cfg.brake_explore_hold_steps, action_dim,
            )
            for seq in noise_seeds
        ]  # fmt: skip
        return cls(agent, buffer, noises)

    def save(self, path: Path, extra: Mapping[str, Any] | None = None) -> None:
        """The agent checkpoint (``checkpoints.save_checkpoint``), with plain ``extra``."""
        save_checkpoint(self.agent, path, extra=dict(extra) if extra else None)

    @classmethod
    def load(cls, path: Path, device: str) -> FamilyEntrant:
        """A driving entrant from an agent checkpoint (no buffer, no noise)."""
        agent, _extra = load_checkpoint(path, device=device)
        return cls(agent)

    # --- demonstrations -----------------------------------------------------------------------
    def use_demonstrations(
        self,
        demos: ReplayBuffer,
        demo_rows: int,
        bc_weight: float,
        bc_q_filter: bool,
        warm_start: Callable[[Agent], tuple[float, float]] | None = None,
    ) -> tuple[float, float] | None:
        """Draw ``demo_rows`` of every batch from ``demos``, clone them in the actor's loss
        with ``bc_weight`` (0: not at all), and first run ``warm_start`` on the agent (the
        loop's behaviour cloning); returns its (MSE before, after) or None."""
        self._set_demonstrations(demos, demo_rows, bc_weight, bc_q_filter)
        if self.cfg.obs_norm:  # the warm start and the first updates read demonstrated states
            self.agent.count_observations(demos.stored_observations())
        return warm_start(self.agent) if warm_start is not None else None

    def _set_demonstrations(
        self, demos: ReplayBuffer, demo_rows: int, bc_weight: float, bc_q_filter: bool
    ) -> None:
        assert self.buffer is not None, "a driving-only entrant learns nothing"
        batch = self.cfg.batch_size
        mix = DemoMix(self.buffer, demos, demo_rows)
        self._sampler, self._priority_sink = mix, mix.priorities(batch)
        self._demos = demos
        self._demo_settings = {"demo_rows": int(demo_rows), "bc_weight": float(bc_weight),
                               "bc_q_filter": bool(bc_q_filter)}  # fmt: skip
        if bc_weight > 0.0:  # the run spec checked that every batch has demo rows
            self._bc = BCLoss(bc_weight, mix.demo_rows, bc_q_filter)

    # --- acting --------------------------------------------------------------------------------
    @property
    def updates(self) -> int:
        """Gradient updates so far (the episodes table's ``updates``)."""
        return self.agent.updates

    def act(self, windows: np.ndarray) -> np.ndarray:
        """The tests' and races' greedy action of each car (``Agent.act_eval``)."""
        return np.stack([self.agent.act_eval(w) for w in windows])

    def explore(self, windows: np.ndarray, env_steps: int) -> np.ndarray:
        """Each car's greedy action plus its own noise at the annealed epsilon; SAC samples its
        policy. Several cars share one actor forward: 6-12 us per car at 8-32 cars against
        ~40 us for one ``act`` per car (400-300 actor, one thread, measured)."""
        cfg, agent = self.cfg, self.agent
        self.epsilon = linear_epsilon(env_steps, cfg.exploration_steps, cfg.epsilon_floor)
        if self._samples_its_policy:
            return np.stack([agent.explore(w) for w in windows])
        if self.cars == 1:
            return self.noises[0](agent.act(windows[0]), self.epsilon)[0][None]
        greedy = agent.act_batch(windows)
        return np.stack([self.noises[car](greedy[car], self.epsilon)[0]
                         for car in range(self.cars)])  # fmt: skip

    def episode_started(self, car: int) -> None:
        self.noises[car].reset()

    # --- learning ------------------------------------------------------------------------------
    def observe(self, transitions: Sequence[Transition]) -> None:
        assert self.buffer is not None, "a driving-only entrant learns nothing"
        self._stored = len(transitions)
        store_transitions(self.buffer, transitions)
        if self.cfg.obs_norm and transitions:
            self.agent.count_observations(np.stack([t.obs for t in transitions]))

    def update(self, env_steps: int) -> dict[str, float]:
        """Earn updates for the step's stored transitions and spend them; the last update's
        losses and the update count (the first non-finite ones at once, unspent credit kept)."""
        cfg, agent, buffer = self.cfg, self.agent, self.buffer
        assert buffer is not None, "a driving-only entrant learns nothing"
        eligible = min(self._stored, env_steps - self._learn_from + 1)
        if eligible <= 0 or len(buffer) < cfg.batch_size:
            return {}
        self.update_credit += eligible * cfg.updates_per_step  # 1 * x == x: N = 1 unchanged
        info: UpdateInfo | None = None
        while self.update_credit >= 1.0:
            self.update_credit -= 1.0
            if cfg.prioritized:
                frac = min(1.0, agent.updates / cfg.per_beta_steps)
                buffer.beta = cfg.per_beta0 + (1.0 - cfg.per_beta0) * frac  # type: ignore[attr-defined]
            info = agent.update(self._sampler.sample(cfg.batch_size), self._priority_sink,
                                bc=self._bc)  # fmt: skip
            if not (math.isfinite(info.critic_loss) and math.isfinite(info.actor_loss)):
                break
        return {} if info is None else _losses(info, agent.updates)

    # --- resuming ------------------------------------------------------------------------------
    def training_state(self) -> dict[str, Any]:
        """Agent (weights, targets, optimisers, its generator), buffers (demonstrations too,
        PER leaves), noises, credit, epsilon and torch's global RNG: plain values only."""
        assert self.buffer is not None, "a driving-only entrant has no training state"
        state: dict[str, Any] = {
            "agent": self.agent.state_dict(),
            "last_actor_loss": float(self.agent._last_actor_loss),
            "buffer": self.buffer.state_dict(),
            "noises": [noise.state_dict() for noise in self.noises],
            "update_credit": self.update_credit,
            "epsilon": self.epsilon,
            "torch_rng": torch.get_rng_state(),
        }
        if self._demos is not None and self._demo_settings is not None:
            state["demos"] = {"buffer": self._demos.state_dict(), **self._demo_settings}
        return state

    def restore_training_state(self, state: dict[str, Any]) -> None:
        assert self.buffer is not None, "a driving-only entrant has no training state"
        self.agent.load_state_dict(state["agent"])
        self.agent._last_actor_loss = float(state["last_actor_loss"])
        self.buffer.load_state_dict(state["buffer"])
        if len(state["noises"]) != len(self.noises):
            raise ValueError(f"{len(state['noises'])} noises saved for {len(self.noises)} cars")
        for noise, saved in zip(self.noises, state["noises"], strict=True):
            noise.load_state_dict(saved)
        self.update_credit = float(state["update_credit"])
        self.epsilon = float(state["epsilon"])
        torch.set_rng_state(state["torch_rng"])
        demos = state.get("demos")
        if demos is not None:  # the same buffer rules as the run's (training.demos)
            cfg, saved = self.cfg, demos["buffer"]
            buffer = ReplayBuffer(
                int(saved["capacity"]), self.agent.obs_dim, self.agent.action_dim,
                gamma=cfg.gamma, n_step=cfg.n_step, window=cfg.window,
                bootstrap_on_truncation=cfg.adopted_target,
            )  # fmt: skip
            buffer.load_state_dict(saved)
            self._set_demonstrations(buffer, int(demos["demo_rows"]), float(demos["bc_weight"]),
                                     bool(demos["bc_q_filter"]))  # fmt: skip

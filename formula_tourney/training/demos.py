"""Demonstrations: the follower's laps in the run's own env, and the behaviour-cloning warm start.

The follower (``bots.follower.Follower``, our Tita; its controller is used as it is) drives
``demos.laps`` timed laps on each train track through exactly the env the agent trains in
(``RunEnvs.make(track, test=False)``: the run's env settings, car, reference line, LAC, random
starts and ``max_steps``), episode after episode as that env ends and resets them. Every step
it drives is one transition of a demonstration buffer with the agent's observation layout,
scaled reward, n-step and window rules (the same ``ReplayBuffer`` class); a drive cut after its
last lap closes its episode without a terminal flag. Batches then draw their
``demos.batch_fraction`` of rows from it (``agents.buffers.DemoMix``).

The demonstrator's own lap time on the key track is its best clean lap there in these laps
(or, when the key track is not a train track, in ``laps`` laps driven there in the test env
from the canonical start): the report counts an entrant "with demos" as beating a bot only when
it beats the bot that demonstrated, and this is that bot's time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from formula_tourney.agents.buffers import ReplayBuffer
from formula_tourney.bots.follower import Follower, FollowerConfig, _car_state
from formula_tourney.bots.line_offsets import reference_offsets
from formula_tourney.sim.env import DEFAULT_START_BEFORE_LINE_M, pedal_action
from formula_tourney.sim.reward import RewardRule
from formula_tourney.training.envs import RunEnvs
from formula_tourney.training.run_spec import DEMO_BOT, RunSpec


@dataclass
class DemoDrive:
    """The follower's drive on one track: its laps and how many steps it took."""

    track: str
    lap_times_s: list[float] = field(default_factory=list)
    lap_damage: list[float] = field(default_factory=list)
    steps: int = 0
    episodes: int = 0

    @property
    def best_lap_s(self) -> float:
        """Best lap with zero lap damage; nan if none."""
        clean = [t for t, d in zip(self.lap_times_s, self.lap_damage, strict=True) if d <= 0.0]
        return min(clean) if clean else math.nan


@dataclass
class Demonstrations:
    """The demonstration buffer and the drives that filled it."""

    buffer: ReplayBuffer
    drives: dict[str, DemoDrive]
    line: str
    key_lap_s: float = math.nan

    @property
    def transitions(self) -> int:
        return len(self.buffer)

    def summary(self, key_track: str) -> dict[str, Any]:
        """What summary.json records: who demonstrated, on which line, and its lap time."""
        lap = self.key_lap_s
        return {
            "bot": DEMO_BOT,
            "line": self.line,
            "track": key_track,
            "lap_s": lap if math.isfinite(lap) else None,
            "laps": int(sum(len(d.lap_times_s) for d in self.drives.values())),
            "transitions": self.transitions,
        }


def follower_for(envs: RunEnvs, track: str, line: str) -> Follower:
    """The follower on ``line`` of ``track`` for the run's car and control period."""
    spec = envs.spec
    car = spec.env.car_params()
    offsets = reference_offsets(envs.tracks[track], line, car)
    config = FollowerConfig(control_period_s=spec.env.control_period_s)
    return Follower(envs.tracks[track], np.asarray(offsets, dtype=float), car, config)


def drive_laps(
    track: str,
    env: Any,
    bot: Follower,
    laps: int,
    rng: np.random.Generator,
    step_cap: int,
    buffer: ReplayBuffer | None = None,
    reward_rule: RewardRule | None = None,
    start_s_m: float | None = None,
) -> DemoDrive:
    """Let ``bot`` drive ``env`` until ``laps`` timed laps are done (or ``step_cap`` steps),
    resetting after each end with a seed drawn from ``rng``; every step goes into ``buffer``
    (with the reward of ``reward_rule``, as the agent's own; the env's reward without one)
    when one is given."""
    drive = DemoDrive(track=track)
    pedal = env.action_space.shape == (2,)
    store = reward_rule or RewardRule()
    options = {} if start_s_m is None else {"start_s_m": float(start_s_m)}
    while len(drive.lap_times_s) < laps and drive.steps < step_cap:
        obs, info = env.reset(seed=int(rng.integers(2**31 - 1)), options=options)
        bot.reset()
        drive.episodes += 1
        ended = False
        while True:
            action = np.asarray(bot.act(_car_state(env)), dtype=np.float32)
            if pedal:  # the bot's (steer, throttle, brake) as the env's (steer, pedal)
                action = pedal_action(action)
            next_obs, reward, terminated, truncated, info = env.step(action)
            drive.steps += 1
            ended = bool(terminated or truncated)
            if buffer is not None:
                stored = store(float(reward), bool(terminated))
                buffer.add(obs, action, stored, next_obs, bool(terminated), bool(truncated))
            done = len(drive.lap_times_s) + int(info["laps"]) >= laps
            if ended or done or drive.steps >= step_cap:
                break
            obs = next_obs
        drive.lap_times_s += [float(t) for t in info["lap_times_s"]]
        drive.lap_damage += [float(d) for d in info["lap_damage"]]
        if buffer is not None and not ended:
            buffer.end_episode()  # cut after the last lap: no terminal flag, a new episode id
    return drive


def _step_cap(bot: Follower, laps: int, period_s: float, max_steps: int) -> int:
    """Generous: three QSS laps' steps per lap asked, plus one training episode."""
    return int(3.0 * laps * bot.profile.lap_time_s / period_s) + max_steps


def collect_demonstrations(
    spec: RunSpec, envs: RunEnvs, obs_dim: int, action_dim: int, seed: np.random.SeedSequence
) -> Demonstrations:
    """The follower's ``spec.demos.laps`` laps on each train track, in the training env, stored
    in a buffer with the agent's n-step, window and target rules; ``seed`` seeds the env resets
    and the buffer's sampling."""
    settings, cfg = spec.demos, spec.agent
    assert settings is not None
    reset_seq, buffer_seq = seed.spawn(2)
    rng = np.random.default_rng(reset_seq)
    period = spec.env.control_period_s
    tracks = list(dict.fromkeys(spec.train_tracks))
    bots = {name: follower_for(envs, name, settings.line) for name in tracks}
    caps = {n: _step_cap(b, settings.laps, period, spec.schedule.max_steps)
            for n, b in bots.items()}  # fmt: skip
    buffer = ReplayBuffer(
        sum(caps.values()), obs_dim, action_dim, gamma=cfg.gamma, n_step=cfg.n_step,
        window=cfg.window, bootstrap_on_truncation=cfg.adopted_target,
        seed=buffer_seq,  # type: ignore[arg-type]
    )  # fmt: skip
    drives: dict[str, DemoDrive] = {}
    for name in tracks:
        env = envs.make(name, test=False)
        drives[name] = drive_laps(name, env, bots[name], settings.laps, rng, caps[name], buffer,
                                  RewardRule.of(cfg))  # fmt: skip
        env.close()
    key = spec.key_track
    if key in drives:
        key_lap = drives[key].best_lap_s
    else:  # a test-only key track: the bot's laps there from the tests' canonical start
        bot = follower_for(envs, key, settings.line)
        cap = _step_cap(bot, settings.laps, period, spec.schedule.test_max_steps)
        env = envs.make(key, test=True, max_steps=cap)
        start = envs.tracks[key].length_m - DEFAULT_START_BEFORE_LINE_M
        key_lap = drive_laps(key, env, bot, settings.laps, rng, cap, start_s_m=start).best_lap_s
        env.close()
    return Demonstrations(buffer=buffer, drives=drives, line=settings.line, key_lap_s=key_lap)


def behaviour_clone(
    agent: Any, demos: ReplayBuffer, steps: int, batch_size: int, lr: float
) -> tuple[float, float]:
    """Fit the actor to the demonstrated actions before RL: ``steps`` Adam steps on
    ``mean((mu(window) - a)^2)`` over batches drawn from ``demos``; the target actor then
    copies the actor. Returns the MSE over every demonstration before and after.

    The agent's parameters have their ``.grad`` bound to one flat gradient buffer
    (``agents.core``): gradients are zeroed in place (never set to None) and left at zero.
    """
    actor = agent.actor
    params = list(actor.parameters())
    optimizer = torch.optim.Adam(params, lr=lr)
    device = agent.device
    everything = demos.gather(np.arange(len(demos)), np.ones(len(demos)))

    def mse(observations: np.ndarray, actions: np.ndarray) -> torch.Tensor:
        obs = agent.normalise(torch.from_numpy(observations).to(device))
        target = torch.from_numpy(actions).to(device)
        return (actor(obs) - target).square().mean()

    with torch.no_grad():
        before = float(mse(everything.observations, everything.actions))
    for _ in range(steps):
        batch = demos.sample(batch_size)
        optimizer.zero_grad(set_to_none=False)
        mse(batch.observations, batch.actions).backward(inputs=params)
        optimizer.step()
    optimizer.zero_grad(set_to_none=False)
    agent.sync_actor_copies()
    with torch.no_grad():
        after = float(mse(everything.observations, everything.actions))
    return before, after

"""One training run: env + DDPG variant + periodic greedy tests, written as a job folder.

The run is fully described by its :class:`~formula_tourney.training.run_spec.RunSpec`, built and
validated by the caller; nothing here re-defaults or re-checks a setting. Files go through
``results.folder.JobFolder`` (the one owner of the layout): ``config.json`` first, tables and
checkpoints as they come, ``summary.json`` last (its presence means finished).

One loop serves every configuration: each step acts for every car (the greedy actor plus the
car's own exploration noise), steps the cars through a collector (``training.collect``: one car,
or ``schedule.cars`` cars of the vector env, each into its own lane of the one buffer), then
earns ``agent.updates_per_step`` updates per stored transition once learning has started and
spends them. Each finished car-episode is one ``episodes.parquet`` row, and the tests and the
progress callback follow the count of finished car-episodes. Every test row records the
CPU-seconds the run had spent when its round ended (``cpu_s``, ``training.budget.CpuClock``), and
a schedule's ``budget_cpu_s`` or ``stop_at`` ends the run (``training.budget.StopRule``). With
``spec.demos`` the follower's laps (``training.demos``) fill a demonstration buffer before the
first step, the actor may be warm-started on them by behaviour cloning, and every batch draws its
share of rows from them (``agents.buffers.DemoMix``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.tensorboard import SummaryWriter

from formula_tourney.agents.buffers import DemoMix, make_buffer
from formula_tourney.agents.checkpoints import save_checkpoint
from formula_tourney.agents.core import Agent, configure_torch
from formula_tourney.agents.families import make_agent
from formula_tourney.agents.mlp_update import BCLoss
from formula_tourney.agents.noise import BrakeExplorationNoise, linear_epsilon
from formula_tourney.results.folder import JobFolder
from formula_tourney.results.layout import BEST_CHECKPOINT, LAST_CHECKPOINT
from formula_tourney.results.metrics import model_clean_lap_s
from formula_tourney.safeio import make_dirs
from formula_tourney.sim.reward import RewardRule
from formula_tourney.training.budget import CpuClock, StopRule
from formula_tourney.training.collect import SingleCarCollector, VectorCollector, split_cars
from formula_tourney.training.demos import behaviour_clone, collect_demonstrations
from formula_tourney.training.envs import RunEnvs
from formula_tourney.training.evaluate import (
    drive_seed,
    laps_rows,
    other_grip_tests,
    run_test_episode,
    start_positions,
    tests_row,
)
from formula_tourney.training.run_spec import RunSpec

Progress = Callable[[dict[str, Any]], Any]


class DivergedError(RuntimeError):
    """A loss became NaN or infinite: the run is unusable and is reported as failed."""


def _nan_to_none(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _greedy_actions(agent: Agent, windows: np.ndarray) -> np.ndarray:
    """mu(s) of every car in one actor forward ``(N, w, D) -> (N, 3)``: 6-12 us per car at 8-32
    cars against ~40 us for one ``agent.act`` per car (400-300 actor, one thread, measured)."""
    with torch.no_grad():
        return agent.actor(torch.from_numpy(windows).to(agent.device)).cpu().numpy()


def train(
    spec: RunSpec, out_dir: str | Path, progress: Progress | None = None
) -> dict[str, Any]:
    """Train ``spec`` and write its job folder under ``out_dir``; returns the summary.

    ``progress(dict(episode=, episodes=, best_lap_s=, env_steps=, updates=, seconds=, cpu_s=))``
    is called after each finished (car-)episode; if it returns ``False`` the run stops early
    (pruned trials) and still writes its summary, as it does when its :class:`StopRule` says so.
    ``env_steps`` counts stored transitions (car-steps) over all cars; ``cpu_s`` the CPU-seconds
    since training started. Raises DivergedError on NaN losses.
    """
    agent_cfg = spec.agent
    schedule = spec.schedule
    stop_rule = StopRule.of(spec)  # drives the bot to beat and warms up: before the clock
    clock = CpuClock()
    clock.start()
    envs = RunEnvs(spec)
    folder = JobFolder(out_dir)
    out = folder.path

    # --- seeding: one block ------------------------------------------------------------------
    configure_torch(spec.threads)
    # spawn(4)'s first three children are spawn(3)'s: adding the demo stream moved no run
    env_seq, noise_seq, buf_seq, demo_seq = np.random.SeedSequence(spec.seed).spawn(4)
    rng = np.random.default_rng(env_seq)
    cars = schedule.cars

    if cars == 1:
        train_envs = {n: envs.make(n, test=False) for n in dict.fromkeys(spec.train_tracks)}
    else:
        train_envs = {n: envs.make_vector(n, k) for n, k in split_cars(cars, spec.train_tracks)}
    test_envs: dict[str, Any] = {}
    first_env = next(iter(train_envs.values()))
    single = cars == 1  # a vector env describes one car by its single_* spaces
    obs_space = first_env.observation_space if single else first_env.single_observation_space
    act_space = first_env.action_space if single else first_env.single_action_space
    obs_dim = int(np.prod(obs_space.shape))
    action_dim = int(np.prod(act_space.shape))
    agent = make_agent(agent_cfg, obs_dim, action_dim, device=spec.device, seed=spec.seed)
    buffer = make_buffer(
        agent_cfg.buffer_size, obs_dim, action_dim, prioritized=agent_cfg.prioritized,
        gamma=agent_cfg.gamma, n_step=agent_cfg.n_step, window=agent_cfg.window,
        bootstrap_on_truncation=agent_cfg.adopted_target, seed=buf_seq,  # type: ignore[arg-type]
        alpha=agent_cfg.per_alpha, beta=agent_cfg.per_beta0, lambda3=agent_cfg.per_lambda3,
        eps=agent_cfg.per_eps, lanes=cars,
    )  # fmt: skip
    noise_seeds = [noise_seq] if cars == 1 else noise_seq.spawn(cars)
    noises = [
        BrakeExplorationNoise(
            np.random.default_rng(seq), agent_cfg.ou_theta, agent_cfg.ou_sigma,
            agent_cfg.noise_prob, agent_cfg.brake_explore_prob, agent_cfg.brake_explore_mean,
            agent_cfg.brake_explore_sigma, agent_cfg.brake_explore_hold_steps, action_dim,
        )
        for seq in noise_seeds
    ]  # fmt: skip

    # --- demonstrations: a second buffer every batch draws from, and the BC warm start -------
    sampler: Any = buffer  # what batches are drawn from
    priority_sink: Any = buffer  # what agent.update hands PER priorities to
    demo_summary: dict[str, Any] | None = None
    demo_seconds = 0.0  # driving and cloning count as training time (``seconds``)
    bc_loss: BCLoss | None = None  # cloning in the actor's loss, all run long
    if spec.demos is not None:
        t_demo = time.perf_counter()
        demos = collect_demonstrations(spec, envs, obs_dim, action_dim, seed=demo_seq)
        mix = DemoMix(buffer, demos.buffer, spec.demos.demo_rows(agent_cfg.batch_size))
        sampler, priority_sink = mix, mix.priorities(agent_cfg.batch_size)
        demo_summary = demos.summary(spec.key_track)
        if spec.demos.bc_steps > 0:
            bc = behaviour_clone(agent, demos.buffer, spec.demos.bc_steps,
                                 agent_cfg.batch_size, spec.demos.bc_lr)  # fmt: skip
            demo_summary.update(bc_mse_before=bc[0], bc_mse_after=bc[1])
        if spec.demos.bc_weight > 0.0:  # RunSpec checked that every batch has demo rows
            bc_loss = BCLoss(spec.demos.bc_weight, mix.demo_rows, spec.demos.bc_q_filter)
        demo_seconds = time.perf_counter() - t_demo
        stop_rule = stop_rule.with_demonstrator(demo_summary.get("lap_s"))

    make_dirs(out, "job folder")
    spec_json = spec.to_json()
    folder.write_config(spec_json, spec.beyond_paper())
    writer = SummaryWriter(str(folder.tb_dir))

    episodes_rows: list[dict[str, Any]] = []
    test_table: list[dict[str, Any]] = []
    grip_test_table: list[dict[str, Any]] = []  # the other test grips: written, not summarised
    lap_table: list[dict[str, Any]] = []
    best_traces: dict[str, float] = {}
    key_track = spec.key_track
    best_key_lap = math.inf
    env_steps = 0
    update_credit = 0.0
    # learning starts at the transition that reaches learning_starts with a batch stored
    learn_from = max(agent_cfg.learning_starts, agent_cfg.batch_size)
    t0 = time.perf_counter() - demo_seconds
    episode = 0

    def run_tests() -> None:
        nonlocal best_key_lap
        round_rows = [test_table, grip_test_table]
        first_rows = [len(rows) for rows in round_rows]
        ckpt_rel = ""
        if schedule.save_test_checkpoints:
            ckpt_rel = folder.checkpoint_rel(f"ep-{episode}.pt")
            save_checkpoint(
                agent, folder.path / ckpt_rel, extra={"episode": episode, "run_spec": spec_json}
            )
        for name in spec.test_tracks:
            env = test_envs.get(name) or test_envs.setdefault(name, envs.make(name, test=True))
            starts = start_positions(envs.tracks[name].length_m, schedule.test_starts)
            drives = [
                run_test_episode(agent, env, name, s0, seed=drive_seed(spec.seed, k))
                for k, s0 in enumerate(starts)
            ]
            for drive in drives:
                limit = envs.test_limit_s(name, drive.grip_scale)
                test_table.append(tests_row(drive, episode, env_steps, ckpt_rel, limit))
                lap_table.extend(laps_rows(drive, episode))
            grip_tests, grip_laps = other_grip_tests(  # schedule.test_grip_scales; tables only
                agent, envs, name, test_envs, episode=episode, env_steps=env_steps,
                checkpoint=ckpt_rel, run_seed=spec.seed)
            grip_test_table.extend(grip_tests)
            lap_table.extend(grip_laps)
            # the model's clean lap, as every table and promotion counts it (results.metrics)
            best_here = model_clean_lap_s([d.best_lap_s for d in drives],
                                          [d.damage for d in drives])  # fmt: skip
            if best_here < best_traces.get(name, math.inf):
                best_traces[name] = best_here
                fastest = next(d for d in drives if d.best_lap_s == best_here)
                folder.write_trace(name, fastest.best_trace)
            if math.isfinite(best_here):
                writer.add_scalar(f"test/best_lap_s/{name}", best_here, env_steps)
            if name == key_track and best_here < best_key_lap:
                best_key_lap = best_here
                save_checkpoint(
                    agent, folder.checkpoint_path(BEST_CHECKPOINT),
                    extra={"episode": episode, "best_lap_s": best_here, "track": name,
                           "run_spec": spec_json},
                )  # fmt: skip
        cpu_s = clock.seconds()  # the round's CPU-seconds: what its milestones are timed at
        for rows, first in zip(round_rows, first_rows, strict=True):
            for row in rows[first:]:
                row["cpu_s"] = cpu_s
        # last.pt is refreshed at every test (a crashed run can still be inspected) and at the end
        save_checkpoint(
            agent,
            folder.checkpoint_path(LAST_CHECKPOINT),
            extra={"episode": episode, "run_spec": spec_json},
        )
        _write_tables()

    def _write_tables() -> None:
        folder.write_tables(episodes_rows, test_table + grip_test_table, lap_table)

    def learn(stored: int) -> None:
        """Earn updates for the ``stored`` transitions of this step and spend them."""
        nonlocal update_credit
        eligible = min(stored, env_steps - learn_from + 1)
        if eligible <= 0 or len(buffer) < agent_cfg.batch_size:
            return
        update_credit += eligible * agent_cfg.updates_per_step  # 1 * x == x: N = 1 unchanged
        while update_credit >= 1.0:
            update_credit -= 1.0
            if agent_cfg.prioritized:
                frac = min(1.0, agent.updates / agent_cfg.per_beta_steps)
                buffer.beta = agent_cfg.per_beta0 + (1.0 - agent_cfg.per_beta0) * frac
            stats = agent.update(sampler.sample(agent_cfg.batch_size), priority_sink, bc=bc_loss)
            if not (math.isfinite(stats.critic_loss) and math.isfinite(stats.actor_loss)):
                writer.close()
                _write_tables()
                raise DivergedError(
                    f"{spec.variant} seed {spec.seed}: loss became {stats.critic_loss} / "
                    f"{stats.actor_loss} at update {agent.updates}, episode {episode + 1}"
                )
            if agent.updates % 250 == 0:
                writer.add_scalar("loss/critic", stats.critic_loss, agent.updates)
                writer.add_scalar("loss/actor", stats.actor_loss, agent.updates)
                writer.add_scalar("q/mean", stats.q_mean, agent.updates)
                writer.add_scalar("q/td_abs", stats.td_abs_mean, agent.updates)

    collector: SingleCarCollector | VectorCollector
    reward_rule = RewardRule.of(agent_cfg)
    if cars == 1:
        collector = SingleCarCollector(train_envs, spec.train_tracks, rng, buffer,
                                       agent_cfg.window, reward_rule)  # fmt: skip
    else:
        collector = VectorCollector(
            list(train_envs.items()), [int(rng.integers(2**31 - 1)) for _ in train_envs],
            buffer, agent_cfg.window, reward_rule,
        )  # fmt: skip
    stopped_early = False
    stopped_by: str | None = None
    epsilon = 1.0
    samples_its_policy = not agent_cfg.uses_action_noise  # decided once, not every step
    last = False
    while not last and not stopped_early:
        for car in collector.started:
            noises[car].reset()
        epsilon = linear_epsilon(env_steps, agent_cfg.exploration_steps, agent_cfg.epsilon_floor)
        if samples_its_policy:  # SAC explores by sampling its own policy
            actions = [agent.explore(window) for window in collector.windows]
        elif cars == 1:
            actions = [noises[0](agent.act(collector.windows[0]), epsilon)[0]]
        else:
            greedy = _greedy_actions(agent, collector.windows)
            actions = [noises[car](greedy[car], epsilon)[0] for car in range(cars)]
        finished = collector.step(actions)
        env_steps += collector.stored
        learn(collector.stored)
        for ended in finished:
            episode += 1
            seconds = time.perf_counter() - t0
            episodes_rows.append({
                "episode": episode, "track": ended.track, "reward": ended.reward,
                "steps": ended.steps, "env_steps": env_steps, "updates": agent.updates,
                "laps": ended.laps, "best_lap_s": ended.best_lap_s, "damage": ended.damage,
                "termination": ended.termination, "epsilon": epsilon, "seconds": seconds,
            })  # fmt: skip
            writer.add_scalar("train/reward", ended.reward, env_steps)
            writer.add_scalar("train/steps", ended.steps, env_steps)
            writer.add_scalar("train/laps", ended.laps, env_steps)
            writer.add_scalar("train/epsilon", epsilon, env_steps)
            budget_spent = schedule.env_steps is not None and env_steps >= schedule.env_steps
            last = budget_spent or episode == schedule.episodes
            if episode % schedule.test_every_episodes == 0 or last:
                run_tests()
            cpu_s = clock.seconds()
            if progress is not None:
                answer = progress({
                    "episode": episode, "episodes": schedule.episodes,
                    "best_lap_s": _nan_to_none(best_key_lap), "env_steps": env_steps,
                    "updates": agent.updates, "seconds": time.perf_counter() - t0,
                    "cpu_s": cpu_s,
                })  # fmt: skip
                if answer is False:
                    stopped_early, stopped_by = True, "progress"
            if not stopped_early and stop_rule.active:
                stopped_by = stop_rule.reason(best_key_lap, cpu_s)
                stopped_early = stopped_by is not None
            if stopped_early or last:
                break
    if stopped_early and not test_table:
        run_tests()
    last_episode = episode
    save_checkpoint(
        agent,
        folder.checkpoint_path(LAST_CHECKPOINT),
        extra={"episode": last_episode, "run_spec": spec_json},
    )
    _write_tables()
    writer.close()
    key_rows = [r for r in test_table if r["track"] == key_track]
    summary = {
        "best_lap_s": _nan_to_none(best_key_lap),
        "track": key_track,
        "laps": int(sum(r["laps"] for r in test_table)),
        "damage": float(sum(r["damage"] for r in test_table)),
        "finished": bool(any(r["finished"] for r in key_rows)),
        "episodes": last_episode,
        "env_steps": env_steps,
        "updates": agent.updates,
        "seconds": time.perf_counter() - t0,
        "cpu_s": clock.seconds(),
        "stopped_early": stopped_early,
    }
    if stopped_by is not None:
        summary["stopped_by"] = stopped_by
    if demo_summary is not None:  # who demonstrated: the report's "with demos" label needs it
        summary["demos"] = demo_summary
    folder.write_summary(summary)
    for e in list(train_envs.values()) + list(test_envs.values()):
        e.close()
    return summary

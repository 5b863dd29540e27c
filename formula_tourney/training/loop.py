"""One training run: env + DDPG variant + periodic greedy tests, written as a job folder.

The run is fully described by its :class:`~formula_tourney.training.spec.RunSpec`, built and
validated by the caller; nothing here re-defaults or re-checks a setting. Files go through
``results.folder.JobFolder`` (the one owner of the layout): ``config.json`` first, tables and
checkpoints as they come, ``summary.json`` last (its presence means finished).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from torch.utils.tensorboard import SummaryWriter

from formula_tourney.agents.ddpg import DDPGAgent, configure_torch, save_checkpoint
from formula_tourney.agents.noise import BrakeExplorationNoise, linear_epsilon
from formula_tourney.agents.replay import ObservationWindow, make_buffer
from formula_tourney.results.folder import JobFolder
from formula_tourney.results.layout import BEST_CHECKPOINT, LAST_CHECKPOINT
from formula_tourney.results.metrics import model_clean_lap_s
from formula_tourney.training.envs import RunEnvs
from formula_tourney.training.evaluate import (
    laps_rows,
    run_test_episode,
    start_positions,
    tests_row,
)
from formula_tourney.training.spec import RunSpec

Progress = Callable[[dict[str, Any]], Any]


class DivergedError(RuntimeError):
    """A loss became NaN or infinite: the run is unusable and is reported as failed."""


def _nan_to_none(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def train(
    spec: RunSpec, out_dir: str | Path, progress: Progress | None = None
) -> dict[str, Any]:
    """Train ``spec`` and write its job folder under ``out_dir``; returns the summary.

    ``progress(dict(episode=, episodes=, best_lap_s=, env_steps=, updates=, seconds=))`` is called
    after each episode; if it returns ``False`` the run stops early (time budgets, benchmarks) and
    still writes its summary. Raises DivergedError on NaN losses.
    """
    agent_cfg = spec.agent
    schedule = spec.schedule
    envs = RunEnvs(spec)
    folder = JobFolder(out_dir)
    out = folder.path

    # --- seeding: one block ------------------------------------------------------------------
    configure_torch(spec.threads)
    env_seq, noise_seq, buf_seq = np.random.SeedSequence(spec.seed).spawn(3)
    rng = np.random.default_rng(env_seq)

    train_envs = {name: envs.make(name, test=False) for name in dict.fromkeys(spec.train_tracks)}
    test_envs: dict[str, Any] = {}
    first_env = next(iter(train_envs.values()))
    obs_dim = int(np.prod(first_env.observation_space.shape))
    action_dim = int(np.prod(first_env.action_space.shape))
    agent = DDPGAgent(agent_cfg, obs_dim, action_dim, device=spec.device, seed=spec.seed)
    buffer = make_buffer(
        agent_cfg.buffer_size, obs_dim, action_dim, prioritized=agent_cfg.prioritized,
        gamma=agent_cfg.gamma, n_step=agent_cfg.n_step, window=agent_cfg.window,
        bootstrap_on_truncation=agent_cfg.adopted_target, seed=buf_seq,  # type: ignore[arg-type]
        alpha=agent_cfg.per_alpha, beta=agent_cfg.per_beta0, lambda3=agent_cfg.per_lambda3,
        eps=agent_cfg.per_eps,
    )  # fmt: skip
    noise = BrakeExplorationNoise(
        np.random.default_rng(noise_seq), agent_cfg.ou_theta, agent_cfg.ou_sigma,
        agent_cfg.noise_prob, agent_cfg.brake_explore_prob, agent_cfg.brake_explore_mean,
        agent_cfg.brake_explore_sigma,
    )  # fmt: skip
    window = ObservationWindow(agent_cfg.window)

    out.mkdir(parents=True, exist_ok=True)
    spec_json = spec.to_json()
    folder.write_config(spec_json)
    writer = SummaryWriter(str(folder.tb_dir))

    episodes_rows: list[dict[str, Any]] = []
    test_table: list[dict[str, Any]] = []
    lap_table: list[dict[str, Any]] = []
    best_traces: dict[str, float] = {}
    key_track = spec.key_track
    best_key_lap = math.inf
    env_steps = 0
    update_credit = 0.0
    t0 = time.perf_counter()
    episode = 0

    def run_tests() -> None:
        nonlocal best_key_lap
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
                run_test_episode(agent, env, name, s0, seed=spec.seed * 1000 + k)
                for k, s0 in enumerate(starts)
            ]
            for drive in drives:
                test_table.append(tests_row(drive, episode, env_steps, ckpt_rel))
                lap_table.extend(laps_rows(drive, episode))
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
        # last.pt is refreshed at every test (a crashed run can still be inspected) and at the end
        save_checkpoint(
            agent,
            folder.checkpoint_path(LAST_CHECKPOINT),
            extra={"episode": episode, "run_spec": spec_json},
        )
        _write_tables()

    def _write_tables() -> None:
        folder.write_tables(episodes_rows, test_table, lap_table)

    train_names = list(spec.train_tracks)
    stopped_early = False
    for episode in range(1, schedule.episodes + 1):
        name = train_names[int(rng.integers(len(train_names)))]
        env = train_envs[name]
        obs, info = env.reset(seed=int(rng.integers(2**31 - 1)))
        stack = window.reset(obs)
        noise.reset()
        ep_reward, steps, epsilon = 0.0, 0, 1.0
        while True:
            epsilon = linear_epsilon(env_steps, agent_cfg.exploration_steps)
            action, _ = noise(agent.act(stack), epsilon)
            next_obs, reward, terminated, truncated, info = env.step(action)
            buffer.add(
                obs, action, float(reward) * agent_cfg.reward_scale, next_obs,
                bool(terminated), bool(truncated),
            )  # fmt: skip
            env_steps += 1
            steps += 1
            ep_reward += float(reward)
            if env_steps >= agent_cfg.learning_starts and len(buffer) >= agent_cfg.batch_size:
                update_credit += agent_cfg.updates_per_step
                while update_credit >= 1.0:
                    update_credit -= 1.0
                    if agent_cfg.prioritized:
                        frac = min(1.0, agent.updates / agent_cfg.per_beta_steps)
                        buffer.beta = agent_cfg.per_beta0 + (1.0 - agent_cfg.per_beta0) * frac
                    stats = agent.update(buffer.sample(agent_cfg.batch_size), buffer)
                    if not (math.isfinite(stats.critic_loss) and math.isfinite(stats.actor_loss)):
                        writer.close()
                        _write_tables()
                        raise DivergedError(
                            f"{spec.variant} seed {spec.seed}: loss became {stats.critic_loss} / "
                            f"{stats.actor_loss} at update {agent.updates}, episode {episode}"
                        )
                    if agent.updates % 250 == 0:
                        writer.add_scalar("loss/critic", stats.critic_loss, agent.updates)
                        writer.add_scalar("loss/actor", stats.actor_loss, agent.updates)
                        writer.add_scalar("q/mean", stats.q_mean, agent.updates)
                        writer.add_scalar("q/td_abs", stats.td_abs_mean, agent.updates)
            if terminated or truncated:
                break
            obs = next_obs
            stack = window.push(obs)
        seconds = time.perf_counter() - t0
        best_train = float(info.get("best_lap_s", math.nan))
        episodes_rows.append({
            "episode": episode, "track": name, "reward": ep_reward, "steps": steps,
            "env_steps": env_steps, "updates": agent.updates, "laps": int(info.get("laps", 0)),
            "best_lap_s": best_train, "damage": float(info.get("damage", 0.0)),
            "termination": str(info.get("termination") or ""), "epsilon": epsilon,
            "seconds": seconds,
        })  # fmt: skip
        writer.add_scalar("train/reward", ep_reward, env_steps)
        writer.add_scalar("train/steps", steps, env_steps)
        writer.add_scalar("train/laps", int(info.get("laps", 0)), env_steps)
        writer.add_scalar("train/epsilon", epsilon, env_steps)
        if episode % schedule.test_every_episodes == 0 or episode == schedule.episodes:
            run_tests()
        if progress is not None:
            answer = progress({
                "episode": episode, "episodes": schedule.episodes,
                "best_lap_s": _nan_to_none(best_key_lap), "env_steps": env_steps,
                "updates": agent.updates, "seconds": time.perf_counter() - t0,
            })  # fmt: skip
            if answer is False:
                stopped_early = True
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
        "stopped_early": stopped_early,
    }
    folder.write_summary(summary)
    for e in list(train_envs.values()) + list(test_envs.values()):
        e.close()
    return summary

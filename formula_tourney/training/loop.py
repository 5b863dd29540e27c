"""One training run: env + DDPG variant + periodic greedy tests, written as a job folder.

The folder layout is the seam the tournament builds on (docs/CONTRACTS.md, "training (one run)"):
``config.json`` first, tables and checkpoints as they come, ``summary.json`` last (its presence
means finished). Every file is written atomically, so a crash never leaves a file a resume trusts.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.safeio import atomic_write_json, atomic_write_parquet
from formula_tourney.training.config import TrainConfig

Progress = Callable[[dict[str, Any]], Any]


class DivergedError(RuntimeError):
    """A loss became NaN or infinite: the run is unusable and is reported as failed."""


def _trace_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.+-]", "_", name)[:100] or "track"


def _nan_to_none(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def load_tracks(names: list[str]) -> dict[str, Any]:
    """Load each named track once (unknown names raise UserInputError listing the known ones)."""
    try:
        from formula_tourney.sim.catalog import load_track
    except ImportError as err:
        raise UserInputError(
            f"track catalog (formula_tourney.sim.catalog) unavailable: {err}"
        ) from None
    return {name: load_track(name) for name in dict.fromkeys(names)}


def reference_for(track: Any, kind: str, car_overrides: dict[str, Any] | None) -> Any:
    """The env's ``reference_line``: "centre", or the offsets of the recorded/mincurv line."""
    if kind == "centre":
        return "centre"
    try:
        from formula_tourney.lines.registry import reference_offsets
    except ImportError as err:  # the lines area is not installed in this checkout
        raise UserInputError(
            f"reference {kind!r} needs formula_tourney.lines.registry.reference_offsets, "
            f"which is unavailable ({err}); use --reference centre"
        ) from None
    from formula_tourney.sim.car_params import CarParams

    car = CarParams(**(car_overrides or {}))
    return np.asarray(reference_offsets(track, kind, car), dtype=np.float64)


def make_env(
    track: Any,
    reference: Any,
    lac: bool,
    max_steps: int,
    random_start: bool,
    env_overrides: dict[str, Any],
) -> Any:
    """A FormulaRacing-v0 env for one track (config keys per docs/CONTRACTS.md)."""
    import gymnasium

    import formula_tourney  # noqa: F401  (registers FormulaRacing-v0)

    config = {
        "track": track,
        "reference_line": reference,
        "lac": lac,
        "max_steps": max_steps,
        "random_start": random_start,
        **env_overrides,
    }
    try:
        return gymnasium.make("FormulaRacing-v0", config=config, disable_env_checker=True)
    except ModuleNotFoundError as err:
        raise RuntimeError(f"simulator formula_tourney.sim.env unavailable: {err}") from err


def train(
    cfg: TrainConfig, out_dir: str | Path, progress: Progress | None = None
) -> dict[str, Any]:
    """Train ``cfg`` and write its job folder under ``out_dir``; returns the summary.

    ``progress(dict(episode=, episodes=, best_lap_s=, env_steps=, updates=, seconds=))`` is called
    after each episode; if it returns ``False`` the run stops early (time budgets, benchmarks) and
    still writes its summary. Raises DivergedError on NaN losses.
    """
    from formula_tourney.agents.ddpg import DDPGAgent, configure_torch, save_checkpoint
    from formula_tourney.agents.noise import BrakeExplorationNoise, linear_epsilon
    from formula_tourney.agents.replay import ObservationWindow, make_buffer
    from formula_tourney.agents.variants import get_variant
    from formula_tourney.training.evaluate import (
        laps_rows,
        run_test_episode,
        start_positions,
        tests_row,
    )

    # --- validate everything before writing anything ----------------------------------------
    agent_cfg = get_variant(cfg.variant, cfg.overrides)
    tracks = load_tracks(cfg.train_tracks + cfg.effective_test_tracks)
    car_overrides = cfg.env_overrides.get("car")
    references = {n: reference_for(t, cfg.reference, car_overrides) for n, t in tracks.items()}
    out = Path(out_dir)

    # --- seeding: one block ------------------------------------------------------------------
    configure_torch(cfg.threads)
    env_seq, noise_seq, buf_seq = np.random.SeedSequence(cfg.seed).spawn(3)
    rng = np.random.default_rng(env_seq)

    def env_for(name: str, test: bool) -> Any:
        return make_env(
            tracks[name], references[name], cfg.lac,
            cfg.test_max_steps if test else cfg.max_steps,
            False if test else cfg.random_start, cfg.env_overrides,
        )  # fmt: skip

    train_envs = {name: env_for(name, test=False) for name in dict.fromkeys(cfg.train_tracks)}
    test_envs: dict[str, Any] = {}
    first_env = next(iter(train_envs.values()))
    obs_dim = int(np.prod(first_env.observation_space.shape))
    action_dim = int(np.prod(first_env.action_space.shape))
    agent = DDPGAgent(agent_cfg, obs_dim, action_dim, device=cfg.device, seed=cfg.seed)
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
    cfg_json = cfg.model_dump(mode="json")
    atomic_write_json(out / "config.json", cfg_json)
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(out / "tb"))

    episodes_rows: list[dict[str, Any]] = []
    test_table: list[dict[str, Any]] = []
    lap_table: list[dict[str, Any]] = []
    best_traces: dict[str, tuple[float, Any]] = {}
    key_track = cfg.train_tracks[0]
    if key_track not in cfg.effective_test_tracks:
        key_track = cfg.effective_test_tracks[0]
    best_key_lap = math.inf
    env_steps = 0
    update_credit = 0.0
    t0 = time.perf_counter()
    episode = 0

    def run_tests() -> None:
        nonlocal best_key_lap
        ckpt_rel = ""
        if cfg.save_test_checkpoints:
            ckpt_rel = f"checkpoints/ep-{episode}.pt"
            save_checkpoint(
                agent, out / ckpt_rel, extra={"episode": episode, "train_config": cfg_json}
            )
        for name in cfg.effective_test_tracks:
            env = test_envs.get(name) or test_envs.setdefault(name, env_for(name, test=True))
            starts = start_positions(tracks[name].length_m, cfg.test_starts)
            best_here = math.inf
            for k, s0 in enumerate(starts):
                drive = run_test_episode(agent, env, name, s0, seed=cfg.seed * 1000 + k)
                test_table.append(tests_row(drive, episode, env_steps, ckpt_rel))
                lap_table.extend(laps_rows(drive, episode))
                if math.isfinite(drive.best_lap_s):
                    best_here = min(best_here, drive.best_lap_s)
                    if drive.best_lap_s < best_traces.get(name, (math.inf, None))[0]:
                        best_traces[name] = (drive.best_lap_s, drive.best_trace)
                        atomic_write_parquet(
                            out / "traces" / f"{_trace_name(name)}.parquet", drive.best_trace
                        )
            if math.isfinite(best_here):
                writer.add_scalar(f"test/best_lap_s/{name}", best_here, env_steps)
            if name == key_track and best_here < best_key_lap:
                best_key_lap = best_here
                save_checkpoint(
                    agent, out / "checkpoints" / "best.pt",
                    extra={"episode": episode, "best_lap_s": best_here, "track": name,
                           "train_config": cfg_json},
                )  # fmt: skip
        # last.pt is refreshed at every test (a crashed run can still be inspected) and at the end
        save_checkpoint(
            agent,
            out / "checkpoints" / "last.pt",
            extra={"episode": episode, "train_config": cfg_json},
        )
        _write_tables()

    def _write_tables() -> None:
        import pandas as pd

        atomic_write_parquet(out / "episodes.parquet", pd.DataFrame(episodes_rows, columns=[
            "episode", "track", "reward", "steps", "env_steps", "updates", "laps", "best_lap_s",
            "damage", "termination", "epsilon", "seconds"]))  # fmt: skip
        atomic_write_parquet(out / "tests.parquet", pd.DataFrame(test_table, columns=[
            "episode", "env_steps", "track", "start_s_m", "finished", "best_lap_s", "laps",
            "damage", "reward", "steps", "termination", "checkpoint"]))  # fmt: skip
        atomic_write_parquet(out / "laps.parquet", pd.DataFrame(lap_table, columns=[
            "episode", "track", "start_s_m", "lap_index", "lap_time_s", "lap_damage",
            "clean"]))  # fmt: skip

    train_names = list(cfg.train_tracks)
    stopped_early = False
    for episode in range(1, cfg.episodes + 1):
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
                            f"{cfg.variant} seed {cfg.seed}: loss became {stats.critic_loss} / "
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
        if episode % cfg.test_every_episodes == 0 or episode == cfg.episodes:
            run_tests()
        if progress is not None:
            answer = progress({
                "episode": episode, "episodes": cfg.episodes,
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
        out / "checkpoints" / "last.pt",
        extra={"episode": last_episode, "train_config": cfg_json},
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
    atomic_write_json(out / "summary.json", summary)
    for e in list(train_envs.values()) + list(test_envs.values()):
        e.close()
    return summary

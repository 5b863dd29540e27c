"""One training run: env + an entrant + periodic greedy tests, written as a job folder.

The run is fully described by its :class:`~formula_tourney.training.run_spec.RunSpec`, built and
validated by the caller; nothing here re-defaults or re-checks a setting. Files go through
``results.folder.JobFolder`` (the one owner of the layout): ``config.json`` first, tables and
checkpoints as they come, ``summary.json`` last (its presence means finished).

The loop drives any :class:`~formula_tourney.agents.protocol.Entrant`: the class and settings
come from ``agents.entrants.resolve_entrant`` (our families' ``FamilyEntrant`` unless an outside
kind claims the run). One loop serves every configuration: each step tells the entrant which
cars began an episode, asks it for every car's exploring action (one window per car), checks
the actions (:func:`checked_actions`: shape ``(cars, action_dim)``, numeric, finite; a faulty
entrant fails its job with a reason, never an env), steps the cars through a collector
(``training.collect``: one car, or ``schedule.cars`` cars of the vector env), hands the step's
stored transitions to ``entrant.observe`` and calls ``entrant.update`` once. Each finished
car-episode is one ``episodes.parquet`` row, and the tests (the entrant's greedy ``act``) and the
progress callback follow the count of finished car-episodes. Every test row records the
CPU-seconds the run had spent when its round ended (``cpu_s``, ``training.budget.CpuClock``),
and a schedule's ``budget_cpu_s`` or ``stop_at`` ends the run (``training.budget.StopRule``).
With ``spec.demos`` the follower's laps (``training.demos``) fill a demonstration buffer before
the first step, handed to the entrant (``use_demonstrations``: the BC warm start, and every
batch's share of demonstration rows, ``agents.buffers.DemoMix``). At step boundaries a run of
one car writes its resume file on schedule and on SIGTERM, and a run finds its folder's resume
file and continues from it (``training.resume``); the finished run deletes it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
from torch.utils.tensorboard import SummaryWriter

from formula_tourney.agents.core import configure_torch
from formula_tourney.agents.entrants import resolve_entrant
from formula_tourney.agents.family_entrant import TB_EVERY_UPDATES
from formula_tourney.agents.protocol import Entrant, EntrantSpaces
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
from formula_tourney.training.resume import (
    PREEMPTED,
    Preempted,
    preemption_requested,
    read_resume,
    refuse,
    rows_from_plain,
    sigterm_checkpoints,
    write_resume,
)
from formula_tourney.training.run_spec import RunSpec

Progress = Callable[[dict[str, Any]], Any]


class DivergedError(RuntimeError):
    """A loss became NaN or infinite: the run is unusable and is reported as failed."""


class EntrantError(RuntimeError):
    """An entrant returned an unusable action (wrong shape, not numeric, NaN or infinite): the
    job fails with a one-line reason naming the entrant, before any env sees the action."""


def _nan_to_none(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def checked_actions(entrant: Entrant, actions: Any, cars: int, action_dim: int) -> np.ndarray:
    """``actions`` as an array if it is one action per car, numeric and finite; else
    EntrantError naming the entrant. One ``np.isfinite`` over the array: a few microseconds."""
    out = actions if isinstance(actions, np.ndarray) else np.asarray(actions)
    if out.shape != (cars, action_dim) or out.dtype.kind not in "fiu":
        raise EntrantError(
            f"entrant {entrant.label} returned actions of shape {out.shape} and dtype "
            f"{out.dtype}, not ({cars}, {action_dim}) numbers"
        )
    if not np.isfinite(out).all():
        raise EntrantError(f"entrant {entrant.label} returned a NaN or infinite action")
    return out


class _TestDriver:
    """The entrant as ``evaluate.run_test_episode`` drives it (``cfg.window``, ``act_eval`` of
    one window): its greedy ``act`` on a batch of one, checked like every action."""

    def __init__(self, entrant: Entrant, action_dim: int) -> None:
        self.entrant = entrant
        self.action_dim = action_dim
        self.cfg = SimpleNamespace(window=entrant.window)

    def act_eval(self, window: np.ndarray) -> np.ndarray:
        actions = self.entrant.act(window[None])
        return checked_actions(self.entrant, actions, 1, self.action_dim)[0]


def _save_model(entrant: Entrant, path: Path, extra: dict[str, Any]) -> None:
    """``entrant.save``; ours also write the run's metadata into the checkpoint."""
    if getattr(entrant, "saves_metadata", False):
        entrant.save(path, extra=extra)  # type: ignore[call-arg]
    else:
        entrant.save(path)


def train(
    spec: RunSpec,
    out_dir: str | Path,
    progress: Progress | None = None,
    resume: bool | dict[str, Any] = True,
) -> dict[str, Any]:
    """Train ``spec`` and write its job folder under ``out_dir``; returns the summary.

    ``progress(dict(episode=, episodes=, best_lap_s=, env_steps=, updates=, seconds=, cpu_s=))``
    is called after each finished (car-)episode; if it returns ``False`` the run stops early
    (pruned trials) and still writes its summary, as it does when its :class:`StopRule` says so.
    ``env_steps`` counts stored transitions (car-steps) over all cars; ``cpu_s`` the CPU-seconds
    since training started. Raises DivergedError on NaN losses, EntrantError on a bad action.

    With ``resume`` True a resume file of this configuration in the folder is continued from
    (``training.resume``), a dict is such a file's state already read
    (``training.resume.read_resume``), False starts afresh. The run writes one every
    ``schedule.resume_every_cpu_s`` and, raising Preempted, on SIGTERM.
    """
    with sigterm_checkpoints():
        return _train(spec, out_dir, progress, resume)


def _train(
    spec: RunSpec, out_dir: str | Path, progress: Progress | None, resume: bool | dict[str, Any]
) -> dict[str, Any]:
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
    # spawn(4)'s first three children are spawn(3)'s: adding the demo stream moved no run; the
    # entrant draws its noise and buffer streams from children 1 and 2 itself (family_entrant)
    env_seq, _noise_seq, _buf_seq, demo_seq = np.random.SeedSequence(spec.seed).spawn(4)
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
    spaces = EntrantSpaces(
        obs_dim=obs_dim, action_dim=action_dim,
        action_low=np.asarray(act_space.low, np.float32).reshape(-1),
        action_high=np.asarray(act_space.high, np.float32).reshape(-1), cars=cars,
    )  # fmt: skip
    entrant_cls, settings = resolve_entrant(spec)
    entrant = entrant_cls.build(settings, spaces, spec.seed, spec.device)
    driver = _TestDriver(entrant, action_dim)
    resumed = resume if isinstance(resume, dict) else read_resume(folder, spec) if resume else None
    if resumed is not None:
        try:
            entrant.restore_training_state(resumed["entrant"])
        except Exception as err:  # a file of this configuration whose state does not fit
            raise refuse(folder, err) from None
    saved: dict[str, Any] = resumed["loop"] if resumed is not None else {}

    # --- demonstrations: a second buffer every batch draws from, and the BC warm start -------
    demo_summary: dict[str, Any] | None = None
    demo_seconds = 0.0  # driving and cloning count as training time (``seconds``)
    if resumed is not None:  # the entrant's state holds the demonstrations and the cloning
        demo_summary = saved["demo_summary"]
        if demo_summary is not None:
            stop_rule = stop_rule.with_demonstrator(demo_summary.get("lap_s"))
    elif spec.demos is not None:
        use_demonstrations = getattr(entrant, "use_demonstrations", None)
        if use_demonstrations is None:
            raise EntrantError(f"entrant {entrant.label} does not learn from demonstrations")
        t_demo = time.perf_counter()
        demos = collect_demonstrations(spec, envs, obs_dim, action_dim, seed=demo_seq)
        demo_summary = demos.summary(spec.key_track)
        warm_start = None
        if spec.demos.bc_steps > 0:
            bc_steps, bc_lr = spec.demos.bc_steps, spec.demos.bc_lr

            def warm_start(agent: Any) -> tuple[float, float]:
                return behaviour_clone(agent, demos.buffer, bc_steps, agent_cfg.batch_size,
                                       bc_lr)  # fmt: skip

        bc = use_demonstrations(
            demos.buffer, spec.demos.demo_rows(agent_cfg.batch_size), spec.demos.bc_weight,
            spec.demos.bc_q_filter, warm_start,
        )  # fmt: skip
        if bc is not None:
            demo_summary.update(bc_mse_before=bc[0], bc_mse_after=bc[1])
        demo_seconds = time.perf_counter() - t_demo
        stop_rule = stop_rule.with_demonstrator(demo_summary.get("lap_s"))

    make_dirs(out, "job folder")
    spec_json = spec.to_json()
    folder.write_config(spec_json, spec.beyond_paper())
    writer = SummaryWriter(str(folder.tb_dir))

    tables = saved.get("tables", {})
    episodes_rows: list[dict[str, Any]] = rows_from_plain(tables.get("episodes", []))
    test_table: list[dict[str, Any]] = rows_from_plain(tables.get("tests", []))
    # the other test grips: written, not summarised
    grip_test_table: list[dict[str, Any]] = rows_from_plain(tables.get("grip_tests", []))
    lap_table: list[dict[str, Any]] = rows_from_plain(tables.get("laps", []))
    best_traces: dict[str, float] = dict(saved.get("best_traces", {}))
    key_track = spec.key_track
    best_key_lap = float(saved.get("best_key_lap", math.inf))
    env_steps = int(saved.get("env_steps", 0))
    logged_updates = int(saved.get("logged_updates", 0))  # the count at the last TB loss point
    t0 = time.perf_counter() - demo_seconds - float(saved.get("seconds", 0.0))
    episode = int(saved.get("episode", 0))
    if resumed is not None:
        clock.resume_from(float(saved["cpu_s"]))
        rng.bit_generator.state = saved["rng"]  # the current episode's start draws

    def updates() -> int:
        """The entrant's gradient updates so far, where it counts them (ours do)."""
        return int(getattr(entrant, "updates", 0))

    def run_tests() -> None:
        nonlocal best_key_lap
        round_rows = [test_table, grip_test_table]
        first_rows = [len(rows) for rows in round_rows]
        ckpt_rel = ""
        if schedule.save_test_checkpoints:
            ckpt_rel = folder.checkpoint_rel(f"ep-{episode}.pt")
            _save_model(entrant, folder.path / ckpt_rel,
                        {"episode": episode, "run_spec": spec_json})  # fmt: skip
        for name in spec.test_tracks:
            env = test_envs.get(name) or test_envs.setdefault(name, envs.make(name, test=True))
            starts = start_positions(envs.tracks[name].length_m, schedule.test_starts)
            drives = [
                run_test_episode(driver, env, name, s0, seed=drive_seed(spec.seed, k))
                for k, s0 in enumerate(starts)
            ]
            for drive in drives:
                limit = envs.test_limit_s(name, drive.grip_scale)
                test_table.append(tests_row(drive, episode, env_steps, ckpt_rel, limit))
                lap_table.extend(laps_rows(drive, episode))
            grip_tests, grip_laps = other_grip_tests(  # schedule.test_grip_scales; tables only
                driver,
                envs,
                name,
                test_envs,
                episode=episode,
                env_steps=env_steps,
                checkpoint=ckpt_rel,
                run_seed=spec.seed,
            )
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
                _save_model(
                    entrant, folder.checkpoint_path(BEST_CHECKPOINT),
                    {"episode": episode, "best_lap_s": best_here, "track": name,
                     "run_spec": spec_json},
                )  # fmt: skip
        cpu_s = clock.seconds()  # the round's CPU-seconds: what its milestones are timed at
        for rows, first in zip(round_rows, first_rows, strict=True):
            for row in rows[first:]:
                row["cpu_s"] = cpu_s
        # last.pt is refreshed at every test (a crashed run can still be inspected) and at the end
        _save_model(entrant, folder.checkpoint_path(LAST_CHECKPOINT),
                    {"episode": episode, "run_spec": spec_json})  # fmt: skip
        _write_tables()

    def _write_tables() -> None:
        folder.write_tables(episodes_rows, test_table + grip_test_table, lap_table)

    def learn() -> None:
        """One ``entrant.update``: its losses checked, logged every TB_EVERY_UPDATES updates."""
        nonlocal logged_updates
        losses = entrant.update(env_steps)
        if not losses:
            return
        if not all(math.isfinite(v) for v in losses.values()):
            writer.close()
            _write_tables()
            shown = " / ".join(f"{k} {v}" for k, v in losses.items() if k != "updates")
            raise DivergedError(
                f"{spec.variant} seed {spec.seed}: {entrant.label}: loss became {shown} at "
                f"update {updates()}, episode {episode + 1}"
            )
        count = updates()
        if count // TB_EVERY_UPDATES > logged_updates // TB_EVERY_UPDATES:
            for key, value in losses.items():
                if key != "updates":
                    writer.add_scalar(f"loss/{key}", value, count)
            logged_updates = count

    collector: SingleCarCollector | VectorCollector
    reward_rule = RewardRule.of(agent_cfg)
    penalty_decays = reward_rule.decays  # then each step is stored with the rule of its step
    if cars == 1:
        collector = SingleCarCollector(train_envs, spec.train_tracks, rng, None,
                                       entrant.window, reward_rule)  # fmt: skip
        if resumed is not None:
            collector.replay(list(np.asarray(saved["actions"])))
    else:
        collector = VectorCollector(
            list(train_envs.items()), [int(rng.integers(2**31 - 1)) for _ in train_envs],
            None, entrant.window, reward_rule,
        )  # fmt: skip
    resume_every_cpu_s = schedule.resume_every_cpu_s
    saved_at_cpu_s = clock.seconds()

    def save_resume() -> None:
        """The resume file (``training.resume``): the entrant's state and the loop's."""
        assert isinstance(collector, SingleCarCollector)
        actions = collector.episode_actions
        loop_state = {
            "episode": episode, "env_steps": env_steps, "logged_updates": logged_updates,
            "best_key_lap": best_key_lap, "best_traces": best_traces,
            "seconds": time.perf_counter() - t0, "cpu_s": clock.seconds(),
            "rng": collector.start_rng_state,
            "actions": np.stack(actions) if actions else np.zeros((0, action_dim), np.float32),
            "demo_summary": demo_summary,
            "tables": {"episodes": episodes_rows, "tests": test_table,
                       "grip_tests": grip_test_table, "laps": lap_table},
        }  # fmt: skip
        write_resume(folder, spec, entrant.training_state(), loop_state)

    stopped_early = False
    stopped_by: str | None = None
    last = False
    while not last and not stopped_early:
        # a step boundary: the resume file on schedule and on SIGTERM (one car: resumable)
        if preemption_requested():
            writer.close()
            if cars == 1:
                save_resume()
                raise Preempted(f"{PREEMPTED}: {folder.resume_path}")
            raise Preempted(f"preempted: a run of {cars} cars starts again when run again")
        if cars == 1 and clock.seconds() - saved_at_cpu_s >= resume_every_cpu_s:
            save_resume()
            saved_at_cpu_s = clock.seconds()
        for car in collector.started:
            entrant.episode_started(car)
        windows = collector.windows
        if cars == 1:
            windows = windows[0][None]
        actions = checked_actions(entrant, entrant.explore(windows, env_steps), cars, action_dim)
        if penalty_decays:
            collector.reward_rule = reward_rule.at(env_steps)
        finished = collector.step(actions)
        env_steps += collector.stored
        entrant.observe(collector.transitions)
        learn()
        for ended in finished:
            episode += 1
            seconds = time.perf_counter() - t0
            epsilon = float(getattr(entrant, "epsilon", math.nan))
            episodes_rows.append({
                "episode": episode, "track": ended.track, "reward": ended.reward,
                "steps": ended.steps, "env_steps": env_steps, "updates": updates(),
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
                    "updates": updates(), "seconds": time.perf_counter() - t0,
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
    _save_model(entrant, folder.checkpoint_path(LAST_CHECKPOINT),
                {"episode": last_episode, "run_spec": spec_json})  # fmt: skip
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
        "updates": updates(),
        "seconds": time.perf_counter() - t0,
        "cpu_s": clock.seconds(),
        "stopped_early": stopped_early,
    }
    if stopped_by is not None:
        summary["stopped_by"] = stopped_by
    if demo_summary is not None:  # who demonstrated: the report's "with demos" label needs it
        summary["demos"] = demo_summary
    folder.write_summary(summary)
    folder.remove_resume()
    for e in list(train_envs.values()) + list(test_envs.values()):
        e.close()
    return summary

"""Measure, on this machine and now, what one job's pieces cost: the rates a cost estimate uses.

For one run specification (built by the planner through ``training.run_spec.build_run_spec``, as
the job would get it) this builds the job's real env (``training.envs.RunEnvs``), agent and
replay buffer exactly as ``training.loop.train`` does, then times, for about ``seconds``:

- exploring env steps (the greedy actor plus the run's exploration noise, stored in the buffer
  through the loop's collector), and the episode lengths they give;
- real updates (``agent.update`` on batches of that buffer, PER priorities included);
- one real test episode (``training.evaluate.run_test_episode``) and one checkpoint save.

Each is timed in chunks, so the spread between chunks gives the rate's standard error. One
thread, as a worker runs (``configure_torch(spec.threads)``). Only single-car runs are measured
as such; with ``schedule.cars > 1`` the per-car-step rates of one car are used (vector envs
step cars faster, so the estimate errs high). An outside entrant is driven as the loop drives
it instead (:func:`calibrate_outside`): its learning schedule is its own.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from formula_tourney.agents.buffers import make_buffer
from formula_tourney.agents.checkpoints import save_checkpoint
from formula_tourney.agents.core import configure_torch
from formula_tourney.agents.families import make_agent
from formula_tourney.agents.noise import BrakeExplorationNoise
from formula_tourney.agents.outside.check import build_entrant
from formula_tourney.sim.reward import RewardRule
from formula_tourney.training.collect import SingleCarCollector
from formula_tourney.training.envs import RunEnvs
from formula_tourney.training.evaluate import run_test_episode, start_positions
from formula_tourney.training.outside import run_spaces
from formula_tourney.training.run_spec import RunSpec


@dataclass(frozen=True)
class Measured:
    """A mean time per item with its standard error over timing chunks."""

    mean_s: float
    se_s: float
    samples: int


@dataclass(frozen=True)
class Rates:
    """What one job's pieces cost here, measured for one run specification."""

    setup_s: float
    """Building the envs (tracks, reference lines), agent and buffer."""
    env_step: Measured
    """One exploring step: actor forward, noise, env step, buffer insert."""
    update: Measured
    """One agent update on a batch of the buffer."""
    test_episode_s: float
    """One greedy test episode of the untrained actor (to its end or test_max_steps)."""
    test_step_s: float
    """Per step of that test episode (for the upper bound of full-length tests)."""
    checkpoint_s: float
    """One checkpoint save (each test saves last.pt, best.pt when better, ep-N.pt if asked)."""
    episode_steps_mean: float
    episode_steps_se: float
    episodes_seen: int
    """Lengths of the exploring episodes seen (cut at max_steps)."""
    learn_from_steps: int | None = None
    """An outside entrant's: the loop step at which its first update did work (None: ours,
    whose learning_starts and updates_per_step say when and how often). Its ``update`` rate is
    then the extra CPU of one loop step once it learns (:func:`calibrate_outside`)."""

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Rates:
        return cls(**{**data, "env_step": Measured(**data["env_step"]),
                      "update": Measured(**data["update"])})


def _measured(chunks: list[tuple[float, int]]) -> Measured:
    """Mean seconds per item over timed chunks (seconds, items), with its standard error."""
    per = np.array([s / n for s, n in chunks if n > 0], dtype=float)
    total_s, total_n = sum(s for s, _ in chunks), sum(n for _, n in chunks)
    mean = total_s / total_n if total_n else math.nan
    se = float(per.std(ddof=1) / math.sqrt(per.size)) if per.size > 1 else math.nan
    return Measured(mean, se, int(total_n))


_WORKER_START = """
import json, sys, tempfile, time
t0 = time.perf_counter()
from formula_tourney.training.loop import train
from formula_tourney.training.run_spec import RunSpec
spec = RunSpec.from_json(json.loads(sys.stdin.read()), "estimate")
t1 = time.perf_counter()
jobs = []
for k in range(2):
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        train(spec, tmp)
        jobs.append(time.perf_counter() - t)
print(json.dumps({"import_s": t1 - t0, "first_job_s": jobs[0], "next_job_s": jobs[1]}))
"""


@dataclass(frozen=True)
class WorkerStart:
    """What a job costs beyond its steps, measured in a fresh process running two minimal
    jobs (one episode of a few steps, one short test) through ``training.loop.train``."""

    start_s: float
    """The process up to its first job: interpreter and imports (torch, the env kernels)."""
    first_job_s: float
    """A worker's first job beyond its steps (lazy imports: TensorBoard, Parquet; first env)."""
    next_job_s: float
    """Every later job of that worker beyond its steps (envs, writer, checkpoints, files)."""

    def to_json(self) -> dict[str, float]:
        return asdict(self)


def minimal_spec(spec: RunSpec) -> RunSpec:
    """``spec`` cut to one episode of a few steps and one short test from one start."""
    schedule = spec.schedule.model_copy(update={
        "episodes": 1, "max_steps": 5, "test_every_episodes": 1, "test_starts": 1,
        "test_max_steps": 5, "save_test_checkpoints": False})  # fmt: skip
    return spec.model_copy(update={"schedule": schedule, "test_tracks": spec.test_tracks[:1]})


def _start_processes(spec: RunSpec, count: int) -> list[tuple[float, dict[str, float]]]:
    """``count`` worker-like processes started at once: each one's wall seconds and times."""
    text = json.dumps(minimal_spec(spec).to_json())
    started = time.perf_counter()
    procs = [subprocess.Popen([sys.executable, "-c", _WORKER_START], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
             for _ in range(count)]  # fmt: skip
    outs: list[tuple[float, dict[str, float]]] = []
    for proc in procs:
        out, _ = proc.communicate(text, timeout=600)
        if proc.returncode != 0:
            raise RuntimeError(f"the worker-start probe failed (exit {proc.returncode})")
        outs.append((time.perf_counter() - started, json.loads(out.strip().splitlines()[-1])))
    return outs


def worker_start(spec: RunSpec, workers: int = 1) -> tuple[WorkerStart, float]:
    """Time a fresh worker-like process (imports and two minimal real jobs of ``spec``; a few
    seconds here, most of a small job's cost), alone and then ``workers`` of them at once.

    Returns the lone worker's times and the contention factor: how much longer a worker takes
    when the run's workers start together on this machine's cores (1 for one worker). Jobs
    that share cores run slower by about that much, so the estimate scales job seconds by it.
    """
    (total, times), = _start_processes(spec, 1)
    alone = WorkerStart(start_s=total - times["first_job_s"] - times["next_job_s"],
                        first_job_s=times["first_job_s"], next_job_s=times["next_job_s"])
    if workers <= 1:
        return alone, 1.0
    together = _start_processes(spec, workers)
    return alone, float(np.mean([t for t, _ in together])) / total


CENSORED_EPISODES = 3
"""A measurement that drove fewer than this many max-length episodes' steps saw only the short
episodes end: its episode length's range is widened to max_steps."""
Z95_STEPS = 1.96


def calibrate(spec: RunSpec, seconds: float = 1.0, chunk_steps: int = 100,
              chunk_updates: int = 10) -> Rates:
    """Time ``spec``'s env steps, updates and a test for about ``seconds`` in all."""
    if spec.outside is not None:
        return calibrate_outside(spec, seconds, chunk_steps)
    cfg = spec.agent
    configure_torch(spec.threads)
    started = time.perf_counter()
    envs = RunEnvs(spec)
    track = spec.train_tracks[0]
    env = envs.make(track, test=False)
    obs_dim = int(np.prod(env.observation_space.shape))
    action_dim = int(np.prod(env.action_space.shape))
    agent = make_agent(cfg, obs_dim, action_dim, device="cpu", seed=spec.seed)
    seqs = np.random.SeedSequence(spec.seed).spawn(3)
    buffer = make_buffer(
        min(cfg.buffer_size, 200_000), obs_dim, action_dim, prioritized=cfg.prioritized,
        gamma=cfg.gamma, n_step=cfg.n_step, window=cfg.window,
        bootstrap_on_truncation=cfg.adopted_target, seed=seqs[2],  # type: ignore[arg-type]
        alpha=cfg.per_alpha, beta=cfg.per_beta0, lambda3=cfg.per_lambda3, eps=cfg.per_eps,
        lanes=1,
    )  # fmt: skip
    noise = BrakeExplorationNoise(
        np.random.default_rng(seqs[1]), cfg.ou_theta, cfg.ou_sigma, cfg.noise_prob,
        cfg.brake_explore_prob, cfg.brake_explore_mean, cfg.brake_explore_sigma,
        cfg.brake_explore_hold_steps,
    )  # fmt: skip
    collector = SingleCarCollector({track: env}, [track], np.random.default_rng(seqs[0]), buffer,
                                   cfg.window, RewardRule.of(cfg))  # fmt: skip
    setup_s = time.perf_counter() - started

    lengths: list[int] = []
    step_chunks: list[tuple[float, int]] = []
    budget_steps = 0.45 * seconds
    t_phase = time.perf_counter()
    while (time.perf_counter() - t_phase < budget_steps or len(buffer) < cfg.batch_size + 1
           or len(step_chunks) < 3):
        t = time.perf_counter()
        for _ in range(chunk_steps):
            if collector.started:
                noise.reset()
            action = noise(agent.act(collector.windows[0]), 1.0)[0]
            for ended in collector.step([action]):
                lengths.append(ended.steps)
        step_chunks.append((time.perf_counter() - t, chunk_steps))

    update_chunks: list[tuple[float, int]] = []
    t_phase = time.perf_counter()
    while time.perf_counter() - t_phase < 0.45 * seconds or len(update_chunks) < 3:
        t = time.perf_counter()
        for _ in range(chunk_updates):
            agent.update(buffer.sample(cfg.batch_size), buffer if cfg.prioritized else None)
        update_chunks.append((time.perf_counter() - t, chunk_updates))

    test_track = spec.test_tracks[0]
    test_env = envs.make(test_track, test=True)
    start = start_positions(envs.tracks[test_track].length_m, 1)[0]
    t = time.perf_counter()
    drive = run_test_episode(agent, test_env, test_track, start, seed=spec.seed * 1000)
    test_s = time.perf_counter() - t
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        save_checkpoint(agent, Path(tmp) / "c.pt", extra={"run_spec": spec.to_json()})
        checkpoint_s = time.perf_counter() - t
    env.close()
    test_env.close()

    driven = sum(n for _, n in step_chunks)
    if not lengths:  # no episode ended: they are at least as long as what was driven
        lengths = [min(spec.schedule.max_steps, driven)]
    arr = np.minimum(np.asarray(lengths, dtype=float), spec.schedule.max_steps)
    mean_steps = float(arr.mean())
    se_steps = (float(arr.std(ddof=1) / math.sqrt(arr.size)) if arr.size > 1
                else mean_steps * 0.5)
    if driven < CENSORED_EPISODES * spec.schedule.max_steps:
        # too few steps driven for a full-length episode to end often: the episodes seen are
        # the short ones, so the range reaches up to max_steps (it does not shrink with a
        # short measurement, it widens)
        se_steps = max(se_steps, (spec.schedule.max_steps - mean_steps) / Z95_STEPS)
    return Rates(
        setup_s=setup_s, env_step=_measured(step_chunks), update=_measured(update_chunks),
        test_episode_s=test_s, test_step_s=test_s / max(1, drive.steps),
        checkpoint_s=checkpoint_s, episode_steps_mean=mean_steps, episode_steps_se=se_steps,
        episodes_seen=int(arr.size),
    )  # fmt: skip


OUTSIDE_MAX_WARMUP_STEPS = 5_000
"""Most loop steps a calibration drives an outside entrant to see it learn: one that has not
updated by then is costed as one that never does within the run (its rate says so)."""


def calibrate_outside(spec: RunSpec, seconds: float = 1.0, chunk_steps: int = 100) -> Rates:
    """An outside entrant's rates, by driving it as the loop does (``explore``, env step,
    ``observe``, ``update``). Its inner schedule is its own, so the rule is measured, not read:
    loop steps are timed in chunks until about ``seconds`` have passed and the entrant has
    learned for a while (its first ``update`` that returned losses, at most
    :data:`OUTSIDE_MAX_WARMUP_STEPS` steps); ``env_step`` is a step before it learns,
    ``update`` the extra of a step once it does, ``learn_from_steps`` where that began."""
    assert spec.outside is not None
    configure_torch(spec.threads)
    started = time.perf_counter()
    envs = RunEnvs(spec)
    track = spec.train_tracks[0]
    env = envs.make(track, test=False)
    entrant = build_entrant(spec.outside, replace(run_spaces(spec), cars=1), spec.seed, "cpu",
                            f"entrant {spec.variant}")  # fmt: skip
    collector = SingleCarCollector({track: env}, [track], np.random.default_rng(spec.seed), None,
                                   entrant.window, RewardRule.of(spec.agent))  # fmt: skip
    setup_s = time.perf_counter() - started
    lengths: list[int] = []
    before: list[tuple[float, int]] = []
    after: list[tuple[float, int]] = []
    learn_from: int | None = None
    steps = 0
    t_phase = time.perf_counter()
    while True:
        elapsed = time.perf_counter() - t_phase
        enough_after = len(after) >= 3 or (learn_from is None and steps >= OUTSIDE_MAX_WARMUP_STEPS)
        if elapsed >= 0.9 * seconds and len(before) + len(after) >= 3 and enough_after:
            break
        t = time.perf_counter()
        learned = 0
        for _ in range(chunk_steps):
            for car in collector.started:
                entrant.episode_started(car)
            action = np.asarray(entrant.explore(np.stack(collector.windows), steps))
            for ended in collector.step([action[0]]):
                lengths.append(ended.steps)
            entrant.observe(collector.transitions)
            if entrant.update(steps):
                learned += 1
                learn_from = steps if learn_from is None else learn_from
            steps += 1
        (after if learned else before).append((time.perf_counter() - t, chunk_steps))
    test_track = spec.test_tracks[0]
    test_env = envs.make(test_track, test=True)
    start = start_positions(envs.tracks[test_track].length_m, 1)[0]
    model = _Greedy(entrant)
    t = time.perf_counter()
    drive = run_test_episode(model, test_env, test_track, start, seed=spec.seed * 1000)
    test_s = time.perf_counter() - t
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        entrant.save(Path(tmp) / "model")
        checkpoint_s = time.perf_counter() - t
    env.close()
    test_env.close()
    step = _measured(before or after)
    extra = _measured(after) if after else Measured(0.0, 0.0, 0)
    update = Measured(max(0.0, extra.mean_s - step.mean_s), math.hypot(extra.se_s, step.se_s),
                      extra.samples)  # fmt: skip
    if not lengths:
        lengths = [min(spec.schedule.max_steps, steps)]
    arr = np.minimum(np.asarray(lengths, dtype=float), spec.schedule.max_steps)
    return Rates(
        setup_s=setup_s, env_step=step, update=update, test_episode_s=test_s,
        test_step_s=test_s / max(1, drive.steps), checkpoint_s=checkpoint_s,
        episode_steps_mean=float(arr.mean()),
        episode_steps_se=float(arr.std(ddof=1) / math.sqrt(arr.size)) if arr.size > 1 else
        float(arr.mean()) * 0.5,
        episodes_seen=int(arr.size),
        learn_from_steps=learn_from if learn_from is not None else 10**12,
    )  # fmt: skip


class _Greedy:
    """An entrant as ``run_test_episode`` drives it: ``cfg.window`` and ``act_eval``."""

    def __init__(self, entrant: Any) -> None:
        self.entrant = entrant
        self.cfg = SimpleNamespace(window=entrant.window)

    def act_eval(self, window: np.ndarray) -> np.ndarray:
        return np.asarray(self.entrant.act(window[None]))[0]

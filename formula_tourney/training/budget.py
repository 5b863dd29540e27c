"""A run's CPU clock and the rule that ends it early: a CPU-second budget or a lap to beat.

Time to competence (``results.competence``) counts the CPU-seconds of training until a model
first laps cleanly or beats a bot, so every run records its process's CPU time at each test
round (``tests.parquet`` ``cpu_s``), read from one :class:`CpuClock` started when training
starts. A run whose schedule sets ``budget_cpu_s`` or ``stop_at`` ends through
:class:`StopRule`, which the training loop asks after every episode; the tune worker's
CPU-second objective reads the same clock from the loop's progress (``cpu_s``).

What such a run must not pay on its clock is paid before the clock starts: the env, track,
reference line and numba kernels are loaded once (:func:`warm_up`), and the bot to beat is
driven (:func:`follower_lap_s`), so a worker's first job is timed as its later ones are.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from formula_tourney.bots.follower import drive
from formula_tourney.bots.line_offsets import reference_offsets
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.catalog import load_track
from formula_tourney.training.envs import RunEnvs
from formula_tourney.training.run_spec import RunSpec

BEST_BOT_LINE = "mincurv"
"""The line of the best bot: the follower is fastest on the minimum-curvature line."""
BOT_LAPS = 2
"""Laps the follower drives; its best clean one is the lap to beat (as a baseline drive)."""


@dataclass
class CpuClock:
    """CPU-seconds of this process (``time.process_time``: every thread) since :meth:`start`."""

    read: Callable[[], float] = time.process_time
    started: float = field(default=0.0, init=False)

    def start(self) -> None:
        self.started = self.read()

    def seconds(self) -> float:
        return self.read() - self.started

    def resume_from(self, cpu_s: float) -> None:
        """Continue a resumed run's clock: :meth:`seconds` reads ``cpu_s`` now."""
        self.started = self.read() - cpu_s


def follower_lap_s(track_name: str, line: str, car: CarParams) -> float:
    """The follower bot's best clean lap of :data:`BOT_LAPS` on ``line`` of a track, in the
    run's car (a bot in another car is no anchor); nan when it laps nothing cleanly."""
    track = load_track(track_name)
    lap = drive(track, reference_offsets(track, line, car), laps=BOT_LAPS, car=car)["best_lap_s"]
    return float(lap)


def warm_up(spec: RunSpec) -> None:
    """Build and step the run's env once, so the track, its line and the numba kernels are
    loaded (from their caches) before a CPU clock starts."""
    env = RunEnvs(spec).make(spec.key_track, test=False)
    env.reset(seed=0)
    half_throttle = np.array([0.0, 0.5, 0.0], np.float32)[: env.action_space.shape[0]]
    for _ in range(3):  # (steer 0, pedal 0.5) in the pedal action mode: the same throttle
        env.step(half_throttle)
    env.close()


@dataclass
class StopRule:
    """When a run ends before its episodes: once it has spent ``budget_cpu_s`` CPU-seconds, or
    once its best clean test lap on the key track is below ``stop_lap_s`` (``-inf``: never)."""

    budget_cpu_s: float | None = None
    stop_lap_s: float = -math.inf

    @property
    def active(self) -> bool:
        return self.budget_cpu_s is not None or self.stop_lap_s > -math.inf

    @classmethod
    def of(cls, spec: RunSpec) -> StopRule:
        """The rule of a run's schedule. For ``stop_at = "best-bot"`` the follower drives the
        min-curvature line here, and an active rule warms the env up: both before the clock."""
        schedule = spec.schedule
        rule = cls(schedule.budget_cpu_s)
        if schedule.stop_at == "best-bot":
            lap = follower_lap_s(spec.key_track, BEST_BOT_LINE, spec.env.car_params())
            rule.stop_lap_s = lap if math.isfinite(lap) else -math.inf
        if rule.active:
            warm_up(spec)
        return rule

    def with_demonstrator(self, demo_lap_s: float | None) -> StopRule:
        """A run that learns from demonstrations beats the bot only when it also beats the bot
        that demonstrated: the lower of the two laps ends it."""
        if self.stop_lap_s == -math.inf or demo_lap_s is None or not math.isfinite(demo_lap_s):
            return self
        return StopRule(self.budget_cpu_s, min(self.stop_lap_s, float(demo_lap_s)))

    def reason(self, best_lap_s: float, cpu_s: float) -> str | None:
        """Why the run stops now (``"stop_at"`` or ``"budget_cpu_s"``), or None to go on."""
        if best_lap_s < self.stop_lap_s:
            return "stop_at"
        if self.budget_cpu_s is not None and cpu_s >= self.budget_cpu_s:
            return "budget_cpu_s"
        return None

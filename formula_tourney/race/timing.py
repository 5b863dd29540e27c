"""Race timing: laps from line crossings, positions, gaps and overtakes from race distances.

Pure bookkeeping on numbers the simulator gives (race distance per car, line-crossing times),
so a race's standings can be checked against a hand computation (tests/test_race_timing.py).

- **Race distance** of a car: its progress since the start, measured from the start line (a
  grid slot behind the line starts negative). The first crossing of the line starts lap 1 (the
  grid is behind the line, as in motorsport); each later one completes a lap.
- **Race clock**: 0 at the green light. Lap 1 is timed from the green light, the others from
  the previous crossing (crossing times come interpolated inside the physics substep).
- **Positions**: finished cars in the order they finished, then running cars by race distance,
  then retired cars by the distance they had covered (classified as motorsport does).
- **Gap to the leader** (s): the time between the leader and the car at the same distance,
  ``t_car(d) - t_leader(d)`` at the car's latest distance ``d`` (for a finished car, its
  finish); ``t_leader(d)`` is read off the leader's recorded (time, distance) trace.
  ``gap_m`` is the difference of race distances.
- **Overtakes**: two running cars that swap positions between steps; lapping a slower car is
  not one (its race distance was behind all along).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

RUNNING = "running"
FINISHED = "finished"
RETIRED = "retired"


@dataclass
class CarRecord:
    """One car's timing record."""

    name: str
    status: str = RUNNING
    reason: str = ""
    crossings_s: list[float] = field(default_factory=list)
    """Race-clock times of its forward line crossings (the first starts lap 1)."""
    distance_m: float = 0.0
    finish_s: float = math.nan
    finish_rank: int = 0
    times_s: list[float] = field(default_factory=list)
    """Its (time, distance) trace, one point per step plus one per crossing."""
    dists_m: list[float] = field(default_factory=list)

    @property
    def laps_done(self) -> int:
        return max(len(self.crossings_s) - 1, 0)

    def lap_times_s(self, green_s: float = 0.0) -> list[float]:
        """Lap k from crossing k - 1 (lap 1: from the green light) to crossing k."""
        c = self.crossings_s
        if len(c) < 2:
            return []
        starts = [green_s, *c[1:-1]]
        return [b - a for a, b in zip(starts, c[1:], strict=True)]

    def time_at(self, d_m: float) -> float:
        """When this car was at race distance ``d_m`` (interpolated; NaN before its trace)."""
        if not self.times_s:
            return math.nan
        d = np.maximum.accumulate(np.asarray(self.dists_m))
        if d_m > d[-1] + 1e-9 or d_m < d[0] - 1e-9:
            return math.nan
        return float(np.interp(d_m, d, np.asarray(self.times_s)))


class RaceTiming:
    """Laps, positions, gaps and overtakes of ``n`` cars on a track of ``length_m``."""

    def __init__(self, names: list[str], length_m: float, laps: int) -> None:
        self.cars = [CarRecord(name) for name in names]
        self.length_m = float(length_m)
        self.laps = int(laps)
        self.n = len(names)
        self.overtakes: list[dict] = []
        self.positions: list[int] = list(range(1, self.n + 1))
        self._finished = 0
        self._stepped = False
        self.winner_done = False

    # --- updates ------------------------------------------------------------------------------
    def crossing(self, c: int, t_s: float) -> None:
        """Car ``c`` crossed the line forwards at race time ``t_s``."""
        car = self.cars[c]
        car.crossings_s.append(float(t_s))
        k = len(car.crossings_s) - 1
        car.times_s.append(float(t_s))
        car.dists_m.append(k * self.length_m)

    def finish(self, c: int, t_s: float) -> None:
        car = self.cars[c]
        self._finished += 1
        car.status = FINISHED
        car.finish_s = float(t_s)
        car.finish_rank = self._finished
        self.winner_done = True

    def retire(self, c: int, reason: str) -> None:
        car = self.cars[c]
        car.status = RETIRED
        car.reason = reason

    def step(self, t_s: float, distance_m: np.ndarray) -> list[int]:
        """Record the running cars' race distances at race time ``t_s``; returns positions."""
        before = self.positions
        for c, car in enumerate(self.cars):
            if car.status == RUNNING:
                car.distance_m = float(distance_m[c])
                car.times_s.append(float(t_s))
                car.dists_m.append(car.distance_m)
        now = self.order()
        pos = [0] * self.n
        for rank, c in enumerate(now, start=1):
            pos[c] = rank
        running = [c for c, car in enumerate(self.cars) if car.status == RUNNING]
        if not self._stepped:  # the grid itself: nobody passed anybody
            running = []
            self._stepped = True
        for a in running:
            for b in running:
                if before[a] > before[b] and pos[a] < pos[b]:
                    self.overtakes.append({"t_s": float(t_s), "lap": self.cars[a].laps_done + 1,
                                           "by": self.cars[a].name, "on": self.cars[b].name})
        self.positions = pos
        return pos

    # --- reads --------------------------------------------------------------------------------
    def order(self) -> list[int]:
        """Car indices, P1 first (see the module docstring)."""
        def key(c: int) -> tuple[int, float]:
            car = self.cars[c]
            if car.status == FINISHED:
                return (0, float(car.finish_rank))
            if car.status == RUNNING:
                return (1, -car.distance_m)
            return (2, -car.distance_m)
        return sorted(range(self.n), key=lambda c: (*key(c), c))

    def leader(self) -> int:
        return self.order()[0]

    def gap_s(self, c: int) -> float:
        """Time behind the leader at the same race distance (0 for the leader)."""
        lead = self.leader()
        if c == lead:
            return 0.0
        car = self.cars[c]
        if car.status == RETIRED:
            return math.nan
        t_car = car.finish_s if car.status == FINISHED else car.times_s[-1] if car.times_s \
            else math.nan
        d = car.laps_done * self.length_m if car.status == FINISHED else car.distance_m
        return t_car - self.cars[lead].time_at(d)

    def gap_m(self, c: int) -> float:
        """Race distance behind the leader."""
        lead = self.cars[self.leader()]
        return lead.distance_m - self.cars[c].distance_m

    def laps_behind(self, c: int) -> int:
        lead = self.cars[self.leader()]
        return lead.laps_done - self.cars[c].laps_done if self.cars[c].status != RETIRED \
            else 0

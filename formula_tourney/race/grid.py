"""The starting grid: qualifying laps, the order they give, and the staggered slots.

Slots are staggered as in motorsport: one car every ``slot_gap_m`` along the track, alternately
left and right of the centre line, the pole ``pole_behind_line_m`` behind the start line (a
rolling start puts the same formation further back and gives it speed). A seed moves each car
by up to 0.5 m along and 0.25 m across its slot, so that races with the same grid but another
seed differ (the cars and drivers are otherwise deterministic).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from formula_tourney.race.entrants import Entrant
from formula_tourney.race.settings import RaceSettings
from formula_tourney.sim import kernels as K
from formula_tourney.sim.multicar import lockstep_kernels as RK
from formula_tourney.sim.multicar.simulator import RaceSim
from formula_tourney.sim.track import Track

QUALIFYING_START_BEFORE_LINE_M = 50.0
JITTER_ALONG_M = 0.5
JITTER_ACROSS_M = 0.25


@dataclass(frozen=True)
class Slot:
    """Where a car starts: track position, lateral offset (left > 0) and speed."""

    s_m: float
    lateral_m: float
    speed_mps: float
    behind_line_m: float
    """Distance to the start line along the track (the car's race distance is minus this)."""


def qualifying_lap_s(entrant: Entrant, settings: RaceSettings) -> float:
    """The entrant's first flying lap alone on the track (50 m run-up from rest); NaN if the
    car retires or runs out of ``qualifying_steps`` before completing one."""
    sim = RaceSim([entrant.config], settings.contact, opponents=entrant.sees_opponents)
    length = sim.track.length_m
    sim.place(0, length - QUALIFYING_START_BEFORE_LINE_M)
    sim.step()
    driver = entrant.make_driver()
    obs = sim.observation(0)
    driver.reset(obs, sim.opp[0])
    actions = np.zeros((1, 3))
    for _ in range(settings.qualifying_steps):
        actions[0] = driver.act(sim.observation(0), sim.opp[0], sim.state[0])
        sim.step(actions)
        lap = sim.out[0, K.O_LAP_TIME]
        if lap == lap:
            return float(lap)
        if sim.out[0, K.O_TERM] > 0:
            return math.nan
    return math.nan


def grid_order(entrants: list[Entrant], settings: RaceSettings,
               qualifying_s: list[float] | None) -> list[int]:
    """Entrant indices, pole first: by qualifying lap (NaN last, in entry order) or given."""
    n = len(entrants)
    if settings.grid == "given" or qualifying_s is None:
        return list(range(n))
    return sorted(range(n), key=lambda i: (not math.isfinite(qualifying_s[i]),
                                           qualifying_s[i] if math.isfinite(qualifying_s[i])
                                           else 0.0, i))


def grid_slots(track: Track, n: int, settings: RaceSettings, seed: int) -> list[Slot]:
    """``n`` staggered slots, pole first."""
    rng = np.random.default_rng(seed)
    rolling = settings.start == "rolling"
    first = settings.rolling_behind_line_m if rolling else settings.pole_behind_line_m
    speed = settings.rolling_speed_mps if rolling else 0.0
    slots = []
    for k in range(n):
        behind = first + k * settings.slot_gap_m + rng.uniform(-JITTER_ALONG_M, JITTER_ALONG_M)
        behind = max(behind, 1.0)  # always behind the line: the first crossing starts lap 1
        s = (track.length_m - behind) % track.length_m
        i = int(track.index_at(s))
        half = min(track.width_left_m[i], track.width_right_m[i])
        side = 1.0 if k % 2 == 0 else -1.0
        lateral = side * min(2.5, 0.3 * half) + rng.uniform(-JITTER_ACROSS_M, JITTER_ACROSS_M)
        slots.append(Slot(float(s), float(lateral), speed, float(behind)))
    return slots


def place_on_grid(sim: RaceSim, slots: list[Slot], order: list[int]) -> None:
    """Car ``order[k]`` on slot ``k``."""
    for k, c in enumerate(order):
        slot = slots[k]
        sim.place(c, slot.s_m, slot.lateral_m, slot.speed_mps)
    assert (sim.mode == RK.MODE_PLACED).all()

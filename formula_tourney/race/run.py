"""One race: grid, start, laps, retirements, contacts, and the classified result.

The loop asks every driver for an action, advances the cars together
(``sim.multicar.simulator``), then reads what happened: line crossings (lap times, finishes),
ends (retirements), car-car contacts (incidents and who caused them) and the race distances that
order the field (``race.timing``). A car that finishes or retires leaves the track. The leader
finishes after ``laps`` laps; every other car finishes when it next crosses the line, a lapped
car laps down.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.race.entrants import Entrant
from formula_tourney.race.grid import grid_order, grid_slots, place_on_grid, qualifying_lap_s
from formula_tourney.race.settings import RaceSettings
from formula_tourney.race.timing import FINISHED, RETIRED, RUNNING, RaceTiming
from formula_tourney.sim import kernels as K
from formula_tourney.sim.multicar import lockstep_kernels as RK
from formula_tourney.sim.multicar.simulator import RaceSim

TERM_REASONS = {K.TERM_OFF_TRACK: "off track", K.TERM_BACKWARDS: "spun",
                K.TERM_SLOW: "stopped"}


@dataclass
class RaceResult:
    """Everything a race produced; ``to_json()`` is the CLI's and the race part's document."""

    track: str
    laps: int
    start: str
    seed: int
    rows: list[dict[str, Any]]
    """One per car, in finishing order: position, name, kind, sees_opponents, grid,
    qualifying_s, status, reason, laps, time_s, gap_s, laps_behind, best_lap_s, lap_times_s,
    damage, contacts, caused, overtakes."""
    overtakes: list[dict[str, Any]]
    incidents: list[dict[str, Any]]
    lap_chart: list[dict[str, Any]]
    """One per completed lap of a car: name, lap, position, gap_s (to the leader at the line)."""
    duration_s: float
    steps: int
    frames: list[Any] = field(default_factory=list, repr=False)

    def to_json(self) -> dict[str, Any]:
        return {"track": self.track, "laps": self.laps, "start": self.start, "seed": self.seed,
                "duration_s": self.duration_s, "steps": self.steps, "results": self.rows,
                "overtakes": self.overtakes, "incidents": self.incidents,
                "lap_chart": self.lap_chart}


@dataclass
class _Incident:
    a: int
    b: int
    t_s: float
    lap: int
    energy_j: float = 0.0
    blame_a_j: float = 0.0
    blame_b_j: float = 0.0
    last_step: int = 0


def _race_config(entrant: Entrant, settings: RaceSettings, max_steps: int):
    """The entrant's env config with the race's ends: grass is no end (walls hold the cars),
    spinning round or stopping is; episodes never time out (the race does)."""
    cfg = entrant.config
    patience = max(int(round(settings.stopped_patience_s / cfg.control_period_s)), 1)
    return cfg.model_copy(update={"terminate_off_track": False, "terminate_backwards": True,
                                  "terminate_slow": True, "slow_patience_steps": patience,
                                  "max_steps": max_steps + 10})


def run_race(entrants: list[Entrant], settings: RaceSettings, seed: int = 0,
             grid: list[int] | None = None,
             frame: Callable[[RaceSim, RaceTiming, float], Any] | None = None) -> RaceResult:
    """Race ``entrants``; ``grid`` (entrant indices, pole first) overrides ``settings.grid``.

    ``frame(sim, timing, race_time_s)``, if given, is called after the start and after every
    step; what it returns is kept in ``RaceResult.frames`` (the renderer's images).
    """
    if not entrants:
        raise UserInputError("a race needs at least one car")
    n = len(entrants)
    period = entrants[0].config.control_period_s
    max_steps = int(math.ceil((settings.laps + 1) * settings.lap_limit_s / period))
    configs = [_race_config(e, settings, max_steps) for e in entrants]
    sim = RaceSim(configs, settings.contact,
                  opponents=any(e.sees_opponents for e in entrants))
    track = sim.track
    length = track.length_m
    qualifying: list[float] | None = None
    if grid is None:
        if settings.grid == "qualifying":
            qualifying = [qualifying_lap_s(e, settings) for e in entrants]
        grid = grid_order(entrants, settings, qualifying)
    elif sorted(grid) != list(range(n)):
        raise UserInputError(f"grid {grid}: expected each of the {n} cars once")
    slots = grid_slots(track, n, settings, seed)
    place_on_grid(sim, slots, grid)
    offset = np.zeros(n)
    for k, c in enumerate(grid):
        offset[c] = -slots[k].behind_line_m
    sim.step()
    drivers = [e.make_driver() for e in entrants]
    for c, d in enumerate(drivers):
        d.reset(sim.observation(c), sim.opp[c])
    timing = RaceTiming([e.name for e in entrants], length, settings.laps)
    green = 0.0 if settings.start == "standing" else math.nan
    last_cross = sim.state[:, K.ST_LAP_START].copy()
    incidents: list[_Incident] = []
    open_inc: dict[tuple[int, int], _Incident] = {}
    lap_chart: list[dict[str, Any]] = []
    timing.step(0.0, offset + sim.state[:, K.ST_DIST])
    frames = [frame(sim, timing, 0.0)] if frame else []
    actions = np.zeros((n, 3))
    steps = 0
    t_sim = 0.0
    for steps in range(1, max_steps + 1):  # noqa: B007  (steps is read after the loop)
        for c in range(n):
            if sim.mode[c] == RK.MODE_DRIVING:
                actions[c] = drivers[c].act(sim.observation(c), sim.opp[c], sim.state[c])
            else:
                actions[c] = 0.0
        sim.step(actions)
        t_sim = steps * period
        if math.isnan(green):
            crossed = [c for c in range(n) if sim.state[c, K.ST_LAP_START] != last_cross[c]]
            if crossed:
                green = min(float(sim.state[c, K.ST_LAP_START]) for c in crossed)
        clock = t_sim - (green if math.isfinite(green) else t_sim)
        # Line crossings in the order they happened inside the step (finishes are ranked).
        crossings = sorted((float(sim.state[c, K.ST_LAP_START]), c) for c in range(n)
                           if timing.cars[c].status == RUNNING
                           and sim.state[c, K.ST_LAP_START] != last_cross[c])
        last_cross[:] = sim.state[:, K.ST_LAP_START]
        done_laps = []
        for t_cross, c in crossings:
            timing.crossing(c, t_cross - green)
            car = timing.cars[c]
            if car.laps_done >= 1:
                done_laps.append((c, car.laps_done, t_cross - green))
            if car.laps_done >= settings.laps or (timing.winner_done and car.laps_done >= 1):
                timing.finish(c, t_cross - green)
                sim.remove(c)
        for c in range(n):
            if timing.cars[c].status != RUNNING:
                continue
            term = int(sim.out[c, K.O_TERM])
            if term:
                timing.retire(c, TERM_REASONS.get(term, "ended"))
            elif sim.state[c, K.ST_DAMAGE] >= settings.max_damage:
                timing.retire(c, f"damage {sim.state[c, K.ST_DAMAGE]:.0f}")
            else:
                continue
            timing.cars[c].distance_m = float(offset[c] + sim.state[c, K.ST_DIST])
            sim.remove(c)
        timing.step(clock, offset + sim.state[:, K.ST_DIST])
        for c, lap, t_cross in done_laps:
            lead = timing.cars[timing.leader()]
            gap = t_cross - lead.time_at(lap * length) if lead is not timing.cars[c] else 0.0
            lap_chart.append({"name": entrants[c].name, "lap": lap,
                              "position": timing.positions[c], "gap_s": _num(gap)})
        _contacts(sim, timing, steps, clock, open_inc, incidents)
        if frame:
            frames.append(frame(sim, timing, clock))
        if all(car.status != RUNNING for car in timing.cars):
            break
    incidents = [i for i in incidents if i.energy_j >= 1000.0 * settings.incident_min_kj]
    rows = _rows(entrants, timing, sim, grid, qualifying, incidents, settings)
    return RaceResult(track.name, settings.laps, settings.start, seed, rows, timing.overtakes,
                      [_incident_json(i, entrants, settings) for i in incidents], lap_chart,
                      t_sim, steps, frames)


def _contacts(sim: RaceSim, timing: RaceTiming, step: int, clock: float,
              open_inc: dict[tuple[int, int], _Incident], incidents: list[_Incident]) -> None:
    """Merge this step's touching pairs into incidents (consecutive steps are one incident)."""
    touch = np.argwhere(sim.pair_touch > 0.0)
    for a, b in touch.tolist():
        inc = open_inc.get((a, b))
        if inc is None or inc.last_step < step - 1:
            lap = max(timing.cars[a].laps_done, timing.cars[b].laps_done) + 1
            inc = _Incident(a, b, clock, lap)
            open_inc[(a, b)] = inc
            incidents.append(inc)
        inc.energy_j += float(sim.pair_energy[a, b])
        inc.blame_a_j += float(sim.pair_blame[a, b])
        inc.blame_b_j += float(sim.pair_blame[b, a])
        inc.last_step = step


def _caused_by(inc: _Incident, settings: RaceSettings) -> int | None:
    total = inc.blame_a_j + inc.blame_b_j
    if total <= 0.0:
        return None
    if inc.blame_a_j >= settings.blame_share * total:
        return inc.a
    if inc.blame_b_j >= settings.blame_share * total:
        return inc.b
    return None


def _incident_json(inc: _Incident, entrants: list[Entrant],
                   settings: RaceSettings) -> dict[str, Any]:
    cause = _caused_by(inc, settings)
    return {"t_s": round(inc.t_s, 3), "lap": inc.lap,
            "cars": [entrants[inc.a].name, entrants[inc.b].name],
            "energy_kj": round(inc.energy_j / 1000.0, 3),
            "caused_by": entrants[cause].name if cause is not None else None}


def _num(x: float) -> float | None:
    return float(x) if isinstance(x, float | int) and math.isfinite(x) else None


def _rows(entrants: list[Entrant], timing: RaceTiming, sim: RaceSim, grid: list[int],
          qualifying: list[float] | None, incidents: list[_Incident],
          settings: RaceSettings) -> list[dict[str, Any]]:
    rows = []
    for pos, c in enumerate(timing.order(), start=1):
        car = timing.cars[c]
        laps = car.lap_times_s(0.0)
        involved = [i for i in incidents if c in (i.a, i.b)]
        caused = [i for i in involved if _caused_by(i, settings) == c]
        rows.append({
            "position": pos,
            "name": entrants[c].name,
            "kind": entrants[c].kind,
            "sees_opponents": entrants[c].sees_opponents,
            "grid": grid.index(c) + 1,
            "qualifying_s": _num(qualifying[c]) if qualifying else None,
            "status": car.status if car.status != RUNNING else "running",
            "reason": car.reason,
            "laps": car.laps_done,
            "time_s": _num(car.finish_s) if car.status == FINISHED else None,
            "gap_s": _num(timing.gap_s(c)) if car.status != RETIRED else None,
            "laps_behind": timing.laps_behind(c),
            "distance_m": round(car.distance_m, 2),
            "best_lap_s": _num(min(laps)) if laps else None,
            "lap_times_s": [round(t, 4) for t in laps],
            "damage": round(float(sim.state[c, K.ST_DAMAGE]), 1),
            "contacts": len(involved),
            "caused": len(caused),
            "overtakes": sum(1 for o in timing.overtakes if o["by"] == entrants[c].name),
        })
    return rows

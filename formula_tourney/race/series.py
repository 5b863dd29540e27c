"""A series of races between the same entrants: rotated grids and seeds (a race part's races).

The entrants qualify once (or keep the given order); race ``k`` starts from that grid rotated by
``k`` slots (the pole goes to the back, everyone else moves up one), with seed ``seed + k`` for
the slots' jitter, so over ``n`` races each entrant starts once from each slot and no result
hangs on one grid. Scoring is the report's (``report.race_standings``): this module only races.
"""

from __future__ import annotations

from collections.abc import Callable

from formula_tourney.errors import UserInputError
from formula_tourney.race.entrants import Entrant
from formula_tourney.race.grid import grid_order, qualifying_lap_s
from formula_tourney.race.run import RaceResult, run_race
from formula_tourney.race.settings import RaceSettings


def rotated_grid(base: list[int], k: int) -> list[int]:
    """``base`` (pole first) rotated by ``k`` slots: race ``k``'s grid."""
    r = k % len(base)
    return base[r:] + base[:r]


def qualify(entrants: list[Entrant], settings: RaceSettings) -> tuple[list[float] | None,
                                                                       list[int]]:
    """Each entrant's qualifying lap (None with a given grid) and the base grid, pole first."""
    qualifying = None
    if settings.grid == "qualifying":
        qualifying = [qualifying_lap_s(e, settings) for e in entrants]
    return qualifying, grid_order(entrants, settings, qualifying)


def race_k(entrants: list[Entrant], settings: RaceSettings, base: list[int],
           qualifying: list[float] | None, seed: int, k: int) -> RaceResult:
    """Race ``k`` of a series: the base grid rotated by ``k``, seed ``seed + k``; its rows
    carry each car's qualifying lap. A function of its arguments alone, so a resumed series
    races a missing race exactly as the first run would have."""
    result = run_race(entrants, settings, seed=seed + k, grid=rotated_grid(base, k))
    if qualifying is not None:
        for row in result.rows:
            i = next(j for j, e in enumerate(entrants) if e.name == row["name"])
            q = qualifying[i]
            row["qualifying_s"] = float(q) if q == q else None
    return result


def run_series(entrants: list[Entrant], settings: RaceSettings, races: int, seed: int = 0,
               on_race: Callable[[int, RaceResult], None] | None = None) -> list[RaceResult]:
    """``races`` races; ``on_race(k, result)`` after each (a part writes its files there)."""
    if races < 1:
        raise UserInputError(f"races: expected at least 1, got {races}")
    qualifying, base = qualify(entrants, settings)
    results = []
    for k in range(races):
        result = race_k(entrants, settings, base, qualifying, seed, k)
        results.append(result)
        if on_race is not None:
            on_race(k, result)
    return results

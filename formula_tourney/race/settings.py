"""A race's rules: laps, start, grid, retirement limits and how cars touch (one pydantic model)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from formula_tourney.sim.multicar.simulator import ContactSettings


class RaceSettings(BaseModel):
    """Everything a race needs besides its entrants and its track."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    laps: int = Field(3, ge=1, le=200, description="laps to run; the winner is the first to "
                      "complete them, the others finish when they next cross the line")
    start: Literal["standing", "rolling"] = Field(
        "standing", description="standing: from rest on the grid, the clock starts at once; "
        "rolling: the grid rolls at `rolling_speed_mps` from further back and the clock starts "
        "when the leader crosses the line")
    grid: Literal["qualifying", "given"] = Field(
        "qualifying", description="qualifying: by each entrant's solo flying lap (no lap: at "
        "the back, in entry order); given: in entry order")
    slot_gap_m: float = Field(8.0, gt=0.0, le=50.0, description="distance along the track "
                              "between consecutive grid slots (F1: 8 m); slots alternate left "
                              "and right of the centre line")
    pole_behind_line_m: float = Field(10.0, ge=0.0, le=500.0, description="the pole slot's "
                                      "distance behind the start line (standing start)")
    rolling_speed_mps: float = Field(25.0, gt=0.0, le=80.0, description="speed of the cars "
                                     "when a rolling start is given")
    rolling_behind_line_m: float = Field(150.0, ge=0.0, le=1000.0, description="the pole "
                                         "car's distance behind the line at a rolling start")
    max_damage: float = Field(5000.0, gt=0.0, description="a car with this much damage "
                              "retires (walls: 100 points per m/s of impact speed)")
    stopped_patience_s: float = Field(5.0, gt=0.0, le=120.0, description="a car that makes "
                                      "less than 10 km/h of progress this long retires")
    lap_limit_s: float = Field(300.0, gt=0.0, description="time allowed per lap: the race "
                               "stops after (laps + 1) x this, running cars classified by "
                               "distance")
    qualifying_steps: int = Field(3000, ge=10, description="longest qualifying run (control "
                                  "steps) for the out lap and one flying lap")
    contact: ContactSettings = Field(default_factory=ContactSettings,
                                     description="how cars touch")
    incident_min_kj: float = Field(0.05, ge=0.0, description="touches that remove less "
                                   "impact energy than this (kJ) are not counted as contacts "
                                   "(two bots nose to tail brush at a few joules)")
    blame_share: float = Field(0.6, gt=0.5, le=1.0, description="a contact is blamed on the "
                               "car that brought at least this share of the closing speed "
                               "(weighted by impact energy); else it is a racing incident")

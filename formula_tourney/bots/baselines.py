"""The baseline numbers every lap-time table is read against, one function per CLI command.

``line_report`` (a line's geometry and QSS lap), ``bot_report`` (the follower driving a line in
the simulator, with the gap to the track's reference limit) and ``reference_table`` (``lines
table``: reference limit, follower on the centre line, follower on the min-curvature line and the
genetic bot, per track). The tourney stores ``bot_report`` rows as its baselines.
"""

from __future__ import annotations

import math

import numpy as np

from formula_tourney.bots.follower import FollowerConfig, drive
from formula_tourney.bots.line_offsets import reference_offsets
from formula_tourney.lines.limit import reference_limit_s
from formula_tourney.lines.registry import check_kind
from formula_tourney.lines.speed_profile import speed_profile
from formula_tourney.results.metrics import gap_pct
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.reference_line import ReferenceLine
from formula_tourney.sim.track import Track

BUILT_IN_TRACKS: tuple[str, ...] = ("oval", "technical", "flowing")


def line_report(track: Track, kind: str, car: CarParams | None = None) -> dict:
    """Geometry and QSS lap of one reference line, plus the arrays a plot needs."""
    car = car or CarParams()
    check_kind(kind)
    offsets = reference_offsets(track, kind, car)
    line = ReferenceLine.from_offsets(track, offsets)
    profile = speed_profile(track, offsets, car)
    limit = reference_limit_s(track, car)
    return {
        "track": track.name,
        "line": kind,
        "track_length_m": track.length_m,
        "line_length_m": profile.line_length_m,
        "profile_lap_s": profile.lap_time_s,
        "reference_limit_s": limit,
        "gap_to_limit_pct": gap_pct(profile.lap_time_s, limit),
        "mean_speed_kmh": profile.mean_speed_kmh,
        "min_speed_kmh": float(profile.speed_kmh.min()),
        "max_speed_kmh": float(profile.speed_kmh.max()),
        "sum_curvature_sq": float(np.sum(line.curvature_1pm**2)),
        "offset_min_m": float(offsets.min()),
        "offset_max_m": float(offsets.max()),
        "_arrays": {"x_m": line.x_m, "y_m": line.y_m, "speed_kmh": profile.speed_kmh,
                    "offsets_m": offsets},
    }


def bot_report(track: Track, kind: str, laps: int = 2, car: CarParams | None = None,
               config: FollowerConfig | None = None) -> dict:
    """The follower on line ``kind``: lap times, damage, best clean lap and gap to the limit."""
    car = car or CarParams()
    check_kind(kind)
    offsets = reference_offsets(track, kind, car)
    result = drive(track, offsets, laps=laps, car=car, config=config)
    limit = reference_limit_s(track, car)
    return {
        "track": track.name,
        "line": kind,
        "bot": "genetic" if kind == "genetic" else "follower",
        "laps": result["lap_times_s"],
        "lap_damage": result["lap_damage"],
        "best_lap_s": result["best_lap_s"],
        "damage": result["damage"],
        "finished": result["finished"],
        "termination": result["termination"],
        "profile_lap_s": result["profile_lap_s"],
        "reference_limit_s": limit,
        "gap_to_limit_pct": gap_pct(result["best_lap_s"], limit),
        "_trace": result["trace"],
    }


def reference_table(tracks: list[Track], laps: int = 2, car: CarParams | None = None) -> list[dict]:
    """One row per track: the limit and each bot's best clean lap (``lines table``)."""
    car = car or CarParams()
    rows = []
    for track in tracks:
        limit = reference_limit_s(track, car)
        row: dict = {"track": track.name, "length_m": round(track.length_m, 1),
                     "reference_limit_s": limit}
        for key, kind in (("follower_centre", "centre"), ("follower_mincurv", "mincurv"),
                          ("genetic", "genetic")):
            rep = bot_report(track, kind, laps, car)
            row[f"{key}_s"] = rep["best_lap_s"]
            row[f"{key}_damage"] = rep["damage"]
            row[f"{key}_gap_pct"] = rep["gap_to_limit_pct"]
        rows.append(row)
    return rows


def public(report: dict) -> dict:
    """A report without its bulky arrays, NaN as null (what ``--json`` prints: strict JSON)."""
    return {k: _no_nan(v) for k, v in report.items() if not k.startswith("_")}


def _no_nan(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, list):
        return [_no_nan(v) for v in value]
    if isinstance(value, dict):
        return {k: _no_nan(v) for k, v in value.items()}
    return value

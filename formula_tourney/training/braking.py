"""Where a drive brakes for each corner, against its reference line (``replay --braking``).

A driver that leaves the track in a hairpin has usually braked too late or too little, and a
trace of the drive (``replay --trace``) shows it only to someone who reads it beside a speed
profile. This module does that reading. The profile is the QSS lap (``lines.speed_profile``) of
the run's reference line, the line it is asked to follow and the one its braking start
curriculum reads (``training.curriculum``): a car on the centre line must take a hairpin far
slower than the reference limit on the minimum-curvature line. For every braking zone of that
profile (:func:`line_braking_zones`: where the speed falls by at least
``training.curriculum.MIN_DROP_MPS``) it finds the drive's first pass through the zone and
reports where the drive first pressed the brake at least :data:`BRAKE_ON` in the zone's
approach (:data:`APPROACH_M` before the line's braking point, or from the previous zone's apex
when that is nearer) and before the zone's slowest point (its *apex*), how fast it was then,
how fast it met the line's braking point, and how fast it passed the apex, or where the env
ended the drive. Positions are metres along the centreline, as every table gives them; the
drive's are unwrapped from its start (``start_s_m + distance_m``); a zone whose apex lies ahead
of the start is read on this lap, from the start on when the start lies inside it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import pandas as pd

from formula_tourney.lines.speed_profile import speed_profile
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.track import Track
from formula_tourney.training.curriculum import braking_zones

BRAKE_ON = 0.3
"""Brake pressure that counts as braking: the pedal a hairpin needs for 8-13 steps in a row
(docs/agents.md, "Acting and exploration"); lighter touches trim the speed, they do not stop
a car."""
APPROACH_M = 250.0
"""How far before a zone's braking point the drive's brake is looked for: a driver that
brakes earlier than that for one corner is braking for another."""


@dataclass(frozen=True)
class LineZone:
    """One braking zone of a line's QSS lap: it brakes at ``brake_s_m`` from ``brake_kmh``
    down to ``apex_kmh`` at ``apex_s_m`` (positions along the centreline)."""

    brake_s_m: float
    brake_kmh: float
    apex_s_m: float
    apex_kmh: float


@dataclass(frozen=True)
class ZoneDrive:
    """The drive's first pass through one zone. ``brake_s_m`` / ``brake_kmh``: its first step
    with brake >= :data:`BRAKE_ON` in the approach (None: it did not brake there);
    ``late_m``: how far after the line's braking point that was (negative: earlier);
    ``at_line_brake_kmh``: its speed where the line starts braking; ``apex_kmh``: its speed
    at the apex, None when it did not get there; ``ended_by`` / ``ended_s_m`` / ``ended_kmh``:
    why, where and how fast the drive ended in this zone or on the way out of it
    (``off_track``, ``backwards``, ``slow``: the env's termination), if it did."""

    zone: int
    line: LineZone
    brake_s_m: float | None
    brake_kmh: float | None
    late_m: float | None
    at_line_brake_kmh: float | None
    apex_kmh: float | None
    ended_by: str | None
    ended_s_m: float | None
    ended_kmh: float | None

    def as_dict(self) -> dict[str, Any]:
        """JSON-able: the line's zone flattened in with ``line_`` keys."""
        out = {k: v for k, v in asdict(self).items() if k != "line"}
        out.update({f"line_{k}": v for k, v in asdict(self.line).items()})
        return out


def line_braking_zones(track: Track, offsets_m: np.ndarray | float, car: CarParams,
                       grip_scale: float = 1.0) -> list[LineZone]:  # fmt: skip
    """The braking zones of the QSS profile (``lines.speed_profile``) of the line with these
    lateral offsets, in track order."""
    v = np.asarray(speed_profile(track, offsets_m, car, grip_scale=grip_scale).speed_mps,
                   dtype=float)  # fmt: skip
    s = np.asarray(track.s_m, dtype=float)
    return [LineZone(float(s[i]), float(v[i] * 3.6), float(s[j]), float(v[j] * 3.6))
            for i, j in braking_zones(v)]  # fmt: skip


def _first_pass(start_s_m: float, zone: LineZone, length_m: float) -> tuple[float, float]:
    """The unwrapped braking point and apex of the zone's first pass: the first whose apex
    lies ahead of the start (a start inside a zone reads that zone from the start on)."""
    apex_ahead = (zone.apex_s_m - zone.brake_s_m) % length_m
    laps = math.floor((start_s_m - zone.brake_s_m - apex_ahead) / length_m) + 1
    brake = zone.brake_s_m + laps * length_m
    return brake, brake + apex_ahead


def drive_braking(steps: pd.DataFrame, start_s_m: float, length_m: float,
                  zones: list[LineZone], termination: str) -> list[ZoneDrive]:
    """Read each zone's first pass from a drive's steps (``DriveResult.steps_trace``: its
    ``distance_m``, ``speed_kmh`` and ``brake`` columns). Zones the drive never approached are
    left out. A drive that the env ended (``termination`` other than ``max_steps``) is
    reported in the last zone whose braking point it passed (the corner it was in or leaving),
    or in the first zone when it ended in that one's approach; the zones after it are left out.

    The drive's brake for a zone is a press that *begins* in the approach: a press held on from
    the corner before is that corner's."""
    ended_early = termination not in ("", "max_steps")
    u = start_s_m + steps["distance_m"].to_numpy(dtype=float)
    kmh = steps["speed_kmh"].to_numpy(dtype=float)
    on = steps["brake"].to_numpy(dtype=float) >= BRAKE_ON
    begins = on & ~np.concatenate(([False], on[:-1]))  # a press starts at this step
    passes = sorted((_first_pass(start_s_m, zone, length_m), k, zone)
                    for k, zone in enumerate(zones))  # fmt: skip
    last = len(passes) - 1
    if ended_early and len(u):
        passed = [i for i, ((b, _), _, _) in enumerate(passes) if b < u[-1]]
        last = passed[-1] if passed else 0
    out = []
    for i, ((b, a), k, zone) in enumerate(passes[:last + 1]):
        # the approach: APPROACH_M before the braking point, or from the previous zone's apex
        previous_apex = zones[k - 1].apex_s_m  # zone -1: the last, the lap before
        since = max(b - APPROACH_M, b - (b - previous_apex) % length_m)
        if not len(u) or u.max() <= since:
            continue  # never approached
        past = np.flatnonzero(u >= a)
        end = int(past[0]) if past.size else len(u)  # the steps before the apex
        approach = np.flatnonzero(u[:end] > since)
        pressed = approach[begins[approach]]
        at_b = np.flatnonzero(u[:end] >= b)
        ended = ended_early and i == last
        first = int(pressed[0]) if pressed.size else None
        out.append(ZoneDrive(
            zone=k, line=zone,
            brake_s_m=None if first is None else float(u[first] % length_m),
            brake_kmh=None if first is None else float(kmh[first]),
            late_m=None if first is None else float(u[first] - b),
            at_line_brake_kmh=float(kmh[at_b[0]]) if at_b.size else None,
            apex_kmh=float(kmh[past[0]]) if past.size else None,
            ended_by=termination if ended else None,
            ended_s_m=float(u[-1] % length_m) if ended else None,
            ended_kmh=float(kmh[-1]) if ended else None,
        ))  # fmt: skip
    return out


def _kmh(x: float | None) -> str:
    return "-" if x is None else f"{x:.0f} km/h"


def braking_lines(rows: list[dict[str, Any]], line: str) -> list[str]:
    """The ``replay --braking`` table, one line per zone the drive approached (rows of
    :meth:`ZoneDrive.as_dict`); ``line`` names the profile (e.g. "the centre line's QSS
    lap")."""
    if not rows:
        return [f"braking: the drive approached no braking zone of {line}"]
    out = [f"braking zones of {line}, the drive's first pass (brake >= {BRAKE_ON:g}; late: "
           "after the line's braking point):"]
    for r in rows:
        zone = (f"zone {r['zone']}: the line brakes at {r['line_brake_s_m']:.0f} m from "
                f"{r['line_brake_kmh']:.0f} to {r['line_apex_kmh']:.0f} km/h at "
                f"{r['line_apex_s_m']:.0f} m")
        if r["brake_s_m"] is None:
            drive = "no brake in the approach"
        else:
            drive = (f"brakes at {r['brake_s_m']:.0f} m ({r['late_m']:+.0f} m late) at "
                     f"{r['brake_kmh']:.0f} km/h")
        drive += f"; {_kmh(r['at_line_brake_kmh'])} at the line's point"
        if r["ended_by"] is not None:
            drive += (f"; ended ({r['ended_by']}) at {r['ended_s_m']:.0f} m, "
                      f"{r['ended_kmh']:.0f} km/h")
        else:
            drive += f"; {_kmh(r['apex_kmh'])} at the apex"
        out.append(f"  {zone} | drive {drive}")
    return out

"""Where a driven lap loses time against a QSS speed profile, sector by sector.

A race engineer reads a lap against a reference lap as a running time delta along the track;
here the reference is a quasi-steady-state profile (``speed_profile``), usually the one whose lap
is the track's reference limit. A best/limit ratio says how far a driver is from the limit; this
says where: in the braking zones before slow corners, through corners, or on the straights after
them (a slow exit costs time all the way down the next straight, so each sector's exit speed is
kept beside its time).

Times are compared at the same track stations (centreline arc length ``s``), so a driver on
another line than the profile's is charged for its line and its speed together; the sectors'
losses add up to the lap's whole gap to the profile exactly.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.lines.speed_profile import SpeedProfile
from formula_tourney.sim.track import Track


@dataclass(frozen=True)
class Sector:
    """A stretch of track between two stations, named for a reader (``3 arc R12 175deg``);
    ``kind`` (straight, arc, or bin on a track without a segment list) lets a reader add the
    losses of all braking zones, or all corners, into one figure."""

    name: str
    s_start_m: float
    s_end_m: float
    kind: str = "bin"


@dataclass(frozen=True)
class SectorLoss:
    """One sector of one lap against the profile: times, the loss, and speeds (km/h)."""

    name: str
    kind: str
    s_start_m: float
    s_end_m: float
    driven_s: float
    profile_s: float
    loss_s: float
    min_speed_kmh: float
    profile_min_speed_kmh: float
    exit_speed_kmh: float
    profile_exit_speed_kmh: float

    def as_dict(self) -> dict[str, float | str]:
        return asdict(self)


@dataclass(frozen=True)
class LapLoss:
    """One lap against the profile: the running loss along the track and its sectors' shares.

    The sector table and the loss-along-the-track figure both read this one object, so the two
    can never disagree: a sector's loss is the rise of the running loss over it.
    """

    lap_s: float
    profile_lap_s: float
    stations_m: np.ndarray
    time_s: np.ndarray
    loss_s: np.ndarray
    sectors: list[SectorLoss]

    def loss_by_kind(self) -> dict[str, float]:
        """Total loss per sector kind (straight / arc / bin), in the sectors' order of kinds."""
        totals: dict[str, float] = {}
        for sec in self.sectors:
            totals[sec.kind] = totals.get(sec.kind, 0.0) + sec.loss_s
        return totals


def track_sectors(track: Track, bin_m: float = 100.0) -> list[Sector]:
    """The track's own segments (straights and arcs, as its file lists them) when it has them,
    else equal bins of about ``bin_m`` (a track made from a polyline has no segment list)."""
    length = float(track.length_m)
    starts = [float(seg["s_start_m"]) for seg in track.segments if "s_start_m" in seg]
    if starts and len(starts) == len(track.segments):
        names, kinds = [], []
        for k, seg in enumerate(track.segments, start=1):
            kind = str(seg.get("type", "segment"))
            if kind == "arc" and "radius_m" in seg:
                names.append(f"{k} arc R{float(seg['radius_m']):.0f} "
                             f"{abs(float(seg.get('angle_deg', 0.0))):.0f}deg")  # fmt: skip
            else:
                names.append(f"{k} {kind} {float(seg.get('arc_length_m', 0.0)):.0f} m")
            kinds.append(kind)
        ends = [*starts[1:], length]
        spans = zip(names, starts, ends, kinds, strict=True)
        return [Sector(n, a, min(b, length), kind) for n, a, b, kind in spans if b > a]
    if bin_m <= 0:
        raise UserInputError(f"sector length must be > 0 m, got {bin_m}")
    count = max(1, int(round(length / bin_m)))
    edges = np.linspace(0.0, length, count + 1)
    return [Sector(f"{k + 1} {a:.0f}-{b:.0f} m", float(a), float(b), "bin")
            for k, (a, b) in enumerate(zip(edges[:-1], edges[1:], strict=True))]  # fmt: skip


def driven_time_at(time_s: np.ndarray, s_m: np.ndarray, lap_s: float,
                   length_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Stations and times of one timed lap as a monotone curve from (0, 0) to (L, lap_s).

    A lap trace's rows are control steps with ``s`` wrapping at the start line, timed from the
    lap's start to within one step (the env times the crossing inside a physics step, the
    trace's window is cut at whole steps). So the crossings are placed where the rows' own
    positions put them (interpolated, or extrapolated from the two nearest rows) and the rows'
    times are then stretched to the lap's exact time: one step's rounding would otherwise show
    as a 0.1 s loss at the line.
    """
    t = np.asarray(time_s, dtype=float)
    s = np.asarray(s_m, dtype=float)
    if t.ndim != 1 or t.shape != s.shape or t.size < 2:
        raise UserInputError("a lap trace needs matching time_s and s_m columns of >= 2 rows")
    # s wraps forward at the line (and back, for a car that reverses over it); rows before the
    # first wrap that still read the previous lap's end (s near L) lie just before the line
    jumps = np.diff(s)
    wraps = np.cumsum((jumps < -0.5 * length_m).astype(int) - (jumps > 0.5 * length_m))
    first = -length_m if s[0] > 0.5 * length_m else 0.0
    unwrapped = s + first + length_m * np.concatenate([[0], wraps])
    # only rows past every earlier one: a car that stops, or rolls back, adds no station twice
    keep = np.concatenate([[True], unwrapped[1:] > np.maximum.accumulate(unwrapped)[:-1]])
    stations, times = unwrapped[keep], t[keep]
    if stations.size < 2:
        raise UserInputError("a lap trace needs rows at >= 2 distinct positions")
    t_start, t_end = _time_at(0.0, stations, times), _time_at(length_m, stations, times)
    if not t_end > t_start:
        raise UserInputError("a lap trace must run forwards over the lap")
    inside = (stations > 0.0) & (stations < length_m)
    curve_s = np.concatenate([[0.0], stations[inside], [length_m]])
    curve_t = np.concatenate([[t_start], times[inside], [t_end]])
    return curve_s, (curve_t - t_start) * (float(lap_s) / (t_end - t_start))


def _time_at(station_m: float, stations: np.ndarray, times: np.ndarray) -> float:
    """Time at a station: interpolated between rows, extrapolated past the first or last two."""
    if stations[0] <= station_m <= stations[-1]:
        return float(np.interp(station_m, stations, times))
    a, b = (0, 1) if station_m < stations[0] else (-2, -1)
    rate = (times[b] - times[a]) / (stations[b] - stations[a])
    return float(times[a] + (station_m - stations[a]) * rate)


def lap_loss(trace: dict[str, np.ndarray], lap_s: float, track: Track, profile: SpeedProfile,
             sectors: list[Sector]) -> LapLoss:
    """The lap ``trace`` (columns time_s, s_m, speed_kmh; one timed lap of ``lap_s``) against
    ``profile``: the running loss at the lap's stations and each sector's share of it; the
    sectors' losses sum to ``lap_s - profile.lap_time_s`` when they cover the lap."""
    length = float(track.length_m)
    if profile.time_s.shape != track.s_m.shape:
        raise UserInputError(f"the profile has {profile.time_s.size} samples, track "
                             f"{track.name!r} {track.n}: a profile of another track?")  # fmt: skip
    stations, times = driven_time_at(trace["time_s"], trace["s_m"], lap_s, length)
    prof_s = np.concatenate([track.s_m, [length]])
    prof_t = np.concatenate([profile.time_s, [profile.lap_time_s]])
    prof_v = np.concatenate([profile.speed_kmh, [profile.speed_kmh[0]]])
    running = times - np.interp(stations, prof_s, prof_t)
    s_rows = np.mod(np.asarray(trace["s_m"], dtype=float), length)
    v_rows = np.asarray(trace["speed_kmh"], dtype=float)
    out = []
    for sec in sectors:
        a, b = sec.s_start_m, sec.s_end_m
        driven = float(np.interp(b, stations, times) - np.interp(a, stations, times))
        ref = float(np.interp(b, prof_s, prof_t) - np.interp(a, prof_s, prof_t))
        rows = (s_rows >= a) & (s_rows < b)
        # the profile's own samples inside the sector and its values at the two ends
        inside = (prof_s > a) & (prof_s < b)
        prof_min = min(float(np.interp(a, prof_s, prof_v)), float(np.interp(b, prof_s, prof_v)),
                       float(prof_v[inside].min()) if inside.any() else math.inf)  # fmt: skip
        near_end = int(np.argmin(np.abs(((s_rows - b + 0.5 * length) % length) - 0.5 * length)))
        out.append(SectorLoss(
            name=sec.name, kind=sec.kind, s_start_m=a, s_end_m=b, driven_s=driven,
            profile_s=ref, loss_s=driven - ref,
            min_speed_kmh=float(v_rows[rows].min()) if rows.any() else float("nan"),
            profile_min_speed_kmh=prof_min,
            exit_speed_kmh=float(v_rows[near_end]),
            profile_exit_speed_kmh=float(np.interp(b, prof_s, prof_v)),
        ))  # fmt: skip
    return LapLoss(lap_s=float(lap_s), profile_lap_s=float(profile.lap_time_s),
                   stations_m=stations, time_s=times, loss_s=running, sectors=out)  # fmt: skip

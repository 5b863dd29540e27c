"""Recorded line (the paper's RC): the path a driver actually took in one lap.

The paper's agents follow "a racing line recorded from the Tita bot". Here the follower's
trace (one point per 200 ms control step, 3-16 m apart) is cut to one timed lap, projected
onto the track and turned into one offset per track sample through a periodic smoothing
spline that may pass ``smoothing_m`` (RMS) from the points. That bound is what smooths: a
moving average over points 9 m apart cut a 15 m hairpin by a metre and slowed the line's QSS
lap by 13% (measured), while the spline removes the controller's centimetre wobble and keeps
the corner shape. The line's curvature (and hence LAC) is smooth.
"""

from __future__ import annotations

import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.lines.mincurv import spline_offsets
from formula_tourney.sim.track import Track


def lap_points(track: Track, trace: dict) -> tuple[np.ndarray, np.ndarray]:
    """Track position and lateral offset of the trace points of the last complete timed lap.

    ``trace["lap"]`` counts start-line crossings at each step: points with ``lap == k`` were
    driven during timed lap ``k``; the last ``k`` below the final count is complete.
    """
    laps = np.asarray(trace.get("lap", []), dtype=int)
    xs = np.asarray(trace.get("x_m", []), dtype=float)
    ys = np.asarray(trace.get("y_m", []), dtype=float)
    if laps.size == 0 or laps.size != xs.size or xs.size != ys.size:
        raise UserInputError("a recorded line needs a trace with lap, x_m and y_m per step")
    completed = int(laps.max()) - 1
    if completed < 1:
        raise UserInputError("a recorded line needs at least one complete timed lap")
    keep = laps == completed
    s_pts, lat_pts = [], []
    hint = -1
    for x, y in zip(xs[keep], ys[keep], strict=True):
        s, lateral, hint = track.project(float(x), float(y), hint)
        s_pts.append(s)
        lat_pts.append(lateral)
    return np.asarray(s_pts), np.asarray(lat_pts)


def recorded_offsets(track: Track, drive_result: dict, smoothing_m: float = 0.05,
                     min_spacing_m: float = 2.0) -> np.ndarray:
    """Offsets per track sample of the line driven in ``drive_result`` (follower output)."""
    trace = drive_result.get("trace")
    if not isinstance(trace, dict):
        raise UserInputError("a recorded line needs the driver's trace")
    s_pts, lat_pts = lap_points(track, trace)
    order = np.argsort(s_pts)
    s_pts, lat_pts = s_pts[order], lat_pts[order]
    # Drop points closer than min_spacing_m (slow sections): near-duplicate spline nodes
    # would turn measurement wobble into curvature.
    keep = [0]
    for i in range(1, s_pts.size):
        if s_pts[i] - s_pts[keep[-1]] >= min_spacing_m:
            keep.append(i)
    if track.length_m - s_pts[keep[-1]] + s_pts[keep[0]] < min_spacing_m and len(keep) > 1:
        keep.pop()
    s_pts, lat_pts = s_pts[keep], lat_pts[keep]
    if s_pts.size < 8:
        raise UserInputError("the recorded lap has too few points for a line")
    if smoothing_m < 0:
        raise UserInputError(f"smoothing must be >= 0 m, got {smoothing_m}")
    px, py, _ = track.pose_at(s_pts, lat_pts)
    offsets = spline_offsets(track, s_pts, np.asarray(px), np.asarray(py), lat_pts,
                             smoothing_m=smoothing_m)
    return np.clip(offsets, -track.width_right_m, track.width_left_m)

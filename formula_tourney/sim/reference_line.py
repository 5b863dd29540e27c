"""A reference line on a track: lateral offsets per centreline sample, and its geometry.

The env measures angle and trackPos against it, LAC reads its curvature ahead, and the lines
package produces the offsets (centre, min-curvature, recorded, genetic). Kept in ``sim`` because
the env needs it and lower layers never import higher ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from formula_tourney.sim.track import Track


@dataclass(frozen=True, eq=False)
class ReferenceLine:
    """A closed line given by ``offset_m[i]`` (lateral, left > 0) at each track sample ``i``.

    ``s_line_m`` is arc length along the line itself at each sample (racing lines are shorter
    than the centreline); ``curvature_1pm`` is the line's signed curvature there.
    """

    track: Track
    offset_m: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    curvature_1pm: np.ndarray
    s_line_m: np.ndarray
    length_m: float

    @classmethod
    def from_offsets(cls, track: Track, offset_m: np.ndarray | float = 0.0) -> ReferenceLine:
        off = np.broadcast_to(np.asarray(offset_m, dtype=float), (track.n,)).copy()
        x = track.x_m - off * np.sin(track.heading_rad)
        y = track.y_m + off * np.cos(track.heading_rad)
        seg = np.hypot(np.roll(x, -1) - x, np.roll(y, -1) - y)
        s_line = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
        heading, curvature = _uneven_heading_curvature(x, y)
        return cls(track, off, x, y, heading, curvature, s_line, float(seg.sum()))

    @classmethod
    def centre(cls, track: Track) -> ReferenceLine:
        return cls.from_offsets(track, 0.0)

    def curvature_ahead(self, s_m: np.ndarray | float, distances_m) -> np.ndarray:
        """Line curvature at ``distances_m`` ahead of track position ``s`` (LAC), per position.

        Distances are measured along the centreline, which differs from line distance by a few
        percent at most; that keeps the look-up an O(1) index instead of a search.
        """
        s = np.atleast_1d(np.asarray(s_m, dtype=float))
        d = np.asarray(distances_m, dtype=float)
        idx = self.track.index_at(s[:, None] + d[None, :])
        return self.curvature_1pm[idx]


def _uneven_heading_curvature(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heading and curvature of a closed polyline whose spacing varies (offset lines)."""
    xp, xm = np.roll(x, -1), np.roll(x, 1)
    yp, ym = np.roll(y, -1), np.roll(y, 1)
    heading = np.arctan2(yp - ym, xp - xm)
    # Curvature of the circle through three consecutive points (Menger curvature), signed.
    a = np.hypot(x - xm, y - ym)
    b = np.hypot(xp - x, yp - y)
    c = np.hypot(xp - xm, yp - ym)
    cross = (x - xm) * (yp - y) - (y - ym) * (xp - x)
    curvature = 2.0 * cross / np.maximum(a * b * c, 1e-12)
    return heading, curvature

"""Test tracks for the simulator tests, built without the track catalog (no tests here).

A stadium oval (two straights joined by half circles) has known geometry: straight length,
radius and width, so tests can compare range finders and lap distances with closed forms.
"""

from __future__ import annotations

import numpy as np

from formula_tourney.sim.track import Track


def stadium(straight_m: float = 400.0, radius_m: float = 80.0, width_m: float = 12.0,
            name: str = "stadium", step_m: float = 0.25) -> Track:
    """Counter-clockwise stadium; the start line is at the start of the bottom straight."""
    n_s = int(round(straight_m / step_m))
    n_a = int(round(np.pi * radius_m / step_m))
    xs = np.linspace(0.0, straight_m, n_s, endpoint=False)
    bottom = np.c_[xs, np.zeros_like(xs)]
    a = np.linspace(-np.pi / 2, np.pi / 2, n_a, endpoint=False)
    right = np.c_[straight_m + radius_m * np.cos(a), radius_m + radius_m * np.sin(a)]
    top = np.c_[straight_m - xs, np.full_like(xs, 2 * radius_m)]
    left = np.c_[radius_m * np.cos(a + np.pi), radius_m + radius_m * np.sin(a + np.pi)]
    pts = np.vstack([bottom, right, top, left])
    return Track.from_centreline(name, pts[:, 0], pts[:, 1], width_m / 2, width_m / 2)


def long_straight(length_m: float = 6000.0, width_m: float = 20.0) -> Track:
    """A very long, thin stadium: a straight long enough to reach top speed."""
    return stadium(straight_m=length_m, radius_m=150.0, width_m=width_m, name="straight",
                   step_m=1.0)

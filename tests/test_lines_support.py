"""Small synthetic tracks for the lines and bots tests (no tests here).

Built from (length, curvature) segments exactly like authored tracks are: straights and
constant-radius arcs meeting with a curvature jump, so the tests see the joins that real
tracks have, without depending on the built-in catalog.
"""

from __future__ import annotations

import numpy as np

from formula_tourney.sim.track import Track


def segment_track(name: str, segments: list[tuple[float, float]], width_m: float,
                  fine_m: float = 0.05) -> Track:
    """Integrate heading along ``(length_m, curvature_1pm)`` segments; close the last gap."""
    kappa = np.concatenate([np.full(max(int(round(length / fine_m)), 1), k)
                            for length, k in segments])
    heading = np.concatenate([[0.0], np.cumsum(kappa * fine_m)[:-1]])
    x = np.cumsum(np.cos(heading)) * fine_m
    y = np.cumsum(np.sin(heading)) * fine_m
    # Spread the small closure gap linearly so the loop closes exactly.
    gap_x, gap_y = x[-1] + np.cos(heading[-1]) * fine_m - x[0], y[-1] + np.sin(heading[-1]) * \
        fine_m - y[0]
    frac = np.linspace(0.0, 1.0, x.size, endpoint=False)
    x, y = x - gap_x * frac, y - gap_y * frac
    return Track.from_centreline(name, x, y, width_m / 2, width_m / 2)


def stadium(radius_m: float = 60.0, straight_m: float = 300.0, width_m: float = 12.0) -> Track:
    """Two straights joined by two half circles (left turns)."""
    k = 1.0 / radius_m
    arc = np.pi * radius_m
    return segment_track("stadium", [(straight_m, 0.0), (arc, k), (straight_m, 0.0), (arc, k)],
                         width_m)


def hairpins(width_m: float = 10.0) -> Track:
    """A technical loop: a hairpin of 15 m radius, a chicane and sweepers (total turn 2 pi)."""
    segs = [
        (250.0, 0.0), (np.pi * 15.0, 1 / 15.0), (120.0, 0.0),
        (np.pi / 4 * 40.0, -1 / 40.0), (np.pi / 4 * 40.0, 1 / 40.0), (150.0, 0.0),
        (np.pi / 2 * 80.0, 1 / 80.0), (200.0, 0.0), (np.pi / 2 * 25.0, 1 / 25.0),
    ]
    return segment_track("hairpins", segs, width_m)


def circle(radius_m: float, width_m: float = 10.0, points: int = 40000) -> Track:
    """A circle sampled finely enough that the 1 m resampling keeps curvature exact to 1e-5."""
    th = np.linspace(0.0, 2 * np.pi, points, endpoint=False)
    return Track.from_centreline("circle", radius_m * np.cos(th), radius_m * np.sin(th),
                                 width_m / 2, width_m / 2)


def symmetric_track(name: str, half: list[tuple[float, float]], width_m: float) -> Track:
    """A closed track mirror-symmetric about the vertical through its start.

    ``half`` (length, curvature) segments must turn by exactly pi; a straight is appended so
    the half ends on the axis, and the second half is the first one reversed (mirror plus
    reversed direction keeps each turn's sign), so the loop closes by construction.
    """
    heading, x = 0.0, 0.0
    for length, k in half:
        if k == 0.0:
            x += length * np.cos(heading)
        else:
            x += (np.sin(heading + k * length) - np.sin(heading)) / k
            heading += k * length
    assert abs(heading - np.pi) < 1e-9, "half must turn by pi"
    segs = half + [(2.0 * x, 0.0)] + half[::-1]
    return segment_track(name, segs, width_m)


def technical_like(width_m: float = 10.0) -> Track:
    """About 2 km, 10 m wide, 12 m hairpins, a chicane and a fast sweeper (like Aalborg)."""
    q = np.pi / 2
    half = [
        (250.0, 0.0), (q * 40.0, 1 / 40.0), (100.0, 0.0), (q * 25.0, -1 / 25.0), (60.0, 0.0),
        (np.pi * 12.0, 1 / 12.0), (120.0, 0.0), (q / 2 * 30.0, 1 / 30.0),
        (q / 2 * 30.0, -1 / 30.0), (90.0, 0.0), (q * 15.0, 1 / 15.0), (40.0, 0.0),
        (q * 15.0, -1 / 15.0), (60.0, 0.0), (q / 2 * 60.0, -1 / 60.0), (q / 2 * 60.0, 1 / 60.0),
        (80.0, 0.0),
    ]
    return symmetric_track("technical-like", half, width_m)

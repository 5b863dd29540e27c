"""Track maps with matplotlib's Agg backend: asphalt, edges, start line and driving direction,
and under the map of a track with heights its elevation profile (height and banking along s).

Used by ``tracks show --plot``, ``tracks generate --plot`` and for the README figure. Headless
(Agg) so it works on servers and in worker processes; written through ``safeio.atomic_write`` so
a failed plot never leaves a truncated image.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.safeio import atomic_write
from formula_tourney.sim.track import Track

PLOT_SUFFIXES = (".png", ".svg", ".pdf")
ELEVATION_MIN_RANGE_M = 0.5
"""A track whose heights span less than this (and that has no banking) gets no profile: a
map is all there is to see of it (the built-in three are flat)."""


def has_elevation(track: Track) -> bool:
    """True when heights or banking matter enough to plot a profile under the map."""
    return bool(np.ptp(track.z_m) >= ELEVATION_MIN_RANGE_M or np.any(track.banking_rad != 0.0))


def check_plot_path(path: str | Path) -> Path:
    """Refuse an unsupported image type before any work is done (the suffix picks the format)."""
    path = Path(path)
    if path.suffix.lower() not in PLOT_SUFFIXES:
        raise UserInputError(f"--plot {path}: use a {', '.join(PLOT_SUFFIXES)} file name")
    if path.exists() and path.is_dir():
        raise UserInputError(f"--plot {path}: is a folder, not a file name")
    return path


def track_title(track: Track) -> str:
    """``name: 2.37 km, 18 m wide, min radius 250 m``: the numbers people compare tracks by."""
    width = float(np.mean(track.width_m))
    return (f"{track.name}: {track.length_m / 1000:.2f} km, {width:.3g} m wide, "
            f"min radius {track.min_radius_m:.0f} m")


def draw_track(ax, track: Track) -> None:
    """Draw one track on a matplotlib axes: grey asphalt, dark edges, start line and arrow."""
    from matplotlib.patches import FancyArrowPatch, PathPatch
    from matplotlib.path import Path as MplPath

    s = track.s_m
    lx, ly, _ = track.pose_at(s, track.width_left_m)
    rx, ry, _ = track.pose_at(s, -track.width_right_m)
    # The asphalt is the ring between the edges: left loop forward, right loop backward, so the
    # non-zero winding rule leaves the infield empty whichever way the lap turns.
    verts = np.concatenate([
        np.column_stack([lx, ly]), [[lx[0], ly[0]]],
        np.column_stack([rx[::-1], ry[::-1]]), [[rx[-1], ry[-1]]],
    ])
    n = track.n
    codes = ([MplPath.MOVETO] + [MplPath.LINETO] * (n - 1) + [MplPath.CLOSEPOLY]) * 2
    ax.add_patch(PathPatch(MplPath(verts, codes), facecolor="0.72", edgecolor="none"))
    for ex, ey in ((lx, ly), (rx, ry)):
        ax.plot(np.append(ex, ex[0]), np.append(ey, ey[0]), color="0.15", lw=0.7)
    # Start line across the asphalt at s = 0, with an arrow showing the driving direction.
    ax.plot([lx[0], rx[0]], [ly[0], ry[0]], color="red", lw=2.2, solid_capstyle="butt",
            label="start line")
    span = max(np.ptp(track.x_m), np.ptp(track.y_m))
    ahead = min(0.08 * span, 0.1 * track.length_m)
    x0, y0, _ = track.pose_at(0.0)
    x1, y1, _ = track.pose_at(ahead)
    ax.add_patch(FancyArrowPatch((float(x0), float(y0)), (float(x1), float(y1)),
                                 arrowstyle="-|>", mutation_scale=12, color="red", lw=1.2))
    ax.set_aspect("equal")
    ax.set_title(track_title(track), fontsize=9)
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.autoscale_view()


def draw_elevation(ax, track: Track) -> None:
    """Height of the centreline along s (m), with the banking (deg) on a second axis when any:
    where the map cannot show what a car climbs, drops or leans into."""
    s = np.append(track.s_m, track.length_m)
    z = np.append(track.z_m, track.z_m[0])
    ax.fill_between(s, z, float(z.min()) - 0.05 * max(np.ptp(z), 1.0), color="0.8", lw=0)
    ax.plot(s, z, color="0.15", lw=0.9)
    ax.set_xlim(0.0, track.length_m)
    ax.set_xlabel("s (m)", fontsize=8)
    ax.set_ylabel("z (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.set_title(f"elevation: {np.ptp(track.z_m):.1f} m range, max grade "
                 f"{100 * np.max(np.abs(np.tan(track.slope_rad))):.1f} %", fontsize=8)
    if np.any(track.banking_rad != 0.0):
        bank = ax.twinx()
        bank.plot(s, np.degrees(np.append(track.banking_rad, track.banking_rad[0])),
                  color="tab:blue", lw=0.8)
        bank.set_ylabel("banking (deg)", fontsize=8, color="tab:blue")
        bank.tick_params(labelsize=7, colors="tab:blue")


def plot_tracks(
    tracks: Track | Sequence[Track], path: str | Path, *, columns: int | None = None,
    dpi: int = 120,
) -> Path:
    """Write a map of one or several tracks (one panel each) to ``path`` (.png/.svg/.pdf)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = check_plot_path(path)
    items = [tracks] if isinstance(tracks, Track) else list(tracks)
    if not items:
        raise ValueError("plot_tracks needs at least one track")
    cols = columns or min(len(items), 3)
    rows = math.ceil(len(items) / cols)
    # Panels as tall as the tallest track needs, so wide tracks do not float in white space.
    aspect = max(float(np.ptp(t.y_m) + 40.0) / float(np.ptp(t.x_m) + 40.0) for t in items)
    panel_h = 4.6 * min(max(aspect, 0.45), 1.4) + 0.6
    if not any(has_elevation(t) for t in items):
        fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, panel_h * rows),
                                 squeeze=False)
        for ax in axes.flat[len(items):]:
            ax.set_visible(False)
        for ax, track in zip(axes.flat, items, strict=False):
            draw_track(ax, track)
    else:
        # Each panel: the map, and under it a strip with the profile (a flat track's strip
        # stays empty so that panels line up).
        profile_h = 1.5
        fig = plt.figure(figsize=(4.6 * cols, (panel_h + profile_h) * rows))
        grid = fig.add_gridspec(2 * rows, cols, height_ratios=[panel_h, profile_h] * rows)
        for k, track in enumerate(items):
            row, col = divmod(k, cols)
            draw_track(fig.add_subplot(grid[2 * row, col]), track)
            if has_elevation(track):
                draw_elevation(fig.add_subplot(grid[2 * row + 1, col]), track)
    fig.tight_layout()
    fmt = path.suffix.lstrip(".").lower()
    try:
        atomic_write(path, lambda p: fig.savefig(p, format=fmt, dpi=dpi))
    finally:
        plt.close(fig)
    return path

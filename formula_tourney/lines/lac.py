"""Look-ahead curvature (LAC): curvature of a reference line at fixed distances ahead.

The paper feeds the agent the curvature 20/40/60/80 m ahead "recorded from a previous lap";
here it is read from any line's geometry (``ReferenceLine.curvature_ahead``), optionally
smoothed first so that a kinked offset array does not turn into spikes in the agent's input.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.sim.reference_line import ReferenceLine
from formula_tourney.sim.track import Track

DEFAULT_LAC_DISTANCES_M: tuple[float, ...] = (20.0, 40.0, 60.0, 80.0)
"""The paper's look-ahead distances (its telemetry table)."""


def smoothed_curvature(line: ReferenceLine, window_m: float = 0.0) -> np.ndarray:
    """Line curvature per track sample, averaged over a centred window of ``window_m`` metres.

    A moving average on the closed loop: curvature from three-point circles is noisy at 1 m
    spacing wherever offsets come from data (recorded laps), and LAC should describe the corner,
    not the noise.
    """
    kappa = np.asarray(line.curvature_1pm, dtype=float)
    if window_m <= 0.0:
        return kappa.copy()
    spacing = line.track.length_m / line.track.n
    half = max(int(round(window_m / spacing / 2.0)), 0)
    if half == 0:
        return kappa.copy()
    kernel = np.ones(2 * half + 1) / (2 * half + 1)
    padded = np.concatenate([kappa[-half:], kappa, kappa[:half]])
    return np.convolve(padded, kernel, mode="valid")


def lac(
    track: Track,
    offsets_m: np.ndarray,
    s_m: np.ndarray | float,
    distances_m: Sequence[float] = DEFAULT_LAC_DISTANCES_M,
    window_m: float = 0.0,
) -> np.ndarray:
    """LAC of the line given by ``offsets_m``: shape ``(len(s), len(distances))`` in 1/m.

    Distances are along the centreline (the same O(1) look-up the env uses).
    """
    offsets = np.asarray(offsets_m, dtype=float)
    if offsets.shape != (track.n,):
        raise UserInputError(
            f"offsets for track {track.name!r} must have {track.n} values, got {offsets.shape}"
        )
    if any(d < 0 for d in distances_m):
        raise UserInputError(f"LAC distances must be >= 0 m, got {list(distances_m)}")
    line = ReferenceLine.from_offsets(track, offsets)
    kappa = smoothed_curvature(line, window_m)
    s = np.atleast_1d(np.asarray(s_m, dtype=float))
    idx = track.index_at(s[:, None] + np.asarray(distances_m, dtype=float)[None, :])
    return kappa[idx]

"""One entry point for reference lines: ``reference_offsets(track, kind, car)``, cached on disk.

A tournament asks for the same lines over and over (every job, every worker process), and
the genetic and recorded lines cost seconds to minutes of driving, so each line is computed
once per track geometry and car and stored as ``.npy`` under the user cache dir
(``platformdirs.user_cache_dir("formula-tourney")/lines``, or ``$FORMULA_TOURNEY_CACHE_DIR``).
The key holds the track name, a hash of its geometry, ``car.fingerprint()``, the kind and an
algorithm version, so a changed track, car or algorithm never reads a stale line.

The recorded and genetic lines need a driver (the follower bot). ``lines`` sits below ``bots``
(imports go downward), so the driver is an argument here, required for those two kinds;
``bots.line_offsets.reference_offsets(track, kind, car)`` is the same call with the follower passed
in, and is what training, tournaments and the CLI use.
"""

from __future__ import annotations

import hashlib
import io
import os
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.lines.centre import centre_offsets
from formula_tourney.lines.genetic import genetic_line
from formula_tourney.lines.kinds import LINE_KINDS
from formula_tourney.lines.mincurv import mincurv_offsets
from formula_tourney.lines.recorded import recorded_offsets
from formula_tourney.safeio import atomic_write_bytes
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.track import Track

ALGORITHM_VERSION = 2
"""Bump when a line's algorithm changes: old cache entries then stop matching."""

DRIVEN_KINDS: tuple[str, ...] = ("recorded", "genetic")
"""Lines made by driving: they need a driver (``bots.follower.drive``)."""

CACHE_ENV_VAR = "FORMULA_TOURNEY_CACHE_DIR"

Driver = Callable[..., dict]
"""``drive(track, offsets, laps=2, car=car) -> dict`` with ``trace``, ``best_lap_s``, ``damage``
and ``finished``, as ``bots.follower.drive`` returns."""


def cache_dir() -> Path:
    """Folder of cached lines: ``$FORMULA_TOURNEY_CACHE_DIR`` or the platform's user cache."""
    env = os.environ.get(CACHE_ENV_VAR)
    if env:
        return Path(env) / "lines"
    from platformdirs import user_cache_dir

    return Path(user_cache_dir("formula-tourney")) / "lines"


def geometry_hash(track: Track) -> str:
    """Hash of the arrays that define a track (rounded to 0.1 mm so re-loads match)."""
    h = hashlib.sha256()
    for arr in (track.x_m, track.y_m, track.width_left_m, track.width_right_m):
        h.update(np.round(np.asarray(arr, dtype=float), 4).tobytes())
    h.update(np.float64(round(track.length_m, 4)).tobytes())
    # Heights, banking and surfaces change how the driven lines come out; hashed only where a
    # track has them, so a level asphalt track keeps its key (and its cached lines).
    if track.has_surface:
        for arr in (track.z_m, track.banking_rad):
            h.update(np.round(np.asarray(arr, dtype=float), 4).tobytes())
    if np.any(track.friction_road != 1.0) or np.any(track.rolling_road != 0.0):
        for arr in (track.friction_road, track.rolling_road):
            h.update(np.round(np.asarray(arr, dtype=float), 6).tobytes())
    return h.hexdigest()[:12]


def cache_path(track: Track, kind: str, car: CarParams) -> Path:
    safe_name = re.sub(r"[^A-Za-z0-9_.+-]", "_", track.name)[:64] or "track"
    return cache_dir() / (
        f"{safe_name}-{geometry_hash(track)}-{car.fingerprint()}-{kind}-v{ALGORITHM_VERSION}.npy"
    )


def check_kind(kind: str) -> str:
    if kind not in LINE_KINDS:
        raise UserInputError(f"unknown line {kind!r}; known lines: {', '.join(LINE_KINDS)}")
    return kind


def reference_offsets(
    track: Track,
    kind: str,
    car: CarParams | None = None,
    driver: Driver | None = None,
    *,
    use_cache: bool = True,
) -> np.ndarray:
    """Lateral offsets (one per track sample) of the reference line ``kind`` on ``track``.

    ``driver`` drives the recorded and genetic lines (pass ``bots.follower.drive``, or call
    ``bots.line_offsets.reference_offsets``); a cached line is returned without driving.
    """
    check_kind(kind)
    if kind == "centre":
        return centre_offsets(track)
    if kind in DRIVEN_KINDS and driver is None:
        raise TypeError(
            f"the {kind} line is made by driving: pass driver= (bots.follower.drive), or call "
            "formula_tourney.bots.line_offsets.reference_offsets"
        )
    car = car or CarParams()
    path = cache_path(track, kind, car)
    if use_cache and path.is_file():
        try:
            offsets = np.load(path, allow_pickle=False)
            if offsets.shape == (track.n,) and np.all(np.isfinite(offsets)):
                return offsets
        except (OSError, ValueError):
            pass  # a damaged entry is recomputed and overwritten below
    offsets = _compute(track, kind, car, driver, use_cache)
    if use_cache:
        buf = io.BytesIO()
        np.save(buf, offsets, allow_pickle=False)
        atomic_write_bytes(path, buf.getvalue())
    return offsets


def _compute(track: Track, kind: str, car: CarParams, driver: Driver | None,
             use_cache: bool) -> np.ndarray:
    if kind == "mincurv":
        return mincurv_offsets(track)
    assert driver is not None  # checked by reference_offsets
    mincurv_line = reference_offsets(track, "mincurv", car, use_cache=use_cache)
    if kind == "recorded":
        result = driver(track, mincurv_line, laps=2, car=car)
        return recorded_offsets(track, result)

    def retime(trk: Track, offsets: np.ndarray) -> dict:
        return driver(trk, offsets, laps=2, car=car)

    return genetic_line(track, car, seed=0, seed_offsets_m=mincurv_line, driver=retime).offsets_m

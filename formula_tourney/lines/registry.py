"""One entry point for reference lines: ``reference_offsets(track, kind, car)``, cached on disk.

A tournament asks for the same lines over and over (every job, every worker process), and
the genetic and recorded lines cost seconds to minutes of driving, so each line is computed
once per track geometry and car and stored as ``.npy`` under the user cache dir
(``platformdirs.user_cache_dir("formula-tourney")/lines``, or ``$FORMULA_TOURNEY_CACHE_DIR``).
The key holds the track name, a hash of its geometry, ``car.fingerprint()``, the kind and an
algorithm version, so a changed track, car or algorithm never reads a stale line.

The recorded and genetic lines need a driver (the follower bot). ``lines`` sits below ``bots``
(imports go downward), so the driver is an argument; when it is omitted the follower is looked
up at call time, never at import time.
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
from formula_tourney.safeio import atomic_write_bytes
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.track import Track

LINE_KINDS: tuple[str, ...] = ("centre", "mincurv", "recorded", "genetic")
"""centre = the paper's MOT; recorded = the paper's RC (the line the Tita bot drove)."""

ALGORITHM_VERSION = 2
"""Bump when a line's algorithm changes: old cache entries then stop matching."""

CACHE_ENV_VAR = "FORMULA_TOURNEY_CACHE_DIR"

Driver = Callable[..., dict]


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
    *,
    driver: Driver | None = None,
    use_cache: bool = True,
) -> np.ndarray:
    """Lateral offsets (one per track sample) of the reference line ``kind`` on ``track``."""
    check_kind(kind)
    if kind == "centre":
        from formula_tourney.lines.centre import centre_offsets

        return centre_offsets(track)
    car = car or CarParams()
    path = cache_path(track, kind, car)
    if use_cache and path.is_file():
        try:
            offsets = np.load(path, allow_pickle=False)
            if offsets.shape == (track.n,) and np.all(np.isfinite(offsets)):
                return offsets
        except (OSError, ValueError):
            pass  # a damaged entry is recomputed and overwritten below
    offsets = _compute(track, kind, car, driver)
    if use_cache:
        buf = io.BytesIO()
        np.save(buf, offsets, allow_pickle=False)
        atomic_write_bytes(path, buf.getvalue())
    return offsets


def _default_driver() -> Driver:
    from formula_tourney.bots.follower import drive

    return drive


def _compute(track: Track, kind: str, car: CarParams, driver: Driver | None) -> np.ndarray:
    if kind == "mincurv":
        from formula_tourney.lines.mincurv import mincurv_offsets

        return mincurv_offsets(track)
    drive = driver or _default_driver()
    mincurv_line = reference_offsets(track, "mincurv", car, driver=driver)
    if kind == "recorded":
        from formula_tourney.lines.recorded import recorded_offsets

        result = drive(track, mincurv_line, laps=2, car=car)
        return recorded_offsets(track, result)
    from formula_tourney.lines.genetic import genetic_line

    def retime(trk: Track, offsets: np.ndarray) -> dict:
        return drive(trk, offsets, laps=2, car=car)

    return genetic_line(track, car, seed=0, seed_offsets_m=mincurv_line, driver=retime).offsets_m

"""Writing user tracks: ``tracks import`` (TORCS XML -> TOML) and ``tracks generate --save``.

The read side is :mod:`formula_tourney.sim.catalog`; this module sits above it and
:mod:`formula_tourney.sim.torcs` (imports go store -> catalog -> torcs, never back), so the
reserved-name rule a save must respect is the catalog's own.
"""

from __future__ import annotations

from pathlib import Path

from formula_tourney.errors import UserInputError
from formula_tourney.safeio import atomic_write_text, check_name
from formula_tourney.sim.catalog import BUILTIN_TRACKS, is_reserved_track_name, user_tracks_dir
from formula_tourney.sim.segments import TrackSpec, build_track, parse_spec, spec_to_toml
from formula_tourney.sim.torcs import build_torcs_spec, read_torcs_spec


def user_track_target(name: str, label: str, *, overwrite: bool = False,
                      generated_seed: int | None = None) -> Path:
    """Path a user track ``name`` would be saved to; refuses bad, reserved and taken names.

    Built-in names and ``gen-<digits>`` are reserved because ``load_track`` resolves them before
    the user folder; ``generated_seed`` allows exactly ``gen-<that seed>`` (saving a generated
    track under its own name stores the very track the name already loads).
    """
    check_name(name, "track name")
    if name in BUILTIN_TRACKS:
        raise UserInputError(
            f"{label}: {name!r} is reserved (a built-in track name); pick another --name"
        )
    if is_reserved_track_name(name) and name != f"gen-{generated_seed}":
        raise UserInputError(
            f"{label}: track name {name!r} is reserved for generated tracks (gen-<seed>); "
            "pick another --name"
        )
    target = user_tracks_dir() / f"{name}.toml"
    if target.exists() and not overwrite:
        raise UserInputError(
            f"{label}: user track {name!r} already exists ({target}); use --force to replace "
            "it or --name to pick another name"
        )
    return target


def save_user_track(spec: TrackSpec, target: Path) -> Path:
    """Write ``spec`` as TOML to ``target`` (from :func:`user_track_target`), atomically."""
    return atomic_write_text(target, spec_to_toml(spec))


def import_torcs_track(path: str | Path, name: str | None = None, *,
                       overwrite: bool = False) -> Path:
    """Convert a TORCS file to our TOML in the user's track folder; returns the written path.

    Everything is checked first: the file parses, the track closes and does not overlap, the
    TOML we are about to write loads back to the same track, and the name is free.
    """
    spec = read_torcs_spec(path, name)
    target = user_track_target(spec.name, str(path), overwrite=overwrite)
    track = build_torcs_spec(spec, str(path))
    again = build_track(parse_spec(spec_to_toml(spec), str(target)), str(target))
    if abs(again.length_m - track.length_m) > 1e-6:  # pragma: no cover - repr round-trips
        raise RuntimeError(f"TOML round trip changed the length of {spec.name}")
    return save_user_track(spec, target)

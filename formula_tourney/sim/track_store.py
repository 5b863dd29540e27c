"""Writing user tracks: ``tracks import`` (TORCS XML -> TOML) and ``tracks generate --save``.

The read side is :mod:`formula_tourney.sim.catalog`; this module sits above it and
:mod:`formula_tourney.sim.torcs` (imports go store -> catalog -> torcs, never back), so the
reserved-name rule a save must respect is the catalog's own.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.safeio import atomic_write_text, check_name
from formula_tourney.sim.catalog import BUILTIN_TRACKS, is_reserved_track_name, user_tracks_dir
from formula_tourney.sim.generate import GENERATED_FORMS
from formula_tourney.sim.segments import TrackSpec, build_track, parse_spec, spec_to_toml
from formula_tourney.sim.torcs import build_torcs_spec, read_torcs_spec
from formula_tourney.sim.track import Track


def user_track_target(name: str, label: str, *, overwrite: bool = False,
                      generated_name: str | None = None) -> Path:
    """Path a user track ``name`` would be saved to; refuses bad, reserved and taken names.

    Built-in names and generated names (``gen-<digits>``, ``gen-short-<digits>``) are reserved
    because ``load_track`` resolves them before the user folder; ``generated_name`` allows
    exactly that name (saving a generated track under its own name stores the very track the
    name already loads).
    """
    check_name(name, "track name")
    if name in BUILTIN_TRACKS:
        raise UserInputError(
            f"{label}: {name!r} is reserved (a built-in track name); pick another --name"
        )
    if is_reserved_track_name(name) and name != generated_name:
        raise UserInputError(
            f"{label}: track name {name!r} is reserved for generated tracks "
            f"({GENERATED_FORMS}); pick another --name"
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
    _checked_track(spec, path, target)
    return save_user_track(spec, target)


def _checked_track(spec: TrackSpec, path: str | Path, target: Path) -> Track:
    """The track ``spec`` builds, after checking that its TOML loads back to the same track."""
    track = build_torcs_spec(spec, str(path))
    again = build_track(parse_spec(spec_to_toml(spec), str(target)), str(target))
    if abs(again.length_m - track.length_m) > 1e-6:  # pragma: no cover - repr round-trips
        raise RuntimeError(f"TOML round trip changed the length of {spec.name}")
    return again


def find_torcs_files(folder: str | Path) -> list[Path]:
    """Every ``*.xml`` below ``folder`` (a TORCS tree: ``<category>/<track>/<track>.xml``),
    sorted; a missing folder, a file, or a folder without XML is a :class:`UserInputError`."""
    root = Path(folder)
    if not root.exists():
        raise UserInputError(f"{root}: folder not found")
    if not root.is_dir():
        raise UserInputError(f"{root}: not a folder")
    files = sorted(p for p in root.rglob("*") if p.suffix.lower() == ".xml" and p.is_file())
    if not files:
        raise UserInputError(f"{root}: no .xml track files in this folder or below it")
    return files


def _reason(err: Exception, path: Path) -> str:
    """The error without the file name the row already shows."""
    text = str(err)
    for prefix in (f"{path}: ", f"{path}, "):
        if text.startswith(prefix):
            return text[len(prefix):]
    return text if isinstance(err, UserInputError) else f"{type(err).__name__}: {text}"


def import_torcs_tree(folder: str | Path, *, overwrite: bool = False) -> list[dict[str, Any]]:
    """Import every TORCS track file below ``folder`` (names from the file stems), one row per
    file: ``name``, ``category`` (the folder above the track's own), ``file``, ``length_m``,
    ``z_range_m``, ``max_banking_deg``, ``imported``, ``reason`` (why not) and ``saved``.

    A file that fails (bad XML, a track that does not close, a reserved or taken name, a stem
    another file of this import already uses) is a row with ``imported`` false; the others
    are still imported, each written atomically.
    """
    rows: list[dict[str, Any]] = []
    taken: dict[str, Path] = {}
    for path in find_torcs_files(folder):
        row: dict[str, Any] = {
            "name": path.stem, "category": path.parent.parent.name, "file": str(path),
            "length_m": None, "z_range_m": None, "max_banking_deg": None,
            "imported": False, "reason": None, "saved": None,
        }
        rows.append(row)
        try:
            spec = read_torcs_spec(path)
            row["name"] = spec.name
            track = _checked_track(spec, path, user_tracks_dir() / f"{spec.name}.toml")
            row["length_m"] = round(float(track.length_m), 3)
            row["z_range_m"] = round(float(np.ptp(track.z_m)), 3)
            row["max_banking_deg"] = round(float(np.degrees(np.max(np.abs(track.banking_rad)))),
                                           3)
            if spec.name in taken:
                raise UserInputError(f"{path}: track name {spec.name!r} is already used by "
                                     f"{taken[spec.name]} in this import")
            target = user_track_target(spec.name, str(path), overwrite=overwrite)
            row["saved"] = str(save_user_track(spec, target))
            row["imported"] = True
            taken[spec.name] = path
        except Exception as err:  # noqa: BLE001 - one bad file must not stop the others
            row["reason"] = _reason(err, path)
    return rows

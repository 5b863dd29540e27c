"""Where tracks come from: built-in TOMLs, the user's track folder, files, and generated seeds.

``load_track`` is the one function the env, lines, bots and tournaments call with a name from
the user, so its error lists what names exist. Built tracks are cached per process: sampling a
segment track through highway-env lanes costs ~50 ms, and an env is made per episode in tests.
"""

from __future__ import annotations

import os
import re
from functools import lru_cache
from importlib import resources
from pathlib import Path

from formula_tourney.errors import UserInputError
from formula_tourney.sim.segments import build_track, load_spec
from formula_tourney.sim.track import Track

BUILTIN_TRACKS = ("oval", "technical", "flowing")
GENERATED_PATTERN = re.compile(r"^gen-(\d{1,9})$")
DATA_DIR_ENV = "FORMULA_TOURNEY_DATA_DIR"


def data_dir() -> Path:
    """The per-user data folder (``FORMULA_TOURNEY_DATA_DIR`` overrides it, e.g. in tests)."""
    override = os.environ.get(DATA_DIR_ENV)
    if override:
        return Path(override)
    from platformdirs import user_data_dir

    return Path(user_data_dir("formula-tourney"))


def user_tracks_dir() -> Path:
    return data_dir() / "tracks"


def builtin_track_path(name: str) -> Path:
    return Path(str(resources.files("formula_tourney.sim").joinpath("tracks", f"{name}.toml")))


def load_track(name_or_path: str | os.PathLike | Track) -> Track:
    """A Track from a built-in name, a user track, ``gen-<seed>``, or a .toml/.xml path."""
    if isinstance(name_or_path, Track):
        return name_or_path
    text = str(name_or_path)
    if text.endswith((".toml", ".xml")) or os.sep in text:
        path = Path(text)
        if not path.is_file():
            raise UserInputError(f"{path}: track file not found")
        return _load_file(str(path.resolve()), path.stat().st_mtime_ns)
    match = GENERATED_PATTERN.match(text)
    if match:
        from formula_tourney.sim.generate import generate_track

        return _generated(int(match.group(1)), generate_track)
    if text in BUILTIN_TRACKS:
        path = builtin_track_path(text)
        return _load_file(str(path), path.stat().st_mtime_ns)
    user = user_tracks_dir() / f"{text}.toml"
    if user.is_file():
        return _load_file(str(user), user.stat().st_mtime_ns)
    known = ", ".join(t["name"] for t in list_tracks())
    raise UserInputError(
        f"unknown track {text!r}; known tracks: {known}; or gen-<seed> for a generated track, "
        "or a path to a .toml/.xml file"
    )


@lru_cache(maxsize=64)
def _load_file(path: str, _mtime_ns: int) -> Track:
    if path.endswith(".xml"):
        from formula_tourney.sim.torcs import load_torcs_track

        return load_torcs_track(path)
    spec = load_spec(path)
    return build_track(spec, path, source=path)


@lru_cache(maxsize=64)
def _generated(seed: int, generate) -> Track:
    return generate(seed)


def list_tracks() -> list[dict]:
    """Every named track: built-ins first, then the user's folder (length from the file)."""
    rows = []
    for name in BUILTIN_TRACKS:
        track = load_track(name)
        rows.append({"name": name, "source": "built-in", "length_m": round(track.length_m, 1),
                     "width_m": float(track.width_m.mean())})
    folder = user_tracks_dir()
    if folder.is_dir():
        for path in sorted(folder.glob("*.toml")):
            try:
                track = _load_file(str(path), path.stat().st_mtime_ns)
            except UserInputError as err:
                rows.append({"name": path.stem, "source": str(path), "error": str(err)})
                continue
            rows.append({"name": path.stem, "source": str(path),
                         "length_m": round(track.length_m, 1),
                         "width_m": float(track.width_m.mean())})
    return rows

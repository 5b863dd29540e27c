"""Where tracks come from: built-in TOMLs, the user's track folder, files, and generated seeds.

One resolution rule, used by :func:`check_track_name` (validate a reference without building it,
e.g. when a tournament or run specification is read) and by :func:`load_track` (build it), so a
name that passes the check always loads and one that fails it never does:

1. a ``.toml``/``.xml`` file name or anything with a path separator is a file (relative paths
   against ``base_dir``, else the current folder); it must exist;
2. ``gen-<seed>`` is the procedural track of that seed (the seed in ``0..generate.MAX_SEED``),
   and ``gen-short-<seed>`` the short one (``generate.GENERATED_KINDS``);
3. a built-in name (``oval``, ``technical``, ``flowing``);
4. a user track: ``<data dir>/tracks/<name>.toml``.

Built-in, ``gen-<digits>`` and ``gen-short-<digits>`` names are reserved: a user track of such
a name could never be loaded, so ``tracks import``/``--save`` refuse them
(:func:`is_reserved_track_name`).

Built tracks are cached per process: sampling a segment track through highway-env lanes costs
~50 ms, and an env is made per episode in tests.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path

from platformdirs import user_data_dir

from formula_tourney.errors import UserInputError
from formula_tourney.safeio import is_safe_name
from formula_tourney.sim.generate import (
    GENERATED_FORMS,
    GENERATED_KINDS,
    MAX_SEED,
    generated_name,
    generated_track,
)
from formula_tourney.sim.segments import build_track, load_spec
from formula_tourney.sim.torcs import load_torcs_track
from formula_tourney.sim.track import Track

BUILTIN_TRACKS = ("oval", "technical", "flowing")
GENERATED_PATTERN = re.compile(
    r"^(" + "|".join(sorted(map(re.escape, GENERATED_KINDS), key=len, reverse=True))
    + r")-([0-9]+)\Z"
)
"""``gen-<digits>``, ``gen-short-<digits>``: reserved for generated tracks (the seed's range is
checked separately)."""
TRACK_FILE_SUFFIXES = (".toml", ".xml")
DATA_DIR_ENV = "FORMULA_TOURNEY_DATA_DIR"


def data_dir() -> Path:
    """The per-user data folder (``FORMULA_TOURNEY_DATA_DIR`` overrides it, e.g. in tests)."""
    override = os.environ.get(DATA_DIR_ENV)
    if override:
        return Path(override)
    return Path(user_data_dir("formula-tourney"))


def user_tracks_dir() -> Path:
    return data_dir() / "tracks"


def builtin_track_path(name: str) -> Path:
    return Path(str(resources.files("formula_tourney.sim").joinpath("tracks", f"{name}.toml")))


def is_reserved_track_name(name: str) -> bool:
    """True for names :func:`load_track` resolves before the user folder (built-in, gen-N,
    gen-short-N)."""
    return name in BUILTIN_TRACKS or GENERATED_PATTERN.match(name) is not None


@dataclass(frozen=True)
class _Ref:
    """A resolved track reference: ``name`` is canonical (absolute path for files)."""

    kind: str  # "file" | "generated" | "builtin" | "user"
    name: str
    path: Path | None = None
    seed: int | None = None
    prefix: str | None = None  # a generated track's kind (``gen``, ``gen-short``)


def _looks_like_file(text: str) -> bool:
    seps = {"/", os.sep} | ({os.altsep} if os.altsep else set())
    return text.lower().endswith(TRACK_FILE_SUFFIXES) or any(sep in text for sep in seps)


def _resolve(name: object, base_dir: Path | str | None) -> _Ref:
    """The one definition of what a track reference means (see the module docstring)."""
    if isinstance(name, os.PathLike):
        name = os.fspath(name)
    if not isinstance(name, str):
        raise UserInputError(
            f"track: expected a track name or a .toml/.xml path, got {type(name).__name__}"
        )
    text = name
    if _looks_like_file(text):
        path = Path(text)
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        if path.suffix.lower() not in TRACK_FILE_SUFFIXES:
            raise UserInputError(f"{path}: a track file must end in .toml or .xml")
        if not path.is_file():
            raise UserInputError(f"{path}: track file not found")
        resolved = path.resolve()
        return _Ref("file", str(resolved), path=resolved)
    match = GENERATED_PATTERN.match(text)
    if match:
        prefix, seed = match.group(1), int(match.group(2))
        if seed > MAX_SEED:
            raise UserInputError(
                f"track {text!r}: seed {match.group(2)} is out of range; {prefix}-<seed> takes "
                f"a seed in 0..{MAX_SEED}"
            )
        return _Ref("generated", generated_name(prefix, seed), seed=seed, prefix=prefix)
    if text in BUILTIN_TRACKS:
        return _Ref("builtin", text, path=builtin_track_path(text))
    if is_safe_name(text):
        user = user_tracks_dir() / f"{text}.toml"
        if user.is_file():
            return _Ref("user", text, path=user)
    raise UserInputError(
        f"unknown track {text!r}; known tracks: {', '.join(known_track_names())}; or "
        f"{GENERATED_FORMS} for a generated track, or a path to a .toml/.xml file"
    )


def check_track_name(name: str, base_dir: Path | None = None) -> str:
    """Validate a track reference without building the track; return its canonical form.

    Accepts exactly what :func:`load_track` accepts: a built-in or user track name,
    ``gen-<seed>`` or ``gen-short-<seed>`` (seed in ``0..MAX_SEED``, returned without leading
    zeros), or an existing
    ``.toml``/``.xml`` file (returned as an absolute path; relative paths resolve against
    ``base_dir``, else the current folder). Anything else -> UserInputError listing the known
    names. A track file (the user's or a path) is also built once (cached for the load that
    follows), so one that does not parse, does not close or has no finite length is refused
    here, before any job that would drive it starts.
    """
    ref = _resolve(name, base_dir)
    if ref.path is not None and ref.kind != "builtin":
        _load_file(str(ref.path), ref.path.stat().st_mtime_ns)
    return ref.name


def load_track(name_or_path: str | os.PathLike | Track, base_dir: Path | None = None) -> Track:
    """A Track from a built-in name, a user track, ``gen-<seed>``, ``gen-short-<seed>``, or a
    .toml/.xml path."""
    if isinstance(name_or_path, Track):
        return name_or_path
    ref = _resolve(name_or_path, base_dir)
    if ref.kind == "generated":
        return _generated(ref.prefix, ref.seed)
    return _load_file(str(ref.path), ref.path.stat().st_mtime_ns)


@lru_cache(maxsize=64)
def _load_file(path: str, _mtime_ns: int) -> Track:
    if path.lower().endswith(".xml"):
        return load_torcs_track(path)
    spec = load_spec(path)
    return build_track(spec, path, source=path)


@lru_cache(maxsize=64)
def _generated(prefix: str, seed: int) -> Track:
    return generated_track(prefix, seed)


def _user_track_files() -> list[Path]:
    folder = user_tracks_dir()
    return sorted(folder.glob("*.toml")) if folder.is_dir() else []


def known_track_names() -> list[str]:
    """Built-in names, then the user's tracks (from file names; nothing is built)."""
    users = [p.stem for p in _user_track_files()]
    return [*BUILTIN_TRACKS, *(n for n in users if is_safe_name(n) and n not in BUILTIN_TRACKS)]


def list_tracks() -> list[dict]:
    """Every named track: built-ins first, then the user's folder (length from the file)."""
    rows = []
    for name in BUILTIN_TRACKS:
        track = load_track(name)
        rows.append({"name": name, "source": "built-in", "length_m": round(track.length_m, 1),
                     "width_m": float(track.width_m.mean())})
    for path in _user_track_files():
        name = path.stem
        if not is_safe_name(name) or name in BUILTIN_TRACKS:
            # load_track never reaches these files (a gen-<seed> file saved by ``tracks
            # generate --save`` is listed: it holds the very track its name generates).
            why = "the built-in of that name is loaded instead" if is_safe_name(name) else (
                "not a valid track name")
            rows.append({"name": name, "source": str(path),
                         "error": f"{path}: {why}; rename the file to use it"})
            continue
        try:
            track = _load_file(str(path), path.stat().st_mtime_ns)
        except UserInputError as err:
            rows.append({"name": name, "source": str(path), "error": str(err)})
            continue
        rows.append({"name": name, "source": str(path),
                     "length_m": round(track.length_m, 1),
                     "width_m": float(track.width_m.mean())})
    return rows

"""Segment tracks: the TOML format, its validation, and sampling through highway-env lanes.

A track is authored as a list of straights and arcs (spirals are arcs with an end radius). Each
segment becomes highway-env ``StraightLane``/``CircularLane`` objects chained end to start, so the
same geometry can be drawn by highway-env's viewer; the lanes are then sampled once, at a uniform
~1 m arc-length spacing, into the arrays of :class:`~formula_tourney.sim.track.Track`. TORCS
imports and the procedural generator produce the same :class:`TrackSpec`, so every track in the
project goes through the closure and overlap checks here.

Format (one file per track)::

    name = "oval"                 # optional, defaults to the file name
    description = "..."           # optional, free text
    width_m = 18.0                # or width_left_m and width_right_m
    [[segment]]
    type = "straight"             # the start line is the start of the first segment
    length_m = 300.0
    [[segment]]
    type = "arc"
    radius_m = 200.0
    angle_deg = 180.0             # sign gives the direction: left (counter-clockwise) > 0
    end_radius_m = 150.0          # optional: a spiral, radius linear in turned angle
    steps = 12                    # optional, with end_radius_m: TORCS' stepped spiral (below)
    z_end_m = 12.0                # optional on any segment, with z_start_m, grade_start_pct,
    banking_deg = 5.0             # grade_end_pct, banking_start_deg, banking_end_deg
    surface = "dirt"              # optional on any segment: the road's surface (default
    side_surface = "sand"         # "asphalt") and the side's, beyond each edge ("grass")
    [surfaces.dirt-d2]            # optional, before the segments: a track's own surfaces
    friction = 0.8                # (TORCS numbers: asphalt 1.2) and rolling_resistance
    rolling_resistance = 0.03     # (asphalt 0.001), over sim.surfaces.TORCS_SURFACES

Heights and banking (:func:`surface_profile`): a segment starts where the previous one ended
(``z_start_m`` overrides; 0 for the first) and ends at ``z_end_m`` (default: level); between, the
height is the cubic through the end heights with the end slopes ``grade_*_pct`` (default: the
chord's, a straight ramp). Banking (> 0 raises the left edge) is linear from start to end; a
segment without banking keys is not banked. A track without any of these keys is flat.

Surfaces (:mod:`~formula_tourney.sim.surfaces`): TORCS surface names; each segment's own, not
carried to the next. A track without surface keys drives as asphalt with grass beside it.

A spiral without ``steps`` is ours: its radius is linear in the turned angle (built from ~2 m
sub-arcs), and it is ``angle * (radius + end_radius) / 2`` long. With ``steps = N`` it is the
spiral TORCS' track loader builds: ``N`` arcs of one common length whose radii step linearly
*by index* from ``radius_m`` (the first) to ``end_radius_m`` (the last), ``r_i = r0 + i (r1 -
r0) / (N - 1)``, the common length chosen so that they turn exactly ``angle_deg``:
``L = |angle| / sum(1 / r_i)`` each, ``N * L`` in all. TORCS imports use it so that their
geometry, and so their closure, is TORCS' own (:mod:`formula_tourney.sim.torcs`).
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from formula_tourney.errors import UserInputError
from formula_tourney.safeio import check_name, read_user_text
from formula_tourney.sim.surfaces import sample_surfaces
from formula_tourney.sim.track import LEVEL_SEPARATION_M, SAMPLE_SPACING_M, Track

CLOSURE_TOLERANCE_M = 1.0
"""A track whose end misses its start by more than this is refused: its lap would not close."""

HEADING_TOLERANCE_DEG = 2.0
"""A track that returns to its start at a kink sharper than this is refused."""

SPIRAL_STEP_M = 2.0
"""Sub-arc length of a spiral: stepped radii this short keep curvature within ~1% of linear."""

OVERLAP_MARGIN_M = 2.0
"""Asphalt of two distant parts of a track must be at least this far apart."""

MAX_TRACK_LENGTH_M = 100_000.0
"""Longest track accepted (100 km; the Nordschleife is 20.8 km). Sampling at ~1 m costs memory
and time in proportion, so a segment or a lap longer than this is refused before any array is
built: a TORCS file with one 1e9 m straight once asked for GiBs."""

MAX_SEGMENTS = 10_000
"""Most segments in one track (real TORCS tracks have a few hundred)."""

MAX_STEPPED_ARCS = 100_000
"""Most sub-arcs that the stepped (TORCS) spirals of one track may have in all: each becomes a
lane object, and a TORCS file can ask for any number (a tiny ``profil steps length``). The
38 tracks of torcs-data use at most a few thousand."""

Z_CLOSURE_TOLERANCE_M = 1.0
"""A track whose last segment ends more than this above or below its start is refused; a smaller
gap is spread along the lap like the plan's closure gap."""

MAX_ABS_Z_M = 10_000.0
MAX_ABS_GRADE_PCT = 100.0
MAX_ABS_BANKING_DEG = 45.0

SURFACE_KEYS = ("z_start_m", "z_end_m", "grade_start_pct", "grade_end_pct", "banking_deg",
                "banking_start_deg", "banking_end_deg")
"""Optional on any segment: heights, the profile's end slopes and the banking (module doc)."""
SURFACE_NAME_KEYS = ("surface", "side_surface")
GRIP_KEY = "grip"
"""Optional on any segment: a friction factor on its road surface (a wet patch 0.6, ice 0.2)."""
MIN_GRIP, MAX_GRIP = 0.05, 2.0
TOP_KEYS = ("name", "description", "width_m", "width_left_m", "width_right_m", "surfaces",
            "segment")
MAX_SURFACES = 256
STRAIGHT_KEYS = ("type", "length_m", "name", *SURFACE_KEYS, *SURFACE_NAME_KEYS, GRIP_KEY)
ARC_KEYS = ("type", "radius_m", "angle_deg", "end_radius_m", "steps", "name", *SURFACE_KEYS,
            *SURFACE_NAME_KEYS, GRIP_KEY)
SEGMENT_TYPES = ("straight", "arc")
MIN_WIDTH_M = 3.0
MAX_WIDTH_M = 60.0


@dataclass(frozen=True)
class SegmentSpec:
    """One authored segment. ``angle_deg > 0`` turns left; straights have no radius or angle."""

    type: str
    length_m: float = 0.0
    radius_m: float = 0.0
    angle_deg: float = 0.0
    end_radius_m: float | None = None
    name: str = ""
    steps: int | None = None
    """With ``end_radius_m``: a TORCS stepped spiral of this many arcs (module docstring)."""
    z_start_m: float | None = None
    """Centreline height at the start; None: where the previous segment ended (0 for the first)."""
    z_end_m: float | None = None
    """Centreline height at the end; None: the start height (a level segment)."""
    grade_start_pct: float | None = None
    """Slope of the height profile at the start and end (100 dz/ds); None: the chord's slope,
    so a segment with neither is a straight ramp. With them the profile is a cubic."""
    grade_end_pct: float | None = None
    banking_start_deg: float = 0.0
    """Banking at the start and end (> 0 raises the left edge), linear along the segment."""
    banking_end_deg: float = 0.0
    surface: str = ""
    """TORCS name of the road's surface; "" is asphalt."""
    side_surface: str = ""
    """TORCS name of the side's surface (beyond each edge, to the wall); "" is grass."""
    grip: float = 1.0
    """Friction factor on this segment's road surface (a wet patch, ice); 1 unchanged."""

    @property
    def has_surface(self) -> bool:
        return (self.z_start_m is not None or self.z_end_m is not None
                or self.grade_start_pct is not None or self.grade_end_pct is not None
                or self.banking_start_deg != 0.0 or self.banking_end_deg != 0.0)

    @property
    def arc_length_m(self) -> float:
        """Centreline length; our spiral's radius is linear in angle, so its mean radius is exact;
        a stepped spiral is ``steps`` arcs of the length :func:`stepped_spiral` gives."""
        if self.type == "straight":
            return self.length_m
        if self.steps is not None:
            radii, sub_length = stepped_spiral(self)
            return len(radii) * sub_length
        end = self.radius_m if self.end_radius_m is None else self.end_radius_m
        return abs(math.radians(self.angle_deg)) * 0.5 * (self.radius_m + end)

    def to_dict(self) -> dict[str, Any]:
        """The TOML table of this segment (only the keys it uses)."""
        out: dict[str, Any] = {"type": self.type}
        if self.type == "straight":
            out["length_m"] = self.length_m
        else:
            out["radius_m"] = self.radius_m
            out["angle_deg"] = self.angle_deg
            if self.end_radius_m is not None:
                out["end_radius_m"] = self.end_radius_m
            if self.steps is not None:
                out["steps"] = self.steps
        if self.name:
            out["name"] = self.name
        for key in ("z_start_m", "z_end_m", "grade_start_pct", "grade_end_pct"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.banking_start_deg == self.banking_end_deg:
            if self.banking_start_deg != 0.0:
                out["banking_deg"] = self.banking_start_deg
        else:
            out["banking_start_deg"] = self.banking_start_deg
            out["banking_end_deg"] = self.banking_end_deg
        if self.surface:
            out["surface"] = self.surface
        if self.side_surface:
            out["side_surface"] = self.side_surface
        if self.grip != 1.0:
            out["grip"] = self.grip
        return out


def stepped_spiral(seg: SegmentSpec) -> tuple[list[float], float]:
    """Radii and common sub-arc length of a stepped (TORCS) spiral: ``steps`` radii linear by
    index from ``radius_m`` to ``end_radius_m`` (both included), each arc ``|angle| / sum(1/r)``
    long so that ``sum(length / r_i)`` is exactly the segment's angle."""
    steps = int(seg.steps or 0)
    if steps < 2 or seg.end_radius_m is None:
        raise ValueError("a stepped spiral needs steps >= 2 and an end radius")
    r0, r1 = seg.radius_m, seg.end_radius_m
    radii = [r0 + (r1 - r0) * i / (steps - 1) for i in range(steps)]
    return radii, abs(math.radians(seg.angle_deg)) / math.fsum(1.0 / r for r in radii)


@dataclass(frozen=True)
class TrackSpec:
    """A whole authored track: widths and the segment list, start line at segment 0's start."""

    name: str
    width_left_m: float
    width_right_m: float
    segments: list[SegmentSpec] = field(default_factory=list)
    description: str = ""
    surfaces: dict[str, tuple[float, float]] = field(default_factory=dict)
    """The track's own surfaces: name -> (TORCS friction, rolling resistance)."""

    @property
    def width_m(self) -> float:
        return self.width_left_m + self.width_right_m


# --------------------------------------------------------------------------------------------
# TOML reading and writing
# --------------------------------------------------------------------------------------------


def load_spec(path: str | Path, name: str | None = None) -> TrackSpec:
    """Read and validate a track TOML file; ``name`` overrides the file's own name."""
    path = Path(path)
    text = read_user_text(path, "track")
    return parse_spec(text, str(path), default_name=name or path.stem, force_name=name)


def parse_spec(
    text: str, label: str, default_name: str = "track", force_name: str | None = None
) -> TrackSpec:
    """Validate TOML text into a :class:`TrackSpec`; errors name ``label``, the line and the key."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise UserInputError(f"{label}: invalid TOML: {err}") from None

    def where(key: str, seg: int | None = None) -> str:
        line = _line_of(text, key, seg)
        return f"{label}, line {line}" if line else label

    for key in data:
        if key not in TOP_KEYS:
            raise UserInputError(
                f"{where(key)}: unknown key {key!r} (allowed: {', '.join(TOP_KEYS)})"
            )
    name = force_name or data.get("name", default_name)
    if not isinstance(name, str):
        raise UserInputError(f"{where('name')}: 'name' must be a string")
    check_name(name, f"track name in {label}")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise UserInputError(f"{where('description')}: 'description' must be a string")

    has_sides = "width_left_m" in data or "width_right_m" in data
    if "width_m" in data and has_sides:
        raise UserInputError(
            f"{where('width_m')}: give width_m or both width_left_m and width_right_m, not both"
        )
    if has_sides:
        if "width_left_m" not in data or "width_right_m" not in data:
            raise UserInputError(f"{label}: give both width_left_m and width_right_m")
        left = _number(data, "width_left_m", where("width_left_m"), low=MIN_WIDTH_M / 2)
        right = _number(data, "width_right_m", where("width_right_m"), low=MIN_WIDTH_M / 2)
    elif "width_m" in data:
        width = _number(data, "width_m", where("width_m"), low=MIN_WIDTH_M)
        left = right = width / 2.0
    else:
        raise UserInputError(f"{label}: missing 'width_m' (track width in metres)")
    if left + right > MAX_WIDTH_M:
        raise UserInputError(f"{label}: track width {left + right:g} m exceeds {MAX_WIDTH_M:g} m")

    raw_segments = data.get("segment")
    if not isinstance(raw_segments, list) or not raw_segments:
        raise UserInputError(f"{label}: no [[segment]] tables (a track needs segments)")
    if len(raw_segments) > MAX_SEGMENTS:
        raise UserInputError(
            f"{label}: {len(raw_segments)} segments; at most {MAX_SEGMENTS} are accepted"
        )
    segments = [
        _segment(raw, i, label, lambda key, i=i: where(key, i), left, right)
        for i, raw in enumerate(raw_segments)
    ]
    spec = TrackSpec(name, left, right, segments, description,
                     _surface_table(data.get("surfaces", {}), where("surfaces")))
    check_track_size(spec, label, lambda i: f"{where('type', i)}: segment {i + 1}")
    return spec


def check_track_size(spec: TrackSpec, label: str, where=None) -> None:
    """Refuse a spec whose segments or lap exceed :data:`MAX_TRACK_LENGTH_M` (or that has more
    than :data:`MAX_SEGMENTS` segments), naming the file and the first segment at fault.

    Runs on the spec alone, before lanes or sample arrays exist. ``where(i)`` names segment
    ``i`` (0-based) in messages; the default is ``label: segment i+1 ('its name')``.
    """

    def name(i: int) -> str:
        if where is not None:
            return where(i)
        seg_name = spec.segments[i].name
        return f"{label}: segment {i + 1}" + (f" ({seg_name!r})" if seg_name else "")

    if len(spec.segments) > MAX_SEGMENTS:
        raise UserInputError(
            f"{label}: {len(spec.segments)} segments; at most {MAX_SEGMENTS} are accepted"
        )
    stepped = 0
    for i, seg in enumerate(spec.segments):
        if seg.steps is None:
            continue
        if seg.steps < 2 or seg.end_radius_m is None:
            raise UserInputError(
                f"{name(i)}: a stepped spiral needs steps >= 2 and an end radius"
            )
        stepped += seg.steps
        if stepped > MAX_STEPPED_ARCS:
            raise UserInputError(
                f"{name(i)}: the stepped spirals have {stepped} sub-arcs by the end of this "
                f"segment; at most {MAX_STEPPED_ARCS} are accepted"
            )
    limit_km = MAX_TRACK_LENGTH_M / 1000.0
    total = 0.0
    for i, seg in enumerate(spec.segments):
        length = seg.arc_length_m
        if not math.isfinite(length) or length > MAX_TRACK_LENGTH_M:
            raise UserInputError(
                f"{name(i)}: {length:.4g} m long; a whole track may be at most {limit_km:g} km"
            )
        total += length
        if total > MAX_TRACK_LENGTH_M:
            raise UserInputError(
                f"{name(i)}: the track is {total / 1000.0:.1f} km long by the end of this "
                f"segment; tracks longer than {limit_km:g} km are refused"
            )


def _segment(
    raw: Any, i: int, label: str, where, left: float, right: float
) -> SegmentSpec:
    """Validate one ``[[segment]]`` table (``i`` is 0-based, messages count from 1)."""
    head = f"segment {i + 1}"
    if not isinstance(raw, dict):
        raise UserInputError(f"{label}: {head} is not a table")
    kind = raw.get("type")
    if kind not in SEGMENT_TYPES:
        raise UserInputError(
            f"{where('type')}: {head}: 'type' must be one of {', '.join(SEGMENT_TYPES)}, "
            f"got {kind!r}"
        )
    allowed = STRAIGHT_KEYS if kind == "straight" else ARC_KEYS
    for key in raw:
        if key not in allowed:
            raise UserInputError(
                f"{where(key)}: {head} ({kind}): unknown key {key!r} "
                f"(allowed: {', '.join(allowed)})"
            )
    seg_name = raw.get("name", "")
    if not isinstance(seg_name, str):
        raise UserInputError(f"{where('name')}: {head}: 'name' must be a string")
    surface = _surface_keys(raw, head, where)
    for key in SURFACE_NAME_KEYS:
        if key in raw:
            value = raw[key]
            if not isinstance(value, str) or not 0 < len(value) <= 64:
                raise UserInputError(
                    f"{where(key)}: {head}: {key!r} must be a surface name (a string of 1 to 64 "
                    f"characters), got {value!r}")
            surface[key] = value
    if GRIP_KEY in raw:
        surface["grip"] = _number(raw, GRIP_KEY, f"{where(GRIP_KEY)}: {head}", low=MIN_GRIP,
                                  high=MAX_GRIP)
    if kind == "straight":
        length = _number(raw, "length_m", f"{where('length_m')}: {head}", low=1e-3, high=1e5)
        return SegmentSpec("straight", length_m=length, name=seg_name, **surface)
    radius = _number(raw, "radius_m", f"{where('radius_m')}: {head}", low=1e-3, high=1e6)
    angle = _number(raw, "angle_deg", f"{where('angle_deg')}: {head}", low=-360.0, high=360.0)
    if angle == 0.0:
        raise UserInputError(f"{where('angle_deg')}: {head}: 'angle_deg' must not be 0")
    end = None
    if "end_radius_m" in raw:
        end = _number(raw, "end_radius_m", f"{where('end_radius_m')}: {head}", low=1e-3, high=1e6)
    steps = None
    if "steps" in raw:
        steps = raw["steps"]
        if isinstance(steps, bool) or not isinstance(steps, int):
            raise UserInputError(
                f"{where('steps')}: {head}: 'steps' must be an integer, got {steps!r}"
            )
        if not 2 <= steps <= MAX_STEPPED_ARCS:
            raise UserInputError(
                f"{where('steps')}: {head}: 'steps' = {steps} is outside [2, {MAX_STEPPED_ARCS}]"
            )
        if end is None:
            raise UserInputError(
                f"{where('steps')}: {head}: 'steps' needs 'end_radius_m' (it makes a stepped "
                "spiral)"
            )
    inside = left if angle > 0 else right
    tightest = min(radius, end if end is not None else radius)
    if tightest <= inside:
        raise UserInputError(
            f"{where('radius_m')}: {head}: radius {tightest:g} m is not larger than the inside "
            f"half-width {inside:g} m (the inner edge would fold over itself)"
        )
    return SegmentSpec("arc", radius_m=radius, angle_deg=angle, end_radius_m=end, name=seg_name,
                       steps=steps, **surface)


def _surface_table(raw: Any, where: str) -> dict[str, tuple[float, float]]:
    """The optional ``[surfaces]`` table: name -> {friction, rolling_resistance}."""
    if not isinstance(raw, dict) or len(raw) > MAX_SURFACES:
        raise UserInputError(f"{where}: 'surfaces' must be a table of at most {MAX_SURFACES} "
                             "surfaces")
    out = {}
    for name, entry in raw.items():
        head = f"{where}: surface {name!r}"
        if not isinstance(entry, dict) or set(entry) != {"friction", "rolling_resistance"}:
            raise UserInputError(f"{head}: give exactly friction and rolling_resistance")
        out[name] = (_number(entry, "friction", head, low=0.0, high=10.0),
                     _number(entry, "rolling_resistance", head, low=0.0, high=10.0))
    return out


def _surface_keys(raw: dict, head: str, where) -> dict[str, Any]:
    """The optional height, slope and banking keys of a segment table, validated."""
    out: dict[str, Any] = {}
    for key in ("z_start_m", "z_end_m"):
        if key in raw:
            out[key] = _number(raw, key, f"{where(key)}: {head}", low=-MAX_ABS_Z_M,
                               high=MAX_ABS_Z_M)
    for key in ("grade_start_pct", "grade_end_pct"):
        if key in raw:
            out[key] = _number(raw, key, f"{where(key)}: {head}", low=-MAX_ABS_GRADE_PCT,
                               high=MAX_ABS_GRADE_PCT)
    lim = MAX_ABS_BANKING_DEG
    if "banking_deg" in raw:
        if "banking_start_deg" in raw or "banking_end_deg" in raw:
            raise UserInputError(
                f"{where('banking_deg')}: {head}: give banking_deg or banking_start_deg/"
                "banking_end_deg, not both")
        b = _number(raw, "banking_deg", f"{where('banking_deg')}: {head}", low=-lim, high=lim)
        out["banking_start_deg"] = out["banking_end_deg"] = b
    for key in ("banking_start_deg", "banking_end_deg"):
        if key in raw:
            out[key] = _number(raw, key, f"{where(key)}: {head}", low=-lim, high=lim)
    return out


def _number(
    table: dict, key: str, where: str, low: float = -math.inf, high: float = math.inf
) -> float:
    """A finite number within ``[low, high]`` (bools are refused although they are ints)."""
    if key not in table:
        raise UserInputError(f"{where}: missing {key!r}")
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise UserInputError(f"{where}: {key!r} must be a finite number, got {value!r}")
    if not low <= value <= high:
        raise UserInputError(f"{where}: {key!r} = {value!r} is outside [{low:g}, {high:g}]")
    return float(value)


_HEADER = re.compile(r"^\s*\[\[?\s*([A-Za-z0-9_.\-\"']+)\s*\]\]?")


def _line_of(text: str, key: str, segment_index: int | None) -> int | None:
    """1-based line where ``key = ...`` appears (in the given ``[[segment]]``), for messages."""
    seg = -1
    in_top = True
    pattern = re.compile(rf"^\s*[\"']?{re.escape(key)}[\"']?\s*=")
    for number, line in enumerate(text.splitlines(), start=1):
        header = _HEADER.match(line)
        if header:
            in_top = False
            if header.group(1) == "segment":
                seg += 1
            if segment_index is None and header.group(1) == key:
                return number
            continue
        in_wanted = in_top if segment_index is None else seg == segment_index
        if pattern.match(line) and in_wanted:
            return number
    return None


def spec_to_toml(spec: TrackSpec) -> str:
    """Write a spec in the TOML format above (used by ``tracks import`` and ``--save``)."""
    lines = [f"name = {_toml_value(spec.name)}"]
    if spec.description:
        lines.append(f"description = {_toml_value(spec.description)}")
    if abs(spec.width_left_m - spec.width_right_m) < 1e-9:
        lines.append(f"width_m = {_toml_value(spec.width_m)}")
    else:
        lines.append(f"width_left_m = {_toml_value(spec.width_left_m)}")
        lines.append(f"width_right_m = {_toml_value(spec.width_right_m)}")
    used = {s.surface for s in spec.segments} | {s.side_surface for s in spec.segments}
    for name, (friction, rolling) in spec.surfaces.items():
        if name in used:
            lines.append("")
            lines.append(f"[surfaces.{_toml_value(name)}]")
            lines.append(f"friction = {_toml_value(friction)}")
            lines.append(f"rolling_resistance = {_toml_value(rolling)}")
    for seg in spec.segments:
        lines.append("")
        lines.append("[[segment]]")
        lines.extend(f"{k} = {_toml_value(v)}" for k, v in seg.to_dict().items())
    return "\n".join(lines) + "\n"


def _toml_value(value: Any) -> str:
    if isinstance(value, str):
        escaped = value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
        return f'"{escaped}"'
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)  # ``steps``: TOML integer (a float would be refused on reading)
    # repr keeps every digit, so a saved track re-loads bit-identical and closes the same way.
    return repr(float(value))


# --------------------------------------------------------------------------------------------
# Geometry: lanes, sampling, checks
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Piece:
    """One highway-env lane with its signed curvature (spirals are several pieces)."""

    lane: Any
    length_m: float
    curvature_1pm: float
    segment: int


def build_lanes(spec: TrackSpec) -> list[_Piece]:
    """Chain highway-env lanes from the origin, heading east; spirals become stepped arcs."""
    # Local: highway-env (and the gymnasium/pygame stack it pulls in) costs ~0.5 s to import,
    # which ``tracks list`` and every CLI start would pay otherwise.
    from highway_env.road.lane import CircularLane, StraightLane

    x, y, heading = 0.0, 0.0, 0.0
    width = spec.width_m
    pieces: list[_Piece] = []
    for k, seg in enumerate(spec.segments):
        if seg.type == "straight":
            end = (x + seg.length_m * math.cos(heading), y + seg.length_m * math.sin(heading))
            lane = StraightLane((x, y), end, width=width)
            pieces.append(_Piece(lane, seg.length_m, 0.0, k))
            x, y = end
            continue
        total = math.radians(seg.angle_deg)
        side = 1.0 if total > 0 else -1.0
        if seg.steps is not None:
            # TORCS' stepped spiral: radii linear by index, one common length, exact angle.
            radii, sub_length = stepped_spiral(seg)
            arcs = [(radius, side * sub_length / radius) for radius in radii]
        else:
            r0 = seg.radius_m
            r1 = r0 if seg.end_radius_m is None else seg.end_radius_m
            steps = 1 if r1 == r0 else max(4, math.ceil(seg.arc_length_m / SPIRAL_STEP_M))
            arcs = [(r0 + (r1 - r0) * (j + 0.5) / steps, total / steps) for j in range(steps)]
        for radius, dtheta in arcs:
            cx = x - side * radius * math.sin(heading)
            cy = y + side * radius * math.cos(heading)
            start_phase = heading - side * math.pi / 2
            # highway-env's "clockwise" is in screen coordinates (y down): it is our left turn.
            lane = CircularLane(
                (cx, cy), radius, start_phase, start_phase + dtheta, clockwise=side > 0,
                width=width,
            )
            length = radius * abs(dtheta)
            pieces.append(_Piece(lane, length, side / radius, k))
            end_point = lane.position(length, 0.0)
            x, y = float(end_point[0]), float(end_point[1])
            heading += dtheta
    return pieces


def build_track(spec: TrackSpec, label: str, source: str = "") -> Track:
    """Sample a spec into a :class:`Track`; refuse it if it does not close or overlaps itself.

    Samples are placed at a uniform arc-length spacing on the exact lane geometry, and
    curvature comes from the segments (1/R on arcs, 0 on straights), so it is exact rather than a
    noisy finite difference. The residual closure gap (< 1 m) is spread linearly along the lap.
    Specs over :data:`MAX_TRACK_LENGTH_M` are refused before anything is sampled.
    """
    if not spec.segments:
        raise UserInputError(f"{label}: a track needs segments")
    check_track_size(spec, label)
    pieces = build_lanes(spec)
    starts = np.concatenate([[0.0], np.cumsum([p.length_m for p in pieces])])
    length = float(starts[-1])
    last = pieces[-1]
    end = np.asarray(last.lane.position(last.length_m, 0.0), dtype=float)
    gap = end  # the track starts at the origin
    closure = float(np.hypot(*gap))
    if closure > CLOSURE_TOLERANCE_M:
        raise UserInputError(
            f"{label}: track does not close: its end is {closure:.2f} m from the start "
            f"(at x={end[0]:.2f}, y={end[1]:.2f} m; tolerance {CLOSURE_TOLERANCE_M:g} m)"
        )
    end_heading = float(last.lane.heading_at(last.length_m))
    turned = sum(math.radians(s.angle_deg) for s in spec.segments if s.type == "arc")
    kink = math.degrees(math.atan2(math.sin(end_heading), math.cos(end_heading)))
    if abs(kink) > HEADING_TOLERANCE_DEG:
        raise UserInputError(
            f"{label}: track does not close smoothly: it returns to the start {kink:+.2f} deg "
            f"off the start heading (tolerance {HEADING_TOLERANCE_DEG:g} deg)"
        )
    laps_turned = round(turned / (2 * math.pi))
    if (abs(turned - 2 * math.pi * laps_turned) > math.radians(HEADING_TOLERANCE_DEG)
            or (laps_turned not in (-1, 1) and not spec_has_surface(spec))):
        raise UserInputError(
            f"{label}: segments turn {math.degrees(turned):+.1f} deg in total; a simple closed "
            "track turns +360 (counter-clockwise) or -360 (clockwise); another multiple of 360 "
            "(a figure of eight turns 0) needs heights, a bridge where it crosses itself"
        )

    n = max(int(round(length / SAMPLE_SPACING_M)), 8)
    s = np.arange(n) * (length / n)
    which = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(pieces) - 1)
    x = np.empty(n)
    y = np.empty(n)
    heading = np.empty(n)
    for i in range(n):
        piece = pieces[which[i]]
        local = min(s[i] - starts[which[i]], piece.length_m)
        p = piece.lane.position(local, 0.0)
        x[i], y[i] = p[0], p[1]
        heading[i] = piece.lane.heading_at(local)
    x -= gap[0] * s / length
    y -= gap[1] * s / length
    heading = np.angle(np.exp(1j * heading))
    curvature = np.array([p.curvature_1pm for p in pieces])[which]
    z, banking = surface_profile(spec, label, pieces, starts, s, which, length)
    seg_of = np.array([p.segment for p in pieces])[which]
    grip = sample_surfaces([seg.surface for seg in spec.segments],
                           [seg.side_surface for seg in spec.segments], seg_of,
                           spec.surfaces, where=label)
    fr, fs, rr, rs = grip if grip is not None else (None, None, None, None)
    factors = np.array([seg.grip for seg in spec.segments], dtype=float)
    if np.any(factors != 1.0):
        # A section's grip factor scales its road friction (the surface's, or asphalt's 1.0).
        n_samples = len(seg_of)
        fr = (np.ones(n_samples) if fr is None else fr) * factors[seg_of]
        fs = np.full(n_samples, np.nan) if fs is None else fs
        rr = np.zeros(n_samples) if rr is None else rr
        rs = np.zeros(n_samples) if rs is None else rs
    seg_start = {}
    for idx, p in enumerate(pieces):
        seg_start.setdefault(p.segment, starts[idx])
    segments = []
    for k, seg in enumerate(spec.segments):
        entry = seg.to_dict()
        entry["s_start_m"] = float(seg_start[k])
        entry["arc_length_m"] = seg.arc_length_m
        segments.append(entry)
    track = Track(
        name=spec.name,
        s_m=s,
        x_m=x,
        y_m=y,
        heading_rad=heading,
        curvature_1pm=curvature,
        width_left_m=np.full(n, spec.width_left_m),
        width_right_m=np.full(n, spec.width_right_m),
        length_m=length,
        closure_error_m=closure,
        segments=segments,
        source=source,
        z_m=z,
        banking_rad=banking,
        friction_road=fr,
        friction_side=fs,
        rolling_road=rr,
        rolling_side=rs,
    )
    overlap = find_overlap(track)
    if overlap is not None:
        s_a, s_b, dist = overlap
        raise UserInputError(
            f"{label}: track overlaps itself: the asphalt at s={s_a:.0f} m and s={s_b:.0f} m is "
            f"{dist:.1f} m apart centre to centre (a track can only cross itself on a bridge, "
            f"more than {LEVEL_SEPARATION_M:g} m above the other part)"
        )
    return track


def spec_has_surface(spec: TrackSpec) -> bool:
    return any(seg.has_surface for seg in spec.segments)


def segment_heights(spec: TrackSpec) -> list[tuple[float, float, float, float, float, float]]:
    """Per segment ``(z0, z1, slope0, slope1, bank0, bank1)``: heights (m), profile slopes
    (dz/ds) and banking (rad) at its start and end, with the defaults of the format applied."""
    out = []
    z_prev = 0.0
    for seg in spec.segments:
        z0 = z_prev if seg.z_start_m is None else seg.z_start_m
        z1 = z0 if seg.z_end_m is None else seg.z_end_m
        chord = (z1 - z0) / seg.arc_length_m
        g0 = chord if seg.grade_start_pct is None else seg.grade_start_pct / 100.0
        g1 = chord if seg.grade_end_pct is None else seg.grade_end_pct / 100.0
        out.append((z0, z1, g0, g1, math.radians(seg.banking_start_deg),
                    math.radians(seg.banking_end_deg)))
        z_prev = z1
    return out


def surface_profile(spec: TrackSpec, label: str, pieces: list[_Piece], starts: np.ndarray,
                    s: np.ndarray, which: np.ndarray, length: float
                    ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Heights and banking at the samples ``s`` (None, None for a flat spec).

    Along a segment of length ``L`` the height is the cubic (Hermite) through its end heights
    with the end slopes given, in the fraction ``t = (s - s_start) / L``: ``z = z0 h00(t) +
    L g0 h10(t) + z1 h01(t) + L g1 h11(t)``; without slopes it is the straight ramp. The banking
    is linear in ``t``. A height gap between the last segment's end and the first's start is
    refused above :data:`Z_CLOSURE_TOLERANCE_M`, and a smaller one spread along the lap.
    """
    if not spec_has_surface(spec):
        return None, None
    rows = segment_heights(spec)
    z_gap = rows[-1][1] - rows[0][0]
    if abs(z_gap) > Z_CLOSURE_TOLERANCE_M:
        raise UserInputError(
            f"{label}: track does not close in height: it ends {z_gap:+.2f} m above its start "
            f"(tolerance {Z_CLOSURE_TOLERANCE_M:g} m)"
        )
    seg_of = np.array([p.segment for p in pieces])[which]
    seg_start = np.full(len(spec.segments), np.inf)
    for idx, p in enumerate(pieces):
        seg_start[p.segment] = min(seg_start[p.segment], starts[idx])
    seg_len = np.array([seg.arc_length_m for seg in spec.segments])
    table = np.array(rows)
    t = np.clip((s - seg_start[seg_of]) / seg_len[seg_of], 0.0, 1.0)
    z0, z1, g0, g1, b0, b1 = (table[seg_of, k] for k in range(6))
    big_l = seg_len[seg_of]
    t2 = t * t
    t3 = t2 * t
    z = ((2 * t3 - 3 * t2 + 1) * z0 + (t3 - 2 * t2 + t) * big_l * g0
         + (-2 * t3 + 3 * t2) * z1 + (t3 - t2) * big_l * g1)
    z = z - z_gap * s / length
    banking = b0 + t * (b1 - b0)
    return z, banking


def find_overlap(
    track: Track, margin_m: float = OVERLAP_MARGIN_M
) -> tuple[float, float, float] | None:
    """First pair of distant track parts whose asphalt (plus margin) overlaps, else None.

    Parts more than :data:`~formula_tourney.sim.track.LEVEL_SEPARATION_M` apart in height do
    not overlap (one crosses the other on a bridge).

    Two samples are *distant* when the way between them along the track is longer than half a
    circle of diameter ``reach`` (a hairpin whose legs are ``reach`` apart is that long); such
    samples must be at least ``reach`` = both half-widths + margin apart. A k-d tree keeps this
    O(n log n): a 6 km track is checked in a few milliseconds.
    """
    from scipy.spatial import cKDTree  # local: scipy is a slow import, only built tracks need it

    half = np.maximum(track.width_left_m, track.width_right_m)
    reach = 2.0 * float(half.max()) + margin_m
    points = np.column_stack([track.x_m, track.y_m])
    pairs = cKDTree(points).query_pairs(reach, output_type="ndarray")
    if len(pairs) == 0:
        return None
    i, j = pairs[:, 0], pairs[:, 1]
    along = np.abs(track.s_m[i] - track.s_m[j])
    along = np.minimum(along, track.length_m - along)
    dist = np.hypot(track.x_m[i] - track.x_m[j], track.y_m[i] - track.y_m[j])
    needed = half[i] + half[j] + margin_m
    # 3-D: parts more than LEVEL_SEPARATION_M apart in height are a bridge over a road.
    level = np.abs(track.z_m[i] - track.z_m[j]) <= LEVEL_SEPARATION_M
    bad = (along > 0.5 * math.pi * reach) & (dist < needed) & level
    if not bad.any():
        return None
    k = int(np.argmin(np.where(bad, dist, np.inf)))
    return float(track.s_m[i[k]]), float(track.s_m[j[k]]), float(dist[k])

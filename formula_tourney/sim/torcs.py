"""TORCS track XML import: the ``Main Track`` segments become a :class:`TrackSpec`.

A TORCS track file is a ``<params>`` document; what we read is::

    <section name="Main Track">
      <attnum name="width" unit="m" val="15"/>
      <section name="Track Segments">           (older files: "segments")
        <section name="s1">
          <attstr name="type" val="str"/>  <attnum name="lg" unit="ft" val="300"/>
        </section>
        <section name="t1">
          <attstr name="type" val="lft"/>  <attnum name="radius" unit="m" val="50"/>
          <attnum name="end radius" unit="m" val="30"/>   (optional: a spiral)
          <attnum name="arc" unit="deg" val="90"/>
        </section>

Like TORCS, numbers without a unit are SI (metres, radians) and the start line is the start of
the first segment. Heights and banking are read (:func:`_heights`), and surface names
(:func:`_surfaces`); the widths of borders, sides and pits are ignored.

Surfaces as TORCS names them: the road's is the ``surface`` of ``Main Track`` (default
``asphalt``), then of each segment, which holds for the following segments until another is
given; the sides' are ``lside surface`` / ``rside surface`` or the ``surface`` of a ``Left Side``
/ ``Right Side`` section, in ``Main Track`` or a segment, carried over the same way (default
``grass``). Our side is one surface for both sides: the one of lower TORCS friction. Borders
(curbs) are not modelled and their surfaces are not read. Every segment of the spec names its
surfaces explicitly, and the file's own ``Surfaces`` section (friction and rolling resistance
of its own names, over :data:`~formula_tourney.sim.surfaces.TORCS_SURFACES`) goes into the
spec, so a TOML written from it drives the same.

Heights as TORCS' loader builds them. Each segment has a height at its start and end on each
edge. The start heights are where the previous segment ended unless ``z start`` (both edges) or
``z start left``/``z start right`` say otherwise; the end heights come from ``z end`` (or its
per-edge forms), else from ``grade`` (the centre climbs ``grade x length``; a grade once given
holds for the following segments until another is given), else stay the previous end's. The
banking at each end is the edges' height difference over the width unless ``banking start`` /
``banking end`` set it, and the edges are then put at the centre height plus or minus
``tan(banking) x width / 2``. Between its ends, each edge follows a cubic in the fraction of
the segment travelled (a Hermite curve: the end heights and the end slopes, each slope times
the segment's declared length); the slopes default to the previous segment's end slope, are
set by ``profil start tangent`` / ``profil end tangent`` (and their left/right forms), and
with ``profil`` other than ``spline`` are the chord's, which makes the profile a straight
ramp. TORCS evaluates the cubic at the ends of the segment's sub-segments and joins those
points by straight pieces; a segment of one sub-segment is therefore a ramp whatever its
slopes. The import keeps the centreline's cubic for segments of several sub-segments (it meets
TORCS' heights at every sub-segment end) and the ramp for segments of one; the banking is
linear between its end values.

Geometry is built as TORCS' track loader builds it, so that a track closes (or misses) exactly
where TORCS' does. TORCS cuts every segment into *sub-segments*; for straights and arcs of
constant radius that changes nothing, but a spiral (``end radius`` differs from ``radius``)
becomes a chain of constant-radius arcs, and that chain, not an ideal clothoid, is the track:

1. The declared length is ``arc * (radius + end radius) / 2`` (``lg`` for a straight).
2. The number of sub-segments ``N``: if the segment's ``profil`` is not ``spline`` (the default),
   ``N = 1``. Otherwise ``N`` is the segment's ``profil steps`` (a number, cut to an integer,
   default 1); if that is 1, a step length is taken: the segment's ``profil steps length``, else
   the one in ``Main Track``, else none; with a step length ``h``, ``N = int(length / h) + 1``.
3. A spiral with ``N >= 2``: the radii step linearly by sub-segment index from ``radius`` (the
   first) to ``end radius`` (the last), ``r_i = r0 + i (r1 - r0) / (N - 1)``; all sub-segments
   get one common length, rescaled so that they turn exactly ``arc``: ``L = arc / sum(1/r_i)``.
   The spiral is then ``N * L`` long, not its declared length; TORCS' lap length is the sum
   of the sub-segment lengths. We keep it as one segment with ``steps = N``
   (:mod:`formula_tourney.sim.segments`).
4. A spiral with ``N = 1`` is one arc of radius ``radius`` and the declared length, so it turns
   ``arc * (radius + end radius) / (2 radius)``, not ``arc``: TORCS builds it so, and so do we.

A segment cut into fewer than one sub-segment (``profil steps`` 0 or negative, a negative step
length) would vanish in TORCS; it is refused here, as is a spiral cut into more than
:data:`~formula_tourney.sim.segments.MAX_STEPPED_ARCS` sub-arcs.

Safety: real files begin with a DOCTYPE that declares *external* entities, e.g.
``<!ENTITY default-surfaces SYSTEM "../../../data/tracks/surfaces.xml">``, used in the body as
``&default-surfaces;``. Nothing external is ever read: the DOCTYPE is cut out by a small scanner
here, references to external entities are dropped, and the rest is parsed by defusedxml with DTDs
forbidden. Internal entity definitions (the stuff of "billion laughs" bombs) and parameter
entities are refused outright rather than expanded.
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import replace
from pathlib import Path

from formula_tourney.errors import UserInputError
from formula_tourney.safeio import check_name
from formula_tourney.sim.segments import (
    MAX_ABS_BANKING_DEG,
    MAX_SEGMENTS,
    MAX_STEPPED_ARCS,
    MAX_WIDTH_M,
    MIN_WIDTH_M,
    SegmentSpec,
    TrackSpec,
    build_track,
    check_track_size,
)
from formula_tourney.sim.surfaces import ROAD_DEFAULT, SIDE_DEFAULT, lookup
from formula_tourney.sim.track import Track

MAX_FILE_BYTES = 8 * 1024 * 1024
"""Real TORCS track files are tens of kB; anything this large is not a track."""

DEFAULT_WIDTH_M = 15.0
"""TORCS' own default when ``Main Track`` has no ``width``."""

LENGTH_UNITS = {"": 1.0, "m": 1.0, "ft": 0.3048, "feet": 0.3048, "km": 1000.0, "cm": 0.01,
                "mm": 0.001, "in": 0.0254, "%": 0.01}
ANGLE_UNITS = {"": 1.0, "rad": 1.0, "deg": math.pi / 180.0, "%": 0.01}
COUNT_UNITS = {"": 1.0}
SLOPE_UNITS = {"": 1.0, "%": 0.01}
"""Unit factors to SI, as TORCS' GfParm applies them (``%`` divides by 100)."""

PREDEFINED_ENTITIES = {"amp", "lt", "gt", "quot", "apos"}
_ENTITY_REF = re.compile(r"&([A-Za-z_][A-Za-z0-9._\-:]*);")
_DECL = re.compile(r"<!ENTITY\s+(%\s+)?([^\s>]+)\s+(SYSTEM|PUBLIC|[\"'])", re.IGNORECASE)


def read_torcs_spec(path: str | Path, name: str | None = None) -> TrackSpec:
    """Parse a TORCS track file into a spec (not built yet: see :func:`load_torcs_track`)."""
    path = Path(path)
    label = str(path)
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise UserInputError(f"{label}: track file not found") from None
    except OSError as err:
        raise UserInputError(f"{label}: cannot read track file ({err})") from None
    if size > MAX_FILE_BYTES:
        raise UserInputError(f"{label}: {size} bytes is too large for a TORCS track file")
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise UserInputError(f"{label}: cannot read track file ({err})") from None
    root = parse_xml_safely(raw, label)
    track_name = name or _default_name(path)
    check_name(track_name, f"track name for {label}")
    return _spec_from_root(root, label, track_name)


def load_torcs_track(path: str | Path, name: str | None = None) -> Track:
    """Build a TORCS file's main track; refused like any track if it misses closure by > 1 m."""
    spec = read_torcs_spec(path, name)
    return build_torcs_spec(spec, str(path))


def build_torcs_spec(spec: TrackSpec, label: str) -> Track:
    """:func:`segments.build_track` with a hint on closure errors (TORCS leaves gaps open)."""
    try:
        return build_track(spec, label, source=label)
    except UserInputError as err:
        if "does not close" in str(err):
            raise UserInputError(
                f"{err}; TORCS links its last segment to the first wherever it ends, we refuse "
                "tracks that miss by more than 1 m (fix the segment lengths or angles)"
            ) from None
        raise


def _default_name(path: Path) -> str:
    """The file stem, made path-safe (TORCS names like ``e-track-1`` pass unchanged)."""
    stem = re.sub(r"[^A-Za-z0-9_.+-]+", "-", path.stem).strip("-.") or "torcs-track"
    return stem[:128]


# --------------------------------------------------------------------------------------------
# Safe XML
# --------------------------------------------------------------------------------------------


def parse_xml_safely(raw: bytes, label: str):
    """Parse TORCS XML without resolving anything external and without entity expansion.

    The bytes are scanned as latin-1 (a 1:1 byte mapping, so UTF-8 content passes through
    unchanged) to cut the DOCTYPE; the cleaned bytes then go to defusedxml with DTDs forbidden,
    so if the scanner ever missed a DOCTYPE the parser refuses instead of expanding it.
    """
    # Local: only an import needs the XML parser; keeps the CLI's start (tracks list) fast.
    import defusedxml.ElementTree as SafeET
    from defusedxml import DefusedXmlException

    text = raw.decode("latin-1")
    text, _external = _strip_doctype(text, label)

    def drop(match: re.Match) -> str:
        # External entities are never fetched; undeclared ones could not be resolved either.
        # Both are dropped, which is what a non-validating reader without the DTD would see.
        return match.group(0) if match.group(1) in PREDEFINED_ENTITIES else ""

    body = _ENTITY_REF.sub(drop, text)
    try:
        return SafeET.fromstring(body.encode("latin-1"), forbid_dtd=True,
                                 forbid_entities=True, forbid_external=True)
    except DefusedXmlException as err:
        raise UserInputError(f"{label}: refused unsafe XML ({type(err).__name__})") from None
    except SafeET.ParseError as err:
        raise UserInputError(f"{label}: malformed XML: {err}") from None


def _strip_doctype(text: str, label: str) -> tuple[str, set[str]]:
    """Remove the DOCTYPE; return the text and the names of the external entities it declared.

    Internal entities (``<!ENTITY x "...">``) and parameter entities (``<!ENTITY % x ...>``) are
    refused: the first are how entity bombs expand, the second pull in further DTD text.
    """
    start = text.find("<!DOCTYPE")
    if start < 0:
        if re.search(r"<!ENTITY", text, re.IGNORECASE):
            raise UserInputError(f"{label}: entity declaration outside a DOCTYPE")
        return text, set()
    if text.find("<!DOCTYPE", start + 1) >= 0:
        raise UserInputError(f"{label}: more than one DOCTYPE")
    end = _doctype_end(text, start, label)
    doctype = text[start:end]
    line = text.count("\n", 0, start) + 1
    external: set[str] = set()
    declared = 0
    for match in _DECL.finditer(doctype):
        declared += 1
        param, entity, kind = match.group(1), match.group(2), match.group(3).upper()
        where = f"{label}, line {line + doctype.count(chr(10), 0, match.start())}"
        if param:
            raise UserInputError(f"{where}: parameter entity %{entity}; is refused")
        if kind not in ("SYSTEM", "PUBLIC"):
            raise UserInputError(
                f"{where}: internal entity definition {entity!r} is refused (entity expansion "
                "can blow up: 'billion laughs')"
            )
        external.add(entity)
    if declared != len(re.findall(r"<!ENTITY", doctype, re.IGNORECASE)):
        raise UserInputError(f"{label}, line {line}: unreadable ENTITY declaration in DOCTYPE")
    return text[:start] + text[end:], external


def _doctype_end(text: str, start: int, label: str) -> int:
    """Index just past the DOCTYPE's closing ``>``, skipping quoted strings and ``[...]``."""
    depth = 0
    quote = ""
    i = start + len("<!DOCTYPE")
    while i < len(text):
        ch = text[i]
        if quote:
            if ch == quote:
                quote = ""
        elif ch in "\"'":
            quote = ch
        elif text.startswith("<!--", i):
            close = text.find("-->", i + 4)
            if close < 0:
                break
            i = close + 3
            continue
        elif ch == "[":
            depth += 1
        elif ch == "]":
            depth -= 1
        elif ch == ">" and depth == 0:
            return i + 1
        i += 1
    line = text.count("\n", 0, start) + 1
    raise UserInputError(f"{label}, line {line}: unterminated DOCTYPE")


# --------------------------------------------------------------------------------------------
# TORCS params -> TrackSpec
# --------------------------------------------------------------------------------------------


def _section(parent, name: str):
    """Child ``<section name=...>`` (case-insensitive, as TORCS compares names)."""
    for child in parent:
        if child.tag == "section" and child.get("name", "").strip().lower() == name.lower():
            return child
    return None


def _attr(section, name: str):
    for child in section:
        if child.tag in ("attnum", "attstr") and child.get("name", "").strip().lower() == name:
            return child
    return None


def _num(section, name: str, units: dict[str, float], where: str, default: float | None = None,
         ) -> float | None:
    """An ``attnum`` in SI units; a missing one gives ``default``."""
    node = _attr(section, name)
    if node is None:
        return default
    raw = node.get("val")
    unit = (node.get("unit") or "").strip()
    try:
        value = float(raw) if raw is not None else math.nan
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise UserInputError(f"{where}: {name!r} must be a finite number, got {raw!r}")
    factor = units.get(unit) if unit in units else units.get(unit.lower())
    if factor is None:
        raise UserInputError(
            f"{where}: {name!r} has unit {unit!r}; known: "
            f"{', '.join(u for u in units if u) or 'none'}"
        )
    return value * factor


def _sub_segments(sec, length: float, global_step: float, where: str, spiral: bool = False,
                  ) -> int:
    """How many sub-segments TORCS cuts a segment of declared ``length`` into (module doc, 2)."""
    node = _attr(sec, "profil")
    profil = (node.get("val") or "").strip() if node is not None else "spline"
    if profil != "spline":
        return 1
    given = _num(sec, "profil steps", COUNT_UNITS, where, 1.0)
    steps = math.trunc(given) if abs(given) < 2.0**53 else given
    source = f"'profil steps' = {given:g}"
    if steps == 1:
        step = _num(sec, "profil steps length", LENGTH_UNITS, where, global_step)
        if step != 0.0:
            ratio = length / step
            source = f"'profil steps length' = {step:g} m over {length:g} m"
            steps = math.trunc(ratio) + 1 if abs(ratio) < 2.0**53 else ratio
    if steps < 1:
        raise UserInputError(
            f"{where}: {source} cuts the segment into {steps:g} pieces; TORCS would drop it "
            "(at least 1 is needed)"
        )
    if spiral and steps > MAX_STEPPED_ARCS:
        raise UserInputError(
            f"{where}: {source} cuts the spiral into {steps:g} arcs; at most "
            f"{MAX_STEPPED_ARCS} are accepted"
        )
    return int(min(steps, 2.0**53))  # only a spiral's count is used, and it is capped above


def _spec_from_root(root, label: str, name: str) -> TrackSpec:
    if root.tag != "params":
        raise UserInputError(f"{label}: not a TORCS params file (root element <{root.tag}>)")
    main = _section(root, "Main Track")
    if main is None:
        raise UserInputError(f"{label}: no <section name=\"Main Track\">")
    width = _num(main, "width", LENGTH_UNITS, f"{label}: Main Track", DEFAULT_WIDTH_M)
    if not MIN_WIDTH_M <= width <= MAX_WIDTH_M:
        raise UserInputError(
            f"{label}: Main Track width {width:g} m is outside [{MIN_WIDTH_M:g}, {MAX_WIDTH_M:g}]"
        )
    segs = _section(main, "Track Segments")
    if segs is None:
        segs = _section(main, "segments")
    if segs is None:
        raise UserInputError(f"{label}: Main Track has no <section name=\"Track Segments\">")
    raw_segments = [c for c in segs if c.tag == "section"]
    if not raw_segments:
        raise UserInputError(f"{label}: Track Segments is empty")
    if len(raw_segments) > MAX_SEGMENTS:
        raise UserInputError(
            f"{label}: {len(raw_segments)} segments; at most {MAX_SEGMENTS} are accepted"
        )
    # TORCS reads the global step length from Main Track; a segment's own one overrides it.
    global_step = _num(main, "profil steps length", LENGTH_UNITS, f"{label}: Main Track", 0.0)
    half = width / 2.0
    out: list[SegmentSpec] = []
    cuts: list[tuple[float, int]] = []  # (declared length, sub-segments) per segment
    for k, sec in enumerate(raw_segments, start=1):
        seg_name = sec.get("name", f"#{k}")
        where = f"{label}: segment {k} ({seg_name!r})"
        node = _attr(sec, "type")
        kind = (node.get("val") or "").strip().lower() if node is not None else ""
        if kind == "str":
            length = _num(sec, "lg", LENGTH_UNITS, where)
            if length is None or length <= 0:
                raise UserInputError(f"{where}: a straight needs a positive 'lg'")
            steps = _sub_segments(sec, length, global_step, where)  # refuses a vanishing one
            out.append(SegmentSpec("straight", length_m=length, name=seg_name))
            cuts.append((length, steps))
        elif kind in ("lft", "rgt"):
            radius = _num(sec, "radius", LENGTH_UNITS, where)
            arc = _num(sec, "arc", ANGLE_UNITS, where)
            end = _num(sec, "end radius", LENGTH_UNITS, where)
            if radius is None or radius <= 0:
                raise UserInputError(f"{where}: a turn needs a positive 'radius'")
            if arc is None or not 0 < arc <= 2 * math.pi:
                raise UserInputError(f"{where}: a turn needs an 'arc' in (0, 360] deg")
            if end is not None and end <= 0:
                raise UserInputError(f"{where}: 'end radius' must be positive")
            if min(radius, end if end is not None else radius) <= half:
                raise UserInputError(
                    f"{where}: radius {min(radius, end or radius):g} m is not larger than the "
                    f"half-width {half:g} m"
                )
            sign = 1.0 if kind == "lft" else -1.0
            end_r = None if end is None or abs(end - radius) < 1e-9 else end
            declared = arc * (radius + (radius if end_r is None else end_r)) / 2.0
            steps = _sub_segments(sec, declared, global_step, where, spiral=end_r is not None)
            if end_r is None:
                out.append(SegmentSpec("arc", radius_m=radius, angle_deg=sign * math.degrees(arc),
                                       name=seg_name))
            elif steps == 1:
                # TORCS keeps the start radius and the declared length: the angle is not `arc`.
                out.append(SegmentSpec("arc", radius_m=radius,
                                       angle_deg=sign * math.degrees(declared / radius),
                                       name=seg_name))
            else:
                out.append(SegmentSpec("arc", radius_m=radius, angle_deg=sign * math.degrees(arc),
                                       end_radius_m=end_r, steps=steps, name=seg_name))
            cuts.append((declared, steps))
        else:
            raise UserInputError(
                f"{where}: 'type' must be str, lft or rgt, got {kind or 'nothing'!r}"
            )
    out = _heights(raw_segments, out, cuts, width, label)
    table = _surface_table(root, label)
    out = _surfaces(main, raw_segments, out, table)
    spec = TrackSpec(name=name, width_left_m=half, width_right_m=half, segments=out,
                     description=f"imported from TORCS file {Path(label).name}", surfaces=table)
    # Lengths are checked on the spec, before any lane or sample array exists (a 1e9 m
    # straight once allocated GiBs before it was refused).
    check_track_size(spec, label)
    return spec


def _side_surface(sec, side: str) -> str | None:
    """``lside surface`` (``side`` "l") or the ``surface`` of ``Left Side`` in ``sec``."""
    node = _attr(sec, f"{side}side surface")
    if node is None:
        part = _section(sec, "Left Side" if side == "l" else "Right Side")
        node = _attr(part, "surface") if part is not None else None
    value = (node.get("val") or "").strip() if node is not None else ""
    return value or None


def _surface_table(root, label: str) -> dict[str, tuple[float, float]]:
    """The file's own ``Surfaces`` section: name -> (friction, rolling resistance), for the
    sections that give a friction (the shared surfaces.xml is an external entity, never read)."""
    surfaces = _section(root, "Surfaces")
    out: dict[str, tuple[float, float]] = {}
    if surfaces is None:
        return out
    for sec in surfaces:
        if sec.tag != "section" or not sec.get("name", "").strip():
            continue
        where = f"{label}: surface {sec.get('name')!r}"
        try:
            friction = _num(sec, "friction", COUNT_UNITS, where)
            rolling = _num(sec, "rolling resistance", COUNT_UNITS, where, 0.0)
        except UserInputError as err:
            warnings.warn(f"{err}; the surface is ignored", stacklevel=2)
            continue
        if friction is None or not 0.0 <= friction <= 10.0:
            continue
        out[sec.get("name").strip()] = (friction, min(max(rolling, 0.0), 10.0))
    return out


def _surfaces(main, raw_segments, segs: list[SegmentSpec], table) -> list[SegmentSpec]:
    """Each segment's road and side surface names, TORCS' carry-over applied (module doc)."""
    def road_of(sec, current: str) -> str:
        node = _attr(sec, "surface")
        value = (node.get("val") or "").strip() if node is not None else ""
        return value or current

    road = road_of(main, ROAD_DEFAULT)
    left = _side_surface(main, "l") or SIDE_DEFAULT
    right = _side_surface(main, "r") or SIDE_DEFAULT
    if road == ROAD_DEFAULT and left == right == SIDE_DEFAULT and not any(
            _attr(sec, "surface") is not None or _side_surface(sec, "l")
            or _side_surface(sec, "r") for sec in raw_segments):
        return segs  # all defaults: the spec (and its TOML) stays as before surfaces
    out = []
    for sec, seg in zip(raw_segments, segs, strict=True):
        road = road_of(sec, road)
        left = _side_surface(sec, "l") or left
        right = _side_surface(sec, "r") or right
        fl = lookup(left, table, warn=False)  # (unknown names are warned once, when sampled)
        fr = lookup(right, table, warn=False)
        side = right if (fr or (1.0,))[0] < (fl or (1.0,))[0] else left
        out.append(replace(seg, surface=road, side_surface=side))
    return out


def _heights(raw_segments, segs: list[SegmentSpec], cuts: list[tuple[float, int]], width: float,
             label: str) -> list[SegmentSpec]:
    """Segments with TORCS' heights, profile slopes and banking (module docstring); unchanged
    when the file has none (every height and banking 0: a flat track stays flat)."""
    zel = zer = 0.0  # previous segment's end heights, left and right edge
    etl = etr = 0.0  # previous segment's end slopes (TORCS' tangents)
    grade = None  # sticky, as in TORCS
    rows = []
    for k, (sec, (length, steps)) in enumerate(zip(raw_segments, cuts, strict=True), start=1):
        where = f"{label}: segment {k} ({sec.get('name', f'#{k}')!r})"

        def num(name, units=LENGTH_UNITS, default=None, sec=sec, where=where):
            return _num(sec, name, units, where, default)

        zsl = num("z start left", default=zel)
        zsr = num("z start right", default=zer)
        zel = num("z end left", default=zel)
        zer = num("z end right", default=zer)
        zs = num("z start")
        ze = num("z end")
        grade = num("grade", SLOPE_UNITS, grade)
        if zs is not None:
            zsl = zsr = zs
        else:
            zs = 0.5 * (zsl + zsr)
        if ze is not None:
            zel = zer = ze
        elif grade is not None:
            ze = zs + length * grade
        else:
            ze = 0.5 * (zel + zer)
        bank_s = num("banking start", ANGLE_UNITS, math.atan2(zsl - zsr, width))
        bank_e = num("banking end", ANGLE_UNITS, math.atan2(zel - zer, width))
        if max(abs(bank_s), abs(bank_e)) >= math.radians(MAX_ABS_BANKING_DEG):
            raise UserInputError(
                f"{where}: banking {math.degrees(max(abs(bank_s), abs(bank_e))):.1f} deg; at "
                f"most {MAX_ABS_BANKING_DEG:g} deg is accepted")
        d = math.tan(bank_s) * width / 2.0
        zsl, zsr = zs + d, zs - d
        d = math.tan(bank_e) * width / 2.0
        zel, zer = ze + d, ze - d
        node = _attr(sec, "profil")
        profil = (node.get("val") or "").strip() if node is not None else "spline"
        stl, str_ = etl, etr
        if profil == "spline":
            stl = num("profil start tangent left", SLOPE_UNITS, stl)
            etl = num("profil end tangent left", SLOPE_UNITS, etl)
            str_ = num("profil start tangent right", SLOPE_UNITS, str_)
            etr = num("profil end tangent right", SLOPE_UNITS, etr)
            st_both = num("profil start tangent", SLOPE_UNITS)
            et_both = num("profil end tangent", SLOPE_UNITS)
            if st_both is not None:
                stl = str_ = st_both
            if et_both is not None:
                etl = etr = et_both
        else:
            steps = 1
            stl = etl = (zel - zsl) / length
            str_ = etr = (zer - zsr) / length
        rows.append((zs, ze, 0.5 * (stl + str_), 0.5 * (etl + etr), bank_s, bank_e, length,
                     steps))
    if all(r[0] == 0.0 and r[1] == 0.0 and r[4] == 0.0 and r[5] == 0.0 for r in rows):
        return segs
    out = []
    for seg, (zs, ze, t0, t1, bank_s, bank_e, length, steps) in zip(segs, rows, strict=True):
        extra: dict = {"z_start_m": zs, "z_end_m": ze,
                       "banking_start_deg": math.degrees(bank_s),
                       "banking_end_deg": math.degrees(bank_e)}
        if steps > 1:
            # TORCS scales the slopes by the declared length; ours by the built one.
            scale = length / seg.arc_length_m * 100.0
            extra["grade_start_pct"] = t0 * scale
            extra["grade_end_pct"] = t1 * scale
        out.append(replace(seg, **extra))
    return out

"""TORCS track XML import: real-file DOCTYPEs with external entities, units, spirals built as
TORCS builds them (sub-segments, ``profil steps``, ``profil steps length``), closure, and refusal
of entity bombs and external-entity tricks (XML files written here, TORCS-style)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from formula_tourney.errors import UserInputError
from formula_tourney.sim.catalog import list_tracks, load_track, user_tracks_dir
from formula_tourney.sim.segments import (
    SegmentSpec,
    TrackSpec,
    build_lanes,
    build_track,
    parse_spec,
    spec_to_toml,
)
from formula_tourney.sim.torcs import load_torcs_track, read_torcs_spec
from formula_tourney.sim.track_store import import_torcs_track

FT = 0.3048

DOCTYPE = """<?xml version="1.0" encoding="UTF-8"?>
<!DOCTYPE params SYSTEM "../../../../src/libs/tgf/params.dtd" [
<!-- general definitions for tracks -->
<!ENTITY default-surfaces SYSTEM "../../../data/tracks/surfaces.xml">
<!ENTITY default-objects SYSTEM "../../../data/tracks/objects.xml">
]>
"""


def straight(name: str, lg: float, unit: str = "m") -> str:
    return (f'<section name="{name}"><attstr name="type" val="str"/>'
            f'<attnum name="lg" unit="{unit}" val="{lg!r}"/></section>\n')


def turn(name: str, side: str, radius: float, arc: float, arc_unit: str | None = "deg",
         end_radius: float | None = None, radius_unit: str = "m", extra: str = "") -> str:
    unit = f' unit="{arc_unit}"' if arc_unit else ""
    end = ("" if end_radius is None else
           f'<attnum name="end radius" unit="{radius_unit}" val="{end_radius!r}"/>')
    return (f'<section name="{name}"><attstr name="type" val="{side}"/>'
            f'<attnum name="radius" unit="{radius_unit}" val="{radius!r}"/>{end}'
            f'<attnum name="arc"{unit} val="{arc!r}"/>{extra}</section>\n')


def steps_attr(n: float) -> str:
    return f'<attnum name="profil steps" val="{n!r}"/>'


def step_length_attr(value: float, unit: str = "m") -> str:
    return f'<attnum name="profil steps length" unit="{unit}" val="{value!r}"/>'


def end_of(pieces):
    """End point and heading of a chain of lanes (the spec's own start is the origin, east)."""
    last = pieces[-1]
    point = last.lane.position(last.length_m, 0.0)
    return float(point[0]), float(point[1]), float(last.lane.heading_at(last.length_m))


def torcs_xml(segments: str, width: str = '<attnum name="width" unit="m" val="12"/>',
              head: str = DOCTYPE, extra: str = "") -> str:
    return (f"{head}<params name=\"test track\" type=\"param\" mode=\"mw\">\n"
            "  &default-surfaces;\n  &default-objects;\n"
            '  <section name="Header"><attstr name="name" val="Test"/></section>\n'
            f'  <section name="Main Track">\n    {width}\n{extra}'
            '    <attstr name="surface" val="asphalt2-lines"/>\n'
            '    <section name="Track Segments">\n'
            f"{segments}"
            "    </section>\n  </section>\n</params>\n")


def stadium_segments(straight_ft: float = 656.168, radius_m: float = 60.0) -> str:
    """Two straights (in feet) and two left half-circles (arc in degrees)."""
    return (straight("start", straight_ft, "ft") + turn("t1", "lft", radius_m, 180.0)
            + straight("back", straight_ft, "ft") + turn("t2", "lft", radius_m, 180.0))


@pytest.fixture(autouse=True)
def _private_data_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("FORMULA_TOURNEY_DATA_DIR", str(tmp_path / "data"))


def write(tmp_path, name: str, text: str):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_doctype_with_external_entities_imports_and_units_convert(tmp_path):
    path = write(tmp_path, "e-stadium.xml", torcs_xml(stadium_segments()))
    track = load_torcs_track(path)
    straight_m = 656.168 * FT  # 200.0 m
    assert track.length_m == pytest.approx(2 * straight_m + 2 * math.pi * 60.0, abs=1e-6)
    assert track.closure_error_m < 1e-6
    assert np.all(track.width_m == 12.0)
    assert track.min_radius_m == pytest.approx(60.0)
    kinds = [(s["type"], round(s.get("length_m", s.get("angle_deg", 0)), 3))
             for s in track.segments]
    assert kinds == [("straight", 200.0), ("arc", 180.0), ("straight", 200.0), ("arc", 180.0)]
    assert track.name == "e-stadium"


def test_units_feet_width_radians_without_unit_and_right_turns(tmp_path):
    # Clockwise stadium; width 40 ft; radius in feet; arcs in radians (TORCS' default unit).
    segs = (straight("a", 300.0) + turn("b", "rgt", 200.0, math.pi, None, radius_unit="ft")
            + straight("c", 300.0) + turn("d", "rgt", 200.0, math.pi, None, radius_unit="ft"))
    path = write(tmp_path, "cw.xml",
                 torcs_xml(segs, width='<attnum name="width" unit="ft" val="40"/>'))
    track = load_torcs_track(path)
    assert np.allclose(track.width_m, 40 * FT)
    assert track.length_m == pytest.approx(600.0 + 2 * math.pi * 200 * FT, abs=1e-6)
    assert np.all(track.curvature_1pm <= 0.0)  # right turns have negative curvature
    assert track.min_radius_m == pytest.approx(200 * FT)


# The spiral of the hand computations below: radius 60 m -> end radius 40 m over 90 deg, cut into
# N = 3 sub-segments. Radii step by index: 60, 50, 40 m. One common length L makes them turn
# exactly 90 deg: L (1/60 + 1/50 + 1/40) = pi/2, so L = (pi/2) / (37/600) = 300 pi / 37
# = 25.4724 m, and the spiral is 3 L = 900 pi / 37 = 76.4171 m long (declared: 50 * pi/2 =
# 78.5398 m). The arcs turn L/r: 5 pi/37, 6 pi/37 and 7.5 pi/37 rad (24.32, 29.19, 36.49 deg).
# Chaining the three arcs from the origin heading east (x += r (sin h1 - sin h0),
# y += r (cos h0 - cos h1) for each arc) ends at (52.158984, 44.941383), heading north. The
# ideal spiral with radius linear in the angle would end at (52.732395, 47.267605): 2.4 m away.
SUB_LENGTH = 300 * math.pi / 37
SPIRAL_END = (52.15898378610933, 44.94138333307578)


@pytest.mark.parametrize(("side", "sign"), [("lft", 1.0), ("rgt", -1.0)])
def test_a_spiral_is_cut_into_profil_steps_arcs_of_one_length_and_exact_angle(
        tmp_path, side, sign):
    segs = turn("t1", side, 60.0, 90.0, end_radius=40.0, extra=steps_attr(3))
    spec = read_torcs_spec(write(tmp_path, "spiral.xml", torcs_xml(segs)))
    (seg,) = spec.segments
    assert (seg.radius_m, seg.end_radius_m, seg.steps, seg.angle_deg) == (60.0, 40.0, 3,
                                                                          sign * 90.0)
    assert seg.arc_length_m == pytest.approx(900 * math.pi / 37, abs=1e-9)  # 76.4171 m
    pieces = build_lanes(spec)
    assert [p.curvature_1pm for p in pieces] == pytest.approx(
        [sign / 60.0, sign / 50.0, sign / 40.0], abs=1e-15)
    assert [p.length_m for p in pieces] == pytest.approx([SUB_LENGTH] * 3, abs=1e-9)
    x, y, heading = end_of(pieces)
    assert (x, y) == pytest.approx((SPIRAL_END[0], sign * SPIRAL_END[1]), abs=1e-9)
    assert heading == pytest.approx(sign * math.pi / 2, abs=1e-12)


def _sum_inverse_radii(r0: float, r1: float, n: int) -> float:
    return sum(1.0 / (r0 + (r1 - r0) * i / (n - 1)) for i in range(n))


@pytest.mark.parametrize(
    ("main_extra", "seg_extra", "steps"),
    [
        # Declared length 78.54 m; with a step length h: N = int(78.54 / h) + 1.
        ("", "", 1),                                            # nothing: one sub-segment
        (step_length_attr(20.0), "", 4),                        # Main Track's: 3.93 -> 4
        (step_length_attr(20.0), step_length_attr(30.0), 3),    # the segment's wins: 2.62 -> 3
        (step_length_attr(20.0), step_length_attr(50.0, "ft"), 6),  # 15.24 m: 5.15 -> 6
        (step_length_attr(20.0), steps_attr(5), 5),             # 'profil steps' wins over both
        ("", steps_attr(2.9), 2),                               # cut to an integer, as C does
        ("", steps_attr(1) + step_length_attr(30.0), 3),        # 1 step: use the step length
        (step_length_attr(20.0), '<attstr name="profil" val="linear"/>', 1),  # not a spline
    ],
)
def test_step_count_from_profil_steps_and_the_segment_or_global_step_length(
        tmp_path, main_extra, seg_extra, steps):
    segs = turn("t1", "lft", 60.0, 90.0, end_radius=40.0, extra=seg_extra)
    spec = read_torcs_spec(write(tmp_path, "n.xml", torcs_xml(segs, extra=main_extra)))
    (seg,) = spec.segments
    pieces = build_lanes(spec)
    if steps == 1:
        # TORCS keeps the start radius over the declared length, 78.54 m: that turns
        # 78.54 / 60 rad = 90 * (60 + 40) / (2 * 60) = 75 deg, not 90.
        assert seg.steps is None and seg.end_radius_m is None and seg.radius_m == 60.0
        assert seg.angle_deg == pytest.approx(75.0, abs=1e-12)
        assert len(pieces) == 1
        assert seg.arc_length_m == pytest.approx(50.0 * math.pi / 2, abs=1e-12)
        return
    assert seg.steps == steps and len(pieces) == steps
    sub = (math.pi / 2) / _sum_inverse_radii(60.0, 40.0, steps)
    assert seg.arc_length_m == pytest.approx(steps * sub, abs=1e-9)
    assert [p.length_m for p in pieces] == pytest.approx([sub] * steps, abs=1e-9)
    assert 1.0 / pieces[0].curvature_1pm == pytest.approx(60.0)
    assert 1.0 / pieces[-1].curvature_1pm == pytest.approx(40.0)
    assert end_of(pieces)[2] == pytest.approx(math.pi / 2, abs=1e-12)
    if steps == 4:  # radii 60, 53.33, 46.67, 40: sum 1/r = 0.0818452, L = 19.19228 m
        assert seg.arc_length_m == pytest.approx(76.76910, abs=1e-5)


def test_stepped_spiral_stadium_closes_and_is_as_long_as_torcs_says(tmp_path):
    """Each half-turn eases in from 60 m to 40 m and out again, 3 sub-segments per spiral."""
    half = (turn("in", "lft", 60.0, 90.0, end_radius=40.0)
            + turn("out", "lft", 40.0, 90.0, end_radius=60.0))
    segs = straight("s1", 250.0) + half + straight("s2", 250.0) + half
    # Global step length 30 m: int(78.54 / 30) + 1 = 3 sub-segments for every spiral.
    xml = torcs_xml(segs, extra=step_length_attr(30.0))
    track = load_torcs_track(write(tmp_path, "spiral.xml", xml))
    # TORCS' lap length: the sum of sub-segment lengths, 4 x 3 L (not 4 x 78.54 m declared).
    assert track.length_m == pytest.approx(500.0 + 4 * 3 * SUB_LENGTH, abs=1e-9)  # 805.668 m
    assert track.closure_error_m < 1e-9
    assert track.min_radius_m == pytest.approx(40.0, abs=1e-9)
    spiral = track.segments[1]
    assert (spiral["radius_m"], spiral["end_radius_m"], spiral["steps"]) == (60.0, 40.0, 3)
    assert spiral["arc_length_m"] == pytest.approx(3 * SUB_LENGTH, abs=1e-9)
    start = spiral["s_start_m"]
    for k, radius in enumerate((60.0, 50.0, 40.0)):  # curvature is 1/r_i on sub-arc i
        mid = start + (k + 0.5) * SUB_LENGTH
        i = int(np.argmin(np.abs(track.s_m - mid)))
        assert track.curvature_1pm[i] == pytest.approx(1.0 / radius, abs=1e-12)
    # Without a step length TORCS makes each spiral one arc of its start radius (75 and
    # 112.5 deg): the lap turns 375 deg and TORCS' own geometry misses the start; so do we.
    with pytest.raises(UserInputError, match=r"spiral.xml: track does not close"):
        load_torcs_track(write(tmp_path, "spiral.xml", torcs_xml(segs)))


def test_track_that_closes_only_with_torcs_sub_segments(tmp_path):
    """A lap that closes with TORCS' stepped spiral and misses by 2.4 m with an ideal one.

    Spiral (60 -> 40 m, 90 deg left, 3 steps) to SPIRAL_END heading north, straight a north,
    180 deg left arc R, straight b south, 90 deg left arc R2, straight c east back to the start:
    closure needs b = y_end + a - R2 and c = 2 R - R2 - x_end.
    """
    a, big, small = 100.0, 60.0, 30.0
    b = SPIRAL_END[1] + a - small
    c = 2 * big - small - SPIRAL_END[0]
    segs = (turn("spiral", "lft", 60.0, 90.0, end_radius=40.0, extra=steps_attr(3))
            + straight("a", a) + turn("u", "lft", big, 180.0) + straight("b", b)
            + turn("q", "lft", small, 90.0) + straight("c", c))
    path = write(tmp_path, "asym.xml", torcs_xml(segs))
    track = load_torcs_track(path)
    assert track.closure_error_m < 1e-9
    expected = 3 * SUB_LENGTH + a + math.pi * big + b + math.pi / 2 * small + c
    assert track.length_m == pytest.approx(expected, abs=1e-9)
    # The same lap with our ideal spiral (radius linear in angle) misses by 2.4 m.
    spec = read_torcs_spec(path)
    ideal = TrackSpec(spec.name, spec.width_left_m, spec.width_right_m,
                      [SegmentSpec("arc", radius_m=60.0, angle_deg=90.0, end_radius_m=40.0)]
                      + spec.segments[1:])
    with pytest.raises(UserInputError, match=r"does not close: its end is 2\.4\d m"):
        build_track(ideal, "ideal")


def test_stepped_spiral_round_trips_through_toml_and_steps_are_checked(tmp_path):
    half = (turn("in", "lft", 60.0, 90.0, end_radius=40.0, extra=steps_attr(3))
            + turn("out", "lft", 40.0, 90.0, end_radius=60.0, extra=steps_attr(3)))
    path = write(tmp_path, "rt.xml", torcs_xml(straight("s1", 250.0) + half
                                               + straight("s2", 250.0) + half))
    written = import_torcs_track(path, "stepped")
    text = written.read_text()
    assert "steps = 3\n" in text
    assert load_track("stepped").length_m == pytest.approx(load_torcs_track(path).length_m,
                                                           abs=1e-9)
    spec = read_torcs_spec(path)
    assert parse_spec(spec_to_toml(spec), "x.toml").segments == spec.segments
    base = 'width_m = 12.0\n[[segment]]\ntype = "arc"\nradius_m = 60.0\nangle_deg = 90.0\n'
    for extra, match in [
        ("end_radius_m = 40.0\nsteps = 3.0\n", r"'steps' must be an integer, got 3\.0"),
        ("end_radius_m = 40.0\nsteps = 1\n", r"'steps' = 1 is outside \[2, 100000\]"),
        ("steps = 3\n", r"'steps' needs 'end_radius_m'"),
    ]:
        with pytest.raises(UserInputError, match=match):
            parse_spec(base + extra, "bad.toml")


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        (steps_attr(0), r"'profil steps' = 0 cuts the segment into 0 pieces; TORCS would drop"),
        (step_length_attr(-30.0), r"'profil steps length' = -30 m over 78.5398 m cuts the "
                                  r"segment into -1 pieces"),
        (step_length_attr(1e-4), r"'profil steps length' = 0.0001 m over 78.5398 m cuts the "
                                 r"spiral into 785399 arcs; at most 100000 are accepted"),
        (step_length_attr(1e-300), r"'profil steps length' = 1e-300 m .* cuts the spiral into "
                                   r"7.85398e\+301 arcs"),
    ],
)
def test_sub_segment_counts_that_vanish_or_explode_are_refused(tmp_path, extra, match):
    segs = turn("t1", "lft", 60.0, 90.0, end_radius=40.0, extra=extra)
    with pytest.raises(UserInputError, match=r"segment 1 \('t1'\): " + match):
        read_torcs_spec(write(tmp_path, "bad.xml", torcs_xml(segs)))
    # A straight: the count does not change its shape, but a vanishing one is still refused.
    if "drop" in match:
        with pytest.raises(UserInputError, match="TORCS would drop it"):
            read_torcs_spec(write(tmp_path, "bad.xml", torcs_xml(
                '<section name="s"><attstr name="type" val="str"/>'
                f'<attnum name="lg" val="100"/>{extra}</section>')))


def test_import_writes_toml_that_loads_and_lists(tmp_path):
    path = write(tmp_path, "e-stadium.xml", torcs_xml(stadium_segments()))
    written = import_torcs_track(path, "my-stadium")
    assert written == user_tracks_dir() / "my-stadium.toml"
    assert "[[segment]]" in written.read_text()
    track = load_track("my-stadium")
    assert track.length_m == pytest.approx(load_torcs_track(path).length_m, abs=1e-9)
    assert "my-stadium" in [row["name"] for row in list_tracks()]
    with pytest.raises(UserInputError, match="already exists"):
        import_torcs_track(path, "my-stadium")
    import_torcs_track(path, "my-stadium", overwrite=True)
    with pytest.raises(UserInputError, match="reserved"):
        import_torcs_track(path, "oval")


BOMB = """<?xml version="1.0"?>
<!DOCTYPE params [
 <!ENTITY lol "lol">
 <!ENTITY lol1 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
 <!ENTITY lol2 "&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;">
]>
<params name="x"><attstr name="bomb" val="&lol2;"/></params>
"""


def test_entity_bomb_is_refused_and_nothing_written(tmp_path):
    path = write(tmp_path, "bomb.xml", BOMB)
    with pytest.raises(UserInputError, match=r"bomb.xml, line 3: internal entity definition "
                                             r"'lol' is refused"):
        import_torcs_track(path)
    assert not user_tracks_dir().exists() or not any(user_tracks_dir().iterdir())


def test_parameter_entities_and_stray_declarations_are_refused(tmp_path):
    param = DOCTYPE.replace("]>", '<!ENTITY % remote SYSTEM "http://example.com/x.dtd">\n%remote;\n]>')
    with pytest.raises(UserInputError, match="parameter entity"):
        read_torcs_spec(write(tmp_path, "param.xml", torcs_xml(stadium_segments(), head=param)))
    stray = '<!ENTITY x "y">\n<params name="x"/>'
    with pytest.raises(UserInputError, match="entity declaration outside a DOCTYPE"):
        read_torcs_spec(write(tmp_path, "stray.xml", stray))


def test_external_entities_are_never_read(tmp_path):
    """An entity pointing at a real local file: its content must not reach the track."""
    (tmp_path / "secret.txt").write_text("999", encoding="utf-8")
    head = DOCTYPE.replace("]>", '<!ENTITY secret SYSTEM "secret.txt">\n]>')
    xml = torcs_xml(stadium_segments(), head=head,
                    width='<attnum name="width" unit="m" val="&secret;12"/>')
    track = load_torcs_track(write(tmp_path, "xxe.xml", xml))
    assert np.all(track.width_m == 12.0)


def test_torcs_track_that_does_not_close_is_refused(tmp_path):
    segs = stadium_segments().replace('val="656.168"', 'val="660.0"', 1)  # 1.17 m short
    with pytest.raises(UserInputError, match=r"open.xml: track does not close: its end is 1.17 m"
                                             r".*TORCS links its last segment to the first"):
        import_torcs_track(write(tmp_path, "open.xml", torcs_xml(segs)))
    assert not user_tracks_dir().exists()


@pytest.mark.parametrize(
    ("segments", "width", "match"),
    [
        ("<section name='s'><attstr name='type' val='str'/>", None, r"bad.xml: malformed XML"),
        (straight("s", 100, "parsec"), None, r"segment 1 \('s'\): 'lg' has unit 'parsec'"),
        ("<section name='s'><attstr name='type' val='curve'/></section>", None,
         r"segment 1 \('s'\): 'type' must be str, lft or rgt, got 'curve'"),
        (turn("t", "lft", 5.0, 360.0), None, r"radius 5 m is not larger than the half-width 6"),
        (straight("s", 100), '<attnum name="width" val="abc"/>', r"'width' must be a finite"),
        ("", None, r"Track Segments is empty"),
    ],
)
def test_malformed_torcs_files_name_the_file_and_problem(tmp_path, segments, width, match):
    xml = torcs_xml(segments) if width is None else torcs_xml(segments, width=width)
    with pytest.raises(UserInputError, match=match):
        read_torcs_spec(write(tmp_path, "bad.xml", xml))


def test_a_giant_segment_is_refused_before_any_array_is_built(tmp_path):
    """A 1e9 m straight used to allocate GiBs (1e6 m: 5.6 s and 1 GB) before being refused."""
    # A stadium that closes: only its size is wrong.
    segs = (straight("huge", 1e9) + turn("t1", "lft", 60.0, 180.0) + straight("back", 1e9)
            + turn("t2", "lft", 60.0, 180.0))
    path = write(tmp_path, "huge.xml", torcs_xml(segs))
    match = rf"{tmp_path / 'huge.xml'}: segment 1 \('huge'\): 1e\+09 m long; a whole track " \
            r"may be at most 100 km"
    with pytest.raises(UserInputError, match=match):
        read_torcs_spec(path)
    with pytest.raises(UserInputError, match=match):
        load_torcs_track(path)
    with pytest.raises(UserInputError, match=match):
        import_torcs_track(path)
    assert not user_tracks_dir().exists()


def test_a_track_over_100_km_in_total_is_refused_at_the_segment_that_passes_it(tmp_path):
    side = [straight(f"s{k}", 9000.0) for k in range(12)]  # 2 x 54 km: a closed stadium
    segs = ("".join(side[:6]) + turn("t1", "lft", 60.0, 180.0) + "".join(side[6:])
            + turn("t2", "lft", 60.0, 180.0))
    with pytest.raises(UserInputError, match=r"long.xml: segment 13 \('s11'\): the track is "
                                             r"108.2 km long by the end of this segment; tracks "
                                             r"longer than 100 km are refused"):
        load_torcs_track(write(tmp_path, "long.xml", torcs_xml(segs)))
    # A huge radius makes a huge arc: refused on its length too.
    arc = straight("s", 100.0) + turn("wide", "lft", 1e7, 360.0)
    with pytest.raises(UserInputError, match=r"segment 2 \('wide'\): 6.283e\+07 m long"):
        read_torcs_spec(write(tmp_path, "wide.xml", torcs_xml(arc)))

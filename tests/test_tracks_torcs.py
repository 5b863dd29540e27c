"""TORCS track XML import: real-file DOCTYPEs with external entities, units, spirals, closure,
and refusal of entity bombs and external-entity tricks (XML files written here, TORCS-style)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from formula_tourney.errors import UserInputError
from formula_tourney.sim.catalog import list_tracks, load_track, user_tracks_dir
from formula_tourney.sim.torcs import import_torcs_track, load_torcs_track, read_torcs_spec

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
         end_radius: float | None = None, radius_unit: str = "m") -> str:
    unit = f' unit="{arc_unit}"' if arc_unit else ""
    end = ("" if end_radius is None else
           f'<attnum name="end radius" unit="{radius_unit}" val="{end_radius!r}"/>')
    return (f'<section name="{name}"><attstr name="type" val="{side}"/>'
            f'<attnum name="radius" unit="{radius_unit}" val="{radius!r}"/>{end}'
            f'<attnum name="arc"{unit} val="{arc!r}"/></section>\n')


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


def test_spiral_end_radius(tmp_path):
    """Each half-turn eases in from 60 m to 40 m and out again: a symmetric, closing stadium."""
    half = (turn("in", "lft", 60.0, 90.0, end_radius=40.0)
            + turn("out", "lft", 40.0, 90.0, end_radius=60.0))
    segs = straight("s1", 250.0) + half + straight("s2", 250.0) + half
    track = load_torcs_track(write(tmp_path, "spiral.xml", torcs_xml(segs)))
    # A spiral's length is arc * (radius + end radius) / 2, as in TORCS' trackgen.
    assert track.length_m == pytest.approx(500.0 + 4 * (math.pi / 2) * 50.0, rel=1e-3)
    assert track.closure_error_m < 0.05
    assert track.min_radius_m == pytest.approx(40.0, rel=0.02)
    spiral = track.segments[1]
    assert spiral["radius_m"] == 60.0 and spiral["end_radius_m"] == 40.0
    inside = (track.s_m > spiral["s_start_m"] + 2) & (
        track.s_m < spiral["s_start_m"] + spiral["arc_length_m"] - 2)
    k = track.curvature_1pm[inside]
    assert np.all(np.diff(k) >= -1e-12)  # curvature grows as the radius shrinks
    assert k[0] == pytest.approx(1 / 60.0, rel=0.03) and k[-1] == pytest.approx(1 / 40.0, rel=0.03)


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
                                             r".*TORCS closes such gaps itself"):
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

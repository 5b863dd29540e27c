"""``formula-tourney tracks ...``: list, show, import, generate; --json; bad input -> exit 2
with a one-line message naming the file, and nothing written."""

from __future__ import annotations

import json
import math

import pytest
from test_tracks_torcs import BOMB, stadium_segments, torcs_xml

from formula_tourney.cli import main


@pytest.fixture(autouse=True)
def data_dir(tmp_path, monkeypatch):
    folder = tmp_path / "data"
    monkeypatch.setenv("FORMULA_TOURNEY_DATA_DIR", str(folder))
    return folder


def run(capsys, *args: str) -> tuple[int, str, str]:
    try:
        main(list(args))
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


def run_json(capsys, *args: str):
    code, out, err = run(capsys, *args, "--json")
    assert code == 0, err
    return json.loads(out)


def test_list_json_shows_built_ins(capsys, data_dir):
    doc = run_json(capsys, "tracks", "list")
    rows = {row["name"]: row for row in doc["tracks"]}
    assert list(rows) == ["oval", "technical", "flowing"]
    assert rows["oval"]["length_m"] == pytest.approx(2372.9, abs=0.1)
    assert rows["technical"]["width_m"] == 10.0
    assert doc["user_tracks_dir"] == str(data_dir / "tracks")


def test_show_json_and_plot(capsys, tmp_path):
    plot = tmp_path / "tech.png"
    doc = run_json(capsys, "tracks", "show", "technical", "--plot", str(plot))
    assert doc["name"] == "technical"
    assert doc["length_m"] == pytest.approx(2527.4, abs=0.1)
    assert doc["width_m"] == 10.0
    assert doc["min_radius_m"] == pytest.approx(12.0)
    assert doc["closure_error_m"] < 0.01
    assert len(doc["segments"]) == 19
    assert sum(s["arc_length_m"] for s in doc["segments"]) == pytest.approx(doc["length_m"],
                                                                           abs=1e-3)
    assert doc["plot"] == str(plot) and plot.read_bytes()[:4] == b"\x89PNG"
    code, out, _ = run(capsys, "tracks", "show", "oval")
    assert code == 0 and "oval" in out and "2.373 km" in out


def test_unknown_track_exit_2(capsys):
    code, out, err = run(capsys, "tracks", "show", "nosuch", "--json")
    assert code == 2 and json.loads(out)["exit_code"] == 2
    assert err.startswith("error: unknown track 'nosuch'; known tracks: oval, technical, flowing")
    assert err.count("\n") == 1


def test_malformed_toml_exit_2_names_file_and_writes_nothing(capsys, tmp_path):
    bad = tmp_path / "broken.toml"
    bad.write_text('width_m = 10\n[[segment]]\ntype = "straight"\nlength_m = \n')
    plot = tmp_path / "broken.png"
    code, out, err = run(capsys, "tracks", "show", str(bad), "--plot", str(plot), "--json")
    assert code == 2 and json.loads(out)["exit_code"] == 2
    assert err.startswith(f"error: {bad}: invalid TOML") and "line 4" in err
    assert not plot.exists()
    wrong_key = tmp_path / "wrong.toml"
    wrong_key.write_text('width_m = 10\n[[segment]]\ntype = "straight"\nlenght_m = 5\n')
    code, _, err = run(capsys, "tracks", "show", str(wrong_key))
    assert code == 2 and f"{wrong_key}, line 4" in err and "'lenght_m'" in err


def test_non_closing_track_exit_2(capsys, tmp_path):
    path = tmp_path / "open.toml"
    path.write_text('width_m = 10\n[[segment]]\ntype = "straight"\nlength_m = 100\n'
                    '[[segment]]\ntype = "arc"\nradius_m = 50\nangle_deg = 360\n')
    code, _, err = run(capsys, "tracks", "show", str(path))
    assert code == 2
    assert f"{path}: track does not close: its end is 100.00 m from the start" in err


def test_import_then_list_and_show(capsys, tmp_path, data_dir):
    xml = tmp_path / "e-stadium.xml"
    xml.write_text(torcs_xml(stadium_segments()))
    doc = run_json(capsys, "tracks", "import", str(xml))
    assert doc["name"] == "e-stadium"
    assert doc["saved"] == str(data_dir / "tracks" / "e-stadium.toml")
    assert doc["length_m"] == pytest.approx(400.0 + 2 * math.pi * 60.0, abs=1e-3)
    names = [row["name"] for row in run_json(capsys, "tracks", "list")["tracks"]]
    assert names == ["oval", "technical", "flowing", "e-stadium"]
    shown = run_json(capsys, "tracks", "show", "e-stadium")
    assert shown["length_m"] == doc["length_m"]
    # Named import; a second import under a taken name is refused.
    assert run_json(capsys, "tracks", "import", str(xml), "--name", "s2")["name"] == "s2"
    code, _, err = run(capsys, "tracks", "import", str(xml), "--name", "s2")
    assert code == 2 and "already exists" in err
    code, _, err = run(capsys, "tracks", "import", str(xml), "--name", "../evil")
    assert code == 2 and "invalid track name" in err


def test_import_entity_bomb_exit_2_nothing_written(capsys, tmp_path, data_dir):
    bomb = tmp_path / "bomb.xml"
    bomb.write_text(BOMB)
    code, out, err = run(capsys, "tracks", "import", str(bomb), "--json")
    assert code == 2 and json.loads(out)["exit_code"] == 2
    assert f"error: {bomb}, line 3: internal entity definition 'lol' is refused" in err
    assert not (data_dir / "tracks").exists()


def test_generate_deterministic_save_and_plot(capsys, tmp_path, data_dir):
    a = run_json(capsys, "tracks", "generate", "--seed", "7")
    b = run_json(capsys, "tracks", "generate", "--seed", "7")
    assert a == b
    assert a["name"] == "gen-7" and 1500 <= a["length_m"] <= 4000
    assert 8 <= a["width_m"] <= 14 and a["min_radius_m"] >= 12
    assert a["closure_error_m"] < 1e-6
    plot = tmp_path / "g7.svg"
    saved = run_json(capsys, "tracks", "generate", "--seed", "7", "--save", "--plot", str(plot))
    assert saved["saved"] == str(data_dir / "tracks" / "gen-7.toml")
    assert plot.read_text().lstrip().startswith("<?xml")
    rows = {r["name"]: r for r in run_json(capsys, "tracks", "list")["tracks"]}
    assert rows["gen-7"]["length_m"] == pytest.approx(a["length_m"], abs=0.05)
    assert run_json(capsys, "tracks", "show", "gen-7")["length_m"] == a["length_m"]
    code, _, err = run(capsys, "tracks", "generate", "--seed", "7", "--save")
    assert code == 2 and "already exists" in err


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (("tracks", "generate", "--seed", "-1"), "seed must be an integer"),
        (("tracks", "generate", "--seed", "1", "--plot", "x.jpg"), "--plot x.jpg"),
        (("tracks", "generate", "--seed", "1", "--name", "x"), "--name only applies with --save"),
        (("tracks", "generate", "--seed", "1", "--save", "--name", "oval"), "built-in"),
        (("tracks", "import", "track.toml"), "expected a TORCS .xml"),
        (("tracks", "import", "missing.xml"), "missing.xml: track file not found"),
    ],
)
def test_bad_arguments_exit_2(capsys, data_dir, args, match):
    code, out, err = run(capsys, *args)
    assert code == 2 and match in err and out == ""
    assert not (data_dir / "tracks").exists()


@pytest.mark.parametrize("name", ["trk\n", "trk\t1", "t\x00k"])
def test_import_refuses_a_name_with_control_characters(capsys, tmp_path, data_dir, name):
    """``--name $'trk\\n'`` used to pass check_name (``$`` matches before a final newline)."""
    xml = tmp_path / "e-stadium.xml"
    xml.write_text(torcs_xml(stadium_segments()))
    code, out, err = run(capsys, "tracks", "import", str(xml), "--name", name, "--json")
    assert code == 2 and json.loads(out)["exit_code"] == 2 and "invalid track name" in err
    assert not (data_dir / "tracks").exists()


def test_generated_names_are_reserved_and_seeds_bounded(capsys, data_dir):
    # gen-8 would be shadowed by the generated gen-8, so seed 7 cannot be saved under it.
    code, out, err = run(capsys, "tracks", "generate", "--seed", "7", "--save", "--name", "gen-8")
    assert code == 2 and "'gen-8' is reserved for generated tracks" in err
    assert not (data_dir / "tracks").exists()
    code, out, err = run(capsys, "tracks", "show", "gen-99999999999", "--json")
    assert code == 2 and json.loads(out)["exit_code"] == 2
    assert err == ("error: track 'gen-99999999999': seed 99999999999 is out of range; "
                   "gen-<seed> takes a seed in 0..999999999\n")


def test_generate_short_saves_under_its_own_name_and_reserves_it(capsys, data_dir):
    short = run_json(capsys, "tracks", "generate", "--seed", "7", "--short", "--save")
    assert short["name"] == "gen-short-7" and 800 <= short["length_m"] <= 1600
    assert short["saved"] == str(data_dir / "tracks" / "gen-short-7.toml")
    assert run_json(capsys, "tracks", "show", "gen-short-7")["length_m"] == short["length_m"]
    # gen-short-8 is generated, so neither kind of seed 7 may be saved under it.
    for args in (("--short",), ()):
        code, _, err = run(capsys, "tracks", "generate", "--seed", "7", *args, "--save",
                           "--name", "gen-short-8")
        assert code == 2 and "'gen-short-8' is reserved for generated tracks" in err
    code, out, err = run(capsys, "tracks", "show", "gen-short-99999999999", "--json")
    assert code == 2 and err == ("error: track 'gen-short-99999999999': seed 99999999999 is out "
                                 "of range; gen-short-<seed> takes a seed in 0..999999999\n")


HILLS = (
    '<?xml version="1.0" encoding="UTF-8"?>\n<params name="t" type="param">\n'
    '<section name="Main Track"><attnum name="width" unit="m" val="12"/>\n'
    '<section name="Track Segments">\n'
    '<section name="s1"><attstr name="type" val="str"/><attnum name="lg" unit="m" val="200"/>'
    '<attnum name="z start" unit="m" val="0"/><attnum name="z end" unit="m" val="5"/></section>\n'
    '<section name="t1"><attstr name="type" val="lft"/>'
    '<attnum name="radius" unit="m" val="50"/><attnum name="arc" unit="deg" val="180"/>'
    '<attnum name="grade" unit="%" val="2"/><attnum name="banking start" unit="deg" val="5"/>'
    '<attnum name="banking end" unit="deg" val="5"/></section>\n'
    '<section name="s2"><attstr name="type" val="str"/><attnum name="lg" unit="m" val="200"/>'
    '<attnum name="z end" unit="m" val="2"/></section>\n'
    '<section name="t2"><attstr name="type" val="lft"/>'
    '<attnum name="radius" unit="m" val="50"/><attnum name="arc" unit="deg" val="180"/>'
    '<attnum name="z end" unit="m" val="0"/></section>\n'
    "</section></section></params>\n"
)


def torcs_tree(root):
    """A TORCS-style tree: two good tracks (one flat, one with heights and banking), one bomb."""
    files = {"oval/stadium/stadium.xml": torcs_xml(stadium_segments()),
             "road/hills/hills.xml": HILLS, "road/broken/broken.xml": BOMB}
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True)
        (root / rel).write_text(text, encoding="utf-8")
    return root


def test_import_a_tree_table_json_and_exit_3(capsys, tmp_path, data_dir):
    tree = torcs_tree(tmp_path / "tracks")
    code, out, err = run(capsys, "tracks", "import", str(tree), "--json")
    assert code == 3, err
    doc = json.loads(out)
    assert (doc["imported"], doc["failed"]) == (2, 1)
    rows = {row["name"]: row for row in doc["tracks"]}
    assert list(rows) == ["stadium", "broken", "hills"]  # sorted by path: oval/, road/b, road/h
    assert rows["stadium"]["category"] == "oval" and rows["stadium"]["imported"] is True
    assert rows["stadium"]["length_m"] == pytest.approx(400.0 + 2 * math.pi * 60.0, abs=1e-3)
    assert rows["stadium"]["z_range_m"] == 0.0 and rows["stadium"]["max_banking_deg"] == 0.0
    hills = rows["hills"]
    assert hills["category"] == "road" and hills["imported"] is True
    assert hills["z_range_m"] == pytest.approx(5.0 + 0.02 * 50 * math.pi, abs=1e-3)
    assert hills["max_banking_deg"] == pytest.approx(5.0)
    assert hills["saved"] == str(data_dir / "tracks" / "hills.toml")
    broken = rows["broken"]
    assert broken["imported"] is False and broken["saved"] is None
    assert broken["reason"].startswith("line 3: internal entity definition 'lol' is refused")
    assert sorted(p.name for p in (data_dir / "tracks").iterdir()) == ["hills.toml",
                                                                       "stadium.toml"]
    names = [row["name"] for row in run_json(capsys, "tracks", "list")["tracks"]]
    assert names[3:] == ["hills", "stadium"]
    # Again: the taken names are per-file failures in the table, not a crash; --force replaces.
    code, out, err = run(capsys, "tracks", "import", str(tree))
    assert code == 3 and "imported 0 of 3 track file(s)" in err and "3 failed" in err
    assert out.count("already exists") == 2 and "Traceback" not in err
    assert "stadium" in out and "8.14" in out and "5.0" in out
    code, out, err = run(capsys, "tracks", "import", str(tree), "--force", "--json")
    assert code == 3 and json.loads(out)["imported"] == 2
    (tree / "road" / "broken" / "broken.xml").unlink()
    code, out, err = run(capsys, "tracks", "import", str(tree), "--force")
    assert code == 0 and "imported 2 of 2" in err


def test_import_a_tree_with_two_files_of_one_name(capsys, tmp_path, data_dir):
    for cat in ("oval", "road"):
        (tmp_path / cat / "same").mkdir(parents=True)
        (tmp_path / cat / "same" / "same.xml").write_text(torcs_xml(stadium_segments()))
    code, out, _ = run(capsys, "tracks", "import", str(tmp_path), "--force", "--json")
    rows = json.loads(out)["tracks"]
    assert code == 3 and [r["imported"] for r in rows] == [True, False]
    assert "'same' is already used by" in rows[1]["reason"]


def test_import_bad_folders_exit_2(capsys, tmp_path, data_dir):
    empty = tmp_path / "empty"
    (empty / "road").mkdir(parents=True)
    code, out, err = run(capsys, "tracks", "import", str(empty), "--json")
    assert code == 2 and json.loads(out)["exit_code"] == 2 and err.count("\n") == 1
    assert err == f"error: {empty}: no .xml track files in this folder or below it\n"
    code, _, err = run(capsys, "tracks", "import", str(tmp_path / "nothere"))
    assert code == 2 and "no such file or folder" in err
    text = tmp_path / "notes.txt"
    text.write_text("x")
    code, _, err = run(capsys, "tracks", "import", str(text))
    assert code == 2 and "not a folder" in err
    code, _, err = run(capsys, "tracks", "import", str(empty), "--name", "x")
    assert code == 2 and "--name applies to one .xml file" in err
    assert not (data_dir / "tracks").exists()
    code, out, _ = run(capsys, "tracks", "import", "--help")
    assert code == 0 and "3 a folder import" in out


TOURNEY = """\
name = "real-tracks"

[[parts]]
name = "p1"
entrants = ["WIN1"]
train_tracks = [{train}]
test_tracks = ["stadium"]
"""


def test_a_tournament_names_xml_files_and_imported_tracks(capsys, tmp_path, data_dir):
    """A TORCS XML by relative path (against the tournament file) and an imported track by
    name plan as they are; a missing XML is an error at its line, exit 2, nothing written."""
    xml = tmp_path / "tt" / "stadium.xml"
    xml.parent.mkdir()
    xml.write_text(torcs_xml(stadium_segments()))
    assert run_json(capsys, "tracks", "import", str(xml))["name"] == "stadium"
    (tmp_path / "tt" / "hills.xml").write_text(HILLS)
    path = tmp_path / "tt" / "real.toml"
    path.write_text(TOURNEY.format(train='"hills.xml", "oval"'))
    results = tmp_path / "res"
    doc = run_json(capsys, "run", str(path), "--dry-run", "--results", str(results))
    part = doc["plan"]["parts"][0]
    assert part["train_tracks"] == ["hills.xml", "oval"] and part["test_tracks"] == ["stadium"]
    assert doc["dry_run"] is True and doc["plan"]["known_jobs"] == 1
    path.write_text(TOURNEY.format(train='"oval", "missing.xml"'))
    code, out, err = run(capsys, "run", str(path), "--dry-run", "--json", "--results",
                         str(results))
    assert code == 2 and json.loads(out)["exit_code"] == 2 and err.count("\n") == 1
    assert err == (f"error: {path}:6: parts[0].train_tracks: {xml.parent / 'missing.xml'}: "
                   "track file not found\n")
    assert not results.exists()

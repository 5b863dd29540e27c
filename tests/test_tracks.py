"""Tracks: the built-in tracks' numbers, segment geometry, projection at the wrap, the
procedural generator (closed, non-overlapping, bounded, deterministic) and the track plot."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from formula_tourney.errors import UserInputError
from formula_tourney.sim.catalog import check_track_name, load_track
from formula_tourney.sim.generate import (
    MAX_SEED,
    generate_spec,
    generate_track,
    tight_corner_share,
)
from formula_tourney.sim.plot import plot_tracks
from formula_tourney.sim.segments import (
    SegmentSpec,
    TrackSpec,
    build_track,
    find_overlap,
    parse_spec,
    spec_to_toml,
)


@pytest.fixture(autouse=True)
def _private_data_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("FORMULA_TOURNEY_DATA_DIR", str(tmp_path / "data"))


@pytest.mark.parametrize(
    ("name", "length_m", "width_m"),
    [("oval", 2372.9, 18.0), ("technical", 2527.4, 10.0), ("flowing", 5652.2, 11.0)],
)
def test_built_in_track_numbers(name, length_m, width_m):
    track = load_track(name)
    assert track.length_m == pytest.approx(length_m, abs=0.5)
    assert np.all(track.width_m == width_m)
    assert track.closure_error_m < 0.01
    assert find_overlap(track) is None
    # ~1 m sample spacing, uniform, start line at s = 0.
    assert track.s_m[0] == 0.0
    assert np.allclose(np.diff(track.s_m), track.length_m / track.n)
    assert abs(track.length_m / track.n - 1.0) < 0.01


def test_built_in_characters():
    """Oval: wide and fast (radii >= 120 m); technical: hairpins <= 15 m; flowing: long."""
    assert load_track("oval").min_radius_m >= 120.0
    assert load_track("technical").min_radius_m <= 15.0
    assert load_track("technical").min_radius_m >= 12.0
    assert load_track("flowing").length_m > 2 * load_track("oval").length_m


@pytest.mark.parametrize("name", ["oval", "technical", "flowing"])
def test_arcs_have_curvature_one_over_r_and_straights_zero(name):
    track = load_track(name)
    checked = 0
    for seg in track.segments:
        start, length = seg["s_start_m"], seg["arc_length_m"]
        inside = (track.s_m > start + 1.5) & (track.s_m < start + length - 1.5)
        if not inside.any() or "end_radius_m" in seg:
            continue
        if seg["type"] == "straight":
            expected = 0.0
        else:
            expected = math.copysign(1.0 / seg["radius_m"], seg["angle_deg"])
        assert np.allclose(track.curvature_1pm[inside], expected, rtol=1e-9, atol=1e-12)
        checked += 1
    assert checked >= 5
    # Heading follows curvature: d(heading)/ds on an arc equals 1/R (finite difference).
    dh = np.angle(np.exp(1j * np.diff(track.heading_rad)))
    ds = np.diff(track.s_m)
    interior = track.curvature_1pm[:-1] == track.curvature_1pm[1:]
    assert np.allclose((dh / ds)[interior], track.curvature_1pm[:-1][interior], atol=2e-3)


def test_project_near_the_wrap():
    """Points just before and just after the start line, with a hint on the other side."""
    track = load_track("oval")
    step = track.length_m / track.n
    for s_true in (track.length_m - 0.5 * step, track.length_m - 0.3, 0.2, 1e-3):
        for lateral in (3.0, -4.5):
            x, y, _ = track.pose_at(s_true, lateral)
            for hint in (0, track.n - 1, -1):
                s, lat, i = track.project(float(x), float(y), hint_index=hint)
                gap = (s - s_true + track.length_m / 2) % track.length_m - track.length_m / 2
                # Off the centreline next to the 250 m arc that ends the lap, the polyline's
                # chords and the interpolated heading disagree by ~lateral * dheading ~ 6 mm.
                assert abs(gap) < 1e-2, (s_true, hint, s)
                assert 0.0 <= s < track.length_m
                assert lat == pytest.approx(lateral, abs=1e-3)
                assert i in (track.n - 1, 0)


def test_segment_track_that_does_not_close_is_refused():
    text = 'width_m = 10\n[[segment]]\ntype = "straight"\nlength_m = 100\n' \
           '[[segment]]\ntype = "arc"\nradius_m = 50\nangle_deg = 360\n'
    spec = parse_spec(text, "open.toml")
    with pytest.raises(UserInputError, match=r"open.toml: track does not close: its end is "
                                             r"100.00 m from the start"):
        build_track(spec, "open.toml")


def test_self_overlapping_track_is_refused():
    """A hairpin stadium: closes, but its 14 m wide straights are 15 m apart centre to centre."""
    text = "width_m = 14\n" + 2 * (
        '[[segment]]\ntype = "straight"\nlength_m = 200\n'
        '[[segment]]\ntype = "arc"\nradius_m = 7.5\nangle_deg = 180\n'
    )
    with pytest.raises(UserInputError, match=r"hairpin.toml: track overlaps itself: .* 15.0 m "
                                             r"apart"):
        build_track(parse_spec(text, "hairpin.toml"), "hairpin.toml")


SEEDS = range(20)


def test_generated_tracks_are_valid_for_20_seeds():
    times = []
    for seed in SEEDS:
        t0 = time.perf_counter()
        track = generate_track(seed)
        times.append(time.perf_counter() - t0)
        assert track.name == f"gen-{seed}"
        assert 1500.0 <= track.length_m <= 4000.0
        assert np.all((track.width_m >= 8.0) & (track.width_m <= 14.0))
        assert track.min_radius_m >= 12.0 - 1e-9
        assert track.closure_error_m < 1e-6
        assert find_overlap(track) is None
        turned = sum(s["angle_deg"] for s in track.segments if s["type"] == "arc")
        assert abs(abs(turned) - 360.0) < 1e-6
    assert float(np.median(times[1:])) < 0.5, times  # the first one pays highway-env's import


def test_generated_tracks_are_deterministic_and_differ_by_seed():
    lengths = set()
    for seed in SEEDS:
        a, b = generate_track(seed), generate_track(seed)
        assert a.length_m == b.length_m
        assert np.array_equal(a.x_m, b.x_m) and np.array_equal(a.y_m, b.y_m)
        assert a.segments == b.segments
        lengths.add(round(a.length_m, 3))
    assert len(lengths) == len(SEEDS)
    # Both directions and both hands of corner appear over 20 seeds.
    signs = {np.sign(sum(s["angle_deg"] for s in generate_track(k).segments if "angle_deg" in s))
             for k in SEEDS}
    assert signs == {-1.0, 1.0}


def test_generated_track_loads_by_name_and_round_trips_through_toml():
    spec, track = generate_spec(5)
    assert load_track("gen-5").length_m == track.length_m
    again = build_track(parse_spec(spec_to_toml(spec), "gen-5.toml"), "gen-5.toml")
    assert again.length_m == track.length_m
    assert np.allclose(again.x_m, track.x_m, atol=1e-9)


def test_short_generated_tracks_are_short_valid_and_tighter():
    shares = {"gen": [], "gen-short": []}
    for seed in SEEDS:
        short = load_track(f"gen-short-{seed}")
        assert short.name == f"gen-short-{seed}"
        assert 800.0 <= short.length_m <= 1600.0
        assert short.min_radius_m >= 12.0 - 1e-9 and short.closure_error_m < 1e-6
        assert find_overlap(short) is None
        assert short.length_m == generate_track(seed, min_length_m=800.0,
                                                max_length_m=1600.0).length_m
        shares["gen-short"].append(tight_corner_share(short))
        shares["gen"].append(tight_corner_share(load_track(f"gen-{seed}")))
    # What the kind is for: tight corners take a technical-like share of the lap (technical:
    # 0.083), where a gen track's is a third of that.
    assert float(np.median(shares["gen-short"])) > 0.07 > 0.035 > float(np.median(shares["gen"]))
    assert tight_corner_share(load_track("technical")) == pytest.approx(0.083, abs=0.002)


def test_generator_bounds_are_respected_and_checked():
    track = generate_track(3, min_length_m=5000.0, max_length_m=6000.0, min_width_m=12.0,
                           max_width_m=12.0, min_radius_m=30.0)
    assert 5000.0 <= track.length_m <= 6000.0
    assert np.all(track.width_m == 12.0)
    assert track.min_radius_m >= 30.0
    with pytest.raises(UserInputError, match="seed must be an integer"):
        generate_track(-1)
    with pytest.raises(UserInputError, match="min length < max length"):
        generate_track(1, min_length_m=3000.0, max_length_m=2000.0)
    with pytest.raises(UserInputError, match="min radius"):
        generate_track(1, min_radius_m=5.0)


def test_plot_writes_png_and_refuses_other_types(tmp_path):
    out = plot_tracks([load_track("oval"), generate_track(1)], tmp_path / "maps.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert out.stat().st_size > 20_000
    with pytest.raises(UserInputError, match="maps.jpg"):
        plot_tracks(load_track("oval"), tmp_path / "maps.jpg")
    assert not (tmp_path / "maps.jpg").exists()


def test_segment_tracks_over_100_km_are_refused_before_sampling():
    huge_arc = ('width_m = 10\n[[segment]]\ntype = "straight"\nlength_m = 100\n'
                '[[segment]]\ntype = "arc"\nradius_m = 900000\nangle_deg = 360\n')
    with pytest.raises(UserInputError, match=r"big.toml, line 6: segment 2: 5.655e\+06 m long; "
                                             r"a whole track may be at most 100 km"):
        parse_spec(huge_arc, "big.toml")
    many = "width_m = 10\n" + 11 * '[[segment]]\ntype = "straight"\nlength_m = 10000\n'
    with pytest.raises(UserInputError, match=r"many.toml, line 33: segment 11: the track is "
                                             r"110.0 km long"):
        parse_spec(many, "many.toml")
    # Specs that never were TOML (generator, TORCS, code) meet the same limit in build_track.
    spec = TrackSpec("big", 5.0, 5.0, [SegmentSpec("straight", length_m=2e5, name="long one")])
    with pytest.raises(UserInputError, match=r"code: segment 1 \('long one'\): 2e\+05 m long"):
        build_track(spec, "code")


STADIUM_TOML = ('width_m = 12\n[[segment]]\ntype = "straight"\nlength_m = 200\n'
                '[[segment]]\ntype = "arc"\nradius_m = 60\nangle_deg = 180\n'
                '[[segment]]\ntype = "straight"\nlength_m = 200\n'
                '[[segment]]\ntype = "arc"\nradius_m = 60\nangle_deg = 180\n')


@pytest.fixture()
def track_files(tmp_path, monkeypatch):
    """A user track ``mine``, a spec folder with ``sub/local.toml`` and a stray ``.json``."""
    users = tmp_path / "data" / "tracks"
    users.mkdir(parents=True)
    (users / "mine.toml").write_text(STADIUM_TOML)
    base = tmp_path / "spec"
    (base / "sub").mkdir(parents=True)
    (base / "sub" / "local.toml").write_text(STADIUM_TOML)
    (base / "sub" / "notes.json").write_text("{}")
    monkeypatch.chdir(tmp_path)
    return base


def test_check_track_name_returns_the_canonical_reference(track_files):
    base = track_files
    assert check_track_name("oval") == "oval"
    assert check_track_name("mine") == "mine"
    assert check_track_name("gen-5") == "gen-5"
    assert check_track_name("gen-005") == "gen-5"  # one name per generated track
    assert check_track_name(f"gen-{MAX_SEED}") == f"gen-{MAX_SEED}"  # not generated here
    local = str((base / "sub" / "local.toml").resolve())
    assert check_track_name("sub/local.toml", base) == local
    assert check_track_name(local) == local
    assert check_track_name("spec/sub/local.toml") == local  # no base_dir: the current folder
    assert check_track_name(base / "sub" / "local.toml") == local


@pytest.mark.parametrize(
    ("ref", "match"),
    [
        ("gen-99999999999", r"track 'gen-99999999999': seed 99999999999 is out of range; "
                            r"gen-<seed> takes a seed in 0..999999999"),
        (f"gen-{MAX_SEED + 1}", "out of range"),
        ("nosuch", r"unknown track 'nosuch'; known tracks: oval, technical, flowing, mine; or "
                   r"gen-<seed>"),
        ("gen-", "unknown track 'gen-'"),
        ("mine\n", "unknown track 'mine\\\\n'"),
        ("sub/missing.toml", r"sub/missing.toml: track file not found"),
        ("missing.xml", r"missing.xml: track file not found"),
        ("sub/notes.json", r"sub/notes.json: a track file must end in .toml or .xml"),
        (3, "expected a track name or a .toml/.xml path, got int"),
    ],
)
def test_check_track_name_and_load_track_refuse_the_same_references(track_files, ref, match):
    with pytest.raises(UserInputError, match=match):
        check_track_name(ref, track_files)
    with pytest.raises(UserInputError, match=match):
        load_track(ref, track_files)


@pytest.mark.parametrize("ref", ["oval", "mine", "gen-2", "gen-02", "sub/local.toml"])
def test_what_check_track_name_accepts_load_track_loads(track_files, ref):
    canonical = check_track_name(ref, track_files)
    assert load_track(canonical).length_m == load_track(ref, track_files).length_m
    assert check_track_name(canonical) == canonical  # canonical is a fixed point

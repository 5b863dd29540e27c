"""Tournament files: schema errors name file, line, key and allowed values; nothing is written."""

from __future__ import annotations

from pathlib import Path

import pytest

from formula_tourney.cli import main
from formula_tourney.errors import UserInputError
from formula_tourney.tourney.api import run_tournament
from formula_tourney.tourney.plan import Planner
from formula_tourney.tourney.spec import TomlLocator, entrant_name, load_spec
from formula_tourney.training.run_spec import RunSpec

GOOD = """\
name = "t1"

[defaults]
episodes = 3
seeds = 2

[variants.FAST4]
base = "WIN4"
overrides = { batch_size = 64 }

[[parts]]
name = "p1"
entrants = ["FAST4", "MS2"]
train_tracks = ["oval"]

[[parts]]
name = "p2"
promoted_from = "p1"
train_tracks = ["technical"]
setups = [{ reference = "centre" }, { reference = "recorded", lac = true }]
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "t.toml"
    path.write_text(text, encoding="utf-8")
    return path


def planner(tmp_path: Path, text: str) -> Planner:
    path = write(tmp_path, text)
    spec, text = load_spec(path)
    return Planner(spec, path, text, tmp_path / "results" / spec.name)


def test_good_file_plans_jobs(tmp_path: Path) -> None:
    plans = planner(tmp_path, GOOD)
    assert plans.validate() == 2 + 2 * 2  # p1: 2 entrants; p2: either of them x 2 setups
    plan = plans.plan()
    assert [j.job_id for j in plan[0].jobs] == [
        "p1/FAST4-MOT/seed-0", "p1/FAST4-MOT/seed-1", "p1/MS2-MOT/seed-0", "p1/MS2-MOT/seed-1",
    ]
    fast = plan[0].jobs[0]
    assert fast.spec["variant"] == "WIN4" and fast.spec["agent"]["batch_size"] == 64
    assert fast.spec["schedule"]["episodes"] == 3 and fast.meta["family"] == "DDPG"
    assert fast.config_hash == RunSpec.from_json(fast.spec, "job").digest()
    assert [j.spec["seed"] for j in plan[0].jobs] == [0, 1, 0, 1]
    assert plan[1].variants is None and plan[1].jobs == []
    promoted = plans.jobs(1, ["MS2"])
    assert [j.meta["entrant"] for j in promoted] == ["MS2-MOT"] * 2 + ["MS2-RC-LAC"] * 2
    assert [(j.spec["reference"], j.spec["lac"]) for j in promoted][1:3] == [
        ("centre", False), ("recorded", True)]
    assert plans.describe(plan)["parts"][1]["jobs_per_entrant"] == 4


@pytest.mark.parametrize(
    ("edit", "line", "expected"),
    [
        (("episodes = 3", "episodes = -3"), 4, "defaults.episodes: Input should be greater"),
        (('reference = "recorded"', 'reference = "racing"'), 20,
         "'centre', 'recorded' or 'mincurv'"),
        (('promoted_from = "p1"', 'promoted_from = "p9"'), 18,
         "parts[1].promoted_from: unknown part 'p9'; allowed values (earlier parts): p1"),
        (('entrants = ["FAST4", "MS2"]', 'entrants = ["FAST4", "MS9"]'), 13,
         "unknown variant 'MS9'; allowed values: FAST4, WIN1"),
        (("seeds = 2", "seedz = 2"), 5, "defaults.seedz: unknown key; allowed keys: seeds,"),
        (("batch_size = 64", "batch_size = 0"), 9, "variants.FAST4.overrides: variant WIN4"),
        (('name = "p2"', 'name = "p1"'), 17, "part name 'p1' is already used"),
        (('name = "t1"', 'name = "../t1"'), 1, "name: Value error, invalid tournament name"),
    ],
)
def test_errors_name_file_line_key_and_allowed(
    tmp_path: Path, edit: tuple[str, str], line: int, expected: str
) -> None:
    path = write(tmp_path, GOOD.replace(*edit))
    with pytest.raises(UserInputError) as info:
        run_tournament(path, results_dir=tmp_path / "results")
    text = str(info.value)
    assert f"{path}:{line}: " in text, text
    assert expected in text, text
    assert not (tmp_path / "results").exists()


def test_cli_exit_2_and_nothing_written(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    path = write(tmp_path, GOOD.replace('train_tracks = ["technical"]',
                                        'train_tracks = ["technicall"]'))
    results = tmp_path / "results"
    with pytest.raises(SystemExit) as info:
        main(["run", str(path), "--results", str(results)])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert f"{path}:19: parts[1].train_tracks: unknown track 'technicall'" in err
    assert "known tracks: " in err and "oval" in err and "gen-<seed>" in err
    assert not results.exists()


def test_toml_syntax_error_names_line(tmp_path: Path) -> None:
    with pytest.raises(UserInputError, match=r"t.toml: not valid TOML: .*line 2, column 12"):
        load_spec(write(tmp_path, 'name = "x"\nparts = [1,,]\n'))


def test_locator_counts_array_tables() -> None:
    loc = TomlLocator(GOOD)
    assert loc.line_of(("parts", 1, "train_tracks")) == 19
    assert loc.line_of(("parts", 0, "train_tracks")) == 14
    assert loc.line_of(("variants", "FAST4", "overrides", "batch_size")) == 9
    assert loc.line_of(("parts", 1, "setups", 0, "reference")) == 20


def test_shipped_tournaments_validate() -> None:
    root = Path(__file__).resolve().parents[1] / "tournaments"
    for name in ("quick", "study1", "study2", "replication", "replication-pilot"):
        spec, text = load_spec(root / f"{name}.toml")
        assert spec.name == name
        assert Planner(spec, root / f"{name}.toml", text, Path("unused")).validate() > 0
    spec, _ = load_spec(root / "replication.toml")
    assert spec.adaptive is not None and spec.adaptive.budget_cpu_h == 4  # sequential
    budgets = {p.name: spec.settings(p)["budget_cpu_s"] for p in spec.parts}
    assert [budgets[p] for p in ("r1-oval", "r2-technical-rc", "r3-lac-flowing")] == [150, 200, 200]
    assert {spec.settings(p)["preset"] for p in spec.parts} == {"best"}  # from scratch
    assert all(spec.settings(p)["demos"] is None for p in spec.parts)
    spec, _ = load_spec(root / "study1.toml")
    assert spec.settings(spec.parts[0])["seeds"] == 10
    assert spec.settings(spec.parts[0])["episodes"] == 500
    assert spec.settings(spec.parts[1])["episodes"] == 7000
    assert {s.reference for s in spec.parts[1].setups} == {"centre", "recorded"}


def test_entrant_names() -> None:
    from formula_tourney.tourney.spec import Setup

    assert entrant_name("PER1M", Setup(reference="recorded", lac=True)) == "PER1M-RC-LAC"
    assert entrant_name("WIN4", Setup()) == "WIN4-MOT"


def test_locator_is_built_once_per_text(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Bug 11: a locator was built for every error; the scan is now cached per text."""
    from formula_tourney.tourney import spec as spec_mod

    built = []
    original = spec_mod.TomlLocator.__init__

    def counting(self: TomlLocator, text: str) -> None:
        built.append(len(text))
        original(self, text)

    monkeypatch.setattr(spec_mod.TomlLocator, "__init__", counting)
    spec_mod.locator_for.cache_clear()
    text = GOOD + "\n" * 3
    path = tmp_path / "t.toml"
    first = spec_mod.error_at(path, text, ("parts", 1, "train_tracks"), "one")
    second = spec_mod.error_at(path, text, ("defaults", "seeds"), "two")
    assert str(first).startswith(f"{path}:19: ") and str(second).startswith(f"{path}:5: ")
    with pytest.raises(UserInputError):
        load_spec(write(tmp_path, text.replace("seeds = 2", "seeds = 0")))
    assert built == [len(text), len(text.replace("seeds = 2", "seeds = 0"))]


def test_large_valid_file_dry_runs(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Bug 11: a 100 KB file took 56 s to dry-run (a backtracking key pattern was cubic in a
    line's leading spaces). 200 KB of indented description text now plans like a small file."""
    body = "\n".join(" " * 2000 + f"line {i} of a long description" for i in range(100))
    text = GOOD.replace('name = "t1"\n', f'name = "t1"\ndescription = """\n{body}\n"""\n')
    path = write(tmp_path, text)
    assert path.stat().st_size > 200_000
    main(["run", str(path), "--dry-run", "--json", "--results", str(tmp_path / "results")])
    out = capsys.readouterr().out
    assert '"known_jobs": 4' in out
    assert TomlLocator(text).line_of(("parts", 1, "train_tracks")) == 19 + 102


def test_oversized_file_is_refused_before_reading(tmp_path: Path) -> None:
    path = write(tmp_path, GOOD + "#" * (2 * 1024 * 1024) + "\n")
    with pytest.raises(UserInputError, match=rf"{path}: the tournament file is 2\.0 MiB; at "
                       r"most 1024 KiB is read"):
        load_spec(path)
    with pytest.raises(SystemExit) as info:
        main(["run", str(path), "--dry-run", "--results", str(tmp_path / "results")])
    assert info.value.code == 2


def test_a_former_preset_name_is_an_error_at_its_part_naming_the_replacement(
        tmp_path: Path) -> None:
    text = GOOD.replace('name = "p2"\n', 'name = "p2"\npreset = "tuned-progress"\n')
    with pytest.raises(UserInputError, match=r"t\.toml:18: parts\[1\]\.preset: .*preset "
                                             r"'tuned-progress' is now 'best'"):
        planner(tmp_path, text).validate()

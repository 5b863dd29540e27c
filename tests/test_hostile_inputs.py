"""Hostile input a new user may give: every case ends in one line naming the file or key, exit
code 2 and nothing written, before the first job starts; text from user files is printed as
text, never read as rich markup or terminal escape codes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from tourney_fixtures import TINY

from formula_tourney.cli import main


def cli(capsys: pytest.CaptureFixture, *args: str) -> tuple[int, str, str]:
    """Run the command line in this process: (exit code, stdout, stderr)."""
    try:
        main(list(args))
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


def one_line_error(code: int, err: str, *words: str) -> str:
    """The error line, after checking it is exit 2, one line, and names every word."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    for word in words:
        assert word in lines[0], (word, err)
    return lines[0]


def tournament(folder: Path, text: str, name: str = "t.toml") -> Path:
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


def tiny(folder: Path, entrants: str = '["WIN1"]', more: str = "") -> Path:
    return tournament(folder, TINY.format(entrants=entrants, p2=more))


def dry_run(capsys: pytest.CaptureFixture, path: Path, results: Path) -> tuple[int, str, str]:
    return cli(capsys, "run", str(path), "--dry-run", "--results", str(results))


# ------------------------------------------------------------------ bad values in a tournament

WIN1_OVERRIDES = "overrides = { hidden = [32, 32], batch_size = 16, learning_starts = 16 }"
BAD_TOURNAMENT_VALUES = {
    "actor_lr_inf": (WIN1_OVERRIDES, "overrides = { actor_lr = inf }", ("actor_lr",)),
    "critic_lr_inf": (WIN1_OVERRIDES, "overrides = { critic_lr = inf }", ("critic_lr",)),
    "critic_lr_nan": (WIN1_OVERRIDES, "overrides = { critic_lr = nan }", ("critic_lr",)),
    "hidden_huge": (WIN1_OVERRIDES, "overrides = { hidden = [1000000000000, 32] }",
                    ("hidden",)),
    "seed_base_huge": ('name = "tiny"\n', 'name = "tiny"\nseed_base = 99999999999999999999\n',
                       ("seed_base",)),
    "seeds_true": ("seeds = 1\n", "seeds = true\n", ("seeds",)),
    "episodes_true": ("episodes = 2\n", "episodes = true\n", ("episodes",)),
    "episodes_huge": ("episodes = 2\n", "episodes = 99999999999999999999999\n", ("episodes",)),
    "max_steps_huge": ("max_steps = 30\n", "max_steps = 99999999999999999999\n",
                       ("max_steps",)),
}


@pytest.mark.parametrize("case", sorted(BAD_TOURNAMENT_VALUES))
def test_bad_value_is_refused_at_its_line(
    case: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    old, new, words = BAD_TOURNAMENT_VALUES[case]
    text = TINY.format(entrants='["WIN1"]', p2="")
    assert old in text, old
    path = tournament(tmp_path, text.replace(old, new, 1))
    results = tmp_path / "res"
    code, _, err = dry_run(capsys, path, results)
    one_line_error(code, err, str(path), *words)
    assert not results.exists()


@pytest.mark.parametrize("name", ["index.sqlite", "estimate.json", ".lock", "optuna",
                                  "_baselines", "_races", "index.sqlite.corrupt"])
def test_reserved_part_name_is_refused(
    name: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    text = TINY.format(entrants='["WIN1"]', p2="").replace('name = "p1"', f'name = "{name}"')
    path = tournament(tmp_path, text)
    results = tmp_path / "res"
    code, _, err = dry_run(capsys, path, results)
    line = one_line_error(code, err, f"{path}:", "name")
    assert name in line
    assert not results.exists()


@pytest.mark.parametrize("text", [
    "x = " + "[" * 50_000 + "]" * 50_000 + "\n",
    "x = " + "{a = " * 3_000 + "1" + "}" * 3_000 + "\n",
], ids=["arrays-50000-deep", "tables-3000-deep"])
def test_deep_nesting_is_one_line(text: str, tmp_path: Path, capsys: pytest.CaptureFixture
                                  ) -> None:
    path = tournament(tmp_path, text)
    results = tmp_path / "res"
    code, _, err = dry_run(capsys, path, results)
    one_line_error(code, err, str(path), "nest")
    assert not results.exists()


def test_bad_preset_in_defaults_is_reported_at_defaults(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    text = TINY.format(entrants='["WIN1"]', p2="").replace(
        'device = "cpu"', 'device = "cpu"\npreset = "no-such-preset"')
    path = tournament(tmp_path, text)
    code, _, err = dry_run(capsys, path, tmp_path / "res")
    line = one_line_error(code, err, f"{path}:11:", "defaults.preset", "no-such-preset")
    assert "parts" not in line


# ------------------------------------------------------------------ track files of a tournament

OPEN_TRACK = """\
name = "open"
width_m = 12

[[segment]]
type = "straight"
length_m = 300.0

[[segment]]
type = "arc"
radius_m = 100
angle_deg = 90
"""
OVAL = Path(__file__).resolve().parents[1] / "formula_tourney" / "sim" / "tracks" / "oval.toml"


@pytest.mark.parametrize("key,track_text,words", [
    ("train_tracks", OPEN_TRACK, ("does not close",)),
    ("test_tracks", OVAL.read_text().replace("length_m = 150.0000", "length_m = nan", 1),
     ("length_m", "finite")),
], ids=["train-track-does-not-close", "test-track-nan-length"])
def test_track_file_is_validated_not_only_found(
    key: str, track_text: str, words: tuple[str, ...], tmp_path: Path,
    capsys: pytest.CaptureFixture,
) -> None:
    (tmp_path / "bad.toml").write_text(track_text, encoding="utf-8")
    text = TINY.format(entrants='["WIN1"]', p2="")
    if key == "train_tracks":
        text = text.replace('train_tracks = ["oval"]', 'train_tracks = ["bad.toml"]')
    else:
        text = text.replace('train_tracks = ["oval"]',
                            'train_tracks = ["oval"]\ntest_tracks = ["oval", "bad.toml"]')
    path = tournament(tmp_path, text)
    results = tmp_path / "res"
    code, _, err = dry_run(capsys, path, results)
    one_line_error(code, err, f"{path}:", f"parts[0].{key}", "bad.toml", *words)
    assert not results.exists()


def test_tracks_sharing_a_trace_name_are_refused(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture) -> None:
    """``tr a.toml`` and ``tr_a.toml`` both become the trace ``..._tr_a.toml``: one test drive
    and one baseline row would be dropped."""
    for name in ("tr a.toml", "tr_a.toml"):
        (tmp_path / name).write_text(OVAL.read_text(), encoding="utf-8")
    text = TINY.format(entrants='["WIN1"]', p2="").replace(
        'train_tracks = ["oval"]',
        'train_tracks = ["oval"]\ntest_tracks = ["tr a.toml", "tr_a.toml"]\n'
        'baselines = [{ bot = "follower", reference = "centre" }]')
    path = tournament(tmp_path, text)
    results = tmp_path / "res"
    code, _, err = dry_run(capsys, path, results)
    one_line_error(code, err, f"{path}:23:", "parts[0].test_tracks", "tr a.toml", "tr_a.toml",
                   "rename")
    assert not results.exists()


# ------------------------------------------------------------------ checkpoints and output paths


@pytest.fixture(scope="module")
def job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny trained job folder (seconds): its checkpoints are tampered with below."""
    out = tmp_path_factory.mktemp("job") / "run"
    main(["train", "--out", str(out), "--variant", "WIN1", "--track", "oval", "--episodes", "1",
          "--max-steps", "20", "--test-every", "1", "--test-starts", "1",
          "--test-max-steps", "20", "--device", "cpu", "--set", "hidden=[16, 16]",
          "--set", "batch_size=8", "--set", "learning_starts=8", "--json"])
    assert (out / "checkpoints" / "last.pt").is_file()
    return out


class Foreign:
    """Any class: a pickle of it is code a weights-only load refuses to run."""


def _tamper(state: dict, case: str) -> None:
    if case == "extra-list":
        state["extra"] = [1, 2]
    elif case == "extra-string":
        state["extra"] = "episode 3"
    elif case == "actor-nan":
        for tensor in state["actor"].values():
            tensor.fill_(float("nan"))
    elif case == "obs-dim-huge":
        state["obs_dim"] = 10**13
    elif case == "foreign-object":
        state["extra"] = {"note": Foreign()}
    else:
        raise AssertionError(case)


CHECKPOINT_WORDS = {
    "extra-list": ("extra", "list"),
    "extra-string": ("extra", "str"),
    "actor-nan": ("actor", "not finite"),
    "obs-dim-huge": ("bad sizes", "10000000000000"),
    "foreign-object": ("not a formula-tourney checkpoint",),
}


@pytest.mark.parametrize("case", sorted(CHECKPOINT_WORDS))
def test_bad_checkpoint_is_one_line(case: str, job: Path, tmp_path: Path,
                                    capsys: pytest.CaptureFixture) -> None:
    import shutil

    import torch

    folder = tmp_path / "run"
    shutil.copytree(job, folder)
    path = folder / "checkpoints" / "last.pt"
    state = torch.load(path, weights_only=True)
    _tamper(state, case)
    torch.save(state, path)
    code, _, err = cli(capsys, "eval", str(path), "--starts", "1", "--max-steps", "10")
    line = one_line_error(code, err, str(path), *CHECKPOINT_WORDS[case])
    assert "weights_only" not in line


@pytest.fixture
def a_file(tmp_path: Path) -> Path:
    path = tmp_path / "plain-file"
    path.write_text("not a folder\n", encoding="utf-8")
    return path


def test_run_results_under_a_file(a_file: Path, tmp_path: Path,
                                  capsys: pytest.CaptureFixture) -> None:
    path = tiny(tmp_path)
    code, _, err = cli(capsys, "run", str(path), "--results", str(a_file / "res"))
    one_line_error(code, err, "--results", str(a_file), "is a file")


def test_train_out_under_a_file(a_file: Path, capsys: pytest.CaptureFixture) -> None:
    code, _, err = cli(capsys, "train", "--out", str(a_file / "run"), "--variant", "WIN1",
                       "--episodes", "1", "--max-steps", "5", "--test-starts", "1",
                       "--test-max-steps", "5")
    one_line_error(code, err, "--out", str(a_file), "is a file")


def test_tracks_show_plot_under_a_file(a_file: Path, capsys: pytest.CaptureFixture) -> None:
    code, _, err = cli(capsys, "tracks", "show", "oval", "--plot", str(a_file / "oval.png"))
    one_line_error(code, err, "--plot", str(a_file), "is a file")


def test_replay_gif_under_a_file_before_driving(
    job: Path, a_file: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    from formula_tourney.training import replay

    def no_drive(*args: object, **kwargs: object) -> None:
        raise AssertionError("drove before checking --gif")

    monkeypatch.setattr(replay, "replay", no_drive)
    code, _, err = cli(capsys, "replay", str(job / "checkpoints" / "last.pt"), "--track", "oval",
                       "--gif", str(a_file / "lap.gif"))
    one_line_error(code, err, "--gif", str(a_file), "is a file")


def test_report_out_under_a_file(job: Path, a_file: Path, tmp_path: Path,
                                 capsys: pytest.CaptureFixture) -> None:
    from report_fixtures import build_tournament

    build_tournament(tmp_path / "results")
    code, _, err = cli(capsys, "report", "--tournament", "fixture-cup", "--results",
                       str(tmp_path / "results"), "--out", str(a_file / "report"),
                       "--no-figures", "--no-claims")
    one_line_error(code, err, "--out", str(a_file), "is a file")


@pytest.mark.parametrize("under", [True, False], ids=["parent-is-a-file", "out-is-a-file"])
def test_race_out_under_a_file(under: bool, a_file: Path, capsys: pytest.CaptureFixture) -> None:
    out = a_file / "races" if under else a_file
    code, _, err = cli(capsys, "race", "--bots", "follower", "--track", "oval", "--laps", "1",
                       "--out", str(out))
    one_line_error(code, err, "--out", str(a_file), "is a file")


# ------------------------------------------------------------------ user text is printed as text


@pytest.mark.parametrize("description", ["[/bogus] [bold]x", "red \x1b[31mALERT\x1b[0m \x1b[2J"],
                         ids=["rich-markup", "ansi-escapes"])
def test_description_is_printed_as_text(description: str, tmp_path: Path,
                                        capsys: pytest.CaptureFixture) -> None:
    toml_text = description.replace("\x1b", "\\u001b")  # TOML's escape for ESC
    text = TINY.format(entrants='["WIN1"]', p2="").replace(
        'name = "tiny"\n', f'name = "tiny"\ndescription = "{toml_text}"\n')
    path = tournament(tmp_path, text)
    results = tmp_path / "res"
    code, out, err = dry_run(capsys, path, results)
    assert code == 0, err
    assert "\x1b" not in out
    assert description.replace("\x1b", "\\x1b") in out
    assert not results.exists()


def test_track_path_with_markup_is_printed_as_text(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture) -> None:
    (tmp_path / "[").mkdir()
    (tmp_path / "[" / "x].toml").write_text(OVAL.read_text(), encoding="utf-8")
    (tmp_path / "[bold]b.toml").write_text(OVAL.read_text(), encoding="utf-8")
    text = TINY.format(entrants='["WIN1"]', p2="").replace(
        'train_tracks = ["oval"]', 'train_tracks = ["[/x].toml", "[bold]b.toml"]')
    path = tournament(tmp_path, text)
    code, out, err = dry_run(capsys, path, tmp_path / "res")
    assert code == 0, err
    assert "train [/x].toml, [bold]b.toml; test [/x].toml, [bold]b.toml" in out


def test_tracks_list_shows_user_file_names_as_text(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    from formula_tourney.sim.catalog import DATA_DIR_ENV

    monkeypatch.setenv(DATA_DIR_ENV, str(tmp_path))
    (tmp_path / "tracks").mkdir()
    (tmp_path / "tracks" / "[x].toml").write_text(OVAL.read_text(), encoding="utf-8")
    (tmp_path / "tracks" / "[red]y.toml").write_text(OVAL.read_text(), encoding="utf-8")
    code, out, err = cli(capsys, "tracks", "list")
    assert code == 0, err
    assert "[x]" in out and "[red]y" in out


# ------------------------------------------------------------------ resume checks the files


def test_resume_runs_again_a_done_job_whose_files_are_lost(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture) -> None:
    """A finished job whose folder is deleted, and one whose tests.parquet is cut in half, were
    still counted as done: the resume ran nothing and said nothing."""
    import shutil

    import pandas as pd

    path = tiny(tmp_path, '["WIN1", "MS2"]')
    results = tmp_path / "res"
    code, _, err = cli(capsys, "run", str(path), "--results", str(results), "--workers", "1")
    assert code == 0, err
    root = results / "tiny" / "p1"
    gone, cut = root / "WIN1-MOT" / "seed-0", root / "MS2-MOT" / "seed-0"
    before = {job: pd.read_parquet(job / "tests.parquet") for job in (gone, cut)}
    shutil.rmtree(gone)
    data = (cut / "tests.parquet").read_bytes()
    (cut / "tests.parquet").write_bytes(data[: len(data) // 2])

    code, out, err = cli(capsys, "run", str(path), "--results", str(results), "--workers", "1",
                         "--json")
    assert code == 0, err
    result = json.loads(out)
    assert result["this_run"]["lost"] == 2 and result["this_run"]["done"] == 2
    reasons = {x["job_id"]: x["reason"] for x in result["lost"]}
    assert "is missing" in reasons["p1/WIN1-MOT/seed-0"]
    assert "tests.parquet" in reasons["p1/MS2-MOT/seed-0"]
    for job, table in before.items():  # the same seed: the same tests (but the CPU clock)
        pd.testing.assert_frame_equal(pd.read_parquet(job / "tests.parquet").drop(
            columns="cpu_s"), table.drop(columns="cpu_s"))


# ------------------------------------------------------------------ tune storage

TUNE_FILE = Path(__file__).resolve().parents[1] / "tournaments" / "tune.toml"


@pytest.mark.parametrize("extra,words", [
    (("--storage", "sqlite:////nonexistent/dir/x.db"), ("--storage", "cannot open")),
    (("--storage", "garbage://x"), ("--storage", "garbage", "sqlite://")),
    (("--resume",), ("--resume", "no study")),
], ids=["sqlite-folder-missing", "unknown-scheme", "resume-without-study"])
def test_tune_storage_errors_leave_nothing(extra: tuple[str, ...], words: tuple[str, ...],
                                           tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    results = tmp_path / "res"
    code, _, err = cli(capsys, "tune", str(TUNE_FILE), "--variant", "WIN1", "--trials", "1",
                       "--results", str(results), *extra)
    one_line_error(code, err, *words)
    assert not results.exists()  # no .lock, no empty journal


# ------------------------------------------------------------------ the env's actions and seeds

BAD_ACTIONS = {
    "strings": np.array(["0.0", "0.5", "0.0"]),
    "complex": np.array([0.0, 0.5 + 1j, 0.0]),
    "bools": np.array([False, True, False]),
    "string-list": ["0.0", "0.5", "0.0"],
}


@pytest.mark.parametrize("vector", [False, True], ids=["single", "vector"])
@pytest.mark.parametrize("case", sorted(BAD_ACTIONS))
def test_env_refuses_actions_that_are_not_real_numbers(case: str, vector: bool) -> None:
    from simtracks import stadium

    from formula_tourney.sim.env import FormulaRacingEnv, FormulaRacingVectorEnv, InvalidActionError

    if vector:
        env = FormulaRacingVectorEnv(num_envs=2, config={"track": stadium()})
        action = np.stack([np.asarray(BAD_ACTIONS[case])] * 2)
    else:
        env = FormulaRacingEnv(config={"track": stadium()})
        action = BAD_ACTIONS[case]
    env.reset(seed=0)
    with pytest.raises(InvalidActionError, match="real numbers"):
        env.step(action)


def test_vector_reset_uses_every_seed_or_refuses() -> None:
    from simtracks import stadium

    from formula_tourney.sim.env import FormulaRacingVectorEnv

    env = FormulaRacingVectorEnv(num_envs=2, config={"track": stadium(), "random_start": True})
    with pytest.raises(ValueError, match="one generator"):
        env.reset(seed=[1, 2])
    same, _ = env.reset(seed=[7, 7])
    one, _ = env.reset(seed=7)
    np.testing.assert_array_equal(same, one)


def test_race_negative_seed(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "races"
    code, _, err = cli(capsys, "race", "--bots", "follower", "--track", "oval", "--laps", "1",
                       "--seed", "-5", "--out", str(out))
    one_line_error(code, err, "--seed", "-5")
    assert not out.exists()


def test_report_on_a_config_with_a_word_for_grip(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture) -> None:
    """A traceback (ValueError from float('wet')); now a problem naming the file, as the
    report does for every file it cannot read."""
    from report_fixtures import build_tournament

    root = build_tournament(tmp_path / "results")
    config = next(root.rglob("config.json"))
    doc = json.loads(config.read_text(encoding="utf-8"))
    doc["run_spec"].setdefault("env", {})["grip_scale"] = "wet"
    config.write_text(json.dumps(doc), encoding="utf-8")
    code, out, err = cli(capsys, "report", "--tournament", root.name, "--results",
                         str(tmp_path / "results"), "--no-figures", "--no-claims", "--json")
    assert code == 0 and "Traceback" not in err, err  # the report lists what it cannot read
    problems = [p for p in json.loads(out)["problems"] if str(config) in p]
    assert problems and all("grip_scale is 'wet', not a number" in p for p in problems)


def test_a_full_disk_is_not_called_an_unreadable_index(tmp_path: Path) -> None:
    """SQLite's "database or disk is full" was reported as "cannot read the results index ...
    --rebuild-index", though the index was intact."""
    from formula_tourney.errors import UserInputError
    from formula_tourney.results.folder import CorruptResultError
    from formula_tourney.tourney.store import Store

    store = Store(tmp_path / "t")
    store.add_part("p1", "main", 0, None)
    pages = store.db.execute("PRAGMA page_count").fetchone()[0]
    store.db.execute(f"PRAGMA max_page_count = {pages}")  # the disk is full from now on
    rows = [{"job_id": f"p1/x-{i}", "kind": "train", "part": "p1", "position": 0,
             "path": f"p1/x-{i}", "config_hash": "h" * 64, "attrs": {"note": "x" * 2000}}
            for i in range(50)]
    with pytest.raises(UserInputError) as err:
        store.add_jobs(rows)
    assert not isinstance(err.value, CorruptResultError)
    assert "disk is full" in str(err.value) and "--rebuild-index" not in str(err.value)
    assert "\n" not in str(err.value)
    assert store.part("p1")["status"] == "pending"  # the index still reads


def test_a_rule_across_keys_names_them(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A model-level rule read "value: Value error, ..." (pydantic's loc of the whole model)."""
    text = TINY.format(entrants='["WIN1"]', p2="").replace(
        "batch_size = 16, learning_starts = 16 }\n[variants.MS2]",
        "batch_size = 4096, buffer_size = 1000, learning_starts = 16 }\n[variants.MS2]")
    path = tournament(tmp_path, text)
    code, _, err = dry_run(capsys, path, tmp_path / "res")
    line = one_line_error(code, err, f"{path}:13:", "variants.WIN1.overrides",
                          "batch_size must not exceed buffer_size")
    assert "value:" not in line and "Value error" not in line and "validation error" not in line


@pytest.mark.parametrize("value", ["Infinity", "NaN", "-Infinity"])
def test_train_set_a_learning_rate_that_is_not_finite(value: str, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture) -> None:
    """Accepted, then a DivergedError traceback and a partial job folder."""
    out = tmp_path / "run"
    code, _, err = cli(capsys, "train", "--out", str(out), "--variant", "WIN1", "--episodes", "1",
                       "--max-steps", "20", "--test-starts", "1", "--test-max-steps", "20",
                       "--set", f"critic_lr={value}")
    one_line_error(code, err, "critic_lr", "finite")
    assert not out.exists()

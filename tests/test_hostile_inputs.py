"""Hostile input a new user may give: every case ends in one line naming the file or key, exit
code 2 and nothing written, before the first job starts; text from user files is printed as
text, never read as rich markup or terminal escape codes."""

from __future__ import annotations

from pathlib import Path

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

BAD_TOURNAMENT_VALUES = {
    "actor_lr_inf": (
        ("[variants.WIN1]\noverrides = {{ hidden = [32, 32], batch_size = 16, "
         "learning_starts = 16 }}"),
        "[variants.WIN1]\noverrides = { actor_lr = inf }", ("actor_lr",)),
    "critic_lr_inf": (
        ("[variants.WIN1]\noverrides = {{ hidden = [32, 32], batch_size = 16, "
         "learning_starts = 16 }}"),
        "[variants.WIN1]\noverrides = { critic_lr = inf }", ("critic_lr",)),
    "critic_lr_nan": (
        ("[variants.WIN1]\noverrides = {{ hidden = [32, 32], batch_size = 16, "
         "learning_starts = 16 }}"),
        "[variants.WIN1]\noverrides = { critic_lr = nan }", ("critic_lr",)),
    "hidden_huge": (
        ("[variants.WIN1]\noverrides = {{ hidden = [32, 32], batch_size = 16, "
         "learning_starts = 16 }}"),
        "[variants.WIN1]\noverrides = { hidden = [1000000000000, 32] }", ("hidden",)),
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
    if "{{" in old:
        old = old.replace("{{", "{").replace("}}", "}")
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

"""``train``'s options come from the models that own the settings: names, help, defaults, checks."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import pytest
import typer
from pydantic import BaseModel, ConfigDict, Field
from typer.main import get_command
from typer.testing import CliRunner

import formula_tourney.training.loop as training_loop
from formula_tourney.cli import app, main
from formula_tourney.commands.agents import TRAIN_OPTIONS
from formula_tourney.commands.model_options import (
    chosen_values,
    field_options,
    with_field_options,
)
from formula_tourney.training.run_spec import DemoSettings, RunSpec, Schedule

DOCUMENTED = ("--episodes", "--env-steps", "--test-every", "--test-starts", "--test-max-steps",
              "--test-grip", "--cars", "--traffic-bots", "--demo-laps", "--demo-line",
              "--demo-fraction", "--bc-steps", "--bc-weight", "--seed", "--max-steps", "--device",
              "--threads", "--track", "--test-track", "--reference", "--lac", "--variant",
              "--preset", "--set", "--env-set", "--out", "--json")  # fmt: skip
"""The option names docs/*.md and the README show users."""


def _train_params() -> dict[str, Any]:
    command = get_command(app).commands["train"]  # type: ignore[attr-defined]
    return {p.name: p for p in command.params}


def test_every_schedule_and_demo_field_is_an_option_with_the_models_help_and_default() -> None:
    params = _train_params()
    for model in (Schedule, DemoSettings):
        for field, info in model.model_fields.items():
            option = next(o for o in TRAIN_OPTIONS if o.model is model and o.field == field)
            param = params[option.param]
            assert param.help == info.description, field
            default = list(info.default) if isinstance(info.default, tuple) else info.default
            assert param.default == default, field
    names = {n for p in params.values() for n in (*p.opts, *p.secondary_opts)}
    assert set(DOCUMENTED) <= names, set(DOCUMENTED) - names
    assert {"--random-start", "--no-random-start", "--save-test-checkpoints", "--bc-lr",
            "--bc-q-filter", "--no-bc-q-filter"} <= names  # fmt: skip
    # RunSpec's own fields too (its sections and the preset aside)
    assert params["runspec__seed"].help == RunSpec.model_fields["seed"].description
    assert (params["runspec__device"].default, params["runspec__threads"].default) == ("auto", 1)


def test_train_help_lists_each_schedule_option_and_its_default() -> None:
    result = CliRunner().invoke(app, ["train", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    for option in TRAIN_OPTIONS:
        assert option.name in result.output, option.name
    assert "[default: 1500]" in result.output  # test_max_steps
    assert "best-demos" in result.output and "tuned-progress" not in result.output


def test_a_field_added_to_a_model_becomes_an_option_validated_by_the_model() -> None:
    """What makes a new Schedule field reach ``train --help``: nothing in the command names it."""

    class Toy(BaseModel):
        model_config = ConfigDict(extra="forbid")
        warmup_steps: int = Field(250, ge=0, le=1000, description="Steps before learning.")
        line: Literal["centre", "mincurv"] = Field("centre", description="Line to drive.")
        grips: tuple[float, ...] = Field((), max_length=2, description="Grips to test at.")

    options = field_options(Toy, "Toy")
    seen: list[dict[str, Any]] = []
    toy = typer.Typer()

    def command(ctx: typer.Context, **values: Any) -> None:
        seen.append(chosen_values(ctx, options, values, Toy))

    toy.command("go")(with_field_options(command, options))
    toy.command("other")(lambda: None)
    runner = CliRunner()
    shown = runner.invoke(toy, ["go", "--help"], env={"COLUMNS": "200"}).output
    assert "--warmup-steps" in shown and "Steps before learning." in shown
    assert "[default: 250]" in shown and "[centre|mincurv]" in shown
    assert runner.invoke(toy, ["go"]).exit_code == 0 and seen[-1] == {}  # nothing given
    runner.invoke(toy, ["go", "--warmup-steps", "7", "--grips", "0.5", "--grips", "1"])
    assert seen[-1] == {"warmup_steps": 7, "grips": (0.5, 1.0)}
    bad = runner.invoke(toy, ["go", "--line", "recorded"])
    assert bad.exit_code != 0
    assert "--line recorded: Input should be 'centre' or 'mincurv'" in str(bad.exception)


@pytest.mark.parametrize(("argv", "words"), [
    (["--test-starts", "0"], "--test-starts 0: Input should be greater than or equal to 1"),
    (["--demo-line", "racing"], "--demo-line racing: Input should be 'centre', 'recorded' or "
                                "'mincurv'"),
    (["--device", "gpu"], "--device gpu: Input should be 'auto', 'cpu' or 'cuda'"),
    (["--test-grip", "0.1"], "--test-grip 0.1: Input should be greater than or equal to 0.2"),
    (["--episodes", "many"], "--episodes many: Input should be a valid integer"),
    (["--preset", "tuned-progress"], "preset 'tuned-progress' is now 'best'"),
    (["--preset", "fast"], "preset 'fast' was retired: use 'best'"),
])  # fmt: skip
def test_a_bad_value_is_the_models_one_line_error_and_nothing_is_written(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], words: str) -> None:
    out = tmp_path / "never"
    with pytest.raises(SystemExit) as exc:
        main(["train", "--out", str(out), *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and words in err, err
    assert not out.exists()


def test_options_left_out_keep_the_presets_demos_and_given_ones_win(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    specs: list[RunSpec] = []
    monkeypatch.setattr(training_loop, "train",
                        lambda spec, out, progress: specs.append(spec) or {"seconds": 0.0})

    main(["train", "--out", str(tmp_path / "a"), "--preset", "tuned-bc", "--demo-laps", "2",
          "--episodes", "7", "--test-grip", "0.8", "--lac", "--json"])  # fmt: skip
    spec = specs[-1]
    assert (spec.demos.laps, spec.demos.batch_fraction, spec.demos.bc_weight) == (2, 0.25, 0.2)
    assert (spec.schedule.episodes, spec.schedule.test_grip_scales, spec.lac) == (7, (0.8,), True)
    assert spec.schedule.test_every_episodes == Schedule().test_every_episodes
    assert (spec.variant, spec.train_tracks, spec.test_tracks) == ("WIN1", ("oval",), ("oval",))

    main(["train", "--out", str(tmp_path / "b"), "--demo-line", "centre", "--no-bc-q-filter",
          "--json"])  # a demo option turns demonstrations on, the model's defaults fill the rest
    assert specs[-1].demos == DemoSettings(line="centre", bc_q_filter=False)
    main(["train", "--out", str(tmp_path / "c"), "--json"])
    assert specs[-1].demos is None and specs[-1].schedule == Schedule()

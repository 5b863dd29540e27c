"""``replay`` drives the very test that made a table's lap: its start, grip, seed and checkpoint,
through the tests' own drive (``training.evaluate.run_test_episode``), to the millisecond.

The run is real (``training.loop.train`` on a 500 m ring, two test starts) with an actor that
laps without learning: its weights are set by hand to steer on the angle to the track and the
track position, and to lift off with speed (``_steered``); ``learning_starts`` beyond the run
keeps them. From the start 300 m before the line it reaches the line at speed; from the start
50 m before it, it does not: the best lap is the second start's, which a replay from the line
cannot drive.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from PIL import Image
from training_fixtures import ring_track

from formula_tourney.agents import family_entrant
from formula_tourney.agents.core import Agent
from formula_tourney.cli import main
from formula_tourney.results import metrics
from formula_tourney.results.folder import JobFolder
from formula_tourney.results.layout import TRACE_COLUMNS
from formula_tourney.training import loop
from formula_tourney.training.evaluate import start_positions
from formula_tourney.training.replay import best_test, replay, replay_best
from formula_tourney.training.run_spec import build_run_spec

ANGLE, TRACK_POS, SPEED_X = 0, 20, 21
"""Observation indices (``sim.sensors.observation_names``) the hand-set actor reads."""
loop_make_agent = family_entrant.make_agent


def _steered(agent: Agent) -> Agent:
    """steer = tanh(0.3 - 10 angle - trackPos), throttle = sigmoid(-3 speedX), no brake: two
    ReLU units per signed input, passed through the second layer unchanged."""
    actor = agent.actor
    with torch.no_grad():
        for layer in (actor.l1, actor.l2, actor.out):
            layer.weight.zero_()
            layer.bias.zero_()
        for unit, (obs, sign) in enumerate(((ANGLE, 1), (ANGLE, -1), (TRACK_POS, 1),
                                            (TRACK_POS, -1), (SPEED_X, 1))):
            actor.l1.weight[unit, obs] = sign
            actor.l2.weight[unit, unit] = 1.0
        actor.out.weight[0, :4] = torch.tensor([-10.0, 10.0, -1.0, 1.0])
        actor.out.bias[0] = 0.3
        actor.out.weight[1, 4] = -3.0
        actor.out.bias[2] = -20.0
    return agent


@pytest.fixture
def job(tmp_path: Path, ring_tracks: None, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A finished job folder whose tests lapped the ring cleanly from one of two starts."""
    steered = lambda *a, **k: _steered(loop_make_agent(*a, **k))  # noqa: E731
    monkeypatch.setattr(family_entrant, "make_agent", steered)
    spec = build_run_spec(
        variant="WIN1", train_tracks=["ring"], seed=5, device="cpu",
        overrides={"hidden": (8, 8), "batch_size": 16, "learning_starts": 10**6},
        schedule={"episodes": 2, "max_steps": 20, "test_every_episodes": 1, "test_starts": 2,
                  "test_max_steps": 300})  # fmt: skip
    loop.train(spec, tmp_path / "job")
    return tmp_path / "job"


def test_best_replays_the_tables_lap_to_the_millisecond(job: Path, tmp_path: Path) -> None:
    tests = JobFolder(job).tests()
    # the table's number, by the tables' rule: the best lap of a model without damage
    table = metrics.run_table(metrics.model_table(tests.assign(job_id="job")))
    lap_s = float(table["run_best_s"].iloc[0])
    row = tests.loc[tests["best_lap_s"] == lap_s].iloc[0]
    first, second = start_positions(ring_track("ring").length_m, 2)  # 50 and 300 m before
    assert np.isfinite(lap_s) and row["start_s_m"] == second
    choice = best_test(job)
    assert (choice.start_s_m, choice.grip_scale, choice.episode) == (second, 1.0, 1)
    assert choice.checkpoint == job / "checkpoints" / "best.pt"
    summary = replay_best(job, gif=tmp_path / "lap.gif")
    assert summary["best_lap_s"] == pytest.approx(lap_s, abs=5e-4)
    assert summary["reproduced"] and summary["table_lap_s"] == lap_s
    assert summary["lap_times_s"] == pytest.approx([float(row["best_lap_s"])])
    assert summary["seed"] == 5 * 1000 + 1  # the second start's seed, as the tests drove it
    # the GIF: the lap in the race GIF's look (track beside a column), the car drawn red
    with Image.open(tmp_path / "lap.gif") as img:
        assert img.n_frames == summary["frames"] > 10 and img.width > img.height
        frame = np.asarray(img.convert("RGB"))
    assert np.any(np.all(frame == (220, 30, 30), axis=-1))
    # from the line, as replay drove before, the same actor does not drive that lap
    from_line = replay(choice.checkpoint)
    assert from_line["start_s_m"] == first
    assert from_line["best_lap_s"] != pytest.approx(lap_s, abs=5e-4)


def test_replay_cli_takes_a_test_rows_start_grip_and_seed(job: Path, capsys) -> None:
    row = JobFolder(job).tests().sort_values("best_lap_s").iloc[0]
    ckpt = job / "checkpoints" / "best.pt"
    assert _cli("replay", str(ckpt), "--start-s-m", str(row["start_s_m"]), "--grip",
                str(row["grip_scale"]), "--seed", "5001", "--json") == 0
    out = json.loads(capsys.readouterr().out)
    assert out["best_lap_s"] == pytest.approx(float(row["best_lap_s"]), abs=5e-4)
    assert _cli("replay", str(ckpt), "--best") == 0
    assert "reproduced" in capsys.readouterr().out
    assert _cli("replay", str(job), "--best", "--seed", "3") == 2
    assert "--best drives the best test's own start, grip and seed" in capsys.readouterr().err
    assert _cli("replay", str(job), "--best", "--track", "elsewhere") == 2
    assert "no test on 'elsewhere'; tested on: ring" in capsys.readouterr().err


def test_replay_trace_holds_every_step_of_the_drive(job: Path, tmp_path: Path, capsys) -> None:
    row = JobFolder(job).tests().sort_values("best_lap_s").iloc[0]
    ckpt = job / "checkpoints" / "best.pt"
    drive = ["replay", str(ckpt), "--start-s-m", str(row["start_s_m"]), "--seed", "5001"]
    assert _cli(*drive, "--trace", str(tmp_path / "steps.csv"), "--json") == 0
    out = json.loads(capsys.readouterr().out)
    steps = pd.read_csv(tmp_path / "steps.csv")
    assert len(steps) == out["steps"] and out["trace"] == str(tmp_path / "steps.csv")
    assert list(steps.columns) == [*TRACE_COLUMNS, "laps"]
    assert steps["laps"].iloc[-1] == len(out["lap_times_s"]) >= 1  # the lap the row recorded
    assert steps["distance_m"].is_monotonic_increasing
    # Parquet by its suffix: the same steps
    assert _cli(*drive, "--trace", str(tmp_path / "steps.parquet")) == 0
    again = pd.read_parquet(tmp_path / "steps.parquet")
    assert np.allclose(again.to_numpy(), steps.to_numpy(), rtol=1e-5)
    capsys.readouterr()
    # --braking reads the drive against the limit's braking zones: a ring of one radius has none
    assert _cli(*drive, "--braking", "--json") == 0
    assert json.loads(capsys.readouterr().out)["braking"] == []
    assert _cli(*drive, "--braking") == 0
    assert "approached no braking zone" in capsys.readouterr().out
    # another suffix is refused before the drive, and nothing is written
    assert _cli(*drive, "--trace", str(tmp_path / "steps.txt")) == 2
    assert "--trace" in capsys.readouterr().err and not (tmp_path / "steps.txt").exists()


def _cli(*args: str) -> int:
    try:
        main(list(args))
    except SystemExit as exc:
        return int(exc.code or 0)
    return 0

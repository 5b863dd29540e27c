"""Races end to end: grid, start, laps, positions from the cars' distances, models and bots, CLI."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from simtracks import stadium

from formula_tourney.agents.checkpoints import save_checkpoint
from formula_tourney.agents.ddpg import DDPGAgent
from formula_tourney.errors import UserInputError
from formula_tourney.race.entrants import bot_entrant, build_entrants, model_entrant
from formula_tourney.race.grid import grid_slots
from formula_tourney.race.run import run_race
from formula_tourney.race.settings import RaceSettings
from formula_tourney.race.timing import RUNNING
from formula_tourney.sim import kernels as K
from formula_tourney.sim.catalog import load_track
from formula_tourney.sim.multicar import lockstep_kernels as RK
from formula_tourney.training.run_spec import build_run_spec

TRACK = stadium()


def test_two_car_race_positions_and_gaps_follow_from_the_cars_distances():
    bots = [bot_entrant("follower", TRACK, None, name) for name in ("a", "b")]
    checked = []

    def check(sim, timing, clock):
        dist = np.array([c.distance_m for c in timing.cars])
        running = [c for c, car in enumerate(timing.cars) if car.status == RUNNING]
        if len(running) == 2:
            # Race distance = progress since the start - the slot's distance behind the line.
            lead = int(np.argmax(dist))
            assert timing.positions[lead] == 1
            assert timing.gap_m(1 - lead) == pytest.approx(dist[lead] - dist[1 - lead])
            st = sim.state
            for c in running:
                assert timing.cars[c].distance_m == pytest.approx(
                    st[c, K.ST_DIST] + offset[c], abs=1e-9)
            checked.append(clock)
        return None

    settings = RaceSettings(laps=2, grid="given")
    slots = grid_slots(TRACK, 2, settings, seed=0)  # car c on slot c (given grid)
    offset = {c: -slots[c].behind_line_m for c in range(2)}
    first = run_race(bots, settings, seed=0)
    assert [r["status"] for r in first.rows] == ["finished", "finished"]
    result = run_race(bots, settings, seed=0, frame=check)
    assert len(checked) > 100
    assert result.to_json() == first.to_json()  # same seed, same race
    win = result.rows[0]
    assert win["position"] == 1 and win["laps"] == 2 and win["gap_s"] == 0.0
    assert win["time_s"] == pytest.approx(sum(win["lap_times_s"]), abs=1e-3)  # rounded laps
    second = result.rows[1]
    assert second["gap_s"] == pytest.approx(second["time_s"] - win["time_s"], abs=1e-9)
    chart = [row for row in result.lap_chart if row["lap"] == 2]
    assert sorted(r["position"] for r in chart) == [1, 2]


def test_rolling_start_clock_starts_at_the_leaders_crossing():
    bots = [bot_entrant("follower", TRACK, None, name) for name in ("a", "b", "c")]
    rolling = run_race(bots, RaceSettings(laps=1, start="rolling", grid="given"), seed=3)
    standing = run_race(bots, RaceSettings(laps=1, grid="given"), seed=3)
    assert [r["status"] for r in rolling.rows] == ["finished"] * 3
    pole_rolling = next(r for r in rolling.rows if r["grid"] == 1)
    pole_standing = next(r for r in standing.rows if r["grid"] == 1)
    # Rolling: the pole's lap 1 runs from its own line crossing at speed, a flying lap, faster
    # than a lap from rest 10 m behind the line; the cars behind are timed from the same green.
    assert pole_rolling["lap_times_s"][0] < pole_standing["lap_times_s"][0] - 1.0
    others = [r for r in rolling.rows if r["grid"] > 1]
    assert all(r["time_s"] > pole_rolling["time_s"] - 1.0 for r in others)


def _checkpoint(tmp: Path, obs_extra: int = 0) -> Path:
    spec = build_run_spec(variant="WIN1", train_tracks=["oval"], seed=0, device="cpu")
    agent = DDPGAgent(spec.agent, obs_dim=29 + obs_extra, seed=0)
    path = tmp / f"m{obs_extra}.pt"
    save_checkpoint(agent, path, extra={"run_spec": spec.to_json()})
    return path


def test_model_entrants_blind_or_seeing_and_bad_shapes(tmp_path):
    blind = model_entrant(_checkpoint(tmp_path), "oval")
    assert blind.kind == "model" and not blind.sees_opponents
    seeing = model_entrant(_checkpoint(tmp_path, RK.N_OPP), "oval")
    assert seeing.sees_opponents
    with pytest.raises(UserInputError, match="takes 31 values"):
        model_entrant(_checkpoint(tmp_path, 2), "oval")
    track = load_track("oval")
    entrants = build_entrants([_checkpoint(tmp_path), _checkpoint(tmp_path, RK.N_OPP)],
                              ["follower"], track, "oval")
    result = run_race(entrants, RaceSettings(laps=1, grid="given", lap_limit_s=60.0))
    rows = {r["name"]: r for r in result.rows}
    assert set(rows) == {"WIN1", "WIN1#2", "follower"}
    assert rows["WIN1"]["sees_opponents"] is False and rows["WIN1#2"]["sees_opponents"] is True
    assert rows["follower"]["position"] == 1 and rows["follower"]["status"] == "finished"


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "formula_tourney.cli", "race", *args],
                          capture_output=True, text=True, timeout=600)


def test_cli_race_json_and_gif(tmp_path):
    gif = tmp_path / "race.gif"
    done = _cli("--bots", "follower,follower", "--track", "oval", "--laps", "1", "--json",
                "--gif", str(gif))
    assert done.returncode == 0, done.stderr
    doc = json.loads(done.stdout)
    assert doc["laps"] == 1 and len(doc["results"]) == 2
    assert gif.stat().st_size > 1000


@pytest.mark.parametrize("args, text", [
    (["--bots", "follower", "--track", "nowhere", "--laps", "1"], "nowhere"),
    (["--bots", "follower", "--track", "oval", "--laps", "0"], "--laps"),
    (["--bots", "taxi", "--track", "oval"], "unknown bot"),
    (["--track", "oval"], "at least one model or bot"),
])
def test_cli_bad_input_is_one_line_exit_2_nothing_written(tmp_path, args, text):
    gif = tmp_path / "r.gif"
    done = _cli(*args, "--gif", str(gif))
    assert done.returncode == 2, done.stderr
    assert text in done.stderr and "Traceback" not in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    assert not gif.exists() and list(tmp_path.iterdir()) == []


def test_cli_mismatched_checkpoint_is_refused(tmp_path):
    path = _checkpoint(tmp_path, 5)
    done = _cli(str(path), "--track", "oval", "--laps", "1", "--json")
    assert done.returncode == 2 and "takes 34 values" in done.stderr
    assert json.loads(done.stdout)["exit_code"] == 2  # --json: the error as JSON too

"""The start curriculum (beyond the paper): training starts spread before the braking zones of
the reference line's QSS speed profile, a share of episodes placed there, tests untouched."""

from __future__ import annotations

import numpy as np
import pytest

from formula_tourney.errors import UserInputError
from formula_tourney.lines.speed_profile import speed_profile
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.catalog import load_track
from formula_tourney.sim.env import FormulaRacingEnv, FormulaRacingVectorEnv
from formula_tourney.training.curriculum import LEAD_M, braking_points_m, braking_starts
from formula_tourney.training.envs import RunEnvs
from formula_tourney.training.run_spec import build_run_spec


def test_the_curriculum_starts_lie_before_braking_zones_on_technical() -> None:
    track = load_track("technical")
    v = speed_profile(track, 0.0, CarParams()).speed_mps
    points = braking_points_m(track, 0.0, CarParams())
    assert len(points) >= 5  # technical's hairpins and chicanes
    for p in points:  # each is where the profile starts to fall, by a real braking
        i = int(np.searchsorted(track.s_m, p))
        assert v[(i + 1) % len(v)] < v[i] and v[i - 1] <= v[i]
    starts = np.asarray(braking_starts(track, 0.0, CarParams()))
    assert len(starts) == 6 * len(points)
    # every start lies 25..150 m before some braking point, along the lap
    ahead = (points[None, :] - starts[:, None]) % track.length_m
    nearest = np.where(ahead > 0, ahead, np.inf).min(axis=1)
    assert (nearest >= 25.0 - 1e-6).all() and (nearest <= LEAD_M + 1e-6).all()
    # while a start drawn uniformly over the lap is that close to a braking point far less often
    uniform = np.linspace(0.0, track.length_m, 2000, endpoint=False)
    near = ((points[None, :] - uniform[:, None]) % track.length_m <= LEAD_M).any(axis=1)
    assert near.mean() < 0.6  # 0.47 of the lap


def test_a_share_of_episodes_starts_at_the_curriculum_positions() -> None:
    track = load_track("technical")
    starts = braking_starts(track, 0.0, CarParams())
    config = {"track": track, "random_start": True, "start_curriculum": "braking",
              "start_curriculum_share": 0.5, "curriculum_starts_m": starts}  # fmt: skip
    env = FormulaRacingEnv(config=config)
    placed = []
    for seed in range(200):
        _, info = env.reset(seed=seed)
        placed.append(min(abs(info["s_m"] - s) for s in starts) < 0.5)
    assert 0.4 < np.mean(placed) < 0.6
    venv = FormulaRacingVectorEnv(400, config=config)
    venv.reset(seed=0)
    venv._needs_reset[:] = True  # every car through the autoreset's path
    _, _, _, _, info = venv.step(np.zeros((400, 3)))
    placed = [min(abs(x - s) for s in starts) < 0.5 for x in info["s_m"]]
    assert 0.4 < np.mean(placed) < 0.6
    with pytest.raises(UserInputError, match="start_curriculum 'braking' needs curriculum_starts"):
        FormulaRacingEnv(config={"track": track, "start_curriculum": "braking"})


def test_the_run_fills_training_envs_only_and_labels_the_run() -> None:
    spec = build_run_spec(variant="WIN1", train_tracks=["technical"],
                          env_overrides={"start_curriculum": "braking"})  # fmt: skip
    assert spec.beyond_paper() == ["start_curriculum braking"]
    assert "start_curriculum" not in build_run_spec(
        variant="WIN1", train_tracks=["technical"]
    ).to_json()["env"]
    envs = RunEnvs(spec)
    train = envs.config("technical", test=False)
    assert train.curriculum_starts_m == envs.curriculum_starts("technical")
    assert len(train.curriculum_starts_m) > 0
    test = envs.config("technical", test=True)
    assert test.start_curriculum == "none" and test.curriculum_starts_m == ()
    with pytest.raises(UserInputError, match="curriculum_starts_m"):
        build_run_spec(variant="WIN1", train_tracks=["technical"],
                       env_overrides={"curriculum_starts_m": [10.0]})  # fmt: skip


def test_curriculum_starts_roll_at_a_fraction_of_the_limit_speed() -> None:
    """From rest the car reaches a hairpin too slowly to need the brakes; with
    start_curriculum_speed a placed start rolls at that fraction of the limit's speed there."""
    spec = build_run_spec(variant="WIN1", train_tracks=["technical"],
                          env_overrides={"start_curriculum": "braking",
                                         "start_curriculum_share": 1.0,
                                         "start_curriculum_speed": 0.8})  # fmt: skip
    assert "start_curriculum_speed 0.8" in spec.beyond_paper()
    envs = RunEnvs(spec)
    train = envs.config("technical", test=False)
    vlim = np.asarray(train.limit_speeds_mps)
    track = envs.tracks["technical"]
    assert len(vlim) == track.n  # the run filled the limit's speeds for the starts
    env = FormulaRacingEnv(config=train)
    for seed in range(20):
        _, info = env.reset(seed=seed)
        i = int(np.searchsorted(track.s_m, info["s_m"], side="right") - 1)
        assert info["speed_mps"] == pytest.approx(0.8 * vlim[i], rel=1e-6)
        assert info["speed_mps"] > 15.0  # not at rest: before a braking zone the car is fast
    # the vector autoreset gives its placed cars the same speeds
    venv = FormulaRacingVectorEnv(64, config=train)
    venv.reset(seed=0)
    venv._needs_reset[:] = True
    _, _, _, _, info = venv.step(np.zeros((64, 3)))  # reset, then one 0.2 s step coasting
    idx = np.searchsorted(track.s_m, info["s_m"], side="right") - 1
    assert (info["speed_mps"] > 15.0).all()
    assert np.allclose(info["speed_mps"], 0.8 * vlim[idx], rtol=0.03)
    # with a share of 0.5 the other half still starts at rest (start_speed_mps 0)
    half = FormulaRacingVectorEnv(64, config=train.model_copy(update={
        "start_curriculum_share": 0.5}))
    half.reset(seed=1)
    half._needs_reset[:] = True
    _, _, _, _, info = half.step(np.zeros((64, 3)))
    v = info["speed_mps"]
    rest = v == 0.0  # no throttle for 0.2 s from rest: still at rest
    idx = np.searchsorted(track.s_m, info["s_m"], side="right") - 1
    assert 0.2 < rest.mean() < 0.8
    assert np.allclose(v[~rest], 0.8 * vlim[idx][~rest], rtol=0.03)
    # tests start as always: at rest, no curriculum
    test = envs.config("technical", test=True)
    assert test.start_curriculum_speed == 0.0 and test.start_curriculum == "none"
    # without the curriculum the setting has no starts to speed up: refused before any run
    with pytest.raises(UserInputError, match="needs start_curriculum 'braking'"):
        build_run_spec(variant="WIN1", train_tracks=["technical"],
                       env_overrides={"start_curriculum_speed": 0.8})  # fmt: skip
    # an env built by hand must be given the speeds the run would fill
    with pytest.raises(UserInputError, match="start_curriculum_speed needs limit_speeds_mps"):
        FormulaRacingEnv(config={"track": track, "start_curriculum": "braking",
                                 "curriculum_starts_m": train.curriculum_starts_m,
                                 "start_curriculum_speed": 0.8})  # fmt: skip

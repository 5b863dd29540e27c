"""Grip as an axis: per-episode grip, a drying track, train on one grip and
test on another, and the report's lap time over the limit at each grip."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pandas as pd
import pytest
from simtracks import stadium
from training_fixtures import SMALL, ring_track

from formula_tourney.bots.follower import drive
from formula_tourney.bots.line_offsets import reference_offsets
from formula_tourney.cli import main
from formula_tourney.errors import UserInputError
from formula_tourney.lines.limit import reference_limit_s
from formula_tourney.lines.speed_profile import lap_time_s
from formula_tourney.report.build import build_report
from formula_tourney.results import layout as L
from formula_tourney.results.folder import JobFolder
from formula_tourney.sim import kernels as K
from formula_tourney.sim.car_params import CarParams
from formula_tourney.sim.config import EnvSettings
from formula_tourney.sim.env import FormulaRacingEnv, FormulaRacingVectorEnv
from formula_tourney.tourney.api import plan_tournament
from formula_tourney.training import loop
from formula_tourney.training.envs import RunEnvs
from formula_tourney.training.run_spec import RunSpec, build_run_spec

TRACK = stadium()  # 400 m straights, radius 80 m, 12 m wide


@pytest.fixture
def line_cache(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("FORMULA_TOURNEY_CACHE_DIR", str(tmp_path / "cache"))


# --- per-episode grip --------------------------------------------------------------------------


def test_drawn_grip_is_deterministic_per_seed_and_inside_its_range() -> None:
    env = FormulaRacingEnv({"track": TRACK, "grip_scale_range": [0.6, 0.9]})
    first = [env.reset(seed=s)[1]["grip_scale"] for s in range(20)]
    again = [env.reset(seed=s)[1]["grip_scale"] for s in range(20)]
    assert first == again
    assert all(0.6 <= g <= 0.9 for g in first) and len(set(first)) == 20
    # unseeded resets keep drawing from the seeded stream: a new grip each episode
    env.reset(seed=3)
    follow = [env.reset()[1]["grip_scale"] for _ in range(5)]
    assert len(set(follow)) == 5 and all(0.6 <= g <= 0.9 for g in follow)
    # the vector env: each car its own grip, the same for the same seed, redrawn at autoreset
    vec = FormulaRacingVectorEnv(8, {"track": TRACK, "grip_scale_range": [0.5, 1.2],
                                     "max_steps": 2})
    grips = vec.reset(seed=7)[1]["grip_scale"]
    assert np.array_equal(grips, vec.reset(seed=7)[1]["grip_scale"])
    assert len(set(grips.tolist())) == 8 and ((grips >= 0.5) & (grips <= 1.2)).all()
    idle = np.zeros((8, 3))
    vec.step(idle)
    vec.step(idle)  # truncated at max_steps 2
    redrawn = vec.step(idle)[4]["grip_scale"]
    assert ((redrawn >= 0.5) & (redrawn <= 1.2)).all() and not np.array_equal(redrawn, grips)


def _rollout(env, actions: np.ndarray) -> np.ndarray:
    out = []
    for a in actions:
        obs = env.step(a)[0]
        out.append(obs[0] if obs.ndim == 2 else obs)
    return np.array(out)


def test_a_drawn_grip_drives_exactly_like_that_fixed_grip_scale() -> None:
    """The per-car factor in the kernel: a vector car at drawn grip g is the single env at
    grip_scale g, bit for bit (g - 1 + 1 == g in [0.5, 2])."""
    rng = np.random.default_rng(0)
    actions = rng.uniform([-0.3, 0.5, 0.0], [0.3, 1.0, 0.3], size=(150, 3))
    # no ends: the vector car would autoreset (and draw again) where the single env goes on
    base = {"track": TRACK, "terminate_off_track": False, "terminate_backwards": False,
            "terminate_slow": False}
    vec = FormulaRacingVectorEnv(1, {**base, "grip_scale_range": [0.55, 0.95]})
    grip = float(vec.reset(seed=11)[1]["grip_scale"][0])
    single = FormulaRacingEnv({**base, "grip_scale": grip})
    single.reset(seed=0)
    drawn = _rollout(vec, actions[:, None, :])
    fixed = _rollout(single, actions)
    assert np.array_equal(drawn, fixed)
    own = K.ST_GRIP_DELTA  # every state column but the grip factor itself
    assert (vec._b.state[0, :own] == single.unwrapped._b.state[0, :own]).all()
    # and the grip matters: the same actions at grip 1 give another trajectory
    dry = FormulaRacingEnv(base)
    dry.reset(seed=0)
    assert not np.array_equal(_rollout(dry, actions), fixed)


def test_drying_track_rises_linearly_with_distance_to_the_dry_grip() -> None:
    over_laps = 0.1  # dry after 10 % of the ~1303 m lap
    env = FormulaRacingEnv({"track": TRACK, "grip_scale": 1.2, "start_speed_mps": 20.0,
                            "grip_drying": {"start": 0.6, "over_laps": over_laps}})
    info = env.reset(seed=0)[1]
    assert info["grip_scale"] == pytest.approx(0.6, abs=1e-12)
    dry_m = over_laps * TRACK.length_m
    seen = []
    for _ in range(40):
        dist_before = info["distance_m"]
        info = env.step(np.array([0.0, 1.0, 0.0]))[4]
        expected = 0.6 + (1.2 - 0.6) * min(max(dist_before / dry_m, 0.0), 1.0)
        assert info["grip_scale"] == pytest.approx(expected, abs=1e-12)
        seen.append(info["grip_scale"])
    assert seen[0] < 0.8 and seen[-1] == pytest.approx(1.2, abs=1e-12)
    assert info["distance_m"] > dry_m
    # every car of a vector env starts wet, and is wet again after its autoreset
    vec = FormulaRacingVectorEnv(3, {"track": TRACK, "grip_scale": 1.2, "max_steps": 3,
                                     "start_speed_mps": 20.0,
                                     "grip_drying": {"start": 0.6, "over_laps": over_laps}})
    assert np.allclose(vec.reset(seed=0)[1]["grip_scale"], 0.6, atol=1e-12)
    full = np.tile([0.0, 1.0, 0.0], (3, 1))
    grips = [vec.step(full)[4]["grip_scale"] for _ in range(4)]
    assert (grips[2] > grips[0]).all() and np.allclose(grips[3], 0.6, atol=1e-12)


@pytest.mark.parametrize("bad, needle", [
    ({"grip_scale_range": [0.9, 0.6]}, "lo 0.9 above hi 0.6"),
    ({"grip_scale_range": [0.1, 0.6]}, "'grip_scale_range.0'"),
    ({"grip_scale_range": [0.6, 0.9], "grip_scale": 0.8}, "leave grip_scale at 1"),
    ({"grip_scale_range": [0.6, 0.9], "grip_drying": {"start": 0.5, "over_laps": 1}},
     "set one, not both"),
    ({"grip_drying": {"start": 0.5}}, "'grip_drying.over_laps'"),
    ({"grip_drying": {"start": 2.0, "over_laps": 1}}, "'grip_drying.start'"),
])
def test_bad_grip_settings_name_the_key(bad, needle) -> None:
    with pytest.raises(UserInputError) as err:
        EnvSettings.parse(bad, "study.toml: env_overrides")
    assert needle in str(err.value) and str(err.value).startswith("study.toml: env_overrides")
    assert "\n" not in str(err.value)


# --- lower grip: a slower follower and a slower reference limit -------------------------------


def test_lower_grip_raises_the_follower_lap_and_the_reference_limit(line_cache) -> None:
    car = CarParams()
    offsets = reference_offsets(TRACK, "mincurv", car)
    limits = {g: reference_limit_s(TRACK, car, grip_scale=g) for g in (1.0, 0.8, 0.6)}
    assert limits[1.0] < limits[0.8] < limits[0.6]
    assert limits[0.8] == lap_time_s(TRACK, offsets, car, grip_scale=0.8)
    assert limits[1.0] == reference_limit_s(TRACK, car)  # grip 1 is the limit of before
    laps = {g: drive(TRACK, offsets, laps=2, car=car, env_config={"grip_scale": g})
            for g in (1.0, 0.8)}
    assert all(r["finished"] and r["damage"] == 0.0 for r in laps.values())
    assert laps[0.8]["best_lap_s"] > laps[1.0]["best_lap_s"] + 0.5
    # each lap stays above the limit at its own grip
    assert all(laps[g]["best_lap_s"] > limits[g] for g in laps)


# --- train on one grip, test on another, report lap / limit per grip ----------------------------


def _spec(**schedule):
    return build_run_spec(
        variant="WIN1", overrides=SMALL, train_tracks=["ring"], device="cpu", seed=3,
        schedule={"episodes": 2, "max_steps": 40, "test_every_episodes": 2, "test_starts": 2,
                  "test_max_steps": 50, **schedule},
    )  # fmt: skip


def test_test_grips_are_declared_once_and_keep_the_old_digest(ring_tracks) -> None:
    assert _spec().digest() == _spec(test_grip_scales=[]).digest()
    assert "test_grip_scales" not in _spec().to_json()["schedule"]
    assert "grip_scale_range" not in _spec().to_json()["env"]
    spec = _spec(test_grip_scales=[0.8, 1.0])
    assert spec.test_grips == (1.0, 0.8) and spec.digest() != _spec().digest()
    with pytest.raises(UserInputError, match="list each grip once"):
        _spec(test_grip_scales=[0.8, 0.8])
    with pytest.raises(UserInputError, match="test_grip_scales.0"):
        _spec(test_grip_scales=[0.1])


def _index(root, job_dir_rel: str) -> None:
    con = sqlite3.connect(root / L.INDEX_FILE)
    con.executescript(L.INDEX_SCHEMA)
    attrs = {"study": "s", "entrant": "win1", "variant": "WIN1", "family": "win", "seed": 3,
             "reference": "centre", "lac": False, "train_tracks": ["ring"]}
    con.execute("INSERT INTO jobs (job_id, kind, part, status, path, attrs) "
                "VALUES (?, 'train', 'wet', 'done', ?, ?)",
                (job_dir_rel, job_dir_rel, json.dumps(attrs)))
    con.execute("INSERT INTO parts (part, study, position, status, entrants, promoted) VALUES "
                "('wet', 's', 0, 'done', '[\"win1\"]', '[]')")
    con.commit()
    con.close()


def test_trained_at_grip_1_tested_at_08_records_both_and_reports_lap_over_limit(
        tmp_path, ring_tracks, line_cache) -> None:
    root = tmp_path / "results" / "wet-cup"
    rel = L.job_rel_path("wet", "win1", 3)
    spec = _spec(test_grip_scales=[0.8])
    loop.train(spec, root / rel)
    folder = JobFolder(root / rel)
    tests = folder.grip_tests()
    ring = ring_track("ring")
    car = spec.env.car_params()
    limit = {g: reference_limit_s(ring, car, grip_scale=g) for g in (1.0, 0.8)}
    assert limit[0.8] > limit[1.0]
    assert sorted(tests.grip_scale.unique()) == [0.8, 1.0]
    for g in (1.0, 0.8):
        rows = tests.loc[tests.grip_scale == g]
        assert len(rows) == 2 and (rows.reference_limit_s == limit[g]).all()
    assert sorted(folder.laps().grip_scale.unique().tolist()) in ([], [1.0])
    # promotion, the index and the paper's tables read the run's own grip only
    own = folder.tests()
    assert (own.grip_scale == 1.0).all() and len(own) == 2
    summary = json.loads((root / rel / L.SUMMARY_FILE).read_text())
    assert summary["damage"] == float(own.damage.sum())

    # known laps, to check the report's arithmetic: 5 % over the dry limit, 8 % over the wet
    table = pd.read_parquet(folder.table_path("tests"))
    table["damage"] = 0.0
    table["finished"] = True
    table["best_lap_s"] = np.where(table.grip_scale == 1.0, 1.05 * limit[1.0], 1.08 * limit[0.8])
    table.to_parquet(folder.table_path("tests"))
    _index(root, rel)
    report = build_report("wet-cup", results_dir=tmp_path / "results", formats=("markdown",),
                          out_dir=tmp_path / "report", claims=None, figures=False)
    assert "Lap time over the reference limit at each grip" in report.markdown
    grip = next(t for t in report.tables if t.key == "grip")
    assert grip.groups == ["wet: ring MOT @ grip 1", "wet: ring MOT @ grip 0.8"]
    limit_row = next(r for r in grip.rows if r["kind"] == "limit")
    entrant = next(r for r in grip.rows if r["kind"] == "entrant")
    for group, g, over in zip(grip.groups, (1.0, 0.8), (1.05, 1.08), strict=True):
        assert limit_row["values"][(group, "bLT")] == limit[g]
        assert entrant["values"][(group, "bLT")] == pytest.approx(over * limit[g], rel=1e-12)
        assert entrant["values"][(group, "lap/limit")] == pytest.approx(over, rel=1e-12)
        assert entrant["text"][(group, "lap/limit")] == f"{over:.3f}"
    # Table 1 (the run's own grip) is unchanged by the wet tests
    t1 = next(t for t in report.tables if t.key == "table1")
    row = next(r for r in t1.rows if r["kind"] == "entrant")
    assert row["values"][(t1.groups[0], "bLT")] == pytest.approx(1.05 * limit[1.0], rel=1e-12)


def test_a_layout_2_folder_without_grip_columns_still_reads(tmp_path) -> None:
    folder = JobFolder(tmp_path / "job")
    folder.write_config({"env": {"grip_scale": 0.7}})
    old_tests = [c for c in L.JOB_TABLES["tests"] if c not in L.ADDED_COLUMNS["tests"]]
    row = {c: 0 for c in old_tests} | {"track": "oval", "termination": "max_steps",
                                       "checkpoint": "", "finished": True, "best_lap_s": 30.0}
    pd.DataFrame([row], columns=old_tests).to_parquet(folder.table_path("tests"))
    tests = folder.tests()
    assert list(tests.columns) == L.JOB_TABLES["tests"]
    assert tests.grip_scale.tolist() == [0.7] and tests.reference_limit_s.isna().all()
    assert len(folder.grip_tests()) == 1


def test_kernel_state_has_a_zero_default_grip_column() -> None:
    """Race cars and any zero-filled state row keep the track's grip (no multiply)."""
    assert K.ST_GRIP_DELTA == K.N_STATE - 1
    env = FormulaRacingEnv({"track": TRACK})
    env.reset(seed=0)
    assert env.unwrapped._b.state[0, K.ST_GRIP_DELTA] == 0.0


# --- tournament setups: declared once, flowing to every job, bad values exit 2 ----------------

GRIP_TOURNEY = """\
name = "grip"

[defaults]
episodes = 3
test_grip_scales = {grips}
env_overrides = {env}

[[parts]]
name = "wet"
entrants = ["WIN1"]
train_tracks = ["oval"]
"""


def _tourney(tmp_path, grips: str = "[0.8, 0.6]", env: str = "{ grip_scale_range = [0.7, 1.0] }"):
    path = tmp_path / "grip.toml"
    path.write_text(GRIP_TOURNEY.format(grips=grips, env=env), encoding="utf-8")
    return path


def test_a_tournament_declares_train_and_test_grips_for_its_jobs(tmp_path) -> None:
    _planner, planned, _root = plan_tournament(_tourney(tmp_path), tmp_path / "res")
    job = planned[0].jobs[0]
    spec = RunSpec.from_json(job.spec, "job")
    assert spec.env.grip_scale_range == (0.7, 1.0) and spec.test_grips == (1.0, 0.8, 0.6)
    assert job.config_hash == spec.digest()
    # training draws from the range; each test runs at one fixed grip
    envs = RunEnvs(spec)
    train = envs.config("oval", test=False)
    assert train.grip_scale_range == (0.7, 1.0)
    for grip in spec.test_grips:
        test = envs.config("oval", test=True, grip_scale=grip)
        assert test.grip_scale == grip and test.grip_scale_range is None


@pytest.mark.parametrize("edit, expected", [
    ({"grips": "[0.8, 0.8]"}, "test_grip_scales: [0.8, 0.8]: list each grip once"),
    ({"grips": "[2.0]"}, "grip.toml:5: defaults.test_grip_scales[0]: Input should be less than or "
     "equal to 1.5"),
    ({"env": "{ grip_scale_range = [0.9, 0.5] }"}, "grip_scale_range: lo 0.9 above hi 0.5"),
])
def test_bad_grip_settings_in_a_tournament_exit_2_writing_nothing(
        tmp_path, capsys, edit, expected) -> None:
    path = _tourney(tmp_path, **edit)
    results = tmp_path / "res"
    with pytest.raises(SystemExit) as info:
        main(["run", str(path), "--results", str(results), "--dry-run"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert expected in err and str(path) in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert not results.exists()


def test_cli_trains_on_one_grip_tests_on_another_and_evals_at_a_third(
        tmp_path, ring_tracks, line_cache, capsys) -> None:
    out = tmp_path / "cli"
    main([
        "train", "--variant", "WIN1", "--track", "ringA", "--episodes", "1", "--max-steps", "30",
        "--test-starts", "1", "--test-max-steps", "30", "--set", "hidden=[16,16]",
        "--set", "batch_size=16", "--set", "learning_starts=20", "--set", "buffer_size=1000",
        "--env-set", "grip_scale_range=[0.6,0.9]", "--test-grip", "0.7", "--out", str(out),
        "--json",
    ])  # fmt: skip
    capsys.readouterr()
    spec = RunSpec.from_json(JobFolder(out).config(), "config.json")
    assert spec.env.grip_scale_range == (0.6, 0.9) and spec.test_grips == (1.0, 0.7)
    assert sorted(JobFolder(out).grip_tests().grip_scale) == [0.7, 1.0]
    main(["eval", str(out / "checkpoints" / "last.pt"), "--track", "ringA", "--starts", "1",
          "--max-steps", "20", "--grip", "0.5", "--json"])  # fmt: skip
    assert json.loads(capsys.readouterr().out)["grip_scale"] == 0.5
    with pytest.raises(SystemExit) as exc:
        main(["eval", str(out / "checkpoints" / "last.pt"), "--track", "ringA", "--grip", "3"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "grip_scale" in err and "1.5" in err and "Traceback" not in err, err

"""The plan builds every job's run specification in the parent: settings land where they belong,
and every bad value (env overrides, tracks, promoted variants) is an error at its line before
anything is written, for ``run`` and ``run --dry-run`` alike."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from formula_tourney.cli import main
from formula_tourney.errors import UserInputError
from formula_tourney.results.folder import BaselineFolder
from formula_tourney.tourney.api import plan_tournament, run_tournament
from formula_tourney.tourney.jobs import Job
from formula_tourney.tourney.runner import run_job
from formula_tourney.training.run_spec import RunSpec

REPO = Path(__file__).resolve().parents[1]

BASE = """\
name = "plan"
seed_base = 7

[defaults]
episodes = 3
test_max_steps = 77
env_overrides = {env}

[[parts]]
name = "p1"
entrants = ["WIN1", "PER40k"]
train_tracks = [{track}]
setups = [{{ reference = "centre", lac = true }}]

[[parts]]
name = "p2"
promoted_from = "p1"
train_tracks = ["oval"]
{p2}
"""


def write(tmp_path: Path, env: str = "{}", track: str = '"oval"', p2: str = "") -> Path:
    path = tmp_path / "plan.toml"
    path.write_text(BASE.format(env=env, track=track, p2=p2), encoding="utf-8")
    return path


def line_of(path: Path, needle: str) -> int:
    lines = path.read_text(encoding="utf-8").splitlines()
    return next(i for i, line in enumerate(lines, start=1) if needle in line)


def test_settings_go_to_their_owners(tmp_path: Path) -> None:
    """Schedule from [defaults], LAC from the setup, env keys into spec.env, seed_base + n, and
    a relative track path resolved against the tournament file's folder."""
    shutil.copy(REPO / "formula_tourney/sim/tracks/oval.toml", tmp_path / "mine.toml")
    path = write(tmp_path, env="{ slow_patience_steps = 5 }", track='"mine.toml"',
                 p2="seeds = 2")
    planner, planned, _root = plan_tournament(path, tmp_path / "res")
    job = planned[0].jobs[0]
    spec = RunSpec.from_json(job.spec, "job")
    assert spec.schedule.episodes == 3 and spec.schedule.test_max_steps == 77
    assert spec.lac is True and spec.reference == "centre"
    assert spec.env.slow_patience_steps == 5 and spec.env.slow_penalty == 100.0
    assert spec.seed == 7
    assert spec.train_tracks == (str((tmp_path / "mine.toml").resolve()),)
    assert job.config_hash == spec.digest()
    second = planner.jobs(1, ["WIN1"])[1]
    assert second.spec["seed"] == 8 and second.job_id == "p2/WIN1-MOT/seed-1"
    assert not (tmp_path / "res").exists()


@pytest.mark.parametrize(
    ("env", "hint"),
    [
        ("{ lac = false }", "'lac' is a run setting, not an env override: set it with the "
         "setup's lac"),
        ("{ max_steps = 50 }", "set it with max_steps (training) and test_max_steps (tests)"),
    ],
)
def test_env_override_of_a_run_setting_is_refused(tmp_path: Path, env: str, hint: str) -> None:
    """Bug 2: such an override used to win silently over the setup's LAC and test_max_steps."""
    path = write(tmp_path, env=env)
    with pytest.raises(UserInputError) as info:
        run_tournament(path, results_dir=tmp_path / "res", dry_run=True)
    text = str(info.value)
    assert f"{path}:{line_of(path, 'env_overrides')}: defaults.env_overrides: " in text, text
    assert hint in text, text


@pytest.mark.parametrize(
    ("edit", "needle", "expected"),
    [
        ({"env": "{ slow_patience_step = 5 }"}, "env_overrides",
         "defaults.env_overrides.slow_patience_step: unknown key; allowed keys: "
         "lac_distances_m, control_period_s"),
        ({"env": "{ slow_patience_steps = 0 }"}, "env_overrides",
         "defaults.env_overrides.slow_patience_steps: Input should be greater than or equal to 1"),
        ({"track": '"gen-99999999999"'}, "train_tracks = [\"gen-",
         "parts[0].train_tracks: track 'gen-99999999999': seed 99999999999 is out of range"),
        ({"p2": "variant_overrides = { batch_size = 50000 }"}, "variant_overrides",
         "parts[1].variant_overrides: "),
    ],
)
@pytest.mark.parametrize("dry_run", [False, True])
def test_bad_values_exit_2_before_anything_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture, edit: dict, needle: str, expected: str,
    dry_run: bool,
) -> None:
    """Bug 3: these ran, wrote the index and job folders, and failed in every worker. The last
    case can only reach p2 by promotion (PER40k's buffer is smaller than the batch)."""
    path = write(tmp_path, **edit)
    results = tmp_path / "res"
    with pytest.raises(SystemExit) as info:
        main(["run", str(path), "--results", str(results), *(["--dry-run"] if dry_run else [])])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert f"error: {path}:{line_of(path, needle)}: {expected}" in err, err
    assert "Traceback" not in err
    assert not results.exists()


DEMO_FILE = """\
name = "demo-plan"

[variants.WIN1-demo]
base = "WIN1"
demos = {{ laps = 2, line = "centre", bc_steps = 10 }}

[[parts]]
name = "p1"
entrants = ["WIN1", "WIN1-demo", "SAC"]
train_tracks = ["oval"]
cars = {cars}
"""


def test_demos_and_cars_reach_the_run_spec_and_are_labelled(tmp_path: Path) -> None:
    path = tmp_path / "demo.toml"
    path.write_text(DEMO_FILE.format(cars=2), encoding="utf-8")
    _planner, planned, _root = plan_tournament(path, tmp_path / "res")
    specs = {job.meta["variant"]: RunSpec.from_json(job.spec, job.job_id)
             for job in planned[0].jobs}
    assert specs["WIN1"].demos is None and specs["WIN1"].schedule.cars == 2
    assert specs["WIN1-demo"].demos.laps == 2 and specs["WIN1-demo"].demos.bc_steps == 10
    assert specs["WIN1"].beyond_paper() == ["2 cars"]
    assert specs["WIN1-demo"].beyond_paper() == ["demos (follower on centre)", "2 cars"]
    assert specs["SAC"].beyond_paper() == ["SAC", "2 cars"]


def test_bad_demo_or_car_settings_fail_at_their_line(tmp_path: Path) -> None:
    path = tmp_path / "demo.toml"
    path.write_text(DEMO_FILE.format(cars=0), encoding="utf-8")
    with pytest.raises(UserInputError, match=rf"demo.toml:{line_of(path, 'cars =')}: "):
        plan_tournament(path, tmp_path / "res")
    path.write_text(DEMO_FILE.format(cars=1).replace("laps = 2", "lapz = 2"), encoding="utf-8")
    with pytest.raises(UserInputError, match=rf"demo.toml:{line_of(path, 'lapz')}: .*lapz"):
        plan_tournament(path, tmp_path / "res")
    assert not (tmp_path / "res").exists()


BUDGET_FILE = """\
name = "budget-plan"

[defaults]
env_steps = 90000

[variants.WIN1]
env_steps = {win1}

[[parts]]
name = "p1"
entrants = ["WIN1", "WIN4"]
train_tracks = ["oval"]

[[parts]]
name = "p2"
entrants = ["WIN4"]
train_tracks = ["oval"]
env_steps = 35000
"""


def test_env_step_budgets_resolve_variant_then_part_then_defaults(tmp_path: Path) -> None:
    """A variant entry's budget wins over the part's, the part's over [defaults]; a bad
    budget fails at its line before anything is written."""
    path = tmp_path / "budget.toml"
    path.write_text(BUDGET_FILE.format(win1=50000), encoding="utf-8")
    _planner, planned, _root = plan_tournament(path, tmp_path / "res")
    budgets = {(part.part.name, job.meta["variant"]): RunSpec.from_json(job.spec, job.job_id)
               .schedule.env_steps for part in planned for job in part.jobs}  # fmt: skip
    assert budgets == {("p1", "WIN1"): 50000, ("p1", "WIN4"): 90000, ("p2", "WIN4"): 35000}
    path.write_text(BUDGET_FILE.format(win1=0), encoding="utf-8")
    with pytest.raises(UserInputError, match=rf"budget.toml:{line_of(path, 'env_steps = 0')}: "):
        plan_tournament(path, tmp_path / "res")
    assert not (tmp_path / "res").exists()


def test_dry_run_shows_an_entrants_own_budget(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A variant entry's env_steps wins over the part's: the plan says so per entrant (the demo's
    first plan showed only the part's 40k while WIN4 trained 65k)."""
    path = tmp_path / "budget.toml"
    path.write_text(BUDGET_FILE.format(win1=50000), encoding="utf-8")
    main(["run", str(path), "--results", str(tmp_path / "res"), "--dry-run", "--json"])
    parts = json.loads(capsys.readouterr().out)["plan"]["parts"]
    assert [p["entrant_settings"] for p in parts] == [{"WIN1": {"env_steps": 50000}}, {}]
    assert [p["env_steps"] for p in parts] == [90000, 35000]
    main(["run", str(path), "--results", str(tmp_path / "res"), "--dry-run"])
    assert "WIN1 sets env_steps=50000 (its entry wins)" in capsys.readouterr().out
    assert not (tmp_path / "res").exists()


def test_the_demo_trains_each_job_on_its_declared_budget(tmp_path: Path) -> None:
    """quick.toml's comments give each job's env steps; the planner must agree (WIN1 40k on the
    oval but 85k on technical, WIN4 65k): a variant-level budget would win over the part's."""
    quick = Path(__file__).resolve().parents[1] / "tournaments" / "quick.toml"
    _planner, planned, _root = plan_tournament(quick, tmp_path / "res")
    budgets = {(part.part.name, job.meta["variant"]): RunSpec.from_json(job.spec, job.job_id)
               .schedule.env_steps for part in planned for job in part.jobs}  # fmt: skip
    assert budgets == {("p1-oval", "WIN1"): 40000, ("p1-oval", "WIN4"): 65000,
                       ("p2-technical", "WIN1"): 85000}
    technical = [RunSpec.from_json(job.spec, job.job_id) for job in planned[1].jobs]
    assert {(s.preset, s.schedule.test_starts, s.schedule.test_every_episodes) for s in technical} \
        == {("tuned-bc", 3, 5)}
    assert {(s.demos.laps, s.demos.bc_weight) for s in technical} == {(10, 0.2)}  # the preset's


def test_baselines_drive_the_parts_car_and_a_changed_car_drives_again(tmp_path: Path) -> None:
    """A bot row is an anchor only in the entrants' car: the part's ``env_overrides.car`` goes
    into the baseline job (and its hash), the follower drives it, and a folder holding the drive
    of another car is driven anew rather than reported."""
    baselines = 'baselines = [{ bot = "follower", reference = "centre", laps = 2 }]'
    path = write(tmp_path, env="{ car = { mu = 1.4 } }", p2=baselines)
    _planner, planned, _root = plan_tournament(path, tmp_path / "res")
    job = planned[1].baselines[0]
    assert job.spec["car"] == {"mu": 1.4}
    (tmp_path / "default").mkdir()
    default_path = write(tmp_path / "default", p2=baselines)
    _p, default_planned, _r = plan_tournament(default_path, tmp_path / "res-default")
    default_job = default_planned[1].baselines[0]
    assert default_job.spec["car"] == {} and default_job.config_hash != job.config_hash

    slippery = run_job(job)
    assert slippery["car"] == {"mu": 1.4} and slippery["config_hash"] == job.config_hash
    assert BaselineFolder(job.out_dir).holds(job.config_hash)
    # the default car's drive into the same folder: the old result is not taken for it
    moved = Job(job_id=job.job_id, kind="baseline", part=job.part, out_dir=job.out_dir,
                spec=default_job.spec, config_hash=default_job.config_hash, meta=job.meta)
    grippy = run_job(moved)
    assert grippy["car"] == {} and grippy["config_hash"] == default_job.config_hash
    # less grip: a slower lap and a slower limit (the oval follower: 35.37 s at mu 1.6)
    assert grippy["best_lap_s"] == pytest.approx(35.37, abs=0.05)
    assert slippery["best_lap_s"] > grippy["best_lap_s"] + 0.5
    assert slippery["reference_limit_s"] > grippy["reference_limit_s"]

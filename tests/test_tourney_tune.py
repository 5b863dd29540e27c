"""Optuna pre-selection: a study in a journal file that resumes, retries a trial left RUNNING by
a dead process, and writes its best parameters into a tournament file; objectives of the best
lap or of CPU-seconds to a milestone."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import pytest

from formula_tourney.errors import UserInputError
from formula_tourney.tourney.spec import load_spec
from formula_tourney.tourney.tune.best_params import write_best_params
from formula_tourney.tourney.tune.run import objective_threshold, run_tune
from formula_tourney.tourney.tune.spec import Objective, check_tune, load_tune_spec
from formula_tourney.tourney.tune.study import suggest
from formula_tourney.tourney.tune.worker import CpuMilestone

TUNE = """\
name = "tinytune"
max_retry = 1

[train]
train_tracks = ["oval"]
episodes = 2
max_steps = 30
test_every_episodes = 1
test_starts = 1
test_max_steps = 30
device = "cpu"

[search]
actor_lr = { low = 1e-5, high = 1e-3, log = true }
batch_size = { choices = [16] }
hidden = { choices = [[32, 32]] }
learning_starts = { low = 16, high = 32, step = 16 }

[sampler]
seed = 3
n_startup_trials = 2

[pruner]
kind = "median"
n_startup_trials = 1
"""

TOURNAMENT = """\
name = "target"
# a comment that must survive

[variants.WIN4]
family = "DDPG"

[[parts]]
name = "p1"
entrants = ["WIN4"]
train_tracks = ["oval"]
"""


def test_search_keys_are_checked_with_line(tmp_path: Path) -> None:
    path = tmp_path / "t.toml"
    path.write_text(TUNE.replace("actor_lr = {", "actor_lrr = {"), encoding="utf-8")
    with pytest.raises(UserInputError, match=r"t.toml:14: search.actor_lrr: unknown hyper.*"
                       r"allowed values: .*actor_lr"):
        load_tune_spec(path)


def test_write_best_merges_into_the_variant(tmp_path: Path) -> None:
    target = tmp_path / "target.toml"
    target.write_text(TOURNAMENT, encoding="utf-8")
    write_best_params(target, "WIN4", {"actor_lr": 3e-4, "batch_size": 64})
    write_best_params(target, "WIN4", {"actor_lr": 2e-4})
    write_best_params(target, "MS2", {"gamma": 0.98})
    text = target.read_text()
    assert "# a comment that must survive" in text
    raw = tomllib.loads(text)
    assert raw["variants"]["WIN4"] == {"family": "DDPG",
                                       "overrides": {"actor_lr": 2e-4, "batch_size": 64}}
    assert raw["variants"]["MS2"]["overrides"] == {"gamma": 0.98}
    load_spec(target)
    with pytest.raises(UserInputError, match="variant WIN4 overrides"):
        write_best_params(target, "WIN4", {"batch_size": -1})
    assert tomllib.loads(target.read_text())["variants"]["WIN4"]["overrides"]["batch_size"] == 64

    # parameters tuned around a preset take the preset along (tune's [train] preset)
    write_best_params(target, "WIN4", {"actor_lr": 1e-4}, preset="fast-small")
    write_best_params(target, "WIN4", {"actor_lr": 1e-4}, preset="tuned-bc")
    write_best_params(target, "WIN1", {"batch_size": 32}, preset="fast-small")
    raw = tomllib.loads(target.read_text())
    assert raw["variants"]["WIN4"]["preset"] == "tuned-bc"
    assert raw["variants"]["WIN4"]["overrides"]["batch_size"] == 64
    assert raw["variants"]["WIN1"] == {"preset": "fast-small", "overrides": {"batch_size": 32}}
    sub = tmp_path / "sub.toml"
    sub.write_text(TOURNAMENT.replace('[variants.WIN4]\nfamily = "DDPG"\n',
                                      "[variants.WIN4.overrides]\ngamma = 0.98\n"))
    write_best_params(sub, "WIN4", {"actor_lr": 1e-4}, preset="fast-small")
    assert tomllib.loads(sub.read_text())["variants"]["WIN4"] == {
        "preset": "fast-small", "overrides": {"gamma": 0.98, "actor_lr": 1e-4}}


def test_study_resumes_and_retries_a_killed_trial(tmp_path: Path) -> None:
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend
    from optuna.trial import TrialState

    path = tmp_path / "tune.toml"
    path.write_text(TUNE, encoding="utf-8")
    target = tmp_path / "target.toml"
    target.write_text(TOURNAMENT, encoding="utf-8")
    results = tmp_path / "res"
    first = run_tune(path, "WIN4", trials=2, workers=1, results_dir=results)
    assert first["counts"]["COMPLETE"] + first["counts"]["PRUNED"] == 2
    journal = results / "tinytune" / "optuna" / "WIN4.journal"
    assert journal.is_file()
    with pytest.raises(UserInputError, match="add --resume"):
        run_tune(path, "WIN4", trials=3, workers=1, results_dir=results)

    # A trial left RUNNING by a process that died (as after kill -9 of a whole run).
    storage = JournalStorage(JournalFileBackend(str(journal)))
    study = optuna.load_study(study_name="tinytune-WIN4", storage=storage)
    orphan = study.ask()
    suggest(orphan, load_tune_spec(path)[0].search)

    second = run_tune(path, "WIN4", trials=4, workers=1, resume=True, results_dir=results,
                      write_best=target)
    assert second["counts"]["COMPLETE"] + second["counts"]["PRUNED"] == 4
    study = optuna.load_study(study_name="tinytune-WIN4", storage=storage)
    trials = study.get_trials()
    assert trials[orphan.number].state == TrialState.FAIL
    assert trials[orphan.number].system_attrs["fail_reason"].startswith("process died")
    retry = [t for t in trials if t.system_attrs.get("failed_trial") == orphan.number]
    assert len(retry) == 1 and retry[0].params == trials[orphan.number].params
    assert retry[0].state in (TrialState.COMPLETE, TrialState.PRUNED)
    best = second["best"]
    assert best is not None
    written = tomllib.loads(target.read_text())["variants"]["WIN4"]["overrides"]
    assert written["actor_lr"] == best["params"]["actor_lr"]
    assert written["hidden"] == [32, 32]


def test_rdb_storage_url_runs_with_heartbeats(tmp_path: Path) -> None:
    """--storage URL (an RDB for many machines): same study, Optuna's heartbeats switched on."""
    import optuna

    path = tmp_path / "tune.toml"
    path.write_text(TUNE, encoding="utf-8")
    url = f"sqlite:///{tmp_path / 'studies.db'}"
    result = run_tune(path, "MS2", trials=1, workers=1, storage=url,
                      results_dir=tmp_path / "res")
    assert result["storage"] == url
    assert result["counts"]["COMPLETE"] + result["counts"]["PRUNED"] == 1
    storage = optuna.storages.RDBStorage(url)
    study = optuna.load_study(study_name="tinytune-MS2", storage=storage)
    assert len(study.get_trials()) == 1
    assert not (tmp_path / "res" / "tinytune" / "optuna").exists()  # no journal file


def test_two_workers_draw_different_parameters(tmp_path: Path) -> None:
    """Workers that all sampled from [sampler] seed gave trials 0 and 1 identical parameters:
    each worker has its own stream derived from the seed."""
    path = tmp_path / "tune.toml"
    path.write_text(TUNE.replace("seed = 3", "seed = 0"), encoding="utf-8")
    result = run_tune(path, "WIN1", trials=2, workers=2, results_dir=tmp_path / "res")
    # a worker done first may start a third trial before the other one finishes (Optuna counts
    # finished trials only), so look at all of them
    lrs = [t["params"]["actor_lr"] for t in result["trials"]]
    assert len(lrs) >= 2 and len(set(lrs)) == len(lrs), result["trials"]


def test_search_values_are_built_into_run_specs_before_the_study(tmp_path: Path) -> None:
    """A search corner no run spec accepts fails in the parent, naming the line, and no study
    is created."""
    path = tmp_path / "tune.toml"
    path.write_text(TUNE.replace("batch_size = { choices = [16] }",
                                 "batch_size = { choices = [16, 0] }"), encoding="utf-8")
    with pytest.raises(UserInputError, match=r"tune.toml:15: search.batch_size: 0 is not a valid "
                       r"batch_size for WIN4"):
        run_tune(path, "WIN4", trials=1, workers=1, results_dir=tmp_path / "res")
    assert not (tmp_path / "res").exists()


# --- CPU-seconds to competence ([objective]) ------------------------------------------------
def test_cpu_objective_arithmetic_on_a_scripted_run() -> None:
    """The value is the CPU-s of the first episode whose best_lap_s is below the threshold
    (strictly); a miss scores budget x penalty_factor; the pruner's sequence never rises."""
    beat = Objective(kind="cpu_s_to_beat_follower", budget_cpu_s=100.0, penalty_factor=3.0)
    clock = CpuMilestone(beat, threshold_s=35.0)
    laps = [None, 41.2, 35.0, 35.0, 34.9]  # 35.0 ties the follower: not beaten
    cpu = [10.0, 20.0, 30.0, 40.0, 55.5]
    stops, projected = [], []
    for episode, (lap, cpu_s) in enumerate(zip(laps, cpu, strict=True), start=1):
        stops.append(clock.update({"episode": episode, "best_lap_s": lap, "env_steps": 100,
                                   "cpu_s": cpu_s}))
        projected.append(clock.projected())
    assert stops == [False, False, False, False, True]
    assert clock.value() == 55.5 and clock.hit == {"cpu_s": 55.5, "episode": 5, "lap_s": 34.9,
                                                  "env_steps": 100}
    assert projected == [300.0, 300.0, 300.0, 300.0, 55.5]  # non-increasing: median-prunable
    assert clock.step() == 55
    series = clock.series()
    assert len(series) == 101 and series[54] == 300.0 and series[55] == series[100] == 55.5

    # the first clean lap: any finite lap; a miss when the budget passes first
    first = Objective(kind="cpu_s_to_first_clean_lap", budget_cpu_s=25.0)
    clock = CpuMilestone(first, threshold_s=math.inf)
    assert clock.update({"episode": 1, "best_lap_s": None, "cpu_s": 12.0}) is False
    assert clock.update({"episode": 2, "best_lap_s": 80.0, "cpu_s": 26.0}) is True  # too late
    assert clock.hit is None and clock.value() == 50.0 and clock.step() == 100
    assert set(clock.series().values()) == {50.0}
    clock = CpuMilestone(first, threshold_s=math.inf)
    assert clock.update({"episode": 1, "best_lap_s": 80.0, "cpu_s": 3.25})
    assert clock.value() == 3.25


def test_median_pruner_cuts_a_trial_behind_on_cpu_seconds() -> None:
    """Optuna's MedianPruner on the reported sequence: with complete trials reaching the
    milestone at 20, 30 and 90 CPU-s, a trial without it is pruned once it has spent more CPU
    than two of them needed, not before."""
    import optuna

    first = Objective(kind="cpu_s_to_first_clean_lap", budget_cpu_s=100.0)
    study = optuna.create_study(pruner=optuna.pruners.MedianPruner(n_startup_trials=3))
    for hit in (20.0, 30.0, 90.0):
        trial = study.ask()
        clock = CpuMilestone(first, math.inf)
        clock.update({"episode": 1, "best_lap_s": 50.0, "cpu_s": hit})
        for step, value in clock.series().items():
            trial.report(value, step)
        study.tell(trial, clock.value())
    trial = study.ask()
    clock = CpuMilestone(first, math.inf)
    verdicts = []
    for cpu_s in (25.0, 35.0):
        clock.update({"episode": 1, "best_lap_s": None, "cpu_s": cpu_s})
        trial.report(clock.projected(), clock.step())
        verdicts.append(trial.should_prune())
    assert verdicts == [False, True]


def test_objective_keys_are_checked_with_line(tmp_path: Path) -> None:
    path = tmp_path / "t.toml"
    n = TUNE.count("\n") + 3  # the line of the first key under an [objective] added at the end
    cases = {
        'kind = "fastest"\n': rf"t.toml:{n}: objective.kind: 'fastest' is not allowed; allowed "
        r"values: best_lap, cpu_s_to_first_clean_lap, cpu_s_to_beat_follower",
        'kind = "cpu_s_to_first_clean_lap"\nbudget_cpu_s = -5\n':
            rf"t.toml:{n + 1}: objective.budget_cpu_s: -5: .*greater than 0; allowed values: "
            r"CPU-seconds > 0",
        'kind = "cpu_s_to_first_clean_lap"\n': rf"t.toml:{n}: objective.kind: "
        r"cpu_s_to_first_clean_lap needs budget_cpu_s",
        'kind = "cpu_s_to_beat_follower"\nline = "recorded"\nbudget_cpu_s = 9\n':
            rf"t.toml:{n + 1}: objective.line: 'recorded' is not allowed; allowed values: "
            r"centre, mincurv",
        "budget = 600\n": rf"t.toml:{n}: objective.budget: unknown key; allowed "
        r"keys: kind, line, budget_cpu_s, penalty_factor",
        "budget_cpu_s = 600\n": rf"t.toml:{n}: objective.budget_cpu_s: only the "
        r"CPU-second kinds",
        'kind = "cpu_s_to_first_clean_lap"\nline = "centre"\nbudget_cpu_s = 9\n':
            rf"t.toml:{n + 1}: objective.line: only kind = cpu_s_to_beat_follower",
    }
    for block, pattern in cases.items():
        path.write_text(_with_objective(block), encoding="utf-8")
        with pytest.raises(UserInputError, match=pattern):
            load_tune_spec(path)
    path.write_text('objectiv = "best_lap"\n' + TUNE, encoding="utf-8")
    with pytest.raises(UserInputError, match=r"t.toml:1: objectiv: unknown key; allowed keys: "
                       r".*objective"):
        load_tune_spec(path)
    path.write_text('objective = "cpu_s_to_beat_follower"\n' + TUNE, encoding="utf-8")
    with pytest.raises(UserInputError, match=r"t.toml:1: objective.kind: .*needs budget_cpu_s"):
        load_tune_spec(path)
    path.write_text(TUNE, encoding="utf-8")
    assert load_tune_spec(path)[0].objective == Objective()  # best_lap, as before


def _with_objective(block: str, tune: str = TUNE) -> str:
    return f"{tune}\n[objective]\n{block}"


def test_follower_lap_to_beat_is_driven_in_the_parent(tmp_path: Path) -> None:
    from formula_tourney.bots.follower import drive
    from formula_tourney.bots.line_offsets import reference_offsets
    from formula_tourney.sim.catalog import load_track

    path = tmp_path / "t.toml"
    path.write_text(_with_objective('kind = "cpu_s_to_beat_follower"\nline = "mincurv"\n'
                                    "budget_cpu_s = 60\n"), encoding="utf-8")
    spec, text = load_tune_spec(path)
    base = check_tune(spec, text, path, "WIN1")
    lap = objective_threshold(spec, base)
    oval = load_track("oval")
    assert lap == drive(oval, reference_offsets(oval, "mincurv"), laps=2)["best_lap_s"]
    assert 20.0 < lap < 60.0
    assert objective_threshold(load_tune_spec(tmp_path / "t.toml")[0].model_copy(
        update={"objective": Objective(kind="cpu_s_to_first_clean_lap", budget_cpu_s=1.0)}),
        base) == math.inf  # fmt: skip
    assert objective_threshold(spec.model_copy(update={"objective": Objective()}), base) is None


def test_cpu_objective_study_around_a_preset_records_its_value(tmp_path: Path) -> None:
    """End to end: one trial of cpu_s_to_first_clean_lap under the fast preset, in a worker
    process on the real clock: 30-step episodes never lap oval, so the trial trains until its
    0.5 CPU-s pass, stops long before its 10000 episodes and scores the miss, 2 x 0.5."""
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    path = tmp_path / "tune.toml"
    tune = TUNE.replace("episodes = 2\n", 'episodes = 10000\npreset = "fast-small"\n'
                        "variant_overrides = { buffer_size = 5000 }\n")
    path.write_text(_with_objective('kind = "cpu_s_to_first_clean_lap"\nbudget_cpu_s = 0.5\n',
                                    tune), encoding="utf-8")
    results = tmp_path / "res"
    result = run_tune(path, "WIN1", trials=1, workers=1, results_dir=results)
    assert result["counts"]["COMPLETE"] == 1, result
    assert result["objective"] == {"kind": "cpu_s_to_first_clean_lap", "line": "centre",
                                   "budget_cpu_s": 0.5, "penalty_factor": 2.0,
                                   "miss_score": 1.0, "threshold_s": None}
    row = result["trials"][0]
    assert row["value"] == 1.0 and row["cpu_s"] is None and row["best_lap_s"] is None
    journal = results / "tinytune" / "optuna" / "WIN1.journal"
    trial = optuna.load_study(study_name="tinytune-WIN1",
                              storage=JournalStorage(JournalFileBackend(str(journal)))).trials[0]
    assert trial.value == 1.0 and trial.user_attrs["cpu_s_used"] >= 0.5
    assert sorted(trial.intermediate_values) == list(range(101))
    assert set(trial.intermediate_values.values()) == {1.0}
    job = results / "tinytune" / "tune" / "WIN1" / "trial-0"
    summary = json.loads((job / "summary.json").read_text())
    assert summary["stopped_early"] and 1 <= summary["episodes"] < 10000
    config = json.loads((job / "config.json").read_text())["run_spec"]
    assert config["preset"] == "fast-small" and config["agent"]["exploration_steps"] == 40_000


def test_resume_refuses_another_objective(tmp_path: Path) -> None:
    """A study's values are of one objective: --resume with another one is refused."""
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    journal = tmp_path / "res" / "tinytune" / "optuna" / "WIN4.journal"
    journal.parent.mkdir(parents=True)
    storage = JournalStorage(JournalFileBackend(str(journal)))
    study = optuna.create_study(study_name="tinytune-WIN4", storage=storage)
    study.set_user_attr("objective", Objective().model_dump())
    path = tmp_path / "tune.toml"
    path.write_text(_with_objective('kind = "cpu_s_to_first_clean_lap"\nbudget_cpu_s = 5\n'),
                    encoding="utf-8")
    with pytest.raises(UserInputError, match=r"--resume: study 'tinytune-WIN4' was run with "
                       r"objective \{'kind': 'best_lap'"):
        run_tune(path, "WIN4", trials=1, workers=1, resume=True, results_dir=tmp_path / "res")
    assert study.get_trials() == []


def test_shipped_study_records_match_their_committed_tune_files() -> None:
    """Each record in tournaments/studies/ is reproducible from a committed file: the file its
    study name names checks for the record's variant, under the record's objective, and every
    trial's parameters lie in that file's search space."""
    root = Path(__file__).resolve().parents[1] / "tournaments"
    records = sorted((root / "studies").glob("*.json"))
    assert len(records) >= 3
    for record_path in records:
        record = json.loads(record_path.read_text())
        variant = record["variant"]
        name = record["study"].removesuffix(f"-{variant}")
        assert record["study"] == record_path.stem == f"{name}-{variant}"
        path = root / f"{name}.toml"
        spec, text = load_tune_spec(path)
        run = check_tune(spec, text, path, variant)
        assert run.variant == variant
        assert spec.objective.kind == record["objective"]["kind"], record_path.name
        assert spec.objective.budget_cpu_s == record["objective"]["budget_cpu_s"]
        for trial in record["trials"]:
            assert set(trial["params"]) == set(spec.search), (record_path.name, trial["number"])
            for key, value in trial["params"].items():
                dim = spec.search[key]
                if dim.choices is not None:
                    assert value in dim.choices
                else:
                    assert dim.low <= value <= dim.high, (record_path.name, key, value)

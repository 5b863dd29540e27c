"""Optuna pre-selection: a study in a journal file that resumes, retries a trial left RUNNING by
a dead process, and writes its best parameters into a tournament file."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from formula_tourney.errors import UserInputError
from formula_tourney.tourney.best_params import write_best_params
from formula_tourney.tourney.spec import load_spec
from formula_tourney.tourney.tune import run_tune
from formula_tourney.tourney.tune_spec import load_tune_spec
from formula_tourney.tourney.tune_study import suggest

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
    """Bug 14: every worker's sampler started from [sampler] seed, so with two workers trials 0
    and 1 had identical parameters. Each worker now has its own stream derived from the seed."""
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

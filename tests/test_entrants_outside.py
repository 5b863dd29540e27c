"""Outside entrants in real tournaments: the example agent, SB3 adapters, faults, resume, checks."""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from formula_tourney.agents.outside.naming import OutsideEntrant
from formula_tourney.errors import UserInputError
from formula_tourney.race.entrants import bot_entrant, model_entrant
from formula_tourney.race.run import run_race
from formula_tourney.race.settings import RaceSettings
from formula_tourney.report.load import load_tournament
from formula_tourney.results.folder import JobFolder
from formula_tourney.results.layout import LAST_CHECKPOINT
from formula_tourney.sim.catalog import load_track
from formula_tourney.tourney.api import run_tournament
from formula_tourney.tourney.runner import FAULTS_ENV
from formula_tourney.training.checkpoint import load_run_checkpoint
from formula_tourney.training.replay import replay

REPO = Path(__file__).resolve().parents[1]

HEAD = """\
name = "byo"

[defaults]
seeds = 1
episodes = 2
max_steps = 40
test_every_episodes = 2
test_starts = 1
test_max_steps = 40
device = "cpu"

[variants.WIN1]
overrides = {{ hidden = [32, 32], batch_size = 16, learning_starts = 16 }}
[variants.Tiny]
impl = "examples.tiny_sac:TinySAC"
settings = {{ hidden = 16, batch_size = 16, learning_starts = 16 }}
{more}
[[parts]]
name = "p1"
entrants = {entrants}
train_tracks = ["oval"]
"""


def tournament(tmp_path: Path, entrants: list[str], more: str = "") -> Path:
    path = tmp_path / "byo.toml"
    path.write_text(HEAD.format(entrants=json.dumps(entrants), more=more), encoding="utf-8")
    return path


def jobs(results: Path) -> dict[str, dict]:
    db = sqlite3.connect(results / "byo" / "index.sqlite")
    db.row_factory = sqlite3.Row
    out = {r["job_id"]: dict(r) for r in db.execute("SELECT * FROM jobs")}
    db.close()
    return out


FAULTS = ("Raises", "ReturnsNaN", "WrongShape")
SB3_VARIANTS = (
    '[variants.SAC3]\nsb3 = "SAC"\nkwargs = { learning_starts = 16, batch_size = 16, '
    'policy_kwargs = { net_arch = [16, 16] } }\n'
    '[variants.CrossQ3]\nsb3_contrib = "CrossQ"\nkwargs = { learning_starts = 16, '
    'batch_size = 16 }\n'
)  # fmt: skip
HAS_SB3 = all(importlib.util.find_spec(m) for m in ("stable_baselines3", "sb3_contrib"))


@pytest.fixture(scope="module")
def ran(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """One tournament for the tests below (workers start once): the example agent, WIN1, the
    three faulty entrants and, with the [sb3] extra, SB3's SAC and sb3-contrib's CrossQ."""
    tmp = tmp_path_factory.mktemp("byo")
    names = ["Tiny", "WIN1", *FAULTS]
    more = "".join(f'[variants.{name}]\nimpl = "outside_entrants:{name}"\n' for name in FAULTS)
    if HAS_SB3:
        names += ["SAC3", "CrossQ3"]
        more += SB3_VARIANTS
    result = run_tournament(tournament(tmp, names, more), workers=2, results_dir=tmp / "res")
    return tmp / "res", result


def test_example_agent_trains_in_a_tournament_and_its_model_loads(
    ran: tuple[Path, dict], tmp_path: Path
) -> None:
    results, _result = ran
    rows = jobs(results)
    assert rows["p1/Tiny-MOT/seed-0"]["status"] == rows["p1/WIN1-MOT/seed-0"]["status"] == "done"
    folder = JobFolder(results / "byo/p1/Tiny-MOT/seed-0")
    assert "outside entrant examples.tiny_sac:TinySAC" in folder.beyond_paper()
    assert len(folder.table("episodes")) == 2 and len(folder.table("tests")) >= 1
    last = folder.checkpoint_path(LAST_CHECKPOINT)
    # races, replays and eval load it through its own class, named by the job's run spec
    model, spec, _ = load_run_checkpoint(last)
    assert spec.outside is not None and model.label == "TinySAC (examples/tiny_sac.py)"
    race = run_race([model_entrant(last, "oval"), bot_entrant("follower", load_track("oval"),
                                                              None)],  # fmt: skip
                    RaceSettings(laps=1, lap_limit_s=5.0))
    assert [r["name"] for r in race.rows if r["kind"] == "model"] == ["Tiny-MOT/seed-0"]
    drive = replay(last, max_steps=20)
    assert drive["track"] == "oval" and drive["checkpoint"] == str(last)
    # the same file outside its job folder is not read (SB3's loader unpickles)
    stray = tmp_path / "stray.pt"
    stray.write_bytes(last.read_bytes())
    with pytest.raises(UserInputError, match="stray.pt"):
        load_run_checkpoint(stray)


def test_each_fault_fails_only_its_job(ran: tuple[Path, dict]) -> None:
    results, result = ran
    rows = jobs(results)
    reasons = {k.split("/")[1]: r["reason"] for k, r in rows.items() if r["status"] == "failed"}
    assert set(reasons) == {f"{name}-MOT" for name in FAULTS}
    assert "driver bug at step 0" in reasons["Raises-MOT"]
    assert "NaN" in reasons["ReturnsNaN-MOT"]
    assert "shape (1, 4)" in reasons["WrongShape-MOT"]
    assert result["this_run"]["failed"] == 3
    assert all(r["status"] == "done" for k, r in rows.items() if k.split("/")[1] not in reasons)
    # the report names each failed job and why
    problems = "\n".join(load_tournament(results / "byo").problems)
    assert "p1/Raises-MOT/seed-0: failed (" in problems and "driver bug at step 0" in problems


@pytest.mark.parametrize(("entry", "message"), [
    ('impl = "no_such_module:X"', "cannot import module 'no_such_module'"),
    ('impl = "examples.tiny_sac:Nope"', "has no class 'Nope'; its classes: Actor, TinySAC"),
    ('impl = "examples.tiny_sac"', 'is not "package.module:Class"'),
    ('impl = "outside_entrants:NotAnEntrant"', "missing settings_model, build, load, act"),
    ('impl = "outside_entrants:BadAtZeros"', "act() on zeros returned shape (3,); allowed: (1, 3)"),
    ('impl = "examples.tiny_sac:TinySAC"\nsettings = { hidden = 1 }', "settings: hidden"),
    ('entry = "nobody"', "no entry point 'nobody' in group 'formula_tourney.entrants'"),
    ('sb3 = "DQN"', "unsupported sb3 algorithm 'DQN' (discrete actions only)"),
    ('sb3 = "SAC"\nkwargs = { bogus = 1 }', "kwargs.bogus: not an argument of SAC; allowed keys"),
    ('sb3 = "SAC"\nkwargs = { seed = 1 }', "kwargs.seed is set by the adapter"),
    ('sb3 = "SAC"\nkwargs = { learning_rate = "fast" }', "build() failed"),
    ('sb3 = "SAC"\noverrides = { hidden = [8] }', "an outside entrant (sb3) takes no agent keys"),
])  # fmt: skip
def test_bad_outside_entrants_are_refused_before_anything_runs(tmp_path: Path, entry: str,
                                                                message: str) -> None:  # fmt: skip
    if "sb3" in entry:
        pytest.importorskip("stable_baselines3", reason="the [sb3] extra is not installed")
    path = tournament(tmp_path, ["Bad", "WIN1"], f"[variants.Bad]\n{entry}\n")
    with pytest.raises(UserInputError) as err:
        run_tournament(path, workers=1, results_dir=tmp_path / "res")
    text = str(err.value)
    assert message in text and "\n" not in text and str(path) in text
    assert not (tmp_path / "res").exists()


def test_the_cli_exits_2_with_one_line(tmp_path: Path) -> None:
    path = tournament(tmp_path, ["Bad"], '[variants.Bad]\nimpl = "examples.tiny_sac:Nope"\n')
    proc = subprocess.run(
        [sys.executable, "-m", "formula_tourney.cli", "run", str(path), "--results",
         str(tmp_path / "res")], cwd=REPO, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2
    assert "has no class 'Nope'" in proc.stderr and not (tmp_path / "res").exists()


@pytest.mark.skipif(not HAS_SB3, reason="the [sb3] extra (stable-baselines3, sb3-contrib) is "
                    "not installed")
def test_sb3_sac_and_crossq_train_through_the_adapter(ran: tuple[Path, dict],
                                                      tmp_path: Path) -> None:  # fmt: skip
    results, _result = ran
    from formula_tourney.agents.outside.sb3 import SB3Entrant

    for name, label in (("SAC3", "sb3 "), ("CrossQ3", "sb3-contrib ")):
        folder = JobFolder(results / f"byo/p1/{name}-MOT/seed-0")
        assert folder.is_finished()
        assert any(b.startswith(f"outside entrant {label}") for b in folder.beyond_paper())
        assert len(folder.table("episodes")) == 2
        last = folder.checkpoint_path(LAST_CHECKPOINT)
        model = SB3Entrant.load(last, "cpu")
        assert model.act(np.zeros((1, 1, model.spaces.obs_dim), np.float32)).shape == (1, 3)
        driver, _spec, _ = load_run_checkpoint(last)
        assert driver.label.startswith(label) and driver.act_eval(
            np.zeros((1, model.spaces.obs_dim), np.float32)).shape == (3,)  # fmt: skip
        stray = tmp_path / f"{name}.zip"
        stray.write_bytes(last.read_bytes())
        with pytest.raises(UserInputError, match="cannot be read|not a formula-tourney"):
            load_run_checkpoint(stray)
        # SB3 wrote nothing of its own: no logs, no monitor files beside the job's
        assert not list(folder.path.rglob("*.monitor.csv")) and not list(
            folder.path.rglob("progress.csv"))  # fmt: skip


def test_kill_9_of_the_parent_then_resume_with_an_outside_entrant(tmp_path: Path) -> None:
    path = tournament(tmp_path, ["Tiny", "WIN1"])
    proc = subprocess.Popen(
        [sys.executable, "-m", "formula_tourney.cli", "run", str(path), "--workers", "2",
         "--results", str(tmp_path / "res"), "--json"], cwd=REPO,
        env={**os.environ, FAULTS_ENV: json.dumps({"p1/Tiny-*": "sleep:30"})},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    deadline = time.monotonic() + 120
    while True:
        assert time.monotonic() < deadline and proc.poll() is None
        try:
            rows = jobs(tmp_path / "res")
        except sqlite3.Error:
            rows = {}
        if rows.get("p1/WIN1-MOT/seed-0", {}).get("status") == "done" and rows.get(
                "p1/Tiny-MOT/seed-0", {}).get("status") == "running":  # fmt: skip
            break
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)
    time.sleep(1.0)  # the orphaned worker follows its parent
    result = run_tournament(path, workers=2, results_dir=tmp_path / "res")
    assert result["this_run"]["skipped"] == 1  # WIN1 was not trained again
    rows = jobs(tmp_path / "res")
    assert rows["p1/Tiny-MOT/seed-0"]["status"] == "done"
    assert rows["p1/Tiny-MOT/seed-0"]["attempts"] == 2


def test_labels_name_the_library_and_version() -> None:
    pytest.importorskip("stable_baselines3", reason="the [sb3] extra is not installed")
    import stable_baselines3

    assert OutsideEntrant(sb3="SAC").label() == f"sb3 {stable_baselines3.__version__} SAC"
    assert OutsideEntrant(impl="examples.tiny_sac:TinySAC").label() == "examples.tiny_sac:TinySAC"


def test_the_cost_estimate_drives_an_outside_entrant_to_learn_its_schedule() -> None:
    from formula_tourney.tourney.estimate.calibrate import calibrate
    from formula_tourney.tourney.estimate.model import job_cost
    from formula_tourney.training.run_spec import build_run_spec

    spec = build_run_spec(
        variant="Tiny", outside={"impl": "examples.tiny_sac:TinySAC",
                                 "settings": {"hidden": 16, "batch_size": 16,
                                              "learning_starts": 40}},
        train_tracks=["oval"], schedule={"episodes": 10, "max_steps": 40, "test_starts": 1},
    )  # fmt: skip
    rates = calibrate(spec, seconds=0.3, chunk_steps=20)
    # TinySAC's first update comes at its 40th stored step (step index 39 of the loop)
    assert rates.learn_from_steps == 39
    assert rates.update.mean_s > 0 and rates.env_step.mean_s > 0
    cost = job_cost(spec, rates)
    assert cost.updates == pytest.approx(max(0.0, cost.env_steps - 39 + 1))


class _Abandoned(Exception):
    """Stands for a kill: the run is dropped mid-way, only its files remain."""


@pytest.mark.parametrize("outside", [
    {"impl": "examples.tiny_sac:TinySAC",
     "settings": {"hidden": 16, "batch_size": 16, "learning_starts": 16}},
    {"sb3": "SAC", "kwargs": {"learning_starts": 16, "batch_size": 16,
                              "policy_kwargs": {"net_arch": [16, 16]}}},
    {"sb3": "PPO", "kwargs": {"n_steps": 32, "batch_size": 16, "n_epochs": 2,
                              "policy_kwargs": {"net_arch": [16, 16]}}},
], ids=["TinySAC", "SB3-SAC", "SB3-PPO"])  # fmt: skip
def test_an_abandoned_outside_run_resumes_to_the_uninterrupted_tables(
    tmp_path: Path, ring_tracks: None, outside: dict
) -> None:
    """Its training_state (weights, optimisers, buffers, every RNG it draws from) resumes the
    run mid-way to the very tables of the run left alone."""
    if "sb3" in outside:
        pytest.importorskip("stable_baselines3", reason="the [sb3] extra is not installed")
    from formula_tourney.training import loop
    from formula_tourney.training.run_spec import build_run_spec

    spec = build_run_spec(
        variant="X", outside=outside, train_tracks=["ring"], device="cpu", seed=4,
        schedule={"episodes": 6, "max_steps": 60, "test_every_episodes": 2, "test_starts": 1,
                  "test_max_steps": 60, "resume_every_cpu_s": 0.05},
    )  # fmt: skip
    loop.train(spec, tmp_path / "whole")
    job = tmp_path / "resumed"

    def abandon(info: dict) -> None:
        if info["episode"] >= 3 and JobFolder(job).resume_path.exists():
            raise _Abandoned

    with pytest.raises(_Abandoned):
        loop.train(spec, job, abandon)
    loop.train(spec, job)
    drop = ["seconds", "cpu_s", "wall_s"]
    for name in ("episodes", "tests", "laps"):
        a = JobFolder(tmp_path / "whole").table(name).drop(columns=drop, errors="ignore")
        b = JobFolder(job).table(name).drop(columns=drop, errors="ignore")
        pd.testing.assert_frame_equal(a, b, check_exact=True)
    assert JobFolder(job).table("episodes")["updates"].iloc[-1] > 0


def test_an_entry_point_names_an_installed_entrant(
    tmp_path: Path, ring_tracks: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A package's ``formula_tourney.entrants`` entry point (its dist-info on the path, as pip
    installs it) is found, labelled with the distribution and trained."""
    info = tmp_path / "site" / "my_driver-1.2.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: my-driver\nVersion: 1.2\n")
    (info / "entry_points.txt").write_text(
        "[formula_tourney.entrants]\ntiny = examples.tiny_sac:TinySAC\n")  # fmt: skip
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    from formula_tourney.training import loop
    from formula_tourney.training.run_spec import build_run_spec

    ref = OutsideEntrant(entry="tiny", settings={"hidden": 16, "learning_starts": 8,
                                                 "batch_size": 8})  # fmt: skip
    assert ref.label() == "tiny (my-driver 1.2)"
    spec = build_run_spec(variant="tiny", outside=ref, train_tracks=["ring"], device="cpu",
                          schedule={"episodes": 2, "max_steps": 30, "test_every_episodes": 2,
                                    "test_starts": 1, "test_max_steps": 30})  # fmt: skip
    summary = loop.train(spec, tmp_path / "job")
    assert summary["episodes"] == 2 and summary["updates"] > 0
    assert JobFolder(tmp_path / "job").beyond_paper()[0] == "outside entrant tiny (my-driver 1.2)"


def test_without_the_extra_an_sb3_entrant_names_how_to_install_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import importlib

    from formula_tourney.agents.outside import sb3

    real = importlib.import_module

    def without_sb3(name: str, *args: object) -> object:
        if name.startswith(("stable_baselines3", "sb3_contrib")):
            raise ImportError(f"No module named {name!r}")
        return real(name, *args)

    monkeypatch.setattr(sb3.importlib, "import_module", without_sb3)
    with pytest.raises(UserInputError, match=r"pip install formula-tourney\[sb3\]"):
        sb3.algorithm_class("sb3_contrib", "CrossQ")


@pytest.mark.skipif(not HAS_SB3, reason="the [sb3] extra is not installed")
def test_the_shipped_byo_tournament_validates_with_its_outside_entrants() -> None:
    from formula_tourney.tourney.plan import Planner
    from formula_tourney.tourney.spec import load_spec

    path = REPO / "tournaments" / "examples" / "byo.toml"
    spec, text = load_spec(path)
    planner = Planner(spec, path, text, Path("unused"))
    assert planner.validate() == 3  # and each outside entrant acted on zeros in its spaces
    runs = {v: planner.run_spec(0, v, 0) for v in ("TinySAC", "SB3-SAC", "WIN1")}
    assert runs["SB3-SAC"].outside.sb3 == "SAC" and runs["WIN1"].outside is None
    assert spec.claims is not None
    assert [c.id for c in spec.claims.claim] == ["win1-vs-sb3", "tiny-vs-sb3"]


def test_train_takes_an_outside_entrant_and_refuses_a_bad_one_up_front(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from formula_tourney.cli import main

    short = ["--episodes", "2", "--max-steps", "30", "--test-every", "2", "--test-starts", "1",
             "--test-max-steps", "30", "--json"]  # fmt: skip
    with pytest.raises(SystemExit) as exc:
        main(["train", "--out", str(tmp_path / "bad"), "--impl", "examples.tiny_sac:TinySAC",
              "--entrant-set", "hidden=1", *short])  # fmt: skip
    assert exc.value.code == 2 and "settings: hidden" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
    main(["train", "--out", str(tmp_path / "tiny"), "--impl", "examples.tiny_sac:TinySAC",
          "--entrant-set", "hidden=16", "--entrant-set", "learning_starts=8", "--entrant-set",
          "batch_size=8", *short])  # fmt: skip
    out = capsys.readouterr().out
    summary = json.loads(out[out.index("{"):])
    assert summary["episodes"] == 2 and summary["updates"] > 0
    spec = JobFolder(tmp_path / "tiny").config()
    assert spec["variant"] == "TinySAC" and spec["outside"]["settings"]["hidden"] == 16

"""Sequential runs (tourney.adaptive): where the next seeds go on synthetic claim readings, the
stops (decided, budget, max_seeds), the [adaptive] table, and real tiny runs: a claim decided
before max_seeds, the budget stop, and a kill -9 in the middle of a wave resumed to the same
seeds and verdicts as a run never interrupted."""

from __future__ import annotations

import json
import math
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from formula_tourney.cli import main
from formula_tourney.errors import UserInputError
from formula_tourney.report.claims.judge import judge
from formula_tourney.tourney.adaptive import (
    STOP_BUDGET,
    STOP_DECIDED,
    STOP_MAX_SEEDS,
    ClaimLook,
    Look,
    allocate,
)
from formula_tourney.tourney.api import plan_tournament, run_tournament
from formula_tourney.tourney.estimate.calibrate import WorkerStart, calibrate
from formula_tourney.tourney.estimate.model import Estimate, JobCost, PartCost
from formula_tourney.tourney.runner import FAULTS_ENV
from formula_tourney.tourney.spec import Adaptive, parse_spec
from formula_tourney.training.run_spec import build_run_spec

REPO = Path(__file__).resolve().parents[1]
DESIGN = Adaptive(min_seeds=5, max_seeds=8, wave_seeds=4)


def _look(
    claim: str,
    a: list[tuple[str, str]],
    b: list[tuple[str, str]],
    mean: float,
    low: float,
    high: float,
    n_a: int = 5,
    n_b: int = 5,
) -> Look:
    return Look(
        claim,
        f"{claim} comparison",
        "inconclusive",
        tuple(a),
        tuple(b),
        n_a,
        n_b,
        min(n_a, n_b) if a and b else max(n_a, n_b),
        mean,
        low,
        high,
    )


NEAR = _look("near", [("p1", "WIN1-MOT")], [], 3.0, -0.5, 6.5)
"""Half-width 3.5, 0.5 short of excluding 0: one more run may decide it."""
FAR = _look("far", [("p2", "PER1M-RC")], [], 0.2, -3.0, 3.4)
"""Half-width 3.2, 3.0 short: far from a decision."""


def _claims(*looks: Look, verdict: str = "inconclusive") -> list[ClaimLook]:
    return [ClaimLook(x.claim, verdict, (x,)) for x in looks]


def test_seeds_go_where_a_run_buys_the_most_decision_per_cpu_second() -> None:
    seeds = {("p1", "WIN1-MOT"): 5, ("p2", "PER1M-RC"): 5}
    wave = allocate(_claims(NEAR, FAR), seeds, lambda t: 100.0, DESIGN, 1e9, set())
    assert wave.picks[0]["claim"] == "near"  # same cost: the claim nearer its decision first
    assert sum(wave.added.values()) == DESIGN.wave_seeds and wave.reason is None
    assert wave.added[("p1", "WIN1-MOT")] == 3  # max_seeds 8: 3 more, then the far claim
    assert wave.added[("p2", "PER1M-RC")] == 1

    def dear_near(t: tuple[str, str]) -> float:
        return 1000.0 if t[0] == "p1" else 100.0  # ten times dearer per run

    wave = allocate(_claims(NEAR, FAR), seeds, dear_near, DESIGN, 1e9, set())
    assert wave.picks[0]["claim"] == "far"
    # value per CPU-s: near 0.61 / 1000 s, far 0.093 / 100 s
    assert wave.picks[0]["value_per_cpu_s"] == pytest.approx(
        3.2 * (1 - (5 / 6) ** 0.5) / 3.0 / 100.0
    )


def test_a_pair_needs_the_shorter_side_and_a_pooled_side_its_least_seeded_entrant() -> None:
    two = _look("two", [("p1", "A1"), ("p1", "A2")], [("p1", "B")], 1.0, -2.0, 4.0, n_a=6, n_b=5)
    seeds = {("p1", "A1"): 4, ("p1", "A2"): 2, ("p1", "B"): 5}
    design = Adaptive(min_seeds=2, max_seeds=10, wave_seeds=3)
    wave = allocate(_claims(two), seeds, lambda t: 10.0, design, 1e9, set())
    # B is short of A: B first; then one each (A2 has the fewest seeds of A's entrants)
    assert [p["runs"] for p in wave.picks] == [["p1/B"], ["p1/A2", "p1/B"]]
    assert wave.added == {("p1", "B"): 2, ("p1", "A2"): 1}


def test_decided_claims_ask_for_nothing_and_the_run_stops_with_its_reason() -> None:
    seeds = {("p1", "WIN1-MOT"): 5, ("p2", "PER1M-RC"): 5}
    wave = allocate(
        _claims(NEAR, FAR, verdict="supported"), seeds, lambda t: 1.0, DESIGN, 1e9, set()
    )
    assert wave.added == {} and wave.reason == STOP_DECIDED and not wave.open_parts
    full = {("p1", "WIN1-MOT"): 8, ("p2", "PER1M-RC"): 8}
    wave = allocate(_claims(NEAR, FAR), full, lambda t: 1.0, DESIGN, 1e9, set())
    assert wave.added == {} and wave.reason == STOP_MAX_SEEDS
    wave = allocate(_claims(NEAR, FAR), seeds, lambda t: 1.0, DESIGN, 1e9, {"p1", "p2"})
    assert wave.added == {} and wave.reason == STOP_MAX_SEEDS  # closed parts take no seeds


def test_the_budget_stops_a_wave_and_then_the_run() -> None:
    seeds = {("p1", "WIN1-MOT"): 5, ("p2", "PER1M-RC"): 5}
    wave = allocate(_claims(NEAR, FAR), seeds, lambda t: 100.0, DESIGN, 250.0, set())
    assert sum(wave.added.values()) == 2 and wave.cpu_s == 200.0  # a third would pass it
    wave = allocate(_claims(NEAR, FAR), seeds, lambda t: 100.0, DESIGN, 50.0, set())
    assert wave.added == {} and wave.reason == STOP_BUDGET
    roomy = Adaptive(min_seeds=5, max_seeds=20, wave_seeds=4)
    wave = allocate(_claims(NEAR), seeds, lambda t: 1.0, roomy, 1e9, set())
    assert wave.open_parts == {"p1"}  # p2 is read by no undecided claim: settled
    wave = allocate(_claims(NEAR), seeds, lambda t: 1.0, DESIGN, 1e9, set())
    assert wave.open_parts == set()  # p1 reached max_seeds in this wave


def test_the_adaptive_table_is_validated_with_the_file(tmp_path: Path) -> None:
    base = 'name = "t"\n[[parts]]\nname = "p1"\nentrants = ["WIN1"]\ntrain_tracks = ["oval"]\n'
    spec = parse_spec(base + "[adaptive]\nmin_seeds = 3\nmax_seeds = 9\n", tmp_path / "t.toml")
    assert spec.adaptive == Adaptive(min_seeds=3, max_seeds=9)
    with pytest.raises(
        UserInputError,
        match=r"t.toml:6: adaptive: .*max_seeds \(2\) must be "
        r">= min_seeds \(3\)",
    ):
        parse_spec(base + "[adaptive]\nmin_seeds = 3\nmax_seeds = 2\n", tmp_path / "t.toml")
    with pytest.raises(
        UserInputError,
        match=r"adaptive.waves: unknown key; allowed keys: "
        "min_seeds, max_seeds, wave_seeds, budget_cpu_h",
    ):
        parse_spec(base + "[adaptive]\nwaves = 3\n", tmp_path / "t.toml")
    with pytest.raises(UserInputError, match="budget_cpu_h"):
        parse_spec(base + "[adaptive]\nbudget_cpu_h = -1\n", tmp_path / "t.toml")


# ------------------------------------------------------------------------- real tiny runs

TINY = """\
name = "seqtiny"

[defaults]
episodes = 2
max_steps = 30
test_every_episodes = 2
test_starts = 1
test_max_steps = 30
device = "cpu"

[adaptive]
{adaptive}

[variants.WIN1]
overrides = {{ hidden = [32, 32], batch_size = 16, learning_starts = 16 }}
[variants.MS2]
overrides = {{ hidden = [32, 32], batch_size = 16, learning_starts = 16 }}

[claims]
[[claims.claim]]
id = "reward"
statement = "{statement}"
kind = "higher_reward"
smooth = 1
a = {a}
b = {b}

{parts}"""

LONG_SHORT = """\
[[parts]]
name = "long"
entrants = ["WIN1"]
train_tracks = ["oval"]

[[parts]]
name = "short"
entrants = ["WIN1"]
max_steps = 8
train_tracks = ["oval"]
"""
"""Episodes of 30 steps against 8: the positive per-step reward makes the long part's best
episode reward higher in every pair, a clear effect the sequence decides at 7 pairs."""

ONE_PART = """\
[[parts]]
name = "p1"
entrants = ["WIN1", "MS2"]
train_tracks = ["oval"]
"""


def _file(tmp_path: Path, adaptive: str, parts: str, a: str, b: str, statement: str) -> Path:
    path = tmp_path / "seqtiny.toml"
    path.write_text(
        TINY.format(adaptive=adaptive, parts=parts, a=a, b=b, statement=statement), encoding="utf-8"
    )
    return path


def _long_short(tmp_path: Path, adaptive: str) -> Path:
    return _file(
        tmp_path,
        adaptive,
        LONG_SHORT,
        '{ part = "long" }',
        '{ part = "short" }',
        "30-step episodes reach a higher reward than 8-step ones",
    )


def _cli_json(capsys: pytest.CaptureFixture, *args: str) -> dict:
    """``formula-tourney ARGS --json``'s document (in this process)."""
    capsys.readouterr()
    try:
        main([*args, "--json"])
    except SystemExit as exc:
        assert not exc.code, capsys.readouterr()
    return json.loads(capsys.readouterr().out)


def test_a_clear_claim_stops_the_run_before_max_seeds(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    path = _long_short(tmp_path, "min_seeds = 8\nmax_seeds = 16\nwave_seeds = 2")
    result = run_tournament(path, workers=2, results_dir=tmp_path / "res", judge=judge)
    state = result["adaptive"]
    assert state["stopped"]["reason"] == STOP_DECIDED
    assert state["stopped"]["claims"] == {"reward": "supported"}
    verdicts = [w["claims"][0]["verdict"] for w in state["waves"]]
    assert verdicts[-1] == "supported" and set(verdicts[:-1]) == {"inconclusive"}
    seeds = state["waves"][-1]["seeds"]
    n = seeds["long/WIN1-MOT"]
    assert seeds == {"long/WIN1-MOT": n, "short/WIN1-MOT": n} and 8 < n < 16
    assert [w["added"] for w in state["waves"][:-1]] == [
        {"long/WIN1-MOT": 1, "short/WIN1-MOT": 1}
    ] * (n - 8)  # one pair per wave
    pairs = state["waves"][-1]["claims"][0]["comparisons"][0]
    assert pairs["pairs"] == n and pairs["low"] > 0.0  # the CS excludes 0
    saved = json.loads((tmp_path / "res" / "seqtiny" / "adaptive.json").read_text())
    assert saved == state
    assert result["this_run"]["done"] == 2 * n  # never max_seeds
    # status --json and the report show the decisions
    status = _cli_json(capsys, "status", str(tmp_path / "res" / "seqtiny"))
    assert status["adaptive"]["stopped"]["reason"] == STOP_DECIDED
    tables = _cli_json(capsys, "report", "-t", "seqtiny", "--results", str(tmp_path / "res"))[
        "tables"
    ]
    assert tables["adaptive"]["records"][0]["stopped"] == STOP_DECIDED
    (claim,) = tables["claims"]["records"]
    assert claim["sequential"] == "supported"


def test_the_budget_stops_after_min_seeds(tmp_path: Path) -> None:
    path = _long_short(tmp_path, "min_seeds = 2\nmax_seeds = 6\nwave_seeds = 2")
    result = run_tournament(
        path, workers=2, results_dir=tmp_path / "res", judge=judge, budget_cpu_h=1e-4
    )  # 0.36 CPU-s: no second wave fits
    state = result["adaptive"]
    assert state["stopped"]["reason"] == STOP_BUDGET
    assert state["design"]["budget_cpu_h"] == 1e-4
    assert result["this_run"]["done"] == 4


def _index_rows(root: Path) -> dict[str, dict]:
    db = sqlite3.connect(root / "index.sqlite")
    db.row_factory = sqlite3.Row
    out = {r["job_id"]: dict(r) for r in db.execute("SELECT * FROM jobs")}
    db.close()
    return out


def _verdicts(state: dict) -> list[tuple[dict, list[str]]]:
    return [(w["seeds"], [c["verdict"] for c in w["claims"]]) for w in state["waves"]]


def test_kill_9_in_the_middle_of_a_wave_resumes_to_the_same_seeds_and_verdicts(
    tmp_path: Path,
) -> None:
    adaptive = "min_seeds = 2\nmax_seeds = 3\nwave_seeds = 2"
    path = _file(
        tmp_path,
        adaptive,
        ONE_PART,
        '{ variant = "WIN1" }',
        '{ variant = "MS2" }',
        "WIN1 reaches a higher reward than MS2",
    )
    whole = run_tournament(path, workers=2, results_dir=tmp_path / "whole", judge=judge)
    # the same file, killed while wave 2's MS2 run (seed 2) sleeps and WIN1's has finished
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "formula_tourney.cli",
            "run",
            str(path),
            "--workers",
            "2",
            "--results",
            str(tmp_path / "res"),
            "--json",
        ],
        cwd=REPO,
        env={**os.environ, FAULTS_ENV: json.dumps({"p1/MS2-MOT/seed-2": "sleep:60"})},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    root = tmp_path / "res" / "seqtiny"
    deadline = time.monotonic() + 120
    while True:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "wave 2 never ran"
        try:
            jobs = _index_rows(root) if (root / "index.sqlite").exists() else {}
        except sqlite3.OperationalError:
            jobs = {}
        if (
            jobs.get("p1/WIN1-MOT/seed-2", {}).get("status") == "done"
            and jobs.get("p1/MS2-MOT/seed-2", {}).get("status") == "running"
        ):
            break
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)
    killed = json.loads((root / "adaptive.json").read_text())
    assert killed["stopped"] is None and len(killed["waves"]) == 1
    resumed = run_tournament(path, workers=2, results_dir=tmp_path / "res", judge=judge)
    assert resumed["this_run"]["done"] == 1  # only the run the kill interrupted
    assert _verdicts(resumed["adaptive"]) == _verdicts(whole["adaptive"])
    assert resumed["adaptive"]["stopped"] == whole["adaptive"]["stopped"]
    assert resumed["adaptive"]["stopped"]["reason"] == STOP_MAX_SEEDS


# ------------------------------------------------------------------------- cost up front


def _priced(budget_cpu_h: float | None, cluster_cpus: int | None = None) -> dict:
    """A 2-part estimate at min_seeds 2 (100 CPU-s per job, no contention, no worker start)."""
    parts = [
        PartCost("p1", 0, None, [JobCost(1e4, 1e4, 4, 100.0, 0.0, 300.0)] * 4, baselines_s=[10.0]),
        PartCost("p2", 1, "p1", [JobCost(1e4, 1e4, 4, 50.0, 0.0, 150.0)] * 2),
    ]
    design = Adaptive(min_seeds=2, max_seeds=6, wave_seeds=2, budget_cpu_h=budget_cpu_h)
    return Estimate(
        parts,
        workers=1,
        cluster_cpus=cluster_cpus,
        worker=WorkerStart(0.0, 0.0, 0.0),
        contention=1.0,
        calibration_s=1.0,
        rates={},
        adaptive=design,
    ).to_json()


def test_the_adaptive_estimate_states_its_floor_expected_and_worst_case() -> None:
    est = _priced(None)
    ad = est["adaptive"]
    floor = 4 * 100.0 + 10.0 + 2 * 50.0
    assert est["total"]["cpu_s"] == pytest.approx(floor) == pytest.approx(ad["floor_cpu_s"])
    # every entrant to 6 seeds: the training jobs x 3, the bot once
    assert ad["worst_cpu_s"] == pytest.approx(floor + 2 * (400.0 + 100.0))
    assert ad["expected_cpu_s"] == pytest.approx(floor + 0.5 * 2 * 500.0)
    assert ad["worst_wall_s"] == pytest.approx(ad["worst_cpu_s"])  # one worker
    capped = _priced(1000.0 / 3600.0)["adaptive"]  # the budget caps the worst case
    assert capped["worst_cpu_s"] == pytest.approx(1000.0)
    assert capped["expected_cpu_s"] == pytest.approx(floor + 0.5 * (1000.0 - floor))
    below = _priced(100.0 / 3600.0)["adaptive"]  # the floor always runs
    assert below["worst_cpu_s"] == pytest.approx(floor) == pytest.approx(below["expected_cpu_s"])
    # on a 4-CPU cluster, waves of 2 runs side by side: the floor's wall, then one mean run
    # (4 x 100 + 2 x 50) / 6 s per wave of 2 x that run's CPU
    est = _priced(None, cluster_cpus=4)
    ad, run_s = est["adaptive"], 500.0 / 6
    waves = math.ceil((ad["worst_cpu_s"] - floor) / (2 * run_s))
    assert ad["worst_cluster_wall_s"] == pytest.approx(est["total"]["cluster_wall_s"]
                                                       + waves * run_s)
    assert ad["expected_cluster_wall_s"] < ad["worst_cluster_wall_s"]
    assert "expected_cluster_wall_s" not in _priced(None)["adaptive"]


def test_a_too_short_calibration_is_refused_and_a_censored_one_widens_its_range(
    tmp_path: Path,
    capsys: pytest.CaptureFixture,
) -> None:
    path = _long_short(tmp_path, "min_seeds = 2")
    with pytest.raises(
        UserInputError,
        match=r"^--calibrate-s 0.2 is too short to time the "
        r"jobs' steps and updates; use at least 0.5 s$",
    ):
        run_tournament(
            path, dry_run=True, estimate=True, calibrate_s=0.2, results_dir=tmp_path / "res"
        )
    with pytest.raises(SystemExit) as info:
        main(["run", str(path), "--dry-run", "--estimate", "--calibrate-s", "0.1"])
    assert info.value.code == 2 and len(capsys.readouterr().err.strip().splitlines()) == 1
    plan = run_tournament(path, dry_run=True, results_dir=tmp_path / "res")
    assert plan["adaptive"]["min_seeds"] == 2 and plan["plan"]["known_jobs"] == 4
    long_episodes = build_run_spec(
        variant="WIN1",
        overrides={"hidden": [32, 32], "batch_size": 16},
        train_tracks=["oval"],
        schedule={"episodes": 10, "max_steps": 50_000, "test_max_steps": 100},
        device="cpu",
    )
    measured = calibrate(long_episodes, seconds=0.5)  # far fewer than 3 x 50k steps driven
    assert measured.episode_steps_se >= (50_000 - measured.episode_steps_mean) / 1.96 - 1e-6


def test_wave_seeds_from_the_command_line(tmp_path: Path) -> None:
    """--wave-seeds replaces the design's runs per wave (a cluster's CPUs); it needs a
    sequential run and a count in range, one line each."""
    path = _long_short(tmp_path, "min_seeds = 2\nmax_seeds = 6\nwave_seeds = 2")
    planner, _, _ = plan_tournament(path, tmp_path / "res", wave_seeds=64)
    assert planner.spec.adaptive is not None and planner.spec.adaptive.wave_seeds == 64
    with pytest.raises(UserInputError, match=r"^--wave-seeds must be 1-1000, got 0$"):
        plan_tournament(path, tmp_path / "res", wave_seeds=0)
    fixed = tmp_path / "fixed.toml"
    design = "[adaptive]\nmin_seeds = 2\nmax_seeds = 6\nwave_seeds = 2\n"
    assert design in path.read_text()
    fixed.write_text(path.read_text().replace(design, ""), encoding="utf-8")
    with pytest.raises(UserInputError, match=r"--wave-seeds needs a sequential run"):
        plan_tournament(fixed, tmp_path / "res", wave_seeds=4)

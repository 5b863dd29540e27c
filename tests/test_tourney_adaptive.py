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

from formula_tourney.claims.sequential import confidence_sequence
from formula_tourney.cli import main
from formula_tourney.errors import UserInputError
from formula_tourney.report.claims.judge import judge
from formula_tourney.tourney.adaptive import (
    CONTRADICTED,
    STOP_BUDGET,
    STOP_DECIDED,
    STOP_MAX_SEEDS,
    STOP_OUT_OF_REACH,
    SUPPORTED,
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
    needed: int | None,
    heading: str = SUPPORTED,
    n_a: int = 5,
    n_b: int = 5,
) -> Look:
    pairs = min(n_a, n_b) if a and b else max(n_a, n_b)
    return Look(claim, f"{claim} {a or 'bot'} vs {b or 'bot'}", "inconclusive", tuple(a),
                tuple(b), n_a, n_b, pairs, 0.5, -0.2, 0.9, needed, heading)  # fmt: skip


NEAR = _look("near", [("p1", "WIN1-MOT")], [], 8)
"""Against a bot, projected to decide at 8 pairs: 3 more runs."""
FAR = _look("far", [("p2", "PER1M-RC")], [], 30)
"""Projected to decide at 30 pairs: 25 more runs."""


def _claims(*looks: Look, verdict: str = "inconclusive") -> list[ClaimLook]:
    return [ClaimLook(x.claim, verdict, (x,)) for x in looks]


def test_the_projection_of_wins_is_exact() -> None:
    # won in every pair: 7 pairs decide, however many there are now (a 1/sqrt(n) model of
    # the width at 3 pairs asked for more); a share of 2 in 3 repeated decides much later
    assert confidence_sequence([1.0, 1.0, 1.0], 1.0).projected == 7
    assert confidence_sequence([-1.0] * 5, 1.0).projected == 7
    later = confidence_sequence([1.0, 1.0, -1.0], 1.0).projected
    assert later is not None and later > 50
    assert confidence_sequence([1.0, -1.0, 1.0, -1.0], 1.0).projected is None  # at the threshold
    assert all(confidence_sequence([1.0] * n, 1.0).verdict == "open" for n in range(1, 7))
    assert confidence_sequence([1.0] * 7, 1.0).verdict == "above"


def test_seeds_go_to_the_claim_cheapest_to_decide_and_stop_at_its_projection() -> None:
    seeds = {("p1", "WIN1-MOT"): 5, ("p2", "PER1M-RC"): 5}
    roomy = Adaptive(min_seeds=5, max_seeds=40, wave_seeds=6)
    wave = allocate(_claims(NEAR, FAR), seeds, lambda t: 100.0, roomy, 1e9, set())
    assert wave.picks[0]["claim"] == "near"  # 3 runs to decide against 25 at the same cost
    assert wave.picks[0]["value_per_cpu_s"] == pytest.approx(1.0 / 300.0)
    # the near claim gets the 3 runs it is projected to need, no more; the rest go far
    assert wave.added == {("p1", "WIN1-MOT"): 3, ("p2", "PER1M-RC"): 3} and wave.reason is None

    def dear_near(t: tuple[str, str]) -> float:
        return 1000.0 if t[0] == "p1" else 100.0  # near: 3 000 s to decide, far: 2 500 s

    wave = allocate(_claims(NEAR, FAR), seeds, dear_near, roomy, 1e9, set())
    assert wave.picks[0]["claim"] == "far"
    assert wave.picks[0]["value_per_cpu_s"] == pytest.approx(1.0 / 2500.0)


def test_any_contradicted_comparison_decides_a_claim_so_only_the_cheapest_one_is_funded() -> None:
    seeds = {("p1", "A"): 5, ("p1", "B"): 5, ("p1", "C"): 5}
    roomy = Adaptive(min_seeds=5, max_seeds=40, wave_seeds=8)
    claim = ClaimLook("c", "inconclusive", (
        _look("c", [("p1", "A")], [], 7, CONTRADICTED),
        _look("c", [("p1", "B")], [], 9, CONTRADICTED),
        _look("c", [("p1", "C")], [], 20, SUPPORTED),
    ))  # fmt: skip
    wave = allocate([claim], seeds, lambda t: 10.0, roomy, 1e9, set())
    assert wave.added == {("p1", "A"): 2}  # A's 2 runs decide the claim; B and C get none
    assert wave.open_parts == {"p1"}
    # every comparison heading to supported: all of them are funded, to their projections
    both = ClaimLook("s", "inconclusive", (_look("s", [("p1", "A")], [], 7),
                                           _look("s", [("p1", "B")], [], 8)))  # fmt: skip
    wave = allocate([both], seeds, lambda t: 10.0, roomy, 1e9, set())
    assert wave.added == {("p1", "A"): 2, ("p1", "B"): 3}
    # one heading each way: support is out of reach, the contradicting one decides it
    mixed = ClaimLook("m", "inconclusive", (_look("m", [("p1", "A")], [], 12),
                                            _look("m", [("p1", "B")], [], 9, CONTRADICTED)))
    wave = allocate([mixed], seeds, lambda t: 10.0, roomy, 1e9, set())
    assert wave.added == {("p1", "B"): 4}


def test_a_pair_needs_the_shorter_side_and_a_pooled_side_its_least_seeded_entrant() -> None:
    two = _look("two", [("p1", "A1"), ("p1", "A2")], [("p1", "B")], 20, n_a=6, n_b=5)
    seeds = {("p1", "A1"): 4, ("p1", "A2"): 2, ("p1", "B"): 5}
    design = Adaptive(min_seeds=2, max_seeds=20, wave_seeds=3)
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
    never = _look("never", [("p1", "WIN1-MOT")], [], None)  # its observed wins are at 1/2
    wave = allocate(_claims(never), seeds, lambda t: 1.0, DESIGN, 1e9, set())
    assert wave.added == {} and wave.reason == STOP_OUT_OF_REACH


def test_the_budget_stops_a_wave_and_then_the_run() -> None:
    seeds = {("p1", "WIN1-MOT"): 5, ("p2", "PER1M-RC"): 5}
    roomy = Adaptive(min_seeds=5, max_seeds=40, wave_seeds=4)
    # 400 s: the near claim's 3 runs fit; the far one's 25 do not, so it gets none
    wave = allocate(_claims(NEAR, FAR), seeds, lambda t: 100.0, roomy, 400.0, set())
    assert wave.added == {("p1", "WIN1-MOT"): 3} and wave.cpu_s == 300.0
    assert wave.open_parts == {"p1", "p2"}  # a later budget-free run could still fund p2
    never = _look("never", [("p2", "PER1M-RC")], [], None)
    wave = allocate(_claims(NEAR, never), seeds, lambda t: 100.0, roomy, 400.0, set())
    assert wave.open_parts == {"p1"}  # p2 is on no path that can decide: settled, it may promote
    wave = allocate(_claims(FAR), seeds, lambda t: 100.0, roomy, 400.0, set())
    assert wave.added == {} and wave.reason == STOP_OUT_OF_REACH and not wave.open_parts
    wave = allocate(_claims(NEAR, FAR), seeds, lambda t: 100.0, roomy, 50.0, set())
    assert wave.added == {} and wave.reason == STOP_BUDGET  # not even one run fits
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
    # wave 1 reads 2 pairs and projects 8: wave 2 adds 6 runs of each part
    path = _long_short(tmp_path, "min_seeds = 2\nmax_seeds = 16\nwave_seeds = 20")
    whole = run_tournament(path, workers=2, results_dir=tmp_path / "whole", judge=judge)
    # the same file, killed while wave 2's short run at seed 2 sleeps and the long one's is done
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
        env={**os.environ, FAULTS_ENV: json.dumps({"short/WIN1-MOT/seed-2": "sleep:60"})},
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
            jobs.get("long/WIN1-MOT/seed-2", {}).get("status") == "done"
            and jobs.get("short/WIN1-MOT/seed-2", {}).get("status") == "running"
        ):
            break
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)
    killed = json.loads((root / "adaptive.json").read_text())
    assert killed["stopped"] is None and len(killed["waves"]) == 1
    kept = {k: r for k, r in _index_rows(root).items() if r["status"] == "done"}
    assert "long/WIN1-MOT/seed-2" in kept
    resumed = run_tournament(path, workers=2, results_dir=tmp_path / "res", judge=judge)
    # every job done before the kill is kept as it was (a worker may finish one more as the
    # kill lands): only the rest run
    assert resumed["this_run"]["done"] <= whole["this_run"]["done"] - len(kept)
    after = _index_rows(root)
    assert all(after[k] == r for k, r in kept.items())
    assert _verdicts(resumed["adaptive"]) == _verdicts(whole["adaptive"])
    assert resumed["adaptive"]["stopped"] == whole["adaptive"]["stopped"]
    assert resumed["adaptive"]["stopped"]["reason"] == STOP_DECIDED
    assert len(whole["adaptive"]["waves"]) >= 3  # the kill fell in a wave after the first


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

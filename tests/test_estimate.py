"""The cost estimate: the job model and the wall-time replay by hand, and the measurement on a
real tiny run specification."""

from __future__ import annotations

import math

import pytest

from formula_tourney.tourney.estimate.calibrate import Measured, Rates, WorkerStart, calibrate
from formula_tourney.tourney.estimate.model import (
    Estimate,
    JobCost,
    PartCost,
    candidates_cost,
    combined_se,
    count_test_rounds,
    job_cost,
    simulate_wall,
)
from formula_tourney.training.run_spec import build_run_spec


def rates(**kw) -> Rates:
    base = dict(setup_s=0.5, env_step=Measured(1e-4, 1e-5, 1000), update=Measured(1e-3, 1e-4, 100),
                test_episode_s=0.2, test_step_s=1e-4, checkpoint_s=0.01, episode_steps_mean=50.0,
                episode_steps_se=5.0, episodes_seen=20)
    return Rates(**{**base, **kw})


def spec(**schedule):
    return build_run_spec(
        variant="WIN1", overrides={"hidden": [32, 32], "batch_size": 16, "learning_starts": 100},
        train_tracks=["oval"], schedule={"episodes": 10, "max_steps": 100,
                                         "test_every_episodes": 4, "test_starts": 2,
                                         "test_max_steps": 300, **schedule},
        device="cpu")


def test_rounds_by_hand() -> None:
    assert (count_test_rounds(10, 4), count_test_rounds(8, 4), count_test_rounds(1, 4)) == (3, 2, 1)


def test_job_cost_by_hand() -> None:
    cost = job_cost(spec(), rates())
    # 10 episodes x 50 steps; updates from step max(100, 16) = 100 on: 401; 3 test rounds x 2
    assert cost.env_steps == 500.0 and cost.updates == 401.0 and cost.test_episodes == 6
    expected = 0.5 + 500 * 1e-4 + 401 * 1e-3 + 6 * 0.2 + 3 * 0.01
    assert cost.cpu_s == pytest.approx(expected)
    # se: steps 500 x 1e-5, updates 401 x 1e-4, length 10 x (1e-4 + 1e-3) x 5
    se = math.sqrt((500 * 1e-5) ** 2 + (401 * 1e-4) ** 2 + (10 * 1.1e-3 * 5) ** 2)
    assert cost.cpu_s_se == pytest.approx(se)
    # the bound: every episode to 100 steps (1000 steps, 901 updates), tests to 300 steps
    bound = 0.5 + 1000 * 1e-4 + 901 * 1e-3 + 6 * max(0.2, 300 * 1e-4) + 3 * 0.01
    assert cost.cpu_s_max == pytest.approx(bound)
    assert job_cost(spec(), rates(), fixed_s=2.0).cpu_s == pytest.approx(expected + 1.5)
    # episodes never longer than max_steps
    assert job_cost(spec(), rates(episode_steps_mean=500.0)).env_steps == 1000.0


def test_job_cost_under_an_env_step_budget_by_hand() -> None:
    """A 300-step budget on 10 x 50-step episodes: 300 steps in 6 episodes, 201 updates, tests
    after episodes 4 and 6 (2 rounds x 2 starts); the episode length's spread no longer moves
    the steps; the bound stops one max_steps episode past the budget (400 steps)."""
    cost = job_cost(spec(env_steps=300), rates())
    assert cost.env_steps == 300.0 and cost.updates == 201.0 and cost.test_episodes == 4
    assert cost.cpu_s == pytest.approx(0.5 + 300 * 1e-4 + 201 * 1e-3 + 4 * 0.2 + 2 * 0.01)
    assert cost.cpu_s_se == pytest.approx(math.sqrt((300 * 1e-5) ** 2 + (201 * 1e-4) ** 2))
    bound = 0.5 + 400 * 1e-4 + 301 * 1e-3 + 4 * max(0.2, 300 * 1e-4) + 2 * 0.01
    assert cost.cpu_s_max == pytest.approx(bound)
    # a budget the episodes never reach changes nothing
    assert job_cost(spec(env_steps=5000), rates()).cpu_s == job_cost(spec(), rates()).cpu_s


def test_job_cost_under_a_cpu_budget_by_hand() -> None:
    """A 1 CPU-s budget: the clock counts steps, updates and test rounds (0.41 s a round of
    2 starts and a checkpoint, every 4 x 50 steps: 0.00205 s a step). 100 exploring steps
    cost 0.215 s, the rest of the budget buys 0.785 / 0.00315 steps with an update each, and
    the run stops half an episode later on average. Shared cores do not grow the budget."""
    cost = job_cost(spec(episodes=1000, budget_cpu_s=1.0), rates())
    reach = 100 + (1.0 - 100 * (1e-4 + 0.00205)) / (1e-4 + 1e-3 + 0.00205)
    assert cost.env_steps == pytest.approx(reach + 25.0) and cost.clock_s == 1.0
    # the bound: the budget, one more 100-step episode and a last round at 300-step tests
    assert cost.cpu_s_max == pytest.approx(0.5 + 1.0 + 100 * 1.1e-3 + 2 * 0.2 + 0.01)
    assert cost.scaled(2.0).cpu_s == pytest.approx(1.0 + (cost.cpu_s - 1.0) * 2.0)
    # a budget the episodes never reach changes nothing
    assert job_cost(spec(budget_cpu_s=100.0), rates()) == job_cost(spec(), rates())


def job(seconds: float) -> JobCost:
    return JobCost(0.0, 0.0, 0, seconds, 0.0, seconds)


def costed(seconds: float, se: float, group: str = "") -> JobCost:
    return JobCost(0.0, 0.0, 0, seconds, se, seconds, group)


def test_errors_of_one_measurement_add_linearly() -> None:
    """Five seeds priced from one measurement (se 2 each) err together: 5 x 2 = 10, not
    sqrt(5) x 2; a second measurement's job (se 3) adds in quadrature: sqrt(10^2 + 3^2)."""
    seeds = [costed(100.0, 2.0, "p/WIN1#0")] * 5
    assert combined_se(seeds) == pytest.approx(10.0)
    assert combined_se([*seeds, costed(50.0, 3.0, "p/LSTM4#0")]) == pytest.approx(
        math.sqrt(10.0**2 + 3.0**2))
    # ungrouped jobs are independent
    assert combined_se([costed(1.0, 3.0), costed(1.0, 4.0)]) == pytest.approx(5.0)
    # the part's band: 1.96 x 10 either side
    row = PartCost("p", 0, None, seeds).summary()
    assert row["cpu_s"] == pytest.approx(500.0)
    assert (row["cpu_s_low"], row["cpu_s_high"]) == pytest.approx((500 - 19.6, 500 + 19.6))


def test_promoted_jobs_by_family_and_by_top_k() -> None:
    """Families WIN (WIN1 100 s, WIN4 200 s) and LSTM (LSTM4 1 000 s): one per family comes,
    each at its family's mean (150 + 1 000), the band down to WIN1 (-50) and up to WIN4 (+50).
    Top 1 of the three variants: the mean of the three (433.3 s), from 100 to 1 000 s."""
    units = {"WIN": [costed(100.0, 0.0), costed(200.0, 0.0)], "LSTM": [costed(1000.0, 0.0)]}
    jobs = candidates_cost(units, 2, "r2#0")
    assert [j.cpu_s for j in jobs] == pytest.approx([150.0, 1000.0])
    row = PartCost("r2", 1, "r1", jobs).summary()
    assert (row["cpu_s_low"], row["cpu_s"], row["cpu_s_high"]) == pytest.approx(
        (1100.0, 1150.0, 1200.0))
    by_variant = {"WIN1": [costed(100.0, 0.0)], "WIN4": [costed(200.0, 0.0)],
                  "LSTM4": [costed(1000.0, 0.0)]}  # fmt: skip
    (top,) = candidates_cost(by_variant, 1, "r3#0")
    row = PartCost("r3", 2, "r2", [top]).summary()
    assert (row["cpu_s_low"], row["cpu_s"], row["cpu_s_high"]) == pytest.approx(
        (100.0, 1300.0 / 3, 1000.0))
    # two of three: the two cheapest (150 mean) to the two dearest (600 mean), x 2 jobs
    row = PartCost("r3", 2, "r2", candidates_cost(by_variant, 2, "r3#0")).summary()
    assert (row["cpu_s_low"], row["cpu_s"], row["cpu_s_high"]) == pytest.approx(
        (300.0, 2600.0 / 3, 1200.0))
    # the bound (every episode to its limit) is the dearest candidates' too: never below high
    assert row["cpu_s_max"] == pytest.approx(1200.0) and (
        PartCost("r2", 1, "r1", jobs).summary()["cpu_s_max"] == pytest.approx(1200.0))


def test_wall_replays_the_scheduler() -> None:
    p1 = PartCost("p1", 0, None, [job(10), job(10), job(10)])
    p2 = PartCost("p2", 1, "p1", [job(4)])
    # 2 slots: 10 + 10 in parallel, the third 10 after: p1 closes at 20; p2 after it: 24
    assert simulate_wall([p1, p2], 2) == pytest.approx(24.0)
    # every slot pays its start once; a Ray cluster starts later
    assert simulate_wall([p1, p2], 2, per_worker_s=3.0) == pytest.approx(27.0)
    assert simulate_wall([p1, p2], 4, start_s=13.5) == pytest.approx(13.5 + 14.0)
    # a part with declared entrants does not wait for the one before it
    p3 = PartCost("p3", 2, None, [job(1)])
    assert simulate_wall([p1, p3], 2) == pytest.approx(20.0)


def test_estimate_totals_with_worker_start_and_contention() -> None:
    parts = [PartCost("p1", 0, None, [job(10), job(10)], baselines_s=[2.0])]
    est = Estimate(parts, workers=2, cluster_cpus=4, worker=WorkerStart(3.0, 1.5, 0.5),
                   contention=2.0, calibration_s=1.0, rates={}).to_json()
    # (22 + 2 starts x (3 + 1.5 - 0.5)) x 2
    assert est["total"]["cpu_s"] == pytest.approx((22 + 2 * 4.0) * 2)
    assert est["total"]["jobs"] == 2 and est["total"]["baselines"] == 1
    # slots: (4 + 10) x 2 each = 28, then the baseline 2 x 2: 32
    assert est["total"]["wall_s"] == pytest.approx(32.0)
    assert est["total"]["cluster_wall_s"] > 13.5


def test_calibrate_measures_a_real_spec() -> None:
    measured = calibrate(spec(), seconds=0.3)
    assert measured.env_step.mean_s > 0 and measured.update.mean_s > 0
    assert measured.env_step.samples >= 300 and measured.update.samples >= 30
    assert 1 <= measured.episode_steps_mean <= 100 and measured.test_episode_s > 0

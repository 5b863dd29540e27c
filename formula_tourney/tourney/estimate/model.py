"""What a tournament will cost before it runs: jobs, env steps, CPU-hours and wall time.

The model of one training job, from its run specification and the rates measured here
(``estimate.calibrate``)::

    steps    = episodes x L            L: mean exploring episode length measured, <= max_steps
               (at most ``env_steps``, the schedule's budget; then episodes = env_steps / L)
    updates  = max(0, steps - max(learning_starts, batch_size) + 1) x updates_per_step
    tests    = ceil(episodes / test_every_episodes) rounds x test_starts x test tracks
    cpu_s    = setup + steps x t_step + updates x t_update + tests x t_test_episode
               + rounds x (1 + save_test_checkpoints) x t_checkpoint

The uncertainty (``cpu_s_low``/``cpu_s_high``, about 95 %) propagates the standard errors of
the rates and of L. Jobs that share one measurement (the seeds of an entrant, the copies of a
promoted part's job) share its error, so their errors add up linearly; errors of different
measurements add in quadrature. It does not cover learning: once an agent laps, its episodes
run longer (up to max_steps) and so do its tests; ``cpu_s_max`` is that bound (every episode and
test to its step limit). Baseline drives are timed as they are. A promoted part's entrants are
not known yet: it is counted with the variants its rule can promote at most. With
``best_per_family`` that is one job per family at the mean cost of that family's variants,
with the band widened to its cheapest and its dearest variant; under ``top_k`` (fewer than
could come) each job is at the mean cost of the candidates, and the band runs from the ``k``
cheapest to the ``k`` dearest.

Wall time replays the scheduler (``tourney.scheduler``): earlier parts first and long jobs
first within them, a promoted part once its source closed, one job per worker slot, each
worker paying its imports once; a Ray cluster of N CPUs is N slots plus ``RAY_INIT_S``.

A sequential run (``[adaptive]``, ``tourney.adaptive``) is priced at ``min_seeds`` per entrant
(the floor: every part runs it), and :func:`adaptive_cost` adds what its waves may add: the
worst case is every entrant of every training part at ``max_seeds`` (each part's training
jobs scaled by ``max_seeds / min_seeds``, from the high end of their range), but no more than
the budget allows (a wave that would pass it is not started; the floor always runs); the
expected cost is the floor plus half the room up to that worst case, the design's midpoint:
before the run no effect size is known, and a claim decided at the first look adds nothing
while one never decided takes its entrants to ``max_seeds``. Wall time scales with the CPU
time (waves wait for their slowest job: the barrier is not priced).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from formula_tourney.tourney.estimate.calibrate import Rates, WorkerStart
from formula_tourney.tourney.spec import Adaptive
from formula_tourney.training.run_spec import RunSpec

RAY_INIT_S = 13.5
"""``ray.init`` measured at 12-15 s on this kind of machine."""
Z95 = 1.96


@dataclass(frozen=True)
class JobCost:
    """The estimated cost of one job (seconds of one core)."""

    env_steps: float
    updates: float
    test_episodes: int
    cpu_s: float
    cpu_s_se: float
    cpu_s_max: float
    group: str = ""
    """The measurement this cost comes from: jobs of one group share its error ("" = its own)."""
    choice_below_s: float = 0.0
    choice_above_s: float = 0.0
    """How much cheaper / dearer the job is if the cheapest / dearest candidate is promoted."""
    clock_s: float = 0.0
    """The part of ``cpu_s`` that is the run's own CPU budget (``budget_cpu_s``): cores shared
    with other workers make a budgeted run do less in it, not spend more."""

    def scaled(self, factor: float) -> JobCost:
        """The job on cores shared by the run's workers, each ``factor`` slower: its CPU beyond
        its own budget grows by ``factor``."""
        def grow(x: float) -> float:
            return self.clock_s + (x - self.clock_s) * factor

        return JobCost(self.env_steps, self.updates, self.test_episodes, grow(self.cpu_s),
                       self.cpu_s_se * factor, grow(self.cpu_s_max), self.group,
                       self.choice_below_s * factor, self.choice_above_s * factor, self.clock_s)


def combined_se(jobs: list[JobCost]) -> float:
    """The standard error of the jobs' summed cost: linear within a group, quadrature across."""
    by_group: dict[str, float] = {}
    for k, job in enumerate(jobs):
        key = job.group or f"#{k}"
        by_group[key] = by_group.get(key, 0.0) + job.cpu_s_se
    return math.sqrt(sum(v * v for v in by_group.values()))


def candidates_cost(costs: dict[str, list[JobCost]], count: int, group: str) -> list[JobCost]:
    """The jobs of a promoted part's setup (one seed) when ``count`` of the candidate units
    come. A unit is a family (``best_per_family``: its variants' costs) or a variant (a list of
    one). All units come: one job per unit at its mean, its band from its cheapest to its
    dearest variant. Fewer come: ``count`` jobs at the mean of the units' means, the band from
    the ``count`` cheapest to the ``count`` dearest."""
    units = [(_mean_cost(v), min(c.cpu_s for c in v), max(c.cpu_s for c in v),
              max(c.cpu_s_max for c in v)) for v in costs.values() if v]  # fmt: skip
    if not units or count <= 0:
        return []
    if count >= len(units):  # the bound takes the dearest variant too
        return [replace(mean, group=f"{group}/{k}", choice_below_s=mean.cpu_s - low,
                        choice_above_s=high - mean.cpu_s, cpu_s_max=bound)
                for k, (mean, low, high, bound) in enumerate(units)]  # fmt: skip
    mean = _mean_cost([m for m, _, _, _ in units])
    lows = sorted(low for _, low, _, _ in units)[:count]
    highs = sorted((high for _, _, high, _ in units), reverse=True)[:count]
    bounds = sorted((b for _, _, _, b in units), reverse=True)[:count]
    below = mean.cpu_s - sum(lows) / count
    above = sum(highs) / count - mean.cpu_s
    return [replace(mean, group=group, choice_below_s=below, choice_above_s=above,
                    cpu_s_max=sum(bounds) / count)] * count


def _mean_cost(costs: list[JobCost]) -> JobCost:
    n = len(costs)
    return JobCost(*(sum(getattr(c, f) for c in costs) / n
                     for f in ("env_steps", "updates", "test_episodes", "cpu_s", "cpu_s_se",
                               "cpu_s_max")))  # fmt: skip


def count_test_rounds(episodes: int, every: int) -> int:
    """Test rounds of a run: after every ``every`` episodes, and after the last one."""
    return episodes // every + (1 if episodes % every else 0)


def job_cost(spec: RunSpec, rates: Rates, fixed_s: float | None = None) -> JobCost:
    """The module's model of one training job; ``fixed_s``: what a job costs beyond its steps
    (``WorkerStart.next_job_s``; default: the in-process setup measured with the rates)."""
    sch, cfg = spec.schedule, spec.agent
    length = min(float(rates.episode_steps_mean), float(sch.max_steps))
    steps = sch.episodes * length
    episodes = sch.episodes  # episodes the run drives: fewer under an env-step budget
    capped = sch.env_steps is not None and steps > sch.env_steps
    if capped:
        steps = float(sch.env_steps)
        episodes = min(sch.episodes, math.ceil(sch.env_steps / max(length, 1.0)))
    learn_from = max(cfg.learning_starts, cfg.batch_size)
    ups = cfg.updates_per_step
    if rates.learn_from_steps is not None:  # an outside entrant: its measured schedule
        learn_from, ups = rates.learn_from_steps, 1.0

    def updates_for(n_steps: float) -> float:
        return max(0.0, n_steps - learn_from + 1) * ups

    per_round = (1 + int(sch.save_test_checkpoints)) * rates.checkpoint_s
    t_step, t_upd = rates.env_step.mean_s, rates.update.mean_s
    fixed = rates.setup_s if fixed_s is None else fixed_s
    budgeted, clock = False, 0.0
    if sch.budget_cpu_s is not None:  # the run's clock counts its steps, updates and tests
        round_s = sch.test_starts * len(spec.test_tracks) * rates.test_episode_s + per_round
        test_per_step = round_s / (sch.test_every_episodes * max(length, 1.0))
        explore = learn_from * (t_step + test_per_step)
        budget = float(sch.budget_cpu_s)
        reach = (budget / (t_step + test_per_step) if explore >= budget
                 else learn_from + (budget - explore) / (t_step + ups * t_upd + test_per_step))
        if reach < steps:  # it stops at the first episode end past its budget
            budgeted, clock = True, budget
            steps = reach + 0.5 * length
            episodes = min(sch.episodes, math.ceil(steps / max(length, 1.0)))
    rounds = count_test_rounds(episodes, sch.test_every_episodes)
    tests = rounds * sch.test_starts * len(spec.test_tracks)
    cpu = (fixed + steps * t_step + updates_for(steps) * t_upd
           + tests * rates.test_episode_s + rounds * per_round)  # fmt: skip
    learning = steps > learn_from
    d_length = episodes * (t_step + (ups * t_upd if learning else 0.0))
    var = sum(x * x for x in (
        steps * _finite(rates.env_step.se_s), updates_for(steps) * _finite(rates.update.se_s),
        d_length * _finite(rates.episode_steps_se) if length < sch.max_steps and not capped
        else 0.0,
    ))  # fmt: skip
    full = float(sch.episodes * sch.max_steps)
    if sch.env_steps is not None:  # the run ends at the first episode end past the budget
        full = min(full, float(sch.env_steps + sch.max_steps))
    test_max_s = max(rates.test_episode_s, sch.test_max_steps * rates.test_step_s)
    cpu_max = (fixed + full * t_step + updates_for(full) * t_upd
               + tests * test_max_s + rounds * per_round)  # fmt: skip
    if budgeted:  # its clock's budget, one more episode and its last test round at their limits
        tail = (sch.max_steps * (t_step + ups * t_upd)
                + sch.test_starts * len(spec.test_tracks) * test_max_s + per_round)
        cpu_max = min(cpu_max, fixed + clock + tail)
        var = (0.5 * length * (t_step + ups * t_upd)) ** 2  # where in an episode it stops
    return JobCost(steps, updates_for(steps), tests, cpu, math.sqrt(var), cpu_max,
                   clock_s=clock)


def _finite(x: float) -> float:
    return x if math.isfinite(x) else 0.0


@dataclass
class PartCost:
    """One part: its jobs (known or at most promoted), their cost and the assumption made."""

    part: str
    position: int
    source: str | None
    jobs: list[JobCost] = field(default_factory=list)
    baselines_s: list[float] = field(default_factory=list)
    assumed: str = ""

    @property
    def cpu_s(self) -> float:
        return sum(j.cpu_s for j in self.jobs) + sum(self.baselines_s)

    def summary(self) -> dict[str, Any]:
        se = combined_se(self.jobs)
        cpu = self.cpu_s
        below = sum(j.choice_below_s for j in self.jobs)
        above = sum(j.choice_above_s for j in self.jobs)
        return {
            "part": self.part, "jobs": len(self.jobs), "baselines": len(self.baselines_s),
            "env_steps": sum(j.env_steps for j in self.jobs),
            "updates": sum(j.updates for j in self.jobs),
            "cpu_s": cpu, "cpu_s_low": max(0.0, cpu - Z95 * se - below),
            "cpu_s_high": cpu + Z95 * se + above,
            "cpu_s_max": sum(j.cpu_s_max for j in self.jobs) + sum(self.baselines_s),
            "cpu_h": cpu / 3600.0, "promoted_from": self.source, "assumed": self.assumed,
            "clock_s": sum(j.clock_s for j in self.jobs),
        }  # fmt: skip


def simulate_wall(parts: list[PartCost], slots: int, start_s: float = 0.0,
                  per_worker_s: float = 0.0) -> float:
    """Wall seconds to run every part on ``slots`` workers, as the scheduler orders jobs:
    parts by position, long jobs first, baselines after the part's training jobs; a promoted
    part once its source part's last job ended. Each slot pays ``per_worker_s`` (imports) once."""
    closed: dict[str, float] = {}
    free = [(start_s, k, False) for k in range(max(1, slots))]
    heapq.heapify(free)
    for part in sorted(parts, key=lambda p: p.position):
        avail = closed.get(part.source, start_s) if part.source else start_s
        durations = sorted((j.cpu_s for j in part.jobs), reverse=True) + list(part.baselines_s)
        end = avail
        for seconds in durations:
            t, k, paid = heapq.heappop(free)
            finish = max(t, avail) + (0.0 if paid else per_worker_s) + seconds
            end = max(end, finish)
            heapq.heappush(free, (finish, k, True))
        closed[part.part] = end
    return max(closed.values(), default=start_s)


@dataclass
class Estimate:
    """The whole estimate, as ``run --dry-run --estimate`` prints it and the results keep it."""

    parts: list[PartCost]
    workers: int
    cluster_cpus: int | None
    worker: WorkerStart
    contention: float
    """Measured slow-down of a worker when the run's workers share this machine's cores."""
    calibration_s: float
    rates: dict[str, dict[str, Any]]
    adaptive: Adaptive | None = None
    """A sequential run's design: the parts are priced at min_seeds, plus its waves."""

    def to_json(self) -> dict[str, Any]:
        per_worker = self.worker.start_s + self.worker.first_job_s - self.worker.next_job_s
        rows = [p.summary() for p in self.parts]
        left = self.workers
        for row in rows:  # each worker pays its start once, in the first part it serves
            starts = min(left, row["jobs"] + row["baselines"])
            left -= starts
            clock = row.pop("clock_s")  # budgeted runs' own CPU budgets: not slowed
            for key in ("cpu_s", "cpu_s_low", "cpu_s_high", "cpu_s_max"):
                row[key] = (max(row[key] - clock, 0.0) + starts * per_worker) * self.contention \
                    + min(clock, row[key])
            row["cpu_h"] = row["cpu_s"] / 3600.0
        cpu = sum(r["cpu_s"] for r in rows)
        low = sum(r["cpu_s_low"] for r in rows)
        high = sum(r["cpu_s_high"] for r in rows)
        scaled = [PartCost(p.part, p.position, p.source,
                           [j.scaled(self.contention) for j in p.jobs],
                           [b * self.contention for b in p.baselines_s]) for p in self.parts]
        wall = simulate_wall(scaled, self.workers, per_worker_s=per_worker * self.contention)
        out: dict[str, Any] = {
            "parts": rows,
            "total": {
                "jobs": sum(r["jobs"] for r in rows),
                "baselines": sum(r["baselines"] for r in rows),
                "env_steps": sum(r["env_steps"] for r in rows),
                "updates": sum(r["updates"] for r in rows),
                "cpu_s": cpu, "cpu_s_low": low, "cpu_s_high": high,
                "cpu_s_max": sum(r["cpu_s_max"] for r in rows),
                "cpu_h": cpu / 3600.0,
                "wall_s": wall, "workers": self.workers,
                "wall_s_low": wall * low / cpu if cpu else wall,
                "wall_s_high": wall * high / cpu if cpu else wall,
                "contention": self.contention,
            },
            "worker": self.worker.to_json(), "calibration_s": self.calibration_s,
            "rates": self.rates,
            "model": "steps = episodes x measured exploring episode length; updates per step "
                     "after learning starts; tests at the untrained actor's length; cpu_s_max: "
                     "every episode and test to its step limit",
        }  # fmt: skip
        if self.cluster_cpus:
            out["total"]["cluster_cpus"] = self.cluster_cpus
            out["total"]["cluster_wall_s"] = simulate_wall(
                self.parts, self.cluster_cpus, start_s=RAY_INIT_S,
                per_worker_s=per_worker)
        if self.adaptive is not None:
            out["adaptive"] = adaptive_cost(self.parts, rows, self.adaptive, self.contention,
                                            out["total"])
        return out


RateSource = Callable[[RunSpec], Rates]


def rate_key(spec: RunSpec) -> str:
    """Specs that cost the same per step share one measurement: the agent, the env settings,
    the first train track and LAC (the observation size)."""
    outside = [spec.outside.model_dump_json()] if spec.outside is not None else []
    return "|".join([spec.agent.model_dump_json(), spec.env.model_dump_json(),
                     spec.train_tracks[0], str(spec.lac), spec.test_tracks[0], *outside])


def as_dict(rates: Rates) -> dict[str, Any]:
    return asdict(rates)


def adaptive_cost(parts: list[PartCost], rows: list[dict[str, Any]], design: Adaptive,
                  contention: float, total: dict[str, Any]) -> dict[str, Any]:
    """The CPU and wall time of a sequential run: its floor (every entrant at min_seeds: the
    estimate's total), worst case and expected case (the module's docstring)."""
    scale = (design.max_seeds - design.min_seeds) / design.min_seeds
    floor, floor_high = float(total["cpu_s"]), float(total["cpu_s_high"])
    extra = extra_high = 0.0
    for part, row in zip(parts, rows, strict=True):
        train = sum(j.scaled(contention).cpu_s for j in part.jobs)
        if train <= 0.0:
            continue
        extra += train * scale
        # the part's range, its baselines left out, scaled like its jobs
        share = train / max(row["cpu_s"], 1e-9)
        extra_high += row["cpu_s_high"] * share * scale
    unbudgeted = floor + extra
    unbudgeted_high = floor_high + extra_high
    budget_s = design.budget_cpu_h * 3600.0 if design.budget_cpu_h is not None else math.inf
    worst = max(floor_high, min(unbudgeted_high, budget_s))
    expected = floor + 0.5 * (min(unbudgeted, max(budget_s, floor)) - floor)
    wall = float(total["wall_s"])
    per_cpu = wall / floor if floor > 0 else 0.0
    cluster: dict[str, float] = {}
    train_jobs = [j for part in parts for j in part.jobs]
    if total.get("cluster_cpus") and train_jobs:
        # on a cluster each wave's runs go side by side (up to its CPUs), and a wave takes
        # about one run: the floor's wall, then one run per wave of the added CPU
        run_s = sum(j.cpu_s for j in train_jobs) / len(train_jobs)
        side = min(design.wave_seeds, int(total["cluster_cpus"]))
        for key, cpu in (("expected", expected), ("worst", worst)):
            waves = math.ceil(max(cpu - floor, 0.0) / (side * run_s))
            cluster[f"{key}_cluster_wall_s"] = float(total["cluster_wall_s"]) + waves * run_s
    return {
        **cluster,
        "min_seeds": design.min_seeds, "max_seeds": design.max_seeds,
        "wave_seeds": design.wave_seeds, "budget_cpu_h": design.budget_cpu_h,
        "floor_cpu_s": floor, "floor_cpu_h": floor / 3600.0,
        "expected_cpu_s": expected, "expected_cpu_h": expected / 3600.0,
        "worst_cpu_s": worst, "worst_cpu_h": worst / 3600.0,
        "worst_unbudgeted_cpu_s": unbudgeted_high,
        "expected_wall_s": expected * per_cpu, "worst_wall_s": worst * per_cpu,
        "model": "floor: every entrant at min_seeds; worst: every training part at max_seeds "
                 "(high end of its range), at most the budget; expected: the floor plus half "
                 "the room to the worst case (no effect size is known before the run)",
    }  # fmt: skip

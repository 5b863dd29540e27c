"""A planned tournament's cost estimate: measure the rates its jobs need, then apply the model.

Every distinct job cost (``estimate.model.rate_key``: agent, env settings, track, LAC) is
measured once, for ``seconds``, on the run specification the planner built for that job
(``Planner.run_spec``, the same spec the job would get); each distinct baseline drive is timed by
driving it (``bots.baselines.bot_report``; the lines it computes are cached on disk, as the run
would cache them). Nothing is written to the results folder here.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

from formula_tourney.bots.baselines import bot_report
from formula_tourney.sim.catalog import load_track
from formula_tourney.tourney.estimate.calibrate import Rates, WorkerStart, calibrate, worker_start
from formula_tourney.tourney.estimate.model import (
    Estimate,
    JobCost,
    PartCost,
    candidates_cost,
    job_cost,
    rate_key,
)
from formula_tourney.tourney.plan import PlannedPart, Planner, possible_variants, resolve_variant
from formula_tourney.training.run_spec import RunSpec

Report = Callable[[str], None]


def promoted_count(planner: Planner, item: PlannedPart) -> tuple[int, str]:
    """How many variants a promoted part receives at most under its rule, and that assumption
    in words."""
    part = item.part
    possible = possible_variants(planner.spec, part)
    rule = part.promotion
    units = len(possible)
    why = f"all {units} variants of {part.promoted_from} promoted"
    if rule.best_per_family:
        units = len({resolve_variant(planner.spec, v)[1] for v in possible})
        why = f"one per family ({units} families)"
    n = units
    if rule.top_k is not None and rule.top_k < n:
        n = rule.top_k
        why = f"top {n}"
    cost = ""
    if n < units:
        cost = ", each at the candidates' mean cost, the band from the cheapest to the dearest"
    elif rule.best_per_family:
        cost = ", each at its family's mean cost, the band from its cheapest to its dearest"
    return n, why + cost


def estimate_plan(planner: Planner, planned: list[PlannedPart], workers: int,
                  cluster_cpus: int | None = None, seconds: float = 1.0,
                  report: Report | None = None) -> Estimate:
    """Measure and estimate every part of ``planned`` (``report`` hears progress lines)."""
    began = time.perf_counter()
    first = next(((item, v) for item in planned for v in (item.variants or [])), None)
    start, contention = WorkerStart(0.0, 0.0, 0.0), 1.0
    if first is not None:
        if report is not None:
            report(f"timing a fresh worker and two minimal jobs, alone and {workers} at once")
        start, contention = worker_start(planner.run_spec(first[0].position, first[1], 0),
                                         workers)
    cache: dict[str, Rates] = {}
    rates_out: dict[str, dict] = {}

    def cost_of(spec: RunSpec, label: str) -> JobCost:
        key = rate_key(spec)
        if key not in cache:
            if report is not None:
                report(f"measuring {label} for {seconds:g} s")
            cache[key] = calibrate(spec, seconds)
            rates_out[label] = cache[key].to_json()
        return job_cost(spec, cache[key], start.next_job_s)

    bot_cache: dict[tuple[str, str, int], float] = {}
    parts: list[PartCost] = []
    for item in planned:
        part = item.part
        pc = PartCost(part.name, item.position, part.promoted_from)
        seeds = planner.seeds(part, "")  # a sequential run: every entrant at min_seeds
        if item.variants is not None:
            for variant in item.variants:
                for s_index in range(len(part.setups)):
                    label = f"{part.name}/{variant}#{s_index}"
                    base = cost_of(planner.run_spec(item.position, variant, s_index), label)
                    pc.jobs.extend([replace(base, group=label)] * seeds)
        else:
            count, pc.assumed = promoted_count(planner, item)
            possible = possible_variants(planner.spec, part)
            by_family = part.promotion.best_per_family
            for s_index in range(len(part.setups)):
                units: dict[str, list[JobCost]] = {}
                for v in possible:
                    unit = resolve_variant(planner.spec, v)[1] if by_family else v
                    units.setdefault(unit, []).append(cost_of(
                        planner.run_spec(item.position, v, s_index), f"{part.name}/{v}#{s_index}"))
                jobs = candidates_cost(units, count, f"{part.name}#{s_index}")
                pc.jobs.extend(job for job in jobs for _ in range(seeds))
        for job in item.baselines:
            key = (str(job.spec["track"]), str(job.spec["reference"]), int(job.spec["laps"]))
            if key not in bot_cache:
                if report is not None:
                    report(f"timing the {job.spec['bot']} baseline on {key[0]}")
                t = time.perf_counter()
                bot_report(load_track(key[0]), key[1], laps=key[2])
                bot_cache[key] = time.perf_counter() - t
            pc.baselines_s.append(bot_cache[key])
        parts.append(pc)
    return Estimate(parts=parts, workers=workers, cluster_cpus=cluster_cpus,
                    worker=start, contention=contention, calibration_s=time.perf_counter() - began,
                    rates=rates_out, adaptive=planner.spec.adaptive)

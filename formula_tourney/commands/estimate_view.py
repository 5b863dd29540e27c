"""How a cost estimate looks in a terminal: one row per part and the total (CLI layer only)."""

from __future__ import annotations

from typing import Any

from rich.console import Console
from rich.table import Table


def hours(seconds: float) -> str:
    """CPU or wall time in hours, minutes below an hour, seconds below a minute."""
    if seconds != seconds:
        return "-"
    if seconds >= 3600:
        return f"{seconds / 3600.0:.2f} h"
    return f"{seconds / 60.0:.1f} min" if seconds >= 60 else f"{seconds:.1f} s"


def steps(n: float) -> str:
    return f"{n / 1e6:.2f}M" if n >= 1e6 else f"{n / 1e3:.1f}k" if n >= 1e3 else f"{n:.0f}"


def render_estimate(console: Console, est: dict[str, Any]) -> None:
    """Per part: jobs, env steps, CPU time with its ~95 % range and the no-early-end bound;
    then the total and the wall time for the workers (and a Ray cluster)."""
    table = Table(title="cost estimate (rates measured here just now)", title_justify="left")
    for col in ("part", "jobs", "env steps", "CPU", "CPU ~95%", "CPU max", "note"):
        table.add_column(col, justify="left" if col in ("part", "note") else "right")
    for row in est["parts"]:
        jobs = f"{row['jobs']}" + (f" +{row['baselines']} bots" if row["baselines"] else "")
        table.add_row(row["part"], jobs, steps(row["env_steps"]), hours(row["cpu_s"]),
                      f"{hours(row['cpu_s_low'])}-{hours(row['cpu_s_high'])}",
                      hours(row["cpu_s_max"]), row.get("assumed") or "")
    tot = est["total"]
    table.add_row("total", str(tot["jobs"]), steps(tot["env_steps"]), hours(tot["cpu_s"]),
                  f"{hours(tot['cpu_s_low'])}-{hours(tot['cpu_s_high'])}",
                  hours(tot["cpu_s_max"]), "", end_section=True)
    console.print(table)
    console.print(f"wall time on {tot['workers']} workers: {hours(tot['wall_s'])} "
                  f"({hours(tot['wall_s_low'])}-{hours(tot['wall_s_high'])})"
                  + (f"; on a Ray cluster of {tot['cluster_cpus']} CPUs: "
                     f"{hours(tot['cluster_wall_s'])}" if tot.get("cluster_cpus") else ""))
    if est.get("adaptive"):
        ad = est["adaptive"]
        budget = f", budget {ad['budget_cpu_h']:g} CPU-h" if ad.get("budget_cpu_h") else ""
        console.print(f"sequential run ({ad['min_seeds']}-{ad['max_seeds']} seeds, waves of "
                      f"{ad['wave_seeds']}{budget}): the total above is its floor; expected "
                      f"{hours(ad['expected_cpu_s'])} CPU ({hours(ad['expected_wall_s'])} wall), "
                      f"worst case {hours(ad['worst_cpu_s'])} CPU ({hours(ad['worst_wall_s'])} "
                      "wall)" + (f"; on the cluster, waves of {ad['wave_seeds']}: expected "
                                 f"{hours(ad['expected_cluster_wall_s'])}, worst "
                                 f"{hours(ad['worst_cluster_wall_s'])} wall"
                                 if "expected_cluster_wall_s" in ad else ""), markup=False)
    worker = est["worker"]
    console.print(f"  {est['model']}; measured in {est['calibration_s']:.0f} s: a worker "
                  f"starts in {worker['start_s']:.1f} s, its first job costs "
                  f"{worker['first_job_s']:.1f} s and later ones {worker['next_job_s']:.1f} s "
                  f"beyond their steps; workers sharing the cores run x"
                  f"{tot.get('contention', 1.0):.2f} slower", markup=False)

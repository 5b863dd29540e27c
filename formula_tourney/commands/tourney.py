"""CLI commands for tournaments: ``run`` (plan, train, promote, resume) and ``tune`` (Optuna).

Exit codes of ``run`` (and ``demo``), documented in docs/tourney.md and ``run --help``:
0 every job done; 2 bad input or unreadable results (nothing was started); 3 the run ended but
some jobs failed; 130 interrupted (Ctrl-C). 2 comes from ``cli.main`` (UserInputError).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from formula_tourney.commands.output import emit, message
from formula_tourney.commands.tourney_view import ProgressView, render_results, render_tune
from formula_tourney.safeio import check_output_path

EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_JOBS_FAILED = 3
EXIT_INTERRUPTED = 130

RUN_EXIT_HELP = (
    "Exit codes: 0 every job done; 2 bad input or unreadable results, nothing started; "
    "3 some jobs failed (run again with --retry-failed); 130 interrupted (run again to resume)."
)


def interrupted() -> typer.Exit:
    """The message and exit of a Ctrl-C: finished jobs are recorded, the rest resumes."""
    message("interrupted: finished jobs are kept; run the same command to resume")
    return typer.Exit(EXIT_INTERRUPTED)


def failures_exit(result: dict[str, Any]) -> int:
    """Exit code of a finished run, with the one message that says how to re-run failures."""
    failures = result.get("failures") or []
    if not failures:
        return EXIT_OK
    message(f"{len(failures)} job(s) failed; run again with --retry-failed to re-run them "
            "(the parts they closed are re-opened and promotion is computed again)")
    return EXIT_JOBS_FAILED


def register(app: typer.Typer) -> None:
    """Add this area's commands to the main app."""

    @app.command(epilog=RUN_EXIT_HELP)
    def run(
        file: Path = typer.Argument(..., help="Tournament file, e.g. tournaments/quick.toml."),
        dry_run: bool = typer.Option(
            False, "--dry-run", help="Validate every job's settings, print the plan and exit."
        ),
        workers: int | None = typer.Option(
            None, "--workers",
            help="Parallel jobs (default: the CPU cores this process may use; with --executor "
            "ray --address, the cluster's CPUs).",
        ),
        executor: str = typer.Option(
            "local", "--executor",
            help="local (process pool), ray, slurm (Slurm job arrays through submitit) or "
            "slurm-local (submitit's local processes: the Slurm code path without Slurm).",
        ),
        address: str | None = typer.Option(
            None, "--address", help="Ray cluster address (default: a local Ray instance)."
        ),
        retries: int = typer.Option(
            0, "--retries", help="Extra attempts for a failing job within this run."
        ),
        retry_failed: bool = typer.Option(
            False, "--retry-failed",
            help="Re-run the jobs that failed in earlier runs, re-opening the parts they closed "
            "and computing their promotion again.",
        ),
        rebuild_index: bool = typer.Option(
            False, "--rebuild-index",
            help="Move index.sqlite aside (index.sqlite.corrupt when unreadable) and rebuild it "
            "from the job folders.",
        ),
        results: Path = typer.Option(
            Path("results"), "--results", help="Results folder; the tournament goes in NAME/."
        ),
        estimate: bool = typer.Option(
            False, "--estimate",
            help="Measure this machine's env steps and updates for each distinct job first and "
            "estimate jobs, env steps, CPU-hours and wall time per part: printed with "
            "--dry-run, else kept in the results folder for the report.",
        ),
        calibrate_s: float = typer.Option(
            1.0, "--calibrate-s", help="--estimate: seconds measured per distinct job (at "
            "least 0.5)."
        ),
        cluster_cpus: int | None = typer.Option(
            None, "--cluster-cpus", help="--estimate: also the wall time on a Ray cluster of "
            "this many CPUs."
        ),
        budget_cpu_h: float | None = typer.Option(
            None, "--budget-cpu-h", help="Run sequentially: seeds added in waves where the "
            "claims are undecided, until they are decided, this many CPU-hours are spent or "
            "max_seeds is reached (the file's adaptive table, or its defaults; "
            "docs/claims.md).",
        ),
        wave_seeds: int | None = typer.Option(
            None, "--wave-seeds", help="Sequential run: new runs per wave instead of the "
            "adaptive table's wave_seeds (on a cluster: its CPUs, so a wave runs side by side)."
        ),
        job_timeout_s: float | None = typer.Option(
            None, "--job-timeout-s",
            help="Stop a job that runs longer than this and fail it ('timed out after N s'); "
            "the other jobs go on.",
        ),
        slurm_partition: str | None = typer.Option(
            None, "--slurm-partition", help="slurm: partition (default: the cluster's default)."
        ),
        slurm_time_min: int | None = typer.Option(
            None, "--slurm-time-min",
            help="slurm: time limit of one job in minutes (default 60); at the limit the job is "
            "requeued and continues from its files.",
        ),
        slurm_mem_gb: float | None = typer.Option(
            None, "--slurm-mem-gb", help="slurm: memory of one job in GB (default 4)."
        ),
        slurm_cpus_per_job: int | None = typer.Option(
            None, "--slurm-cpus-per-job", help="slurm: CPUs of one job (default 1)."
        ),
        slurm_max_parallel: int | None = typer.Option(
            None, "--slurm-max-parallel",
            help="slurm: jobs queued or running at once, the job array's cap (default 8).",
        ),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """Run a tournament (again: resume it). Jobs are entrant x seed x part."""
        # agents, sim and the report's readers: not for --help
        from formula_tourney.report.claims.judge import judge
        from formula_tourney.tourney.api import run_tournament
        from formula_tourney.tourney.slurm_executor import slurm_settings

        check_output_path(results, "--results", folder=True)
        given = {"partition": slurm_partition, "time_min": slurm_time_min,
                 "mem_gb": slurm_mem_gb, "cpus_per_job": slurm_cpus_per_job,
                 "max_parallel": slurm_max_parallel}
        slurm = slurm_settings(**given) if any(v is not None for v in given.values()) else None
        try:
            result = run_tournament(
                file, workers=workers, executor=executor, address=address, retries=retries,
                results_dir=results, dry_run=dry_run, retry_failed=retry_failed,
                rebuild_index=rebuild_index, progress=None if dry_run else ProgressView(),
                estimate=estimate, calibrate_s=calibrate_s, cluster_cpus=cluster_cpus,
                report=message, budget_cpu_h=budget_cpu_h, wave_seeds=wave_seeds, judge=judge,
                job_timeout_s=job_timeout_s, slurm=slurm,
            )
        except KeyboardInterrupt:
            raise interrupted() from None
        if result.get("index_moved_to"):
            message(f"moved the old index to {result['index_moved_to']}; rebuilt it from the "
                    "job folders")
        emit(result, as_json, lambda console: render_results(console, result))
        stopped = (result.get("adaptive") or {}).get("stopped")
        if stopped and not as_json:
            verdicts = ", ".join(f"{k} {v}" for k, v in stopped["claims"].items())
            message(f"sequential run stopped after {stopped['waves']} wave(s): "
                    f"{stopped['reason']}" + (f" ({verdicts})" if verdicts else ""))
        if not dry_run:
            raise typer.Exit(failures_exit(result))

    @app.command()
    def tune(
        file: Path = typer.Argument(..., help="Tune file with a search table, e.g. "
                                    "tournaments/tune.toml."),
        variant: str = typer.Option(..., "--variant", help="Variant to tune, e.g. WIN4."),
        trials: int = typer.Option(..., "--trials", help="Finished trials wanted in the study."),
        workers: int | None = typer.Option(None, "--workers", help="Parallel trials."),
        storage: str | None = typer.Option(
            None, "--storage",
            help="Optuna storage URL (e.g. postgresql://... for many machines); default: a "
            "JournalFileBackend file under the results folder.",
        ),
        resume: bool = typer.Option(False, "--resume", help="Continue an existing study."),
        write_best: Path | None = typer.Option(
            None, "--write-best", help="Merge the best parameters into this tournament "
            "file's overrides of the variant."
        ),
        results: Path = typer.Option(Path("results"), "--results", help="Results folder."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """Pre-select a variant's hyperparameters with Optuna (TPE, pruning on test laps)."""
        from formula_tourney.tourney.tune.run import run_tune  # imports optuna: only when tuning

        try:
            result = run_tune(
                file, variant=variant, trials=trials, workers=workers, storage=storage,
                resume=resume, write_best=write_best, results_dir=results,
                report=None if as_json else message,
            )
        except KeyboardInterrupt:
            raise interrupted() from None
        emit(result, as_json, lambda console: render_tune(console, result))

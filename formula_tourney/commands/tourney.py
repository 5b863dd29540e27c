"""CLI commands for tournaments: ``run`` (plan, train, promote, resume) and ``tune`` (Optuna)."""

from __future__ import annotations

from pathlib import Path

import typer

from formula_tourney.commands.output import emit, message


def register(app: typer.Typer) -> None:
    """Add this area's commands to the main app."""

    @app.command()
    def run(
        file: Path = typer.Argument(..., help="Tournament file, e.g. tournaments/quick.toml."),
        dry_run: bool = typer.Option(False, "--dry-run", help="Print the plan and exit."),
        workers: int | None = typer.Option(
            None, "--workers", help="Parallel jobs (default: the CPU cores this process may use)."
        ),
        executor: str = typer.Option("local", "--executor", help="local (process pool) or ray."),
        address: str | None = typer.Option(
            None, "--address", help="Ray cluster address (default: a local Ray instance)."
        ),
        retries: int = typer.Option(0, "--retries", help="Extra attempts for a failing job."),
        results: Path = typer.Option(
            Path("results"), "--results", help="Results folder; the tournament goes in NAME/."
        ),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """Run a tournament (again: resume it). Jobs are entrant x seed x part."""
        from formula_tourney.tourney.api import render_results, run_tournament

        try:
            result = run_tournament(
                file, workers=workers, executor=executor, address=address, retries=retries,
                results_dir=results, dry_run=dry_run, show_progress=not dry_run,
            )
        except KeyboardInterrupt:
            message("interrupted: finished jobs are kept; run the same command to resume")
            raise typer.Exit(130) from None
        emit(result, as_json, lambda console: render_results(console, result))
        if not dry_run and result["failures"]:
            message(f"{len(result['failures'])} job(s) failed; run again to retry them")

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
        from formula_tourney.tourney.tune import render_tune, run_tune

        result = run_tune(
            file, variant=variant, trials=trials, workers=workers, storage=storage,
            resume=resume, write_best=write_best, results_dir=results,
            show_progress=not as_json,
        )
        emit(result, as_json, lambda console: render_tune(console, result))

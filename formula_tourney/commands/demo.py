"""``formula-tourney demo``: the tool's main job on its built-in default.

Runs (or resumes) the shipped ``quick`` tournament -- WIN1 and WIN4 on the oval, then WIN1 on the
technical track (``tournaments/quick.toml`` says why) -- and prints its Table 1 with confidence
intervals. ``make demo`` calls it.
"""

from __future__ import annotations

from pathlib import Path

import typer

from formula_tourney.commands.output import emit, message, stdout_console
from formula_tourney.commands.tourney import failures_exit, interrupted
from formula_tourney.commands.tourney_view import ProgressView
from formula_tourney.errors import UserInputError


def quick_tournament_path() -> Path:
    """``tournaments/quick.toml`` of the source checkout (``make demo`` runs from one)."""
    checkout = Path(__file__).resolve().parents[2] / "tournaments" / "quick.toml"
    if not checkout.is_file():
        raise UserInputError(f"{checkout}: the quick tournament file is missing")
    return checkout


def register(app: typer.Typer) -> None:
    @app.command()
    def demo(
        workers: int = typer.Option(None, help="Worker processes (default: one per core)."),
        results: Path = typer.Option(Path("results"), help="Results folder."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """Run the quick tournament (WIN1 and WIN4 on the oval, WIN1 on technical); print Table 1.

        Exit codes as for run: 0 every job done, 2 bad input, 3 some jobs failed, 130
        interrupted."""
        from formula_tourney.report.build import build_report
        from formula_tourney.tourney.api import run_tournament

        path = quick_tournament_path()
        message(f"demo: running {path} into {results}/ (resumes if already run)")
        try:
            outcome = run_tournament(path, workers=workers, results_dir=results,
                                     progress=None if as_json else ProgressView())
        except KeyboardInterrupt:
            raise interrupted() from None
        report = build_report(outcome.get("tournament", "quick"), results)
        emit({"run": outcome, "report": report.to_json()}, as_json,
             lambda _console: report.render_tables(stdout_console, ("table1",)))
        raise typer.Exit(failures_exit(outcome))

"""CLI: ``report`` (the paper's tables, statistics, figures) and ``replay`` (a lap as a GIF)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from formula_tourney.commands.output import emit, message
from formula_tourney.safeio import check_output_path


def register(app: typer.Typer) -> None:
    """Add this area's commands to the main app."""

    @app.command()
    def report(
        tournament: Annotated[str | None, typer.Option(
            "--tournament", "-t",
            help="Tournament name (a folder under --results) or path to its folder; default: "
                 "the most recently written tournament.")] = None,
        part: Annotated[str | None, typer.Option(
            help="Report one part only.")] = None,
        out: Annotated[Path | None, typer.Option(
            help="Folder for written files (default: <tournament>/report).")] = None,
        markdown: Annotated[bool, typer.Option(
            "--markdown", help="Print GitHub Markdown (and write report.md with --out). Formats "
                               "combine: --markdown --latex --html writes all three.")] = False,
        latex: Annotated[bool, typer.Option(
            "--latex", help="Write tables.tex (standalone, booktabs) and one .tex per table; "
                            "prints the path.")] = False,
        html: Annotated[bool, typer.Option(
            "--html", help="Write a one-page report.html with tables and figures.")] = False,
        figures: Annotated[bool | None, typer.Option(
            "--figures/--no-figures",
            help="Draw figures (PNG+PDF); default on for --latex, --html and with --out.")] = None,
        results: Annotated[Path, typer.Option(
            help="Folder holding tournament results.")] = Path("results"),
        claims: Annotated[list[str] | None, typer.Option(
            "--claims",
            help="Claims to check: a shipped set (paper) or a claims file; repeatable. Default: "
                 "the tournament file's [claims], else the paper's findings.")] = None,
        no_claims: Annotated[bool, typer.Option(
            "--no-claims", help="Leave the claims section out.")] = False,
        as_json: Annotated[bool, typer.Option(
            "--json", help="Print one JSON document (tables with CIs, problems, files).")] = False,
    ) -> None:
        """Tables 1-3 of the paper with 95% CIs, gap to the reference limit, and figures."""
        # Loading the report pulls pandas and scipy (about 1 s): only when this command runs.
        from formula_tourney.report.build import build_report

        if out is not None:
            check_output_path(out, "--out", folder=True)
        chosen = [name for name, on in (("markdown", markdown), ("latex", latex),
                                        ("html", html)) if on]
        if figures or (figures is None and ({"latex", "html"} & set(chosen) or out is not None)):
            message("drawing figures (PNG and PDF); --no-figures skips them")
        built = build_report(tournament, results, part=part, out_dir=out, formats=chosen,
                             figures=figures, claims=None if no_claims else (claims or []))
        if markdown and not as_json:
            for line in built.written():  # stdout is the Markdown document alone
                message(line)
        emit(built.to_json(), as_json, built.render)

    @app.command()
    def replay(
        checkpoint: Annotated[Path, typer.Argument(help="A checkpoint (.pt) of a trained job.")],
        track: Annotated[str, typer.Option(help="Track to drive (name or path).")],
        gif: Annotated[Path, typer.Option(help="GIF file to write.")],
        laps: Annotated[int, typer.Option(min=1, help="Timed laps to record.")] = 1,
        max_steps: Annotated[int, typer.Option(min=1, help="Control steps at most.")] = 3000,
        frame_every: Annotated[int, typer.Option(
            min=1, help="Keep every n-th control step as a frame.")] = 2,
        as_json: Annotated[bool, typer.Option("--json", help="Print one JSON document.")] = False,
    ) -> None:
        """Drive one lap with a trained actor (no exploration) and write it as a GIF."""
        from formula_tourney.commands.output import emit
        from formula_tourney.training.replay import replay as run_replay

        check_output_path(gif, "--gif")
        summary = run_replay(checkpoint, track, gif, max_steps=max_steps,
                             frame_every=frame_every, laps=laps)

        def render(console) -> None:
            laps_s = ", ".join(f"{t:.2f} s" for t in summary["lap_times_s"]) or "no timed lap"
            console.print(f"{summary['gif']}: {summary['frames']} frames, {summary['steps']} "
                          f"steps, ended by {summary['ending']}, laps: {laps_s}",
                          markup=False, highlight=False)

        emit(summary, as_json, render)

"""CLI: ``report`` (the paper's tables, statistics, figures)."""

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
            "--latex", help="Write report.tex (a whole document) and one .tex float per "
                            "table for a paper; prints the paths.")] = False,
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
                 "the tournament file's \\[claims], else the paper's findings.")] = None,
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

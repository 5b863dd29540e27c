"""``report`` end to end: load a tournament, build the tables, write the requested formats.

The CLI calls ``build_report`` once; tests and ``demo`` call it too, so what a user sees and what
is tested are the same code path. One call may write several formats (Markdown, LaTeX, HTML)
from the same tables and figures.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rich.text import Text

from formula_tourney.errors import UserInputError
from formula_tourney.report.claims.evaluate import evaluate_all
from formula_tourney.report.claims.figures import make_claim_figures
from formula_tourney.report.claims.sources import resolve_claims
from formula_tourney.report.claims.table import claims_table
from formula_tourney.report.claims.waves import waves_table
from formula_tourney.report.competence_table import competence_table
from formula_tourney.report.cost import cost_table
from formula_tourney.report.grip_table import grip_table
from formula_tourney.report.html import render_page
from formula_tourney.report.load import TournamentData, load_tournament, resolve_tournament
from formula_tourney.report.paper_tables import Context, build_tables
from formula_tourney.report.plots import make_figures
from formula_tourney.report.race_table import load_race_parts, race_figures, race_table
from formula_tourney.report.renderers import render_markdown, render_rich, write_latex
from formula_tourney.report.table_model import ReportTable
from formula_tourney.results.index import read_meta
from formula_tourney.safeio import atomic_write_text

FORMATS = ("markdown", "latex", "html")
"""Formats a report can be written in, besides the terminal (the default when none is asked)."""


@dataclass
class Report:
    """A built report: the data it read, its tables, and every file it wrote."""

    data: TournamentData
    tables: list[ReportTable]
    formats: tuple[str, ...]
    out_dir: Path | None
    files: dict[str, Path] = field(default_factory=dict)
    figures: dict[str, list[Path]] = field(default_factory=dict)
    markdown: str = ""

    def to_json(self) -> dict[str, Any]:
        """The one JSON document of ``report --json``."""
        return {
            "tournament": self.data.name, "root": str(self.data.root),
            "formats": list(self.formats),
            "jobs": _job_counts(self.data), "problems": list(self.data.problems),
            "tables": {t.key: t.to_json() for t in self.tables},
            "files": {k: str(v) for k, v in self.files.items()},
            "figures": {k: [str(p) for p in v] for k, v in self.figures.items()},
        }

    def render(self, console: Any) -> None:
        """Terminal output: problems first (so a partial report is never mistaken for whole).

        With Markdown among the formats, stdout carries the Markdown document alone (so it can be
        piped into a file); the files written are listed by the caller on stderr.
        """
        if "markdown" in self.formats:
            console.print(self.markdown, markup=False, highlight=False, soft_wrap=True)
            return
        counts = _job_counts(self.data)
        console.print(Text.assemble((self.data.name, "bold"), f"  ({self.data.root})  jobs: "
                                    + ", ".join(f"{k} {v}" for k, v in counts.items())))
        if self.data.problems:
            console.print(Text("Missing or failed:", style="yellow"))
            for problem in self.data.problems:
                console.print(f"  - {problem}", markup=False)
        if not self.formats:
            for table in self.tables:
                render_rich(table, console)
        for line in self.written():
            console.print(line, markup=False, highlight=False)

    def written(self) -> list[str]:
        """One line per file written and one for the figures."""
        lines = [f"wrote {name}: {path}" for name, path in self.files.items()]
        if self.figures:
            lines.append(f"wrote {sum(len(v) for v in self.figures.values())} figure files "
                         f"to {next(iter(self.figures.values()))[0].parent}")
        return lines

    def render_tables(self, console: Any, keys: tuple[str, ...] = ("table1",)) -> None:
        """Only some tables, e.g. Table 1 at the end of ``demo``; problems are still said."""
        for problem in self.data.problems:
            console.print(f"  - {problem}", markup=False)
        for table in self.tables:
            if table.key in keys:
                render_rich(table, console)


def _job_counts(data: TournamentData) -> dict[str, int]:
    if data.jobs.empty:
        return {"total": 0}
    counts = data.jobs["status"].value_counts().to_dict()
    return {"total": len(data.jobs), **{str(k): int(v) for k, v in counts.items()}}


def check_formats(formats: str | Sequence[str]) -> tuple[str, ...]:
    """The asked formats, in FORMATS order, each once; "terminal" (or none) is the terminal."""
    asked = [formats] if isinstance(formats, str) else list(formats)
    unknown = [f for f in asked if f not in (*FORMATS, "terminal")]
    if unknown:
        raise UserInputError(f"unknown report format {unknown[0]!r}; choose from "
                             f"{', '.join(FORMATS)} (or none for the terminal)")
    return tuple(f for f in FORMATS if f in asked)


def build_report(tournament: str | None = None, results_dir: str | Path = "results",
                 part: str | None = None, out_dir: str | Path | None = None,
                 formats: str | Sequence[str] = (), figures: bool | None = None,
                 claims: Sequence[str] | None = ()) -> Report:
    """Load, tabulate and write every format in ``formats`` (any of markdown, latex, html;
    none: the terminal). ``figures`` defaults to on for LaTeX and HTML (which embed them) and
    when an ``out_dir`` is given; files go to ``out_dir`` or ``<tournament>/report``.
    ``claims``: shipped claim sets or claims files to check (empty: the tournament's own
    ``[claims]``, else the paper's; None: no claims section)."""
    chosen = check_formats(formats)
    root = resolve_tournament(tournament, results_dir)
    # claims are validated before the results are read: a bad claims file is exit 2 at once
    declared = resolve_claims(claims, read_meta(root)) if claims is not None else None
    data = load_tournament(root, part=part)
    ctx = Context.build(data)
    tables = build_tables(ctx)
    grips = grip_table(ctx)
    if not grips.empty:  # only a study that tested at several grips has one
        tables.append(grips)
    competence = competence_table(ctx)
    if not competence.empty:  # only parts with a CPU budget (budget_cpu_s) have one
        tables.append(competence)
    claim_results = evaluate_all(ctx, declared[0]) if declared is not None else []
    if declared is not None:
        tables.append(claims_table(claim_results, declared[1]))
    waves = waves_table(root)
    if not waves.empty:  # only a sequential run ([adaptive]) has one
        tables.append(waves)
    races = load_race_parts(root, part, data.problems)  # race parts' series (<part>/_races/)
    tables.extend(race_table(item) for item in races)
    if not data.jobs.empty:
        tables.append(cost_table(data))
    out = Path(out_dir) if out_dir is not None else None
    embeds = {"latex", "html"} & set(chosen)
    if figures is None:
        figures = bool(embeds) or out is not None
    writes = figures or bool(embeds) or ("markdown" in chosen and out is not None)
    if writes and out is None:
        out = root / "report" if part is None else root / "report" / part
    report = Report(data=data, tables=tables, formats=chosen, out_dir=out)
    title = f"Tournament {data.name}" + (f", part {part}" if part else "")
    if figures and out is not None:
        report.figures = make_figures(ctx, tables, out / "figures")
        report.figures.update(make_claim_figures(ctx, claim_results, out / "figures"))
        report.figures.update(race_figures(races, out / "figures"))
    if "markdown" in chosen:
        report.markdown = markdown_document(title, tables, data.problems)
        if out is not None:
            report.files["report.md"] = atomic_write_text(out / "report.md", report.markdown)
    if "latex" in chosen and out is not None:
        pdfs = {k: next((p for p in v if p.suffix == ".pdf"), None)
                for k, v in report.figures.items()}
        report.files.update(write_latex(
            tables, out, title, data.problems,
            figures={k: p.relative_to(out) for k, p in pdfs.items() if p is not None},
        ))
    if "html" in chosen and out is not None:
        page = render_page(title, tables, report.figures, data.problems,
                           summary={"root": data.root, **_job_counts(data)})
        report.files["report.html"] = atomic_write_text(out / "report.html", page)
    return report


def markdown_document(title: str, tables: list[ReportTable], problems: list[str]) -> str:
    lines = [f"# {title}", ""]
    if problems:
        lines.append("**Missing or failed jobs**")
        lines.append("")
        lines.extend(f"- {p}" for p in problems)
        lines.append("")
    lines.extend(render_markdown(t) for t in tables)
    return "\n".join(lines)

"""``report`` end to end: load a tournament, build the tables, write the requested formats.

The CLI calls ``build_report`` once; tests and ``demo`` call it too, so what a user sees and what
is tested are the same code path.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from formula_tourney.errors import UserInputError
from formula_tourney.report import tables as tables_mod
from formula_tourney.report.load import TournamentData, load_tournament, resolve_tournament
from formula_tourney.safeio import atomic_write_text

FORMATS = ("terminal", "markdown", "latex", "html")


@dataclass
class Report:
    """A built report: the data it read, its tables, and every file it wrote."""

    data: TournamentData
    tables: list[tables_mod.ReportTable]
    fmt: str
    out_dir: Path | None
    files: dict[str, Path] = field(default_factory=dict)
    figures: dict[str, list[Path]] = field(default_factory=dict)
    markdown: str = ""

    def to_json(self) -> dict[str, Any]:
        """The one JSON document of ``report --json``."""
        return {
            "tournament": self.data.name, "root": str(self.data.root), "format": self.fmt,
            "jobs": _job_counts(self.data), "problems": list(self.data.problems),
            "tables": {t.key: t.to_json() for t in self.tables},
            "files": {k: str(v) for k, v in self.files.items()},
            "figures": {k: [str(p) for p in v] for k, v in self.figures.items()},
        }

    def render(self, console: Any) -> None:
        """Terminal output: problems first (so a partial report is never mistaken for whole)."""
        if self.fmt == "markdown":
            console.print(self.markdown, markup=False, highlight=False, soft_wrap=True)
            return
        counts = _job_counts(self.data)
        console.print(f"[bold]{self.data.name}[/bold]  ({self.data.root})  jobs: "
                      + ", ".join(f"{k} {v}" for k, v in counts.items()))
        if self.data.problems:
            console.print("[yellow]Missing or failed:[/yellow]")
            for problem in self.data.problems:
                console.print(f"  - {problem}", markup=False)
        if self.fmt == "terminal":
            for table in self.tables:
                tables_mod.render_rich(table, console)
        for name, path in self.files.items():
            console.print(f"wrote {name}: {path}", markup=False, highlight=False)
        if self.figures:
            console.print(f"wrote {sum(len(v) for v in self.figures.values())} figure files "
                          f"to {next(iter(self.figures.values()))[0].parent}",
                          markup=False, highlight=False)


    def render_tables(self, console: Any, keys: tuple[str, ...] = ("table1",)) -> None:
        """Only some tables, e.g. Table 1 at the end of ``demo``; problems are still said."""
        for problem in self.data.problems:
            console.print(f"  - {problem}", markup=False)
        for table in self.tables:
            if table.key in keys:
                tables_mod.render_rich(table, console)


def _job_counts(data: TournamentData) -> dict[str, int]:
    if data.jobs.empty:
        return {"total": 0}
    counts = data.jobs["status"].value_counts().to_dict()
    return {"total": len(data.jobs), **{str(k): int(v) for k, v in counts.items()}}


def build_report(tournament: str | None = None, results_dir: str | Path = "results",
                 part: str | None = None, out_dir: str | Path | None = None,
                 fmt: str = "terminal", figures: bool | None = None) -> Report:
    """Load, tabulate and write. ``figures`` defaults to on for LaTeX and HTML (which embed
    them) and when an ``out_dir`` is given; files go to ``out_dir`` or ``<tournament>/report``."""
    if fmt not in FORMATS:
        raise UserInputError(f"unknown report format {fmt!r}; choose one of {', '.join(FORMATS)}")
    root = resolve_tournament(tournament, results_dir)
    data = load_tournament(root, part=part)
    tables = tables_mod.build_tables(data)
    out = Path(out_dir) if out_dir is not None else None
    if figures is None:
        figures = fmt in ("latex", "html") or out is not None
    writes = figures or fmt in ("latex", "html") or (fmt == "markdown" and out is not None)
    if writes and out is None:
        out = root / "report" if part is None else root / "report" / part
    report = Report(data=data, tables=tables, fmt=fmt, out_dir=out)
    title = f"Tournament {data.name}" + (f", part {part}" if part else "")
    if figures and out is not None:
        from formula_tourney.report.plots import make_figures

        report.figures = make_figures(data, tables, out / "figures")
    if fmt == "markdown":
        report.markdown = markdown_document(title, tables, data.problems)
        if out is not None:
            report.files["report.md"] = atomic_write_text(out / "report.md", report.markdown)
    elif fmt == "latex":
        pdfs = {k: next((p for p in v if p.suffix == ".pdf"), None)
                for k, v in report.figures.items()}
        report.files.update(tables_mod.write_latex(
            tables, out, title, data.problems,
            figures={k: p.relative_to(out) for k, p in pdfs.items() if p is not None},
        ))
    elif fmt == "html":
        from formula_tourney.report.html import render_page

        page = render_page(title, tables, report.figures, data.problems,
                           summary={"root": data.root, **_job_counts(data)})
        report.files["report.html"] = atomic_write_text(out / "report.html", page)
    return report


def markdown_document(title: str, tables: list[tables_mod.ReportTable],
                      problems: list[str]) -> str:
    lines = [f"# {title}", ""]
    if problems:
        lines.append("**Missing or failed jobs**")
        lines.append("")
        lines.extend(f"- {p}" for p in problems)
        lines.append("")
    lines.extend(tables_mod.render_markdown(t) for t in tables)
    return "\n".join(lines)

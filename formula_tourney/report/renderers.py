"""Renderers of report tables: rich terminal, GitHub Markdown and LaTeX (booktabs).

Each reads a ``ReportTable`` (``report.table_model``) and writes its display text; none computes
a number. The HTML page is ``report.html``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from formula_tourney.report.table_model import DASH, ReportTable
from formula_tourney.safeio import atomic_write_text


def render_rich(table: ReportTable, console: Any) -> None:
    """One rich table per column group: the paper's wide layout does not fit a terminal."""
    from rich.table import Table
    from rich.text import Text

    console.print(Text(table.title, style="bold"))
    if table.empty:
        console.print("  (empty) " + "; ".join(table.notes))
        return
    best = table.best_cells()
    for group in table.groups:
        metrics = table.metrics[group]
        rt = Table(title=group, title_justify="left", show_lines=False)
        shown = table.shown(group)
        label_width = max([len(table.rows[i]["label"]) for i in shown] + [1])
        rt.add_column("", no_wrap=True, min_width=label_width)
        for m in metrics:
            width = max([len(table.rows[i]["text"].get((group, m), DASH)) for i in shown]
                        + [len(m)])
            rt.add_column(m, justify="right", no_wrap=True, min_width=width)
        for k, i in enumerate(shown):
            row = table.rows[i]
            cells = []
            for m in metrics:
                text = row["text"].get((group, m), DASH)
                cells.append(Text(text, style="bold green") if (i, group, m) in best else text)
            nxt = table.rows[shown[k + 1]] if k + 1 < len(shown) else None
            end = nxt is not None and (nxt["kind"] != row["kind"] or nxt["family"] != row["family"])
            rt.add_row(row["label"], *cells, end_section=end)
        # Never cut a lap time to an ellipsis, nor a column to nothing: a narrow (or piped,
        # 80-column) console gets the table at its natural width instead. The table's own width
        # does it; ``print(width=...)`` is capped at the console's, and a long label (a run's
        # "beyond paper" list) then squeezed the lap columns to zero width.
        natural = sum(c.min_width or 0 for c in rt.columns) + 3 * len(rt.columns) + 1
        if natural > console.width:
            rt.width = natural
        console.print(rt, crop=False)
    for note in table.notes:
        console.print(f"  {note}")


def render_markdown(table: ReportTable) -> str:
    """GitHub Markdown: one pipe table per column group, best per column in bold."""
    lines = [f"### {table.title}", ""]
    if table.empty:
        lines.append("_(empty)_ " + "; ".join(table.notes))
        return "\n".join(lines) + "\n"
    best = table.best_cells()
    for group in table.groups:
        metrics = table.metrics[group]
        lines.append(f"**{_md_escape(group)}**")
        lines.append("")
        lines.append("| | " + " | ".join(_md_escape(m) for m in metrics) + " |")
        lines.append("|---|" + "---:|" * len(metrics))
        for i in table.shown(group):
            row = table.rows[i]
            cells = []
            for m in metrics:
                text = _md_escape(row["text"].get((group, m), DASH))
                cells.append(f"**{text}**" if (i, group, m) in best else text)
            lines.append(f"| {_md_escape(row['label'])} | " + " | ".join(cells) + " |")
        lines.append("")
    lines.append(f"_{table.caption}_")
    lines.extend(f"- {n}" for n in table.notes)
    return "\n".join(lines) + "\n"


def _md_escape(text: str) -> str:
    return str(text).replace("|", "\\|")


def render_latex_tabular(table: ReportTable) -> str:
    """The table as a booktabs ``tabular`` (pandas Styler), best per column in ``\\textbf``.

    A ``\\midrule`` separates families, then the bots, then the reference limit, as in the
    paper's Table 1; ``\\cmidrule`` underlines each column group.
    """
    if table.empty:
        return "% " + table.title + ": empty (" + "; ".join(table.notes) + ")\n"
    frame = table.text_frame()
    best = table.best_cells()
    col_pos = {c: j for j, c in enumerate(table.columns)}
    bold = np.full(frame.shape, "", dtype=object)
    for i, group, metric in best:
        bold[i, col_pos[(group, metric)]] = "textbf:--rwrap;"
    styler = (frame.style.format(escape="latex")
              .format_index(escape="latex", axis=0).format_index(escape="latex", axis=1)
              .apply(lambda d: pd.DataFrame(bold, index=d.index, columns=d.columns), axis=None))
    latex = styler.to_latex(hrules=True, multicol_align="c",
                            column_format="l" + "r" * len(table.columns))
    lines = latex.splitlines()
    # \cmidrule under the group header row (the first row after \toprule).
    start = 2
    rules = []
    for group in table.groups:
        width = len(table.metrics[group])
        rules.append(f"\\cmidrule(lr){{{start}-{start + width - 1}}}")
        start += width
    top = lines.index("\\toprule")
    lines.insert(top + 2, " ".join(rules))
    mid = lines.index("\\midrule")
    out = lines[: mid + 1]
    for i, line in enumerate(lines[mid + 1:]):
        if i < len(table.rows) and i > 0:
            prev, row = table.rows[i - 1], table.rows[i]
            if row["kind"] != prev["kind"] or row["family"] != prev["family"]:
                out.append("\\midrule")
        out.append(line)
    return "\n".join(out) + "\n"


def render_latex_table(table: ReportTable) -> str:
    """A ``table`` float with caption, label and notes, for \\input into a paper."""
    tabular = render_latex_tabular(table)
    wide = len(table.columns) > 12
    body = f"\\resizebox{{\\linewidth}}{{!}}{{%\n{tabular}}}\n" if wide else tabular
    notes = "".join(f"\\par\\smallskip{{\\scriptsize {_latex_text(n)}}}\n" for n in table.notes)
    return (
        "\\begin{table}[ht]\n\\centering\n\\footnotesize\n" + body
        + f"\\caption{{{_latex_text(table.title)}. {_latex_text(table.caption)}}}\n"
        + f"\\label{{table:{table.key}}}\n" + notes + "\\end{table}\n"
    )


def _latex_text(text: str) -> str:
    repl = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
            "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}",
            "^": r"\textasciicircum{}"}
    return "".join(repl.get(ch, ch) for ch in str(text))


def latex_document(tables: list[ReportTable], title: str, problems: list[str],
                   figures: dict[str, Path] | None = None) -> str:
    """A standalone article (booktabs, geometry, graphicx: all in texlive-latex-base/recommended)
    holding every table and, given ``figures`` (name -> PDF path relative to the .tex), every
    figure; compiles with a bare ``pdflatex`` run in the .tex's folder."""
    parts = [
        "\\documentclass[10pt]{article}",
        "\\usepackage{booktabs}",
        "\\usepackage{graphicx}",
        "\\usepackage[a4paper,landscape,margin=1.5cm]{geometry}",
        "\\pagestyle{empty}",
        "\\begin{document}",
        f"\\section*{{{_latex_text(title)}}}",
    ]
    if problems:
        parts.append("\\paragraph{Missing or failed jobs.}")
        parts.append("\\begin{itemize}")
        parts.extend(f"\\item {_latex_text(p)}" for p in problems[:40])
        if len(problems) > 40:
            parts.append(f"\\item \\dots{{}} and {len(problems) - 40} more")
        parts.append("\\end{itemize}")
    for table in tables:
        parts.extend(render_latex_table(t) for t in latex_split(table))
    for name, path in (figures or {}).items():
        parts.append("\\begin{figure}[ht]\\centering")
        parts.append(f"\\includegraphics[width=0.9\\linewidth,height=0.8\\textheight,"
                     f"keepaspectratio]{{{Path(path).as_posix()}}}")
        parts.append(f"\\caption{{{_latex_text(name)}}}\\end{{figure}}")
        parts.append("\\clearpage")
    parts.append("\\end{document}")
    return "\n".join(parts) + "\n"


LATEX_TABLE1_METRICS = ["bLT", "aLT", "95% CI", "gap", "runs"]
"""Table 1 in LaTeX keeps the paper's columns plus the CI, gap and runs: IQM and damage stay in
the terminal/JSON so that a part fits a page."""


def latex_split(table: ReportTable) -> list[ReportTable]:
    """Table 1 as one float per part (the paper's width: a part holds 1-2 lines), else as is."""
    if table.key != "table1" or table.empty:
        return [table]
    by_part: dict[str, list[str]] = {}
    for group in table.groups:
        by_part.setdefault(group.split(":", 1)[0], []).append(group)
    out = []
    for part, groups in by_part.items():
        sub = table.subset(groups, LATEX_TABLE1_METRICS, suffix=f"-{part}")
        sub.title = f"{table.title} ({part})"
        out.append(sub)
    return out


def write_latex(tables: list[ReportTable], out_dir: Path, title: str, problems: list[str],
                figures: dict[str, Path] | None = None) -> dict[str, Path]:
    """``tables.tex`` (standalone) plus one ``<key>.tex`` float per table for \\input."""
    out_dir = Path(out_dir)
    paths = {"tables.tex": atomic_write_text(
        out_dir / "tables.tex", latex_document(tables, title, problems, figures))}
    for table in tables:
        body = "".join(render_latex_table(t) for t in latex_split(table))
        paths[f"{table.key}.tex"] = atomic_write_text(out_dir / f"{table.key}.tex", body)
    return paths

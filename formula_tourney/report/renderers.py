"""Renderers of report tables: rich terminal, GitHub Markdown and LaTeX (booktabs).

Each reads a ``ReportTable`` (``report.table_model``) and writes its display text; none computes
a number. The HTML page is ``report.html``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from formula_tourney.report.table_model import DASH, ReportTable
from formula_tourney.safeio import atomic_write_text


def render_rich(table: ReportTable, console: Any) -> None:
    """One rich table per column group: the paper's wide layout does not fit a terminal."""
    from rich.table import Table
    from rich.text import Text

    # Every text is plain: a label or note holding "[...]" must print as written.
    console.print(Text(table.title, style="bold"))
    if table.empty:
        console.print(Text("  (empty) " + "; ".join(table.notes)))
        return
    best = table.best_cells()
    for group in table.groups:
        metrics = table.metrics[group]
        rt = Table(title=Text(group), title_justify="left", show_lines=False)
        shown = table.shown(group)
        label_width = max([len(table.rows[i]["label"]) for i in shown] + [1])
        rt.add_column("", no_wrap=True, min_width=label_width)
        for m in metrics:
            width = max([len(table.rows[i]["text"].get((group, m), DASH)) for i in shown]
                        + [len(m)])
            rt.add_column(Text(m), justify="right", no_wrap=True, min_width=width)
        for k, i in enumerate(shown):
            row = table.rows[i]
            cells = []
            for m in metrics:
                text = row["text"].get((group, m), DASH)
                cells.append(Text(text, style="bold green" if (i, group, m) in best else ""))
            nxt = table.rows[shown[k + 1]] if k + 1 < len(shown) else None
            end = nxt is not None and (nxt["kind"] != row["kind"] or nxt["family"] != row["family"])
            rt.add_row(Text(row["label"]), *cells, end_section=end)
        print_whole(rt, console)
    for note in table.footnotes(by_group=True):
        console.print(Text(f"  {note}"))


def print_whole(rt: Any, console: Any) -> None:
    """Print a rich table whose columns are ``no_wrap`` with ``min_width`` their longest text,
    never cutting a cell to an ellipsis nor a column to nothing: a narrow (or piped, 80-column)
    console gets the table at its natural width instead. The table's own width does it;
    ``print(width=...)`` is capped at the console's, and a long label (a run's "beyond paper"
    list, a race car's job and seed) then squeezed the other columns."""
    natural = sum(c.min_width or 0 for c in rt.columns) + 3 * len(rt.columns) + 1
    if natural > console.width:
        rt.width = natural
    console.print(rt, crop=False)


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
    lines.append(f"_{table.full_caption}_")
    lines.extend(f"- {n}" for n in table.footnotes(by_group=True))
    return "\n".join(lines) + "\n"


def _md_escape(text: str) -> str:
    return str(text).replace("|", "\\|")


LABEL_WRAP_CHARS = 24
"""Row labels longer than this wrap in a column of ``LABEL_WIDTH`` (a run's "beyond paper"
list runs to 65 characters and would set a table's width)."""
LABEL_WIDTH = r"14em"
LATEX_PACKAGES = ("booktabs", "array", "graphicx")
"""What a ``<table>.tex`` float needs in the paper's preamble (all in texlive-latex-base and
texlive-latex-recommended)."""


def render_latex_tabular(table: ReportTable) -> str:
    """The table as a booktabs ``tabular``, best per column in ``\\textbf``.

    A ``\\midrule`` separates families, then the bots, then the reference limit, as in the
    paper's Table 1; ``\\cmidrule`` underlines each column group. Every text is escaped
    (``latex_escape``); long row labels wrap.
    """
    if table.empty:
        return "% " + latex_escape(table.title) + ": empty (" + latex_escape(
            "; ".join(table.notes)) + ")\n"
    best = table.best_cells()
    long_labels = max(len(r["label"]) for r in table.rows) > LABEL_WRAP_CHARS
    label_col = f">{{\\raggedright\\arraybackslash}}p{{{LABEL_WIDTH}}}" if long_labels else "l"
    lines = [f"\\begin{{tabular}}{{{label_col}{'r' * len(table.columns)}}}", "\\toprule"]
    heads, rules, start = [], [], 2
    for group in table.groups:
        width = len(table.metrics[group])
        heads.append(f"\\multicolumn{{{width}}}{{c}}{{{latex_escape(group)}}}")
        rules.append(f"\\cmidrule(lr){{{start}-{start + width - 1}}}")
        start += width
    lines.append(" & " + " & ".join(heads) + " \\\\")
    lines.append(" ".join(rules))
    lines.append(" & " + " & ".join(latex_escape(m) for _, m in table.columns) + " \\\\")
    lines.append("\\midrule")
    for i, row in enumerate(table.rows):
        prev = table.rows[i - 1] if i else row
        if row["kind"] != prev["kind"] or row["family"] != prev["family"]:
            lines.append("\\midrule")
        cells = []
        for group, metric in table.columns:
            text = latex_escape(row["text"].get((group, metric), DASH))
            cells.append(f"\\textbf{{{text}}}" if (i, group, metric) in best else text)
        lines.append(" & ".join([latex_escape(row["label"]), *cells]) + " \\\\")
    lines += ["\\bottomrule", "\\end{tabular}"]
    return "\n".join(lines) + "\n"


def render_latex_table(table: ReportTable) -> str:
    """A ``table`` float with caption, label and notes, for \\input into a paper.

    A table wider than the text is shrunk to the text width (never widened); the caption drops
    the paper's "Table N:" since LaTeX numbers its floats itself. An empty table is a
    comment saying why, not a float.
    """
    tabular = render_latex_tabular(table)
    if table.empty:
        return tabular
    body = ("\\resizebox{\\ifdim\\width>\\linewidth\\linewidth\\else\\width\\fi}{!}{%\n"
            + tabular + "}\n")
    notes = "".join(f"\\par\\smallskip{{\\raggedright\\scriptsize "
                    f"{latex_escape(n, prose=True)}\\par}}\n" for n in table.footnotes())
    title = _PAPER_NUMBER.sub("", table.title)
    title = title[:1].upper() + title[1:]
    label = re.sub(r"[^A-Za-z0-9:.-]+", "-", table.key)
    return (
        "\\begin{table}[ht]\n\\centering\n\\footnotesize\n" + body
        + f"\\caption{{{latex_escape(title)}. {latex_escape(table.full_caption)}}}\n"
        + f"\\label{{table:{label}}}\n" + notes + "\\end{table}\n"
    )


_PAPER_NUMBER = re.compile(r"^Table \d+:\s*")
_LATEX_CHARS = {
    "\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
    "{": r"\{", "}": r"\}", "~": r"$\sim$", "^": r"\textasciicircum{}", "<": r"\textless{}",
    ">": r"\textgreater{}", "|": r"\textbar{}",
    "±": r"$\pm$", "×": r"$\times$", "≤": r"$\leq$", "≥": r"$\geq$", "≈": r"$\approx$",
    "→": r"$\to$", "·": r"$\cdot$", "…": r"\dots{}", "–": "--", "—": "---", "°": r"$^\circ$",
    "µ": r"$\mu$", "μ": r"$\mu$", "Δ": r"$\Delta$", "−": "-",
}
_LATEX_SPECIAL = re.compile("-(?=-)|" + "|".join(re.escape(ch) for ch in _LATEX_CHARS))
"""A character to replace, or a hyphen followed by another (``-{}`` keeps them apart)."""


def latex_escape(text: object, prose: bool = False) -> str:
    """``text`` as LaTeX that prints it literally: specials escaped, "--" kept as two hyphens
    (not an en dash), "~" as the "about" sign it means in our texts, and the few non-ASCII
    signs our texts use as their LaTeX commands. In ``prose`` (notes, problems) a line may
    also break after a "/", so that a long path does not run into the margin."""
    out = _LATEX_SPECIAL.sub(lambda m: _LATEX_CHARS.get(m.group(), "-{}"), str(text))
    return out.replace("/", "/\\allowbreak{}") if prose else out


def latex_document(tables: list[ReportTable], title: str, problems: list[str],
                   figures: dict[str, Path] | None = None) -> str:
    """A whole article (portrait A4, as a paper's page; packages ``LATEX_PACKAGES`` and
    geometry: all in texlive-latex-base/recommended) holding every table and, given
    ``figures`` (name -> PDF path relative to the .tex), every figure; compiles with a bare
    ``pdflatex`` run in the .tex's folder."""
    parts = [
        "\\documentclass[10pt]{article}",
        *(f"\\usepackage{{{name}}}" for name in LATEX_PACKAGES),
        "\\usepackage[a4paper,margin=2.5cm]{geometry}",
        "\\pagestyle{empty}",
        "\\begin{document}",
        f"\\section*{{{latex_escape(title)}}}",
    ]
    if problems:
        parts.append("\\paragraph{Missing or failed jobs.}")
        parts.append("\\begin{itemize}")
        parts.extend(f"\\item {latex_escape(p, prose=True)}" for p in problems[:40])
        if len(problems) > 40:
            parts.append(f"\\item \\dots{{}} and {len(problems) - 40} more")
        parts.append("\\end{itemize}")
    for table in tables:
        if table.empty:
            parts.append(f"\\paragraph{{{latex_escape(table.title)}.}} (empty) "
                         + latex_escape("; ".join(table.notes), prose=True))
        parts.extend(render_latex_table(t) for t in latex_split(table))
    for name, path in (figures or {}).items():
        parts.append("\\begin{figure}[ht]\\centering")
        parts.append(f"\\includegraphics[width=\\linewidth,height=0.8\\textheight,"
                     f"keepaspectratio]{{{Path(path).as_posix()}}}")
        parts.append(f"\\caption{{{latex_escape(name)}}}\\end{{figure}}")
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
    """``report.tex`` (a whole document) plus one ``<key>.tex`` float per table for
    \\input."""
    out_dir = Path(out_dir)
    paths = {"report.tex": atomic_write_text(
        out_dir / "report.tex", latex_document(tables, title, problems, figures))}
    for table in tables:
        body = "".join(render_latex_table(t) for t in latex_split(table))
        paths[f"{table.key}.tex"] = atomic_write_text(out_dir / f"{table.key}.tex", body)
    return paths

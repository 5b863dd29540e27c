"""One self-contained HTML page: problems, the tables and every figure (PNG inlined as base64).

A single file with no external assets can be mailed, attached to an issue or opened from a
results folder copied off a cluster, which is how tournament results travel in practice.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path
from typing import Any

from PIL import Image

from formula_tourney.report.table_model import DASH, ReportTable

_CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222; }
h1 { font-size: 1.6em; } h2 { font-size: 1.25em; margin-top: 2em; } h3 { font-size: 1em; }
table { border-collapse: collapse; margin: 0.5em 0 1em; font-size: 0.9em; }
th, td { padding: 0.2em 0.7em; text-align: right; border-bottom: 1px solid #ddd; }
th:first-child, td:first-child { text-align: left; }
tr.bot td { color: #555; } tr.limit td { font-style: italic; color: #555; }
td.best { font-weight: bold; }
.caption, .note { color: #555; font-size: 0.85em; max-width: 60em; }
.problems { background: #fff4e5; border-left: 4px solid #f0a020; padding: 0.5em 1em; }
figure { margin: 1em 0; } figure img { max-width: 100%; border: 1px solid #eee; }
figcaption { font-size: 0.85em; color: #555; }
"""


def table_html(table: ReportTable) -> str:
    """A table as HTML: one sub-table per column group, best per column in bold."""
    parts = [f"<h2>{html.escape(table.title)}</h2>"]
    if table.empty:
        parts.append(f"<p class='note'>(empty) {html.escape('; '.join(table.notes))}</p>")
        return "\n".join(parts)
    best = table.best_cells()
    for group in table.groups:
        metrics = table.metrics[group]
        parts.append(f"<h3>{html.escape(group)}</h3>")
        parts.append("<table><thead><tr><th></th>"
                     + "".join(f"<th>{html.escape(m)}</th>" for m in metrics)
                     + "</tr></thead><tbody>")
        for i in table.shown(group):
            row = table.rows[i]
            cells = []
            for m in metrics:
                text = html.escape(row["text"].get((group, m), DASH))
                cls = " class='best'" if (i, group, m) in best else ""
                cells.append(f"<td{cls}>{text}</td>")
            parts.append(f"<tr class='{row['kind']}'><td>{html.escape(row['label'])}</td>"
                         + "".join(cells) + "</tr>")
        parts.append("</tbody></table>")
    parts.append(f"<p class='caption'>{html.escape(table.full_caption)}</p>")
    parts.extend(f"<p class='note'>{html.escape(n)}</p>" for n in table.footnotes(by_group=True))
    return "\n".join(parts)


CAPTIONS: dict[str, str] = {
    "learning": "Training reward (moving average; mean and 95% band over seeds, dashed where a "
                "seed had stopped, x at its last episode, n in the legend where it changes) and "
                "every clean test lap of each seed; a star marks each entrant's best lap, the "
                "tables' bLT.",
    "generalisation": "Clean lap on each test track against training episode, one line per "
                      "run; the red line marks the general model.",
    "trace": "Steer, throttle, brake and speed against distance on the fastest lap.",
    "line": "The fastest lap and its rival on the track map, coloured by speed; the title says "
            "which reference line each followed.",
    "delta": "Both laps' speeds against distance, and the running time difference A \u2212 B "
             "(> 0 where A is behind).",
    "ablation": "Training reward with the setting off (green) and on (red), mean and 95% band "
                "over seeds.",
    "claim": "The data behind the claim's verdict.",
    "profile": "Fraction of runs whose best clean lap over the reference limit is at most tau, "
               "per variant and over all runs, with 95% bootstrap bands.",
    "race": "Each car's place at the end of every lap.",
    "race-gaps": "Each car's gap to the leader at the end of every lap.",
}
"""What each figure kind shows, keyed by the first word of the figure's name (``plots``,
``claims.figures`` and ``race_figures`` name their files ``<kind>-<what>``; a race's are
``<part>-race-<k>-positions|gaps``)."""


def _kind(name: str) -> str:
    if "-race-" in name and name.endswith("-gaps"):
        return "race-gaps"
    if "-race-" in name and name.endswith("-positions"):
        return "race"
    return name.partition("-")[0]


def png_title(png: Path) -> str:
    """The ``Title`` a figure's PNG carries (``plots.save_figure`` writes the figure's title
    there); empty when it has none."""
    try:
        with Image.open(png) as image:
            return str(image.info.get("Title", ""))
    except OSError:
        return ""


def figure_caption(name: str, title: str = "") -> str:
    """The figure's title (what and of which part, column or claim) and a sentence saying what
    it shows; the file name only for a figure kind this module does not know and no title."""
    what = CAPTIONS.get(_kind(name), "")
    head = title or name
    if not what:
        return head
    return f"{head.rstrip('.')}. {what}"


def figure_html(name: str, png: Path) -> str:
    """One figure, its PNG inlined, with its caption."""
    data = base64.b64encode(Path(png).read_bytes()).decode("ascii")
    caption = figure_caption(name, png_title(Path(png)))
    return (f"<figure><img alt='{html.escape(caption)}' src='data:image/png;base64,{data}'>"
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def render_page(title: str, tables: list[ReportTable], figures: dict[str, list[Path]],
                problems: list[str], summary: dict[str, Any] | None = None) -> str:
    """The whole page as a string (no external assets)."""
    body = [f"<h1>{html.escape(title)}</h1>"]
    if summary:
        body.append("<p>" + " · ".join(f"{html.escape(str(k))}: {html.escape(str(v))}"
                                       for k, v in summary.items()) + "</p>")
    if problems:
        body.append("<div class='problems'><strong>Missing or failed jobs</strong><ul>"
                    + "".join(f"<li>{html.escape(p)}</li>" for p in problems) + "</ul></div>")
    body.extend(table_html(t) for t in tables)
    if figures:
        body.append("<h2>Figures</h2>")
        for name, paths in figures.items():
            png = next((p for p in paths if Path(p).suffix == ".png"), None)
            if png is not None and Path(png).is_file():
                body.append(figure_html(name, png))
    return ("<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>\n"
            + "\n".join(body) + "\n</body></html>\n")

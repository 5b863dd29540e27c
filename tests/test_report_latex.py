"""The report's LaTeX compiles clean with pdflatex: every float alone in a portrait article (as a
paper would ``\\input`` it) and the whole ``report.tex``, with no LaTeX error, no undefined
reference and no overfull box wider than 1 pt. Also what the LaTeX says: captions numbered once,
only the metrics shown described, specials escaped, every empty cell saying why."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from report_fixtures import build_tournament

from formula_tourney.report.build import build_report
from formula_tourney.report.renderers import LATEX_PACKAGES, latex_escape
from formula_tourney.results.folder import JobFolder

LONG = ["preset tuned-bc", "demos (follower on mincurv)"]
"""What ``make demo``'s technical part adds to the paper: its label set the width of a table."""
PAPER = ("\\documentclass{article}\n"
         + "".join(f"\\usepackage{{{p}}}\n" for p in LATEX_PACKAGES)
         + "\\begin{document}\n\\input{%s}\n\\end{document}\n")
"""A portrait article with the default text width (345 pt), as a paper's page."""


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The fixture tournament, part2's RC entrant labelled beyond the paper, in LaTeX."""
    base = tmp_path_factory.mktemp("latex")
    root = build_tournament(base / "results")
    for seed in range(3):
        folder = JobFolder(root / f"part2/win4-rc/seed-{seed}")
        if folder.config_path.is_file():
            doc = json.loads(folder.config_path.read_text())
            folder.write_config(doc["run_spec"], beyond_paper=LONG)
    rep = build_report(str(root), base / "results", out_dir=base / "out", formats=["latex"],
                       figures=False)
    return rep.files


def compile_problems(tex: Path) -> list[str]:
    """pdflatex ``tex`` in its folder; the errors, undefined references and overfull boxes
    wider than 1 pt its log reports (empty: it compiled clean)."""
    if shutil.which("pdflatex") is None:
        pytest.skip("pdflatex not found: install texlive-latex-base and "
                    "texlive-latex-recommended (.ci/run does)")
    proc = subprocess.run(
        ["pdflatex", "-interaction=nonstopmode", "-halt-on-error", tex.name],
        cwd=tex.parent, capture_output=True, text=True, timeout=120,
    )
    log = tex.with_suffix(".log").read_text(errors="replace")
    problems = [line for line in log.splitlines() if line.startswith("!")]
    if proc.returncode != 0 and not problems:
        problems.append(f"pdflatex exit {proc.returncode}")
    problems += re.findall(r"LaTeX Warning: (?:Reference|Citation) .* undefined.*", log)
    problems += [f"Overfull \\hbox ({pt}pt too wide) {where}" for pt, where in
                 re.findall(r"Overfull \\hbox \(([\d.]+)pt too wide\)(.*)", log)
                 if float(pt) > 1.0]
    if not problems and not tex.with_suffix(".pdf").is_file():
        problems.append("no PDF written")
    return problems


def test_every_float_fits_a_papers_page(written: dict[str, Path]) -> None:
    floats = [p for name, p in written.items() if name != "report.tex"]
    assert {p.name for p in floats} >= {"table1.tex", "table2.tex", "table3.tex",
                                        "comparisons.tex", "cost.tex"}
    for tex in floats:
        paper = tex.with_name(f"paper-{tex.stem}.tex")
        paper.write_text(PAPER % tex.stem)
        assert compile_problems(paper) == [], tex.name


def test_report_tex_compiles_clean(written: dict[str, Path]) -> None:
    tex = written["report.tex"]
    assert tex.read_text().startswith("\\documentclass")
    assert compile_problems(tex) == []
    assert tex.with_suffix(".pdf").stat().st_size > 10_000


def test_report_tex_with_figures_compiles_clean(tmp_path: Path) -> None:
    root = build_tournament(tmp_path / "results")
    rep = build_report(str(root), tmp_path / "results", part="part3", out_dir=tmp_path / "out",
                       formats=["latex"])
    tex = rep.files["report.tex"]
    assert tex.read_text().count("\\includegraphics") == len(rep.figures) > 3
    assert compile_problems(tex) == []


def test_captions_are_numbered_once_and_describe_only_the_columns_shown(
    written: dict[str, Path],
) -> None:
    doc = written["report.tex"].read_text()
    captions = re.findall(r"\\caption\{(.*)\}", doc)
    assert captions and not [c for c in captions if re.match(r"Table \d+:", c)]
    part1 = next(c for c in captions if "(part1)" in c)
    assert part1.startswith("Best (bLT) and average best (aLT) lap time per part (part1).")
    # Table 1 in LaTeX has bLT, aLT, CI, gap and runs; IQM and dmg stay in terminal and JSON
    assert "aLT: mean over runs" in part1 and "runs: runs with a clean lap" in part1
    assert "IQM" not in part1 and "dmg" not in part1


def test_long_labels_wrap_instead_of_widening_the_table(written: dict[str, Path]) -> None:
    tex = written["table1.tex"].read_text()
    label = "win4 (beyond paper: preset tuned-bc, demos (follower on mincurv))"
    assert latex_escape(label) + " & not run & not run" in tex  # the label is whole...
    part2 = tex[tex.index("(part2)") - 2000: tex.index("(part2)")]
    assert "p{14em}" in part2  # ...in a column that wraps it


def test_specials_are_escaped_not_typeset(written: dict[str, Path]) -> None:
    assert latex_escape("run --estimate") == "run -{}-estimate"  # not an en dash
    assert latex_escape("~95% & $5_x #1 {a}") == r"$\sim$95\% \& \$5\_x \#1 \{a\}"
    assert latex_escape("a/b/c", prose=True) == r"a/\allowbreak{}b/\allowbreak{}c"
    cost = written["cost.tex"].read_text()
    assert "-{}-estimate" in cost and "--estimate" not in cost
    assert r"CPU $\sim$95\%" in cost and "textasciitilde" not in cost


def test_empty_cells_say_why(written: dict[str, Path]) -> None:
    tex = written["table1.tex"].read_text()
    assert not re.search(r"& - (&|\\\\)", tex)  # no bare dash anywhere
    # part3's genetic bot never drove the technical track; bots have no aLT
    genetic = [line for line in tex.splitlines() if line.startswith("Genetic &")]
    assert any(line.startswith("Genetic & not driven & n/a") for line in genetic)
    assert "not driven: no baseline drive of this bot on this track and line" in tex
    assert "n/\\allowbreak{}a: no such number for this row" in tex  # a note is prose
    table2 = written["table2.tex"].read_text()
    assert "per1m RC + LAC & not run & not run" in table2  # never trained on the oval

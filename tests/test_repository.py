"""The repository explains itself: no citation of issue numbers, work sessions or files outside
it, and a README short enough to start from.

A reader has only the repository, so a comment that sends them to an issue tracker or to a
design file kept elsewhere points nowhere; it must state the reason itself, give a figure with
the command that reproduces it, or point to a page under docs/ (docs/ARCHITECTURE.md for the
layering). The diary under docs/lab/ is a historical log: its headings may carry dates, but
it cites nothing outside the repository either.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCANNED = ("formula_tourney", "benchmarks", "tests", "docs", "tournaments")
SCANNED_FILES = ("README.md", "CHANGELOG.md", "Makefile", "pyproject.toml")
SUFFIXES = {".py", ".md", ".toml", ".json", ".txt", ""}
HISTORICAL_LOG = ROOT / "docs" / "lab"

ORDINALS = "first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth"
# Assembled from pieces so that this file's own source does not match its patterns.
FORBIDDEN = {
    "an issue number": re.compile(r"\bissues?\s*" + "(#|[0-9])", re.I),
    "a design document outside the repository": re.compile(r"\bDESIGN" + r"\.md\b"),
    "the style guide outside the repository": re.compile(r"\bSTYLE" + r"\.md\b"),
    "a path outside the repository": re.compile(r"\.\./" + "shared"),
    "a work session": re.compile(rf"\b({ORDINALS})\s+" + "session", re.I),
}
DATED_HEADING = re.compile(r"^#+ (?!\[[0-9.]+\] - ).*\b20[0-9]{2}-[0-9]{2}" + r"-[0-9]{2}", re.M)
"""A Markdown heading with a date: a diary entry, which belongs in docs/lab/ (a release heading of
the changelog, ``## [1.2.0] - <date>``, is not one)."""


def _scanned_files() -> list[Path]:
    """Every text file a reader of the repository reads."""
    files = [ROOT / name for name in SCANNED_FILES]
    for top in SCANNED:
        for path in sorted((ROOT / top).rglob("*")):
            if (
                path.is_file()
                and path.suffix in SUFFIXES
                and "__pycache__" not in path.parts
            ):
                files.append(path)
    return files


def _citations(text: str, markdown: bool = True) -> list[str]:
    """``line N: <what> ('<match>')`` for each forbidden citation in ``text`` (dated headings only
    in Markdown, where a line starting with ``#`` is a heading and not a comment)."""
    found = []
    patterns = dict(FORBIDDEN, **({"a dated heading": DATED_HEADING} if markdown else {}))
    for what, pattern in patterns.items():
        for match in pattern.finditer(text):
            line = text.count("\n", 0, match.start()) + 1
            found.append(f"line {line}: {what} ({match.group(0).strip()!r})")
    return found


def test_the_patterns_catch_citations_and_pass_plain_prose() -> None:
    issue = "Iss" + "ue"
    cited = (
        f"see {issue} 12\nas in {issue} #4\nper DESIGN" + ".md\nfrom ../" + "shared/x\n"
        "the fifth " + "session\n## Screens (2026-12-02" + ")\n"
    )
    assert len(_citations(cited)) == 6
    assert len(_citations(cited, markdown=False)) == 5
    plain = f"an {issue} of the paper\nthe session of a run\n## Results\n## [0.9.0] - 2026-12-06\n"
    assert _citations(plain) == []


def test_no_file_cites_an_issue_a_session_or_a_file_outside_the_repository() -> None:
    offences = [
        f"{path.relative_to(ROOT)} {hit}"
        for path in _scanned_files()
        for hit in _citations(
            path.read_text(encoding="utf-8", errors="replace"),
            markdown=path.suffix == ".md" and not path.is_relative_to(HISTORICAL_LOG),
        )
    ]
    assert offences == [], "\n".join(offences)


def test_readme_is_short_and_shows_the_two_commands() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 150
    assert "make demo" in readme and "make test" in readme

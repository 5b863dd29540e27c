"""Imports go downward and stay visible: ``lines`` never imports ``bots``, and ``lines``, ``bots``
and ``report`` import formula_tourney modules at the top of the file only, in
subpackages too (docs/ARCHITECTURE.md, "Layering")."""

from __future__ import annotations

import ast
from pathlib import Path

import formula_tourney

PACKAGE = Path(formula_tourney.__file__).parent


def _imports(path: Path) -> list[tuple[str, bool]]:
    """(imported module, at module level) for every formula_tourney import in a file."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    top = {id(node) for node in tree.body}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        found.extend((n, id(node) in top) for n in names if n.startswith("formula_tourney"))
    return found


def test_lines_never_import_bots_and_imports_are_at_the_top():
    local, upward = [], []
    for area in ("lines", "bots", "report"):
        for path in sorted((PACKAGE / area).rglob("*.py")):
            for module, at_top in _imports(path):
                if not at_top:
                    local.append(f"{path.name}: {module}")
                if area == "lines" and module.startswith("formula_tourney.bots"):
                    upward.append(f"{path.name}: {module}")
    assert upward == []
    assert local == []


def test_speed_profile_does_not_import_the_registry():
    """reference_limit_s lives in lines.limit, above both, so the two do not import each other."""
    imported = {m for m, _ in _imports(PACKAGE / "lines" / "speed_profile.py")}
    assert "formula_tourney.lines.registry" not in imported
    assert "formula_tourney.lines.speed_profile" in {
        m for m, _ in _imports(PACKAGE / "lines" / "limit.py")}

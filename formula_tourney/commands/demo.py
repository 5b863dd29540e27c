"""``formula-tourney demo``: the tool's main job on its built-in default (see Makefile)."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    @app.command()
    def demo() -> None:
        """Run the built-in demo."""
        raise NotImplementedError

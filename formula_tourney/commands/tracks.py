"""CLI commands for tracks: ``tracks list``, ``tracks show``, ``tracks import``,
``tracks generate``. Each parses arguments and calls the sim functions that do the work;
every check that can fail runs before anything is written."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import typer

from formula_tourney.commands.output import emit, message, styled
from formula_tourney.errors import UserInputError
from formula_tourney.safeio import check_output_path
from formula_tourney.sim.catalog import list_tracks, load_track, user_tracks_dir
from formula_tourney.sim.generate import GENERATED_FORMS, generated_name, generated_spec
from formula_tourney.sim.plot import check_plot_path, plot_tracks
from formula_tourney.sim.track_store import (
    import_torcs_track,
    import_torcs_tree,
    save_user_track,
    user_track_target,
)

JSON_HELP = "Print one JSON document on stdout."
PLOT_HELP = "Write a track map (.png, .svg or .pdf)."
EXIT_SOME_FAILED = 3
IMPORT_EXIT_HELP = ("Exit codes: 0 all imported; 3 a folder import where some files failed (the "
                    "table says why; the others are imported); 2 bad input (no such file or "
                    "folder, no .xml in the folder, a bad single file).")


def track_summary(track: Any) -> dict[str, Any]:
    """What ``tracks show --json`` prints: the numbers that characterise a track."""
    radius = track.min_radius_m
    return {
        "name": track.name,
        "source": track.source,
        "length_m": round(float(track.length_m), 3),
        "width_m": round(float(np.mean(track.width_m)), 3),
        "min_radius_m": round(float(radius), 3) if math.isfinite(radius) else None,
        "closure_error_m": float(track.closure_error_m),
        "n_samples": int(track.n),
        "segments": [dict(seg) for seg in track.segments],
    }


def _render_summary(summary: dict[str, Any]):
    """Human view of a summary: headline numbers, then the segment table."""
    from rich.table import Table  # local: only the human view needs rich.table

    def render(console) -> None:
        radius = summary["min_radius_m"]
        console.print(styled(
            (summary["name"], "bold"), f"  {summary['length_m'] / 1000:.3f} km, "
            f"{summary['width_m']:g} m wide, min radius "
            f"{'-' if radius is None else f'{radius:.1f} m'}, closure error "
            f"{summary['closure_error_m']:.2e} m  ({summary['source'] or 'built'})"
        ))
        if summary.get("saved"):
            console.print(f"saved to {summary['saved']}")
        if summary.get("plot"):
            console.print(f"plot written to {summary['plot']}")
        table = Table(show_edge=False)
        for col in ("#", "type", "s start (m)", "length (m)", "radius (m)", "angle (deg)",
                    "end radius (m)"):
            table.add_column(col, justify="right" if col != "type" else "left")
        for k, seg in enumerate(summary["segments"], start=1):
            arc = seg["type"] == "arc"
            table.add_row(
                str(k), seg["type"], f"{seg.get('s_start_m', 0.0):.1f}",
                f"{seg.get('arc_length_m', seg.get('length_m', 0.0)):.1f}",
                f"{seg['radius_m']:.1f}" if arc else "",
                f"{seg['angle_deg']:+.1f}" if arc else "",
                f"{seg['end_radius_m']:.1f}" if arc and "end_radius_m" in seg else "",
            )
        console.print(table)

    return render


def _fmt(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _render_import_table(rows: list[dict[str, Any]]):
    """Human view of a folder import: one row per file."""
    from rich.table import Table

    def render(console) -> None:
        table = Table(show_edge=False)
        for col in ("name", "category", "length (m)", "z range (m)", "max banking (deg)",
                    "imported"):
            table.add_column(col, justify="left" if col in ("name", "category", "imported")
                             else "right")
        for row in rows:
            table.add_row(row["name"], row["category"], _fmt(row["length_m"]),
                          _fmt(row["z_range_m"], 2), _fmt(row["max_banking_deg"]),
                          "yes" if row["imported"] else styled(("no", "red"),
                                                               f": {row['reason']}"))
        console.print(table)

    return render


def register(app: typer.Typer) -> None:
    """Add this area's commands to the main app."""
    tracks_app = typer.Typer(help="Tracks: list, show, import from TORCS, generate.",
                             no_args_is_help=True)
    app.add_typer(tracks_app, name="tracks")

    @tracks_app.command("list")
    def list_cmd(
        as_json: bool = typer.Option(False, "--json", help=JSON_HELP),
    ) -> None:
        """Built-in tracks and the user's tracks folder, with lengths and widths."""
        rows = list_tracks()
        folder = str(user_tracks_dir())

        def render(console) -> None:
            from rich.table import Table

            table = Table(show_edge=False)
            for col in ("name", "length (km)", "width (m)", "source"):
                table.add_column(col, justify="left" if col in ("name", "source") else "right")
            for row in rows:
                if "error" in row:
                    table.add_row(row["name"], "-", "-", styled((row["error"], "red")))
                    continue
                table.add_row(row["name"], f"{row['length_m'] / 1000:.3f}",
                              f"{row['width_m']:g}", row["source"])
            console.print(table)
            console.print(f"user tracks folder: {folder}; generated: {GENERATED_FORMS}")

        emit({"tracks": rows, "user_tracks_dir": folder}, as_json, render)

    @tracks_app.command("show")
    def show_cmd(
        name: str = typer.Argument(..., help="Track name (oval, technical, flowing, a user "
                                   "track, gen-<seed>, gen-short-<seed>) or a .toml/.xml "
                                   "path."),
        plot: Path | None = typer.Option(None, "--plot", help=PLOT_HELP),
        as_json: bool = typer.Option(False, "--json", help=JSON_HELP),
    ) -> None:
        """Length, width, minimum radius, closure error and segments of a track."""
        if plot is not None:
            check_output_path(check_plot_path(plot), "--plot")
        track = load_track(name)
        summary = track_summary(track)
        if plot is not None:
            summary["plot"] = str(plot_tracks(track, plot))
        emit(summary, as_json, _render_summary(summary))

    @tracks_app.command("import", epilog=IMPORT_EXIT_HELP)
    def import_cmd(
        path: Path = typer.Argument(..., help="A TORCS track XML file, or a folder: every .xml "
                                    "below it is imported (a TORCS tree such as "
                                    "/usr/share/games/torcs/tracks)."),
        name: str | None = typer.Option(None, "--name", help="Track name (default: the file "
                                        "name without .xml; one file only)."),
        force: bool = typer.Option(False, "--force", help="Replace user tracks of those names."),
        as_json: bool = typer.Option(False, "--json", help=JSON_HELP),
    ) -> None:
        """Convert TORCS track XML to TOML in the user's tracks folder (one file or a tree)."""
        if path.is_dir():
            if name is not None:
                raise UserInputError(f"--name applies to one .xml file, not a folder ({path})")
            rows = import_torcs_tree(path, overwrite=force)
            failed = sum(not row["imported"] for row in rows)
            if not as_json:
                message(f"imported {len(rows) - failed} of {len(rows)} track file(s) from {path}"
                        + (f"; {failed} failed" if failed else ""))
            emit({"folder": str(path), "imported": len(rows) - failed, "failed": failed,
                  "tracks": rows}, as_json, _render_import_table(rows))
            if failed:
                raise typer.Exit(EXIT_SOME_FAILED)
            return
        if path.suffix.lower() != ".xml":
            what = "not a folder" if path.exists() else "no such file or folder"
            raise UserInputError(f"{path}: {what}; expected a TORCS .xml track file or a folder "
                                 "of them")
        written = import_torcs_track(path, name, overwrite=force)
        track = load_track(written)
        summary = {**track_summary(track), "name": written.stem, "saved": str(written)}
        if not as_json:
            message(f"imported {path} as {written.stem!r}")
        emit(summary, as_json, _render_summary(summary))

    @tracks_app.command("generate")
    def generate_cmd(
        seed: int = typer.Option(..., "--seed", help="Seed: the same seed gives the same track "
                                 "(also loadable anywhere as gen-<seed>)."),
        short: bool = typer.Option(False, "--short", help="A short track, 0.8-1.6 km (also "
                                   "loadable anywhere as gen-short-<seed>)."),
        save: bool = typer.Option(False, "--save", help="Also store it as a user track TOML."),
        name: str | None = typer.Option(None, "--name", help="Name for --save (default "
                                        "gen-<seed> or gen-short-<seed>)."),
        force: bool = typer.Option(False, "--force", help="Replace a user track of that name."),
        plot: Path | None = typer.Option(None, "--plot", help=PLOT_HELP),
        as_json: bool = typer.Option(False, "--json", help=JSON_HELP),
    ) -> None:
        """A procedural track: closed, non-overlapping, 1.5-4 km (0.8-1.6 km with --short),
        8-14 m wide, radii >= 12 m."""
        if name is not None and not save:
            raise UserInputError("--name only applies with --save")
        if plot is not None:
            check_output_path(check_plot_path(plot), "--plot")
        prefix = "gen-short" if short else "gen"
        own_name = generated_name(prefix, seed)
        target = (user_track_target(name or own_name, "--save", overwrite=force,
                                    generated_name=own_name) if save else None)
        spec, track = generated_spec(prefix, seed, name)
        summary = track_summary(track)
        if target is not None:
            summary["saved"] = str(save_user_track(spec, target))
        if plot is not None:
            summary["plot"] = str(plot_tracks(track, plot))
        emit(summary, as_json, _render_summary(summary))

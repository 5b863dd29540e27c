"""CLI: ``formula-tourney race MODEL... --bots follower --track T --laps L``: one race.

Parses arguments, builds the entrants (``race.entrants``), runs the race (``race.run``), renders
its table or prints one JSON document, and writes the optional GIF/MP4 (``sim.multicar.frames``).
Everything is checked before anything is written: a bad track, zero laps, a checkpoint whose
actor does not fit its telemetry or an output path in a missing folder is one line, exit 2.
"""

from __future__ import annotations

import math
from pathlib import Path

import typer
from rich.table import Table
from rich.text import Text

from formula_tourney.commands.output import emit, message, styled
from formula_tourney.errors import UserInputError
from formula_tourney.report.renderers import print_whole
from formula_tourney.safeio import check_output_path


def _fmt(x: float | None, digits: int = 3) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def race_table_rows(doc: dict) -> list[list[str]]:
    """The race table's rows (also the README's): one per car, finishing order."""
    rows = []
    for r in doc["results"]:
        if r["status"] == "retired":
            result = f"DNF ({r['reason']})"
        elif r["position"] == 1:
            result = _fmt(r["time_s"])
        elif r["laps_behind"] > 0:
            result = f"+{r['laps_behind']} lap" + ("s" if r["laps_behind"] > 1 else "")
        else:
            result = "+" + _fmt(r["gap_s"])
        name = r["name"] + ("" if r["sees_opponents"] or r["kind"] == "bot" else " (blind)")
        rows.append([str(r["position"]), name, str(r["grid"]), str(r["laps"]), result,
                     _fmt(r["best_lap_s"]), f"{r['damage']:.0f}", str(r["contacts"]),
                     str(r["caused"]), str(r["overtakes"])])
    return rows


RACE_COLUMNS = ["pos", "driver", "grid", "laps", "time/gap s", "best lap s", "damage",
                "contacts", "caused", "passes"]


def whole_table(title: str, columns: list[str], rows: list[list[str]]) -> Table:
    """A rich table of plain text whose cells are never cut: each column is as wide as its
    longest text (``report.renderers.print_whole`` prints it whole on a narrow console), so
    two cars "WIN4-MOT/seed-0" and "WIN4-MOT/seed-1" stay apart at 80 columns."""
    table = Table(title=Text(title))
    for k, col in enumerate(columns):
        width = max([len(col), *(len(row[k]) for row in rows)])
        table.add_column(Text(col), justify="left" if col == "driver" else "right",
                         no_wrap=True, min_width=width)
    for row in rows:
        table.add_row(*(Text(cell) for cell in row))
    return table


def _render(doc: dict):
    def render(console) -> None:
        print_whole(whole_table(f"Race: {doc['track']}, {doc['laps']} laps, {doc['start']} "
                                f"start, seed {doc['seed']}", RACE_COLUMNS,
                                race_table_rows(doc)), console)
        if any(not r["sees_opponents"] and r["kind"] == "model" for r in doc["results"]):
            console.print("(blind): a model trained without the opponent sensors; it does not "
                          "see the other cars")
        for inc in doc["incidents"]:
            who = inc["caused_by"] or "racing incident"
            console.print(f"contact lap {inc['lap']} t={inc['t_s']:.1f} s: "
                          f"{' / '.join(inc['cars'])}, {inc['energy_kj']:.1f} kJ, caused by {who}")
        for o in doc["overtakes"]:
            console.print(f"overtake lap {o['lap']} t={o['t_s']:.1f} s: {o['by']} passes {o['on']}")
    return render


def _points(text: str) -> list[float]:
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise UserInputError(f"--points {text!r}: expected numbers separated by commas") from None
    if not values or any(not math.isfinite(v) or v < 0 for v in values):
        raise UserInputError(f"--points {text!r}: expected numbers >= 0")
    return values


def _render_series(table: dict, docs: list[dict]):
    # the standings pull scipy (about 2 s): only when a series is shown, never for --help
    from formula_tourney.report.race_standings import STANDINGS_COLUMNS, standings_rows

    def render(console) -> None:
        for doc in docs:
            _render(doc)(console)
        print_whole(whole_table(f"Standings after {table['races']} races", STANDINGS_COLUMNS,
                                standings_rows(table)), console)
    return render


def _check_out(path: Path | None, suffix: str) -> None:
    if path is None:
        return
    if path.suffix.lower() != suffix:
        raise UserInputError(f"{path}: expected a {suffix} file")
    if not path.parent.is_dir():
        raise UserInputError(f"{path}: folder {path.parent} does not exist")


def register(app: typer.Typer) -> None:
    """Add the ``race`` command to the main app."""

    @app.command("race")
    def race(
        models: list[Path] = typer.Argument(None, help="Checkpoints (.pt) of trained runs."),
        bots: list[str] = typer.Option([], "--bots", help="Bots to add (repeat or comma "
                                       "separated): follower."),
        track: str = typer.Option(..., "--track", help="Track name or file."),
        laps: int = typer.Option(3, "--laps", help="Laps of the race (>= 1)."),
        start: str = typer.Option("standing", "--start", help="standing | rolling"),
        grid: str = typer.Option("qualifying", "--grid", help="qualifying | given (the order "
                                 "of the arguments, models first)"),
        seed: int = typer.Option(0, "--seed", help="Seed of the grid jitter."),
        no_contact: bool = typer.Option(False, "--no-contact", help="Cars pass through each "
                                        "other."),
        gif: Path | None = typer.Option(None, "--gif", help="Write an animated GIF of the race."),
        mp4: Path | None = typer.Option(None, "--mp4", help="Write an MP4 of the race (needs "
                                        "ffmpeg on the PATH)."),
        fps: int = typer.Option(10, "--fps", help="Frames per second of the GIF/MP4 (the race "
                                "runs at 5 control steps per second)."),
        races: int = typer.Option(1, "--races", help="Races with rotated grids and seeds "
                                  "(seed, seed + 1, ...); > 1 prints the standings."),
        points: str = typer.Option("25,18,15,12,10,8,6,4,2,1", "--points", help="Points for "
                                   "P1, P2, ... (comma separated)."),
        out: Path | None = typer.Option(None, "--out", help="Write the races, standings and "
                                        "figures to this new folder (results.layout)."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """Race trained models and bots on one track: grid, start, laps, contacts, result."""
        from formula_tourney.race.entrants import build_entrants
        from formula_tourney.race.run import run_race
        from formula_tourney.race.series import run_series
        from formula_tourney.race.settings import RaceSettings
        from formula_tourney.report.race_figures import plot_race
        from formula_tourney.report.race_standings import markdown as standings_markdown
        from formula_tourney.report.race_standings import standings
        from formula_tourney.results.folder import RaceFolder
        from formula_tourney.sim.catalog import check_track_name, load_track
        from formula_tourney.sim.multicar.frames import RaceRenderer, ffmpeg_path, write_video
        from formula_tourney.sim.multicar.simulator import ContactSettings

        if laps < 1:
            raise UserInputError(f"--laps: expected at least 1, got {laps}")
        if start not in ("standing", "rolling"):
            raise UserInputError(f"--start: expected standing or rolling, got {start!r}")
        if grid not in ("qualifying", "given"):
            raise UserInputError(f"--grid: expected qualifying or given, got {grid!r}")
        if not 1 <= fps <= 60:
            raise UserInputError(f"--fps: expected 1..60, got {fps}")
        if races < 1:
            raise UserInputError(f"--races: expected at least 1, got {races}")
        if seed < 0:
            raise UserInputError(f"--seed: expected 0 or more, got {seed}")
        if races > 1 and (gif or mp4):
            raise UserInputError("--gif/--mp4 render one race: drop --races")
        points_table = _points(points)
        if out is not None:
            check_output_path(out, "--out", folder=True)
        if out is not None and (out.exists() and any(out.iterdir()) or not out.parent.is_dir()):
            raise UserInputError(f"--out {out}: must be a new or empty folder in an existing one")
        _check_out(gif, ".gif")
        _check_out(mp4, ".mp4")
        if mp4 is not None and ffmpeg_path() is None:
            raise UserInputError(f"--mp4 {mp4}: writing MP4 needs ffmpeg on the PATH")
        bot_list = [b.strip() for item in bots for b in item.split(",") if b.strip()]
        track_ref = check_track_name(track)
        track_obj = load_track(track_ref)
        settings = RaceSettings(laps=laps, start=start, grid=grid,
                                contact=ContactSettings(enabled=not no_contact))
        entrants = build_entrants(list(models or []), bot_list, track_obj, track_ref)
        renderer = None
        if gif or mp4:
            renderer = RaceRenderer(track_obj, [e.name for e in entrants],
                                    entrants[0].config.grass_width_m)
        message(f"racing {len(entrants)} cars, {laps} laps of {track_obj.name}"
                + (f", {races} races" if races > 1 else ""))
        if races > 1 or out is not None:
            folder = RaceFolder(out) if out is not None else None
            done = run_series(entrants, settings, races, seed,
                              on_race=(lambda k, r: folder.write_race(k, r.to_json()))
                              if folder else None)
            docs = [r.to_json() for r in done]
            table = standings(docs, points_table)
            if folder is not None:
                folder.write_series({"track": track_ref, "races": races, "seed": seed,
                                     "settings": settings.model_dump(),
                                     "entrants": [{"name": e.name, "kind": e.kind,
                                                   "source": e.source,
                                                   "sees_opponents": e.sees_opponents}
                                                  for e in entrants]})
                folder.write_standings(table, standings_markdown(table))
                for k, d in enumerate(docs):
                    plot_race(d, folder.figures_path / f"race-{k}")
                message(f"wrote {out}")
            emit({"standings": table, "races": docs}, as_json, _render_series(table, docs))
            return
        result = run_race(entrants, settings, seed=seed,
                          frame=renderer.frame if renderer else None)
        doc = result.to_json()
        for path in (gif, mp4):
            if path is not None:
                write_video(path, result.frames, fps)
                kept = sum(f is not None for f in result.frames)
                message(f"wrote {path} ({kept} frames)")
        emit(doc, as_json, _render(doc))

    @app.command("races")
    def races_cmd(
        file: Path = typer.Argument(..., help="Tournament file with parts of kind race."),
        results: Path = typer.Option(Path("results"), "--results", help="Results folder; the "
                                     "tournament goes in NAME/."),
        workers: int | None = typer.Option(None, "--workers", help="Parallel jobs."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """Run FILE (train what is left, race the race parts; resumable), then print the
        standings of every finished race part, also written to <part>/_races/ with figures."""
        from formula_tourney.commands.tourney import failures_exit, interrupted
        from formula_tourney.commands.tourney_view import ProgressView
        from formula_tourney.report.race_figures import plot_race
        from formula_tourney.report.race_standings import markdown as standings_markdown
        from formula_tourney.report.race_standings import standings
        from formula_tourney.results.folder import RaceFolder
        from formula_tourney.tourney.api import run_tournament

        try:
            result = run_tournament(file, workers=workers, results_dir=results,
                                    progress=ProgressView())
        except KeyboardInterrupt:
            raise interrupted() from None
        tables = {}
        for part in result["parts"]:
            race = part.get("race")
            if race is None:
                continue
            if race["status"] != "done":
                message(f"{part['part']}: series {race['status']}"
                        + (f" ({race['reason']})" if race.get("reason") else ""))
                continue
            folder = RaceFolder(Path(result["results"]) / race["path"])
            docs = folder.races()
            table = standings(docs, folder.series()["points"])
            folder.write_standings(table, standings_markdown(table))
            for k, doc in enumerate(docs):
                plot_race(doc, folder.figures_path / f"race-{k}")
            tables[part["part"]] = {"standings": table, "races": docs}
        if not tables:
            message("no race part has raced yet")
        out = {"parts": [{"part": p["part"], **p["race"]} for p in result["parts"]
                         if p.get("race") is not None],
               "standings": {k: v["standings"] for k, v in tables.items()}}

        def render(console) -> None:
            for name, v in tables.items():
                console.print(styled((name, "bold")))
                _render_series(v["standings"], v["races"])(console)
        emit(out, as_json, render)
        raise typer.Exit(failures_exit(result))

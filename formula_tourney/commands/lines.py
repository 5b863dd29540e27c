"""CLI commands for reference lines and the baseline bots: ``lines show``, ``lines table``,
``bot``. Each parses arguments and calls one function of ``bots.baselines``.

``bots.baselines`` pulls numba, quadprog and the simulator (about 0.6 s): it is imported inside
the commands, so that the rest of the CLI does not pay for it (docs/CONTRACTS.md).
"""

from __future__ import annotations

import math
from pathlib import Path

import typer

from formula_tourney.commands.output import emit, message, styled
from formula_tourney.errors import UserInputError
from formula_tourney.safeio import atomic_write
from formula_tourney.sim.catalog import load_track

LINE_HELP = "Reference line: centre | mincurv | recorded | genetic."


def _fmt(x: float, digits: int = 2) -> str:
    return "-" if not (isinstance(x, float | int) and math.isfinite(x)) else f"{x:.{digits}f}"


def _plot_line(report: dict, path: Path) -> None:
    """Map of the line coloured by QSS speed, track edges in grey."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    arrays = report["_arrays"]
    track = report["_track"]
    fig, ax = plt.subplots(figsize=(8, 8))
    for side in (1.0, -1.0):
        width = track.width_left_m if side > 0 else -track.width_right_m
        ex, ey, _ = track.pose_at(track.s_m, width)
        ax.plot(list(ex) + [ex[0]], list(ey) + [ey[0]], color="0.6", lw=0.8)
    points = ax.scatter(arrays["x_m"], arrays["y_m"], c=arrays["speed_kmh"], s=2, cmap="plasma")
    fig.colorbar(points, ax=ax, label="QSS speed (km/h)", shrink=0.8)
    ax.set_aspect("equal")
    ax.set_title(f"{report['track']}: {report['line']} line, QSS lap "
                 f"{report['profile_lap_s']:.2f} s")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fmt = path.suffix.lstrip(".").lower()
    atomic_write(path, lambda p: fig.savefig(p, format=fmt, dpi=120, bbox_inches="tight"))
    plt.close(fig)


def register(app: typer.Typer) -> None:
    """Add this area's commands to the main app."""
    lines_app = typer.Typer(help="Reference lines (centre, min-curvature, recorded, genetic) "
                            "and each track's reference limit.", no_args_is_help=True)
    app.add_typer(lines_app, name="lines")

    @lines_app.command("show")
    def show(
        track: str = typer.Argument(..., help="Track name (oval, technical, flowing, gen-<seed>) "
                                    "or path."),
        line: str = typer.Option("mincurv", "--line", help=LINE_HELP),
        plot: Path | None = typer.Option(None, "--plot", help="Write a map coloured by speed "
                                         "(.png, .svg or .pdf)."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """A line's length, QSS lap time, speeds and gap to the track's reference limit."""
        from formula_tourney.bots.baselines import check_kind, line_report, public

        check_kind(line)
        if plot is not None and plot.suffix.lower() not in (".png", ".svg", ".pdf"):
            raise UserInputError(f"--plot {plot}: use a .png, .svg or .pdf file name")
        trk = load_track(track)
        report = line_report(trk, line)
        if plot is not None:
            _plot_line({**report, "_track": trk}, plot)
            message(f"wrote {plot}")
        data = public(report)

        def render(console) -> None:
            console.print(styled((trk.name, "bold"), f" ({trk.length_m:.0f} m), line ",
                                 (line, "bold")))
            console.print(f"  QSS lap           {_fmt(data['profile_lap_s'])} s "
                          f"(reference limit {_fmt(data['reference_limit_s'])} s, gap "
                          f"{_fmt(data['gap_to_limit_pct'], 1)} %)")
            console.print(f"  line length       {data['line_length_m']:.1f} m")
            console.print(f"  speed             {data['min_speed_kmh']:.0f}-"
                          f"{data['max_speed_kmh']:.0f} km/h, mean "
                          f"{data['mean_speed_kmh']:.1f} km/h")
            console.print(f"  offsets           {data['offset_min_m']:.2f} .. "
                          f"{data['offset_max_m']:.2f} m; sum curvature^2 "
                          f"{data['sum_curvature_sq']:.4f} 1/m^2")

        emit(data, as_json, render)

    @lines_app.command("table")
    def table(
        tracks: str = typer.Option("oval,technical,flowing", "--tracks",
                                   help="Comma-separated track names."),
        laps: int = typer.Option(2, "--laps", min=1, help="Laps driven per bot."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """The README table: reference limit, follower on centre and min-curvature lines, and
        the genetic bot, per track (lap times in s, gap to the limit in %)."""
        from formula_tourney.bots.baselines import public, reference_table

        names = [t.strip() for t in tracks.split(",") if t.strip()]
        if not names:
            raise UserInputError("--tracks: give at least one track name")
        loaded = [load_track(n) for n in names]
        rows = reference_table(loaded, laps)

        def render(console) -> None:
            # A Markdown table (pasted into the README): never wrapped, never styled.
            console.print("| track | reference limit (s) | follower, centre (s) | follower, "
                          "min-curvature (s) | genetic bot (s) |", soft_wrap=True, markup=False)
            console.print("|---|---|---|---|---|", soft_wrap=True, markup=False)
            for r in rows:
                cells = []
                for key in ("follower_centre", "follower_mincurv", "genetic"):
                    dmg = r[f"{key}_damage"]
                    note = "" if dmg == 0 else f", damage {dmg:.0f}"
                    cells.append(f"{_fmt(r[f'{key}_s'])} (+{_fmt(r[f'{key}_gap_pct'], 1)} %"
                                 f"{note})")
                console.print(f"| {r['track']} | {_fmt(r['reference_limit_s'])} | "
                              + " | ".join(cells) + " |", soft_wrap=True, markup=False)

        emit({"rows": [public(r) for r in rows]}, as_json, render)

    @app.command("bot")
    def bot(
        track: str = typer.Argument(..., help="Track name or path."),
        line: str = typer.Option("mincurv", "--line", help=LINE_HELP),
        laps: int = typer.Option(2, "--laps", min=1, help="Timed laps to drive."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """Drive the follower bot (our Tita) on a line: lap times, damage, gap to the limit."""
        from formula_tourney.bots.baselines import bot_report, check_kind, public

        check_kind(line)
        trk = load_track(track)
        data = public(bot_report(trk, line, laps))

        def render(console) -> None:
            console.print(styled((trk.name, "bold"), f", {data['bot']} on the {line} line"))
            for i, (t, d) in enumerate(zip(data["laps"], data["lap_damage"], strict=False), 1):
                console.print(f"  lap {i}: {t:.2f} s" + ("" if d == 0 else f" (damage {d:.0f})"))
            console.print(f"  best clean lap {_fmt(data['best_lap_s'])} s, damage "
                          f"{data['damage']:.0f}, reference limit "
                          f"{_fmt(data['reference_limit_s'])} s, gap "
                          f"{_fmt(data['gap_to_limit_pct'], 1)} %")
            if not data["finished"]:
                console.print(f"  [red]did not finish: {data['termination']}[/red]")

        emit(data, as_json, render)

"""``formula-tourney status RESULTS/NAME``: how far a tournament is, from another shell.

The numbers are ``results.status.tournament_status``'s; this module only renders them (a table
of jobs per kind and state, the CPU time against the estimate, the ETA and its basis).
"""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from formula_tourney.commands.estimate_view import hours
from formula_tourney.commands.output import emit
from formula_tourney.report.claims.waves import read_waves
from formula_tourney.results.status import STATES, TournamentStatus, tournament_status


def render_status(console: Console, st: TournamentStatus) -> None:
    """Jobs per kind and state, then CPU time, the ETA and where each number comes from."""
    run = (f"run pid {st.run_pid} is running" if st.run_alive else
           "no run is working on it" + (f" (pid {st.run_pid} has ended)" if st.run_pid else ""))
    console.print(f"{st.tournament}: {run}", markup=False, highlight=False)
    table = Table(title_justify="left")
    table.add_column("kind")
    for state in STATES:
        table.add_column(state, justify="right")
    for kind, counts in st.counts.items():
        table.add_row(kind, *(str(counts[s]) for s in STATES))
    table.add_row("all", *(str(st.total[s]) for s in STATES), end_section=True)
    console.print(table)
    if st.total["interrupted"]:
        console.print(f"{st.total['interrupted']} job(s) were running when their run stopped; "
                      "the next run starts them again", markup=False, highlight=False)
    if st.parts_not_planned:
        console.print("parts not planned yet (they wait for a promotion): "
                      + ", ".join(st.parts_not_planned), markup=False, highlight=False)
    spent = f"{st.cpu_s_spent / 3600.0:.2f} CPU-h spent"
    if st.cpu_s_estimate is None:
        spent += " (no estimate: run with --estimate to keep one)"
    else:
        share = 100.0 * st.cpu_s_spent / st.cpu_s_estimate if st.cpu_s_estimate > 0 else 0.0
        spent += f" of {st.cpu_s_estimate / 3600.0:.2f} estimated ({share:.0f}%)"
    console.print(spent, markup=False, highlight=False)
    eta = "unknown" if st.eta_s is None else hours(st.eta_s)
    console.print(f"ETA: {eta} ({st.eta_basis}; workers: {st.workers_basis})", markup=False,
                  highlight=False)


def render_waves(console: Console, state: dict) -> None:
    """A sequential run's last reading: each claim's verdict, the seeds, and why it stopped."""
    last = state["waves"][-1] if state["waves"] else {}
    stopped = state.get("stopped")
    console.print(f"sequential run: {len(state['waves'])} wave(s); "
                  + (f"stopped: {stopped['reason']}" if stopped else "not stopped yet"),
                  markup=False, highlight=False)
    for claim in last.get("claims", []):
        console.print(f"  {claim['claim']}: {claim['verdict']}", markup=False, highlight=False)


def register(app: typer.Typer) -> None:
    @app.command()
    def status(
        folder: Path = typer.Argument(..., help="The tournament's results folder, "
                                      "RESULTS/NAME (e.g. results/quick)."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """Jobs done, running, pending and failed, CPU-hours against the estimate and an ETA.

        Reads the index read-only, so it is safe while the tournament's run is writing.
        """
        st = tournament_status(folder)
        waves = read_waves(folder)

        def show(console: Console) -> None:
            render_status(console, st)
            if waves is not None:
                render_waves(console, waves)

        emit({**st.model_dump(), "adaptive": waves}, as_json, show)

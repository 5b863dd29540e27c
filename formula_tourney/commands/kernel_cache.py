"""``formula-tourney compile``: fill numba's on-disk cache once, at install time.

The simulator's and the line tools' kernels are compiled on first use and cached on disk
(``cache=True``). Two reasons to do that once, in ``make setup``, and not inside the first run:
- cost: in a fresh checkout every worker of the first tournament compiles the same kernels at
  once, ~50 s each on the 2-core machine (the demo's first WIN1 jobs took 89 s, 40 s warm);
- determinism: a process that compiles the fastmath kernels itself does not run exactly the
  code a later process loads from the cache. Measured on the demo's technical job, seed 1: the
  reward of episode 35 differed in its last bit (36.628181706279925 against ...92) and the runs
  parted from there (one lapped, the other not). With the cache filled by setup every run loads
  the same code, so the same seed gives the same laps in ``train``, ``run`` and the benchmarks.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import typer

from formula_tourney.commands.output import emit, message


def register(app: typer.Typer) -> None:
    @app.command("compile")
    def compile_cmd(
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """Compile the simulator's kernels into numba's cache (make setup runs it)."""
        # heavy (torch, numba) imports stay inside the command so that --help is instant
        from formula_tourney.bots.baselines import bot_report
        from formula_tourney.sim.catalog import load_track
        from formula_tourney.training.loop import train
        from formula_tourney.training.run_spec import build_run_spec

        started = time.perf_counter()
        message("compile: the follower on the min-curvature line (lines, speed profile, car)")
        bot_report(load_track("oval"), "mincurv", laps=1)
        message("compile: a 40-step training run with LAC (vector env, observations, tests)")
        spec = build_run_spec(
            variant="WIN1", train_tracks=["technical"], reference="recorded", lac=True,
            device="cpu", threads=1,
            schedule={"episodes": 1, "max_steps": 40, "test_every_episodes": 1,
                      "test_starts": 1, "test_max_steps": 40},
            source="compile",
        )  # fmt: skip
        with tempfile.TemporaryDirectory(prefix="formula-tourney-compile-") as folder:
            train(spec, Path(folder) / "run", lambda _progress: None)
        seconds = time.perf_counter() - started
        emit({"compiled": True, "seconds": round(seconds, 1)}, as_json,
             lambda console: console.print(f"kernels compiled and cached in {seconds:.1f} s"))

"""CLI commands of the agents area: ``train`` one run, ``eval`` a checkpoint, list ``variants``.

Heavy imports (torch, the simulator) happen inside the commands so ``--help`` stays instant.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from formula_tourney.commands.output import emit, message
from formula_tourney.errors import UserInputError
from formula_tourney.lines.kinds import REFERENCE_KINDS
from formula_tourney.training.presets import PRESETS

RESULT_KEYS = (
    "best_lap_s", "laps", "damage", "finished", "episodes", "env_steps", "updates", "seconds",
)  # fmt: skip


def _demo_options(laps: int, **given: Any) -> dict[str, Any] | None:
    """``--demo-laps`` and the demo options given: the keys left out keep the preset's (or
    DemoSettings' defaults), so ``--preset tuned-bc --demo-laps 5`` still clones."""
    if laps <= 0:
        return None
    return {"laps": laps, **{k: v for k, v in given.items() if v is not None}}


def _parse_sets(items: list[str], what: str) -> dict[str, Any]:
    """``key=value`` pairs; values parse as JSON when they can (numbers, lists, booleans)."""
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise UserInputError(f"{what} {item!r}: expected key=value")
        key, raw = item.split("=", 1)
        try:
            out[key.strip()] = json.loads(raw)
        except json.JSONDecodeError:
            out[key.strip()] = raw
    return out


def _render_result(data: dict[str, Any]) -> Any:
    def render(console: Any) -> None:
        from rich.table import Table

        table = Table(show_header=False)
        for key in RESULT_KEYS:
            value = data.get(key)
            if isinstance(value, float) and key != "seconds":
                value = f"{value:.3f}"
            elif key == "seconds":
                value = f"{value:.1f}"
            table.add_row(key, "-" if value is None else str(value))
        console.print(table)

    return render


def register(app: typer.Typer) -> None:
    """Add this area's commands to the main app."""

    @app.command("train")
    def train_cmd(
        out: Path = typer.Option(..., "--out", help="Job folder to write (must not be finished)."),
        variant: str = typer.Option("WIN1", help="Variant: WIN1/4/8, LSTM4/8, MS2/3/4, PER40k/1M."),
        track: list[str] = typer.Option(  # noqa: B006
            ["oval"], "--track", help="Training track; repeat to train on several."
        ),
        reference: str = typer.Option(
            "centre", help=f"Reference line: {'|'.join(REFERENCE_KINDS)}."
        ),
        lac: bool = typer.Option(False, "--lac", help="Add look-ahead curvature to observations."),
        episodes: int = typer.Option(100, help="Training episodes."),
        env_steps: int = typer.Option(
            None, help="Env-step budget: also stop at the first episode end at or after it."
        ),
        seed: int = typer.Option(0, help="Random seed."),
        max_steps: int = typer.Option(1000, help="Control steps per training episode."),
        test_every: int = typer.Option(10, help="Test every N episodes (and at the end)."),
        test_track: list[str] = typer.Option(  # noqa: B006
            [], "--test-track", help="Test track (repeatable); default: the training tracks."
        ),
        test_starts: int = typer.Option(3, help="Start positions per test."),
        test_max_steps: int = typer.Option(1500, help="Control steps per test episode."),
        test_grip: list[float] = typer.Option(  # noqa: B006
            [], "--test-grip", help="Also test at this grip scale (repeatable): train on one "
            "grip (--env-set grip_scale=...), test on another."
        ),
        device: str = typer.Option("auto", help="auto|cpu|cuda."),
        threads: int = typer.Option(1, help="torch threads."),
        set_: list[str] = typer.Option(  # noqa: B006
            [], "--set", help="Variant hyperparameter override key=value (repeatable)."
        ),
        env_set: list[str] = typer.Option(  # noqa: B006
            [], "--env-set", help="FormulaRacing-v0 config override key=value (repeatable)."
        ),
        preset: str = typer.Option(
            "paper", help=f"Settings preset: paper (the paper's) or one beyond it: "
            f"{', '.join(p for p in PRESETS if p != 'paper')}."
        ),
        cars: int = typer.Option(1, help="Cars driving into the one replay buffer."),
        traffic_bots: int = typer.Option(
            0, "--traffic-bots", help="Follower bots around the learner in every training "
            "episode (opponent sensors added; beyond the paper; docs/races.md)."
        ),
        demo_laps: int = typer.Option(
            0, "--demo-laps", help="Follower laps per train track seeding a demonstration buffer "
            "(0: no demonstrations; beyond the paper)."
        ),
        demo_line: str = typer.Option(
            None, help="Line the demonstrating follower drives (default: the preset's, else "
            "mincurv)."
        ),
        demo_fraction: float = typer.Option(
            None, help="Share of each batch from the demos (default: the preset's, else 0.5)."
        ),
        bc_steps: int = typer.Option(
            None, help="Behaviour-cloning warm-start steps (with demos; default: the preset's, "
            "else 0)."
        ),
        bc_weight: float = typer.Option(
            None, help="Behaviour cloning in the actor's loss all run long, Q-filtered (with "
            "demos; default: the preset's, else 0 = off; docs/agents.md)."
        ),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """Train one DDPG variant and write its job folder (docs/CONTRACTS.md layout)."""
        # heavy (torch, numba) imports stay inside the command so that --help is instant
        from formula_tourney.results.folder import JobFolder
        from formula_tourney.training.loop import train
        from formula_tourney.training.spec import build_run_spec

        spec = build_run_spec(
            variant=variant, overrides=_parse_sets(set_, "--set"), train_tracks=track,
            test_tracks=test_track, reference=reference, lac=lac, seed=seed, device=device,
            threads=threads, env_overrides=_parse_sets(env_set, "--env-set"),
            schedule={"episodes": episodes, "env_steps": env_steps, "max_steps": max_steps,
                      "test_every_episodes": test_every, "test_starts": test_starts,
                      "test_max_steps": test_max_steps, "cars": cars,
                      "traffic_bots": traffic_bots,
                      "test_grip_scales": list(test_grip)},
            demos=_demo_options(demo_laps, line=demo_line, batch_fraction=demo_fraction,
                                bc_steps=bc_steps, bc_weight=bc_weight),
            preset=preset, source="train options",
        )  # fmt: skip
        if JobFolder(out).is_finished():
            raise UserInputError(f"{out} holds a finished run (summary.json); choose another --out")

        def progress(p: dict[str, Any]) -> None:
            best = p["best_lap_s"]
            message(
                f"episode {p['episode']}/{p['episodes']}  env steps {p['env_steps']}  "
                f"updates {p['updates']}  best lap "
                f"{'-' if best is None else f'{best:.2f} s'}  {p['seconds']:.0f} s"
            )

        summary = train(spec, out, progress)
        summary["out"] = str(out)
        emit(summary, as_json, _render_result(summary))

    @app.command("eval")
    def eval_cmd(
        checkpoint: Path = typer.Argument(..., help="A .pt checkpoint written by train."),
        track: str = typer.Option("oval", "--track", help="Track to drive."),
        starts: int = typer.Option(3, help="Start positions, evenly spaced over the lap."),
        max_steps: int = typer.Option(1500, help="Control steps per test episode."),
        reference: str | None = typer.Option(
            None, help="Reference line (default: the one the model was trained with)."
        ),
        device: str = typer.Option("cpu", help="auto|cpu|cuda."),
        grip: float | None = typer.Option(
            None, "--grip", help="Grip scale to drive at (default: the run's env grip_scale)."
        ),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """Drive a checkpoint greedily (epsilon = 0) and report its laps."""
        if starts < 1 or max_steps < 1:
            raise UserInputError("--starts and --max-steps must be >= 1")
        if reference is not None and reference not in REFERENCE_KINDS:
            raise UserInputError(f"--reference {reference!r}: use "
                                 f"{', '.join(REFERENCE_KINDS[:-1])} or {REFERENCE_KINDS[-1]}")
        from formula_tourney.training.evaluate import evaluate_checkpoint

        result = evaluate_checkpoint(str(checkpoint), track, starts, max_steps, device, reference,
                                     grip_scale=grip)
        emit(result, as_json, _render_result(result))

    @app.command("variants")
    def variants_cmd(
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """List the registered variants (the paper's ten, then those beyond it) and what each
        changes from the defaults."""
        from formula_tourney.agents.variants import ALL_VARIANTS, AgentConfig

        default = AgentConfig()
        rows = []
        for name, v in ALL_VARIANTS.items():
            changed = {
                k: val
                for k, val in v.model_dump().items()
                if k not in ("name", "family") and val != getattr(default, k)
            }
            rows.append({"name": name, "family": v.family, "beyond_paper": v.beyond_paper,
                         "changes": changed})  # fmt: skip

        def render(console: Any) -> None:
            from rich.table import Table

            table = Table("variant", "family", "source", "changes from the defaults")
            for r in rows:
                table.add_row(
                    r["name"],
                    r["family"],
                    "beyond paper" if r["beyond_paper"] else "paper",
                    ", ".join(f"{k}={v}" for k, v in r["changes"].items()) or "-",
                )
            console.print(table)

        emit(rows, as_json, render)

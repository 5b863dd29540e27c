"""CLI commands of the agents area: ``train`` one run, ``eval`` a checkpoint, ``replay`` one of
its tests, list ``variants``.

Heavy imports (torch, the simulator) happen inside the commands so ``--help`` stays instant.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

from formula_tourney.commands.model_options import (
    chosen_values,
    field_options,
    parse_key_values,
    with_field_options,
)
from formula_tourney.commands.output import emit, message
from formula_tourney.errors import UserInputError
from formula_tourney.lines.kinds import REFERENCE_KINDS
from formula_tourney.safeio import check_output_path
from formula_tourney.training.presets import PRESETS
from formula_tourney.training.run_spec import DemoSettings, RunSpec, Schedule, build_run_spec

TRAIN_OPTIONS = [
    *field_options(
        RunSpec, "Run", skip=("agent", "env", "schedule", "demos", "preset", "outside"),
        names={"train_tracks": "--track", "test_tracks": "--test-track"},
        defaults={"variant": "WIN1", "train_tracks": ("oval",)},
    ),
    *field_options(
        Schedule, "Schedule (unset: the preset's, else the default shown)",
        names={"test_every_episodes": "--test-every", "test_grip_scales": "--test-grip"},
    ),
    *field_options(
        DemoSettings, "Demonstrations (beyond the paper: any of these turns them on; unset: the "
        "preset's, else the default shown)", prefix="demo-",
        names={"batch_fraction": "--demo-fraction", "bc_steps": "--bc-steps",
               "bc_lr": "--bc-lr", "bc_weight": "--bc-weight", "bc_q_filter": "--bc-q-filter"},
    ),
]  # fmt: skip
"""``train``'s options for the settings a model owns: each field of RunSpec (its sections and
preset aside), Schedule and DemoSettings, with the model's description and default; ``names``
keeps the option names users already type (``--track``, ``--test-every``, ``--bc-steps``...)."""

RESULT_KEYS = (
    "best_lap_s", "laps", "damage", "finished", "episodes", "env_steps", "updates", "seconds",
)  # fmt: skip


def _outside_option(impl: str | None, entry: str | None, sb3: str | None,
                    sb3_contrib: str | None, sets: dict[str, Any]) -> Any:
    """The outside entrant ``train``'s options name, or None for a variant."""
    from pydantic import ValidationError

    from formula_tourney.agents.outside.naming import OutsideEntrant

    forms = {"impl": impl, "entry": entry, "sb3": sb3, "sb3_contrib": sb3_contrib}
    if all(v is None for v in forms.values()):
        if sets:
            raise UserInputError("--entrant-set needs --impl, --entry, --sb3 or --sb3-contrib")
        return None
    own = "kwargs" if sb3 is not None or sb3_contrib is not None else "settings"
    try:
        return OutsideEntrant(**{k: v for k, v in forms.items() if v is not None}, **{own: sets})
    except ValidationError as err:
        problems = "; ".join(e["msg"].removeprefix("Value error, ") for e in err.errors())
        raise UserInputError(f"train: --impl/--entry/--sb3/--sb3-contrib: {problems}") from None


def _outside_name(outside: Any) -> str:
    """A run name for an outside entrant: its class, entry point, or ``sb3-SAC``."""
    if outside.impl is not None:
        return str(outside.impl.rpartition(":")[2])
    return str(outside.entry or f"{outside.form}-{outside.sb3 or outside.sb3_contrib}")


def _user_set(ctx: typer.Context, name: str) -> bool:
    """Whether the user gave option ``name`` on the command line."""
    source = ctx.get_parameter_source(name)
    return source is not None and source.name == "COMMANDLINE"


def _preset_help() -> str:
    return (f"Settings preset: {', '.join(PRESETS)} (what each holds and the measurement that "
            "chose it: formula_tourney/training/presets.py, docs/results.md).")


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

    def train_cmd(
        ctx: typer.Context,
        out: Path = typer.Option(..., "--out", help="Job folder to write (must not be finished)."),
        set_: list[str] = typer.Option(  # noqa: B006
            [], "--set", help="Variant hyperparameter override key=value (repeatable)."
        ),
        env_set: list[str] = typer.Option(  # noqa: B006
            [], "--env-set", help="FormulaRacing-v0 config override key=value (repeatable)."
        ),
        preset: str = typer.Option("paper", help=_preset_help()),
        impl: str | None = typer.Option(
            None, "--impl", help="Train an outside entrant class \"package.module:Class\" "
            "(docs/entrants.md) instead of a variant.",
        ),  # fmt: skip
        entry: str | None = typer.Option(
            None, "--entry", help="Train the outside entrant of this entry point (group "
            "formula_tourney.entrants).",
        ),  # fmt: skip
        sb3: str | None = typer.Option(
            None, "--sb3", help="Train a Stable-Baselines3 algorithm (SAC, TD3, PPO...)."
        ),
        sb3_contrib: str | None = typer.Option(
            None, "--sb3-contrib", help="Train an sb3-contrib algorithm (CrossQ, TQC...)."
        ),
        entrant_set: list[str] = typer.Option(  # noqa: B006
            [], "--entrant-set", help="An outside entrant's setting key=value (impl, entry) or "
            "its algorithm's constructor argument (sb3, sb3-contrib) (repeatable).",
        ),  # fmt: skip
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
        **values: Any,
    ) -> None:
        """Train one variant, or an outside entrant (--impl, --entry, --sb3, --sb3-contrib),
        and write its job folder (docs/CONTRACTS.md layout)."""
        # heavy (torch, numba) imports stay inside the command so that --help is instant
        from formula_tourney.results.folder import JobFolder
        from formula_tourney.training.loop import train
        from formula_tourney.training.outside import check_outside
        from formula_tourney.training.resume import Preempted

        check_output_path(out, "--out", folder=True)
        demos = chosen_values(ctx, TRAIN_OPTIONS, values, DemoSettings)
        run = chosen_values(ctx, TRAIN_OPTIONS, values, RunSpec)
        outside = _outside_option(impl, entry, sb3, sb3_contrib,
                                  parse_key_values(entrant_set, "--entrant-set"))  # fmt: skip
        if outside is not None and not _user_set(ctx, "variant"):
            run["variant"] = _outside_name(outside)  # WIN1, the default, would mislabel it
        spec = build_run_spec(
            **run, overrides=parse_key_values(set_, "--set"),
            env_overrides=parse_key_values(env_set, "--env-set"),
            schedule=chosen_values(ctx, TRAIN_OPTIONS, values, Schedule),
            demos=demos or None, preset=preset, source="train options", outside=outside,
        )  # fmt: skip
        check_outside(spec, f"train {outside.form if outside else ''}".strip())
        if JobFolder(out).is_finished():
            raise UserInputError(f"{out} holds a finished run (summary.json); choose another --out")

        def progress(p: dict[str, Any]) -> None:
            best = p["best_lap_s"]
            message(
                f"episode {p['episode']}/{p['episodes']}  env steps {p['env_steps']}  "
                f"updates {p['updates']}  best lap "
                f"{'-' if best is None else f'{best:.2f} s'}  {p['seconds']:.0f} s"
            )

        try:
            summary = train(spec, out, progress)
        except Preempted as stop:  # SIGTERM: the job folder holds its resume file (or says why not)
            message(f"stopped: {stop}; the same command with the same --out resumes it")
            raise typer.Exit(143) from None
        summary["out"] = str(out)
        emit(summary, as_json, _render_result(summary))

    app.command("train")(with_field_options(train_cmd, TRAIN_OPTIONS))

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

    @app.command("replay")
    def replay_cmd(
        target: Path = typer.Argument(
            ..., help="A checkpoint (.pt) of a trained job; with --best, the job's folder (or a "
            "checkpoint in it)."),
        track: str | None = typer.Option(
            None, "--track", help="Track to drive (default: the run's first train track)."),
        best: bool = typer.Option(
            False, "--best", help="Replay the test that made the run's best clean lap on the "
            "track, found as the tables find it (its start, grip, seed and checkpoint), and "
            "check that it drives the table's lap time; exit 1 if not."),
        start_s_m: float | None = typer.Option(
            None, "--start-s-m", help="Where the test starts, m along the centre line (a "
            "tests.parquet row's start_s_m; default: the run's first test start, 50 m before "
            "the line)."),
        grip: float | None = typer.Option(
            None, "--grip", help="Grip scale (a row's grip_scale; default: the run's)."),
        seed: int | None = typer.Option(
            None, "--seed", help="Seed of the drive (default: the one the run's tests use at "
            "that start)."),
        gif: Path | None = typer.Option(
            None, "--gif", help="GIF to write: the drive's best clean lap, or the whole drive "
            "without one."),
        trace: Path | None = typer.Option(
            None, "--trace", help="File to write every step of the drive to (.csv or .parquet): "
            "time, distance, position, speed, steer, pedals, laps."),
        braking: bool = typer.Option(
            False, "--braking", help="Where the drive braked for each braking zone of the "
            "QSS lap on the run's reference line: its first brake >= 0.3, how far after the "
            "line's braking point, its speeds there and at the zone's apex, or where it ended."),
        max_steps: int | None = typer.Option(
            None, "--max-steps", min=1, help="Control steps at most (default: the run's "
            "test_max_steps, as its tests)."),
        frame_every: int = typer.Option(
            2, "--frame-every", min=1, help="Keep every n-th control step as a GIF frame."),
        device: str = typer.Option("cpu", help="auto|cpu|cuda."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON document."),
    ) -> None:
        """Drive one test of a trained actor again (no exploration): the same start, grip and
        seed give the same laps as its row in tests.parquet; --best finds the table's."""
        from formula_tourney.training.braking import braking_lines
        from formula_tourney.training.replay import replay, replay_best

        if gif is not None:
            check_output_path(gif, "--gif")  # before the drive, not after it
        if trace is not None:
            check_output_path(trace, "--trace")
        options: dict[str, Any] = {"max_steps": max_steps, "frame_every": frame_every,
                                   "device": device, "trace": trace, "braking": braking}
        if best:
            given = [name for name, value in (("--start-s-m", start_s_m), ("--grip", grip),
                                              ("--seed", seed)) if value is not None]
            if given:
                raise UserInputError(f"--best drives the best test's own start, grip and seed: "
                                     f"leave out {', '.join(given)}")
            job = target.parent.parent if target.is_file() else target
            summary = replay_best(job, track, gif, **options)
        else:
            summary = replay(target, track, gif, start_s_m=start_s_m, grip_scale=grip,
                             seed=seed, **options)

        def render(console: Any) -> None:
            laps = ", ".join(f"{t:.3f} s" + ("" if d <= 0 else " (damaged)")
                             for t, d in zip(summary["lap_times_s"], summary["lap_damage"],
                                             strict=True)) or "no timed lap"
            lines = [f"{summary['track']} from {summary['start_s_m']:.1f} m, grip "
                     f"{summary['grip_scale']:.2f}, seed {summary['seed']}: ended by "
                     f"{summary['termination']} after {summary['steps']} steps; laps: {laps}"]
            if summary["best_lap_s"] is not None:
                lines.append(f"best clean lap {summary['best_lap_s']:.3f} s")
            if best:
                lines.append(f"the table's lap: {summary['table_lap_s']:.3f} s (episode "
                             f"{summary['episode']}): "
                             + ("reproduced" if summary["reproduced"] else "NOT reproduced"))
            if summary["gif"]:
                lines.append(f"{summary['gif']}: {summary['frames']} frames")
            if summary["trace"]:
                lines.append(f"{summary['trace']}: {summary['steps']} steps")
            if summary["braking"] is not None:
                lines += braking_lines(summary["braking"],
                                       f"the {summary['reference']} line's QSS lap")
            for line in lines:
                console.print(line, markup=False, highlight=False)

        emit(summary, as_json, render)
        if best and not summary["reproduced"]:
            raise typer.Exit(1)

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

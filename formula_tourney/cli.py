"""The ``formula-tourney`` command line: parses arguments and calls one function per command.

Each command group lives in ``formula_tourney/commands/<area>.py`` and exposes
``register(app)``; this file only assembles them, maps bad input to exit code 2 and passes on the
exit code a command chose (``run``: 3 when jobs failed, 130 when interrupted). With ``--json``
an error is also one JSON object on stdout, so a script reading stdout always gets a document.
"""

from __future__ import annotations

import json
import sys

import click
import typer

from formula_tourney import __version__
from formula_tourney.commands import (
    agents,
    demo,
    kernel_cache,
    lines,
    race,
    report,
    status,
    tourney,
    tracks,
)
from formula_tourney.errors import UserInputError

try:  # recent typer releases bundle their own copy of click and raise its usage errors
    from typer._click.exceptions import ClickException as _BundledClickException
except ImportError:  # pragma: no cover - typer versions that use click itself
    _BundledClickException = click.exceptions.ClickException

USAGE_ERRORS = (click.exceptions.ClickException, _BundledClickException)

app = typer.Typer(
    name="formula-tourney",
    help="Deep RL drivers race at the grip limit from telemetry: tracks, bots, DDPG variants, "
    "tournaments and the paper's reports.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)



def _print_version(value: bool) -> None:
    """Eager ``--version``: prints before any command is parsed, then exits 0."""
    if value:
        typer.echo(f"formula-tourney {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_print_version, is_eager=True,
        help="Print the version and exit.",
    ),  # fmt: skip
) -> None:
    """Options of the command itself; the work is in the subcommands."""


for module in (demo, tracks, lines, agents, tourney, status, report, race, kernel_cache):
    module.register(app)


def _json_error(args: list[str], message: str, exit_code: int) -> None:
    """With ``--json`` among the arguments, the error as one JSON object on stdout (the message
    goes to stderr as without ``--json``)."""
    if "--json" in args:
        sys.stdout.write(json.dumps({"error": message, "exit_code": exit_code}) + "\n")
        sys.stdout.flush()


def main(argv: list[str] | None = None) -> None:
    """Console entry point: a UserInputError becomes one line on stderr and exit code 2 (and,
    with ``--json``, a JSON error object on stdout); a command's own exit code (``typer.Exit``)
    becomes the process's."""
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        # Without standalone mode click *returns* the code of a typer.Exit instead of exiting.
        code = app(args=args, standalone_mode=False)
    except UserInputError as err:
        print(f"error: {err}", file=sys.stderr)
        _json_error(args, str(err), 2)
        sys.exit(2)
    except typer.Exit as exc:  # raised outside click's own handling
        sys.exit(exc.exit_code)
    except SystemExit:
        raise
    except USAGE_ERRORS as exc:  # usage errors come through here in non-standalone mode
        exc.show()
        _json_error(args, exc.format_message(), exc.exit_code)
        sys.exit(exc.exit_code)
    except click.exceptions.Abort:
        print("aborted", file=sys.stderr)
        sys.exit(130)
    if isinstance(code, int) and code != 0:
        sys.exit(code)


if __name__ == "__main__":
    main()

"""The ``mdgs`` command line (typer): validate, generate, train, evaluate, study.

This package is the only place that imports typer and rich, and the only place where
:mod:`mdgs` and :mod:`validation` meet. Exit codes of every command: 0 success (for
``validate``: every check holds), 1 a claim refuted (``validate``: a finding, not a failure),
2 bad input or usage (one sentence on stderr naming the input and the fix, no traceback),
130 interrupted.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

import click
import typer

__all__ = ["app", "main", "fail", "parse_share", "progress_bar", "EXIT_HOLDS", "EXIT_REFUTED", "EXIT_ERROR"]

EXIT_HOLDS, EXIT_REFUTED, EXIT_ERROR = 0, 1, 2

# Parse errors: typer >= 0.20 vendors click (typer._click); older typer raises click's own.
_CLICK_ERRORS = (click.ClickException, typer.TyperException) if hasattr(typer, "TyperException") else (click.ClickException,)


class _App(typer.Typer):
    """Typer app whose parse errors end in one sentence on stderr and exit code 2."""

    def __call__(self, args: Sequence[str] | None = None, prog_name: str | None = None) -> None:
        sys.exit(main(args, prog_name=prog_name or "mdgs", app_=self))


app = _App(
    name="mdgs",
    help="MDGS: Kane-constrained GNN rigid-body simulator and the checks of its theory.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _root() -> None:
    """MDGS: Kane-constrained GNN rigid-body simulator and the checks of its theory."""


def main(
    args: Sequence[str] | None = None,
    prog_name: str = "mdgs",
    app_: typer.Typer | None = None,
    subcommand: str | None = None,
) -> int:
    """Run the CLI on ``args`` (default ``sys.argv[1:]``) and return its exit code.

    Click's usage errors (unknown flag, bad value) are printed as one sentence on stderr with
    exit code 2, instead of click's usage box. ``subcommand`` runs that sub-command alone
    (``python -m mdgs.cli.validate`` is ``mdgs validate``).
    """
    command = typer.main.get_command(app_ or app)
    if subcommand is not None:
        command = command.commands[subcommand]
    try:
        rv = command.main(args=list(args) if args is not None else None, prog_name=prog_name, standalone_mode=False)
    except _CLICK_ERRORS as e:
        ctx = getattr(e, "ctx", None)
        cmd = ctx.command_path if ctx is not None else prog_name
        if type(e).__name__ == "NoArgsIsHelpError" and ctx is not None:  # `mdgs` alone: the help
            print(ctx.get_help(), file=sys.stderr)
            return EXIT_ERROR
        message = e.format_message().rstrip(".") if hasattr(e, "format_message") else str(e)
        print(f"{cmd}: {message}; see `{cmd} --help`.", file=sys.stderr)
        return EXIT_ERROR
    except (click.Abort, typer.Abort):
        print(f"{prog_name}: aborted.", file=sys.stderr)
        return 130
    return rv if isinstance(rv, int) else 0


def fail(msg: str) -> None:
    """A user error: one sentence on stderr, exit code 2, no traceback."""
    typer.echo(f"error: {msg.rstrip('.')}.", err=True)
    raise typer.Exit(EXIT_ERROR)


def parse_share(text: str, flag: str) -> tuple[int, int]:
    """``"I/N"`` -> ``(I, N)`` with ``0 <= I < N`` (a shard of a dataset, a share of a study's cells)."""
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        fail(f"{flag} '{text}' is not of the form I/N (for example 0/4)")
    if not (n >= 1 and 0 <= i < n):
        fail(f"{flag} {text} is out of range; use I/N with 0 <= I < N")
    return i, n


def progress_bar(*extra_columns):
    """A rich progress bar on stderr (description, bar, n/N, extra columns, elapsed, remaining).

    Returns ``(progress, console)``; use ``progress`` as a context manager.
    """
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    console = Console(stderr=True)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), *extra_columns,
               TimeElapsedColumn(), TimeRemainingColumn())
    return Progress(*columns, console=console, transient=False), console


# the commands register themselves on `app` when imported (torch is imported only when
# train/evaluate run, so `mdgs validate` and `mdgs generate` do not pay for it)
from mdgs.cli import evaluate as _evaluate  # noqa: E402,F401
from mdgs.cli import generate as _generate  # noqa: E402,F401
from mdgs.cli import study as _study  # noqa: E402,F401
from mdgs.cli import train as _train  # noqa: E402,F401
from mdgs.cli import validate as _validate  # noqa: E402,F401

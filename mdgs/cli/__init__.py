"""The ``mdgs`` command line (typer): validate, generate, train, evaluate, study.

This package is the only place that imports typer and rich, and the only place where
:mod:`mdgs` and :mod:`validation` meet. Exit codes of every command (:data:`EXIT_CODES`):
0 success (for ``validate``: every check holds), 1 a claim refuted (``validate`` only: a
finding, not a failure), 2 bad input or usage (one sentence on stderr naming the input and
the fix, no traceback, nothing half-written), 3 an internal error (a bug: one line, the
traceback only under ``mdgs --debug``), 130 interrupted (rerun the same command to resume).

:func:`main` is the one place that maps what a command raises to those codes: the error
types of the command families (:data:`USER_ERRORS`, each message one sentence naming the
input and the fix) and operating-system errors on a named path are exit 2; anything else is
exit 3.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

import click
import typer

__all__ = ["app", "main", "fail", "parse_share", "progress_bar", "EXIT_HOLDS", "EXIT_REFUTED", "EXIT_ERROR",
           "EXIT_INTERNAL", "EXIT_INTERRUPTED", "EXIT_CODES", "USER_ERRORS"]

EXIT_HOLDS, EXIT_REFUTED, EXIT_ERROR, EXIT_INTERNAL, EXIT_INTERRUPTED = 0, 1, 2, 3, 130

#: What each exit code means (also the epilog of ``mdgs --help`` and the README's "Exit codes").
EXIT_CODES = {
    EXIT_HOLDS: "success (validate: every check holds)",
    EXIT_REFUTED: "a claim refuted (validate only: a finding, not a failure)",
    EXIT_ERROR: "bad input or usage: one sentence on stderr naming the input and the fix; nothing half-written "
                "(validate: also a check that could not decide)",
    EXIT_INTERNAL: "an internal error (a bug): one line; the traceback with `mdgs --debug COMMAND ...`",
    EXIT_INTERRUPTED: "interrupted (Ctrl-C): rerun the same command to resume",
}

#: Names of the error types whose message is a user's mistake in one sentence (exit 2). Matched by
#: name so that this module imports none of them (torch is imported only by train/evaluate/study).
USER_ERRORS = frozenset({"DatasetError", "SceneError", "PartitionError", "RunError", "TrainingError",
                         "ModelError", "StudyError", "MjcfError", "MjcfUnsupported", "UsageError"})

_STATE = {"debug": False}

# Parse errors: typer >= 0.20 vendors click (typer._click); older typer raises click's own.
_CLICK_ERRORS = (click.ClickException, typer.TyperException) if hasattr(typer, "TyperException") else (click.ClickException,)


class _App(typer.Typer):
    """Typer app whose parse errors end in one sentence on stderr and exit code 2."""

    def __call__(self, args: Sequence[str] | None = None, prog_name: str | None = None) -> None:
        sys.exit(main(args, prog_name=prog_name or "mdgs", app_=self))


app = _App(
    name="mdgs",
    help="MDGS: Kane-constrained GNN rigid-body simulator and the checks of its theory.",
    epilog="Exit codes: " + "; ".join(f"{k} {v}" for k, v in EXIT_CODES.items()) + ".",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _root(
    debug: bool = typer.Option(False, "--debug", help="On an internal error (exit 3), also print the traceback."),
) -> None:
    """MDGS: Kane-constrained GNN rigid-body simulator and the checks of its theory."""
    _STATE["debug"] = debug or _STATE["debug"]


def _is_user_error(e: BaseException) -> bool:
    return any(t.__name__ in USER_ERRORS for t in type(e).__mro__)


def _one_line(text: str) -> str:
    return " ".join(str(text).split()).rstrip(".")


def _os_error_sentence(e: OSError) -> str:
    """An operating-system error on a path (permissions, a file where a folder belongs, a full disk)."""
    what = e.strerror or type(e).__name__
    where = e.filename if e.filename is not None else "a file"
    return f"cannot write or read {where} ({what}); check that path, its folders and their permissions"


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
    _STATE["debug"] = bool(os.environ.get("MDGS_DEBUG"))
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
    except (click.Abort, typer.Abort, KeyboardInterrupt):
        print(f"{prog_name}: interrupted; rerun the same command to resume.", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as e:  # noqa: BLE001 - the one place that turns any exception into an exit code
        return _exception_exit(e, prog_name)
    return rv if isinstance(rv, int) else 0


def _exception_exit(e: Exception, prog_name: str) -> int:
    """Exit 2 for a user error or an OS error on a path (one sentence), else 3 (a bug: one line)."""
    if _is_user_error(e):
        print(f"error: {_one_line(e)}.", file=sys.stderr)
        return EXIT_ERROR
    if isinstance(e, OSError) and e.filename is not None:
        print(f"error: {_os_error_sentence(e)}.", file=sys.stderr)
        return EXIT_ERROR
    if _STATE["debug"]:
        import traceback

        traceback.print_exception(e, file=sys.stderr)
    hint = "" if _STATE["debug"] else "; rerun with `mdgs --debug ...` (or MDGS_DEBUG=1) for the traceback"
    print(f"{prog_name}: internal error (a bug in mdgs, please report it): {type(e).__name__}: "
          f"{_one_line(e)[:300]}{hint}.", file=sys.stderr)
    return EXIT_INTERNAL


def fail(msg: str) -> None:
    """A user error: one sentence on stderr, exit code 2, no traceback."""
    typer.echo(f"error: {_one_line(msg)}.", err=True)
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

    Returns ``(progress, console)``; use ``progress`` as a context manager. The bar appears at
    its first ``update``/``advance`` (when work starts), so a command refused while it checks its
    inputs prints its one error sentence and nothing else.
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

    class _Lazy(Progress):
        def __enter__(self):
            return self

        def __exit__(self, *exc) -> None:
            if self.live.is_started:
                self.stop()

        def _go(self) -> None:
            if not self.live.is_started:
                self.start()

        def update(self, *a, **kw):
            self._go()
            return super().update(*a, **kw)

        def advance(self, *a, **kw):
            self._go()
            return super().advance(*a, **kw)

    console = Console(stderr=True)
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), *extra_columns,
               TimeElapsedColumn(), TimeRemainingColumn())
    return _Lazy(*columns, console=console, transient=False), console


# the commands register themselves on `app` when imported (torch is imported only when
# train/evaluate run, so `mdgs validate` and `mdgs generate` do not pay for it)
from mdgs.cli import evaluate as _evaluate  # noqa: E402,F401
from mdgs.cli import generate as _generate  # noqa: E402,F401
from mdgs.cli import study as _study  # noqa: E402,F401
from mdgs.cli import train as _train  # noqa: E402,F401
from mdgs.cli import validate as _validate  # noqa: E402,F401

"""The ``mdgs`` command line: ``mdgs validate`` here, simulator sub-commands from :mod:`mdgs.cli`."""

from __future__ import annotations

import typer

import mdgs.cli

app = typer.Typer(
    name="mdgs",
    help="MDGS: Kane-constrained GNN rigid-body simulator and the checks of its theory.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _root() -> None:
    """MDGS: Kane-constrained GNN rigid-body simulator and the checks of its theory."""


@app.command()
def validate(
    quick: bool = typer.Option(False, "--quick", help="Run the fast subset of checks."),
) -> None:
    """Run every check of `kane` and print a verdict per claim."""
    raise typer.Exit(2)


mdgs.cli.register(app)


def validate_main() -> None:
    """Entry point of ``python -m validation``."""
    typer.main.get_command(app).main(args=["validate", *__import__("sys").argv[1:]], prog_name="python -m validation")

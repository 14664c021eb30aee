"""Sub-commands of the ``mdgs`` CLI that belong to the simulator (generate, train, evaluate).

``register(app)`` adds them to the root typer app defined in :mod:`validation.cli`.
"""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    """Add the simulator's sub-commands to ``app``."""
    return None

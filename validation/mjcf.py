"""``mdgs validate --mjcf FILE``: the claim checks that apply to a user's MJCF tree, as report rows (no CLI code here).

:func:`check_mjcf` runs :func:`kane.mjcf_checks.run_mjcf_checks` and returns the report
dict of :func:`validation.report.build_report`, so that the command renders the usual
verdict table and writes the usual JSON. A file the tree derivation cannot take (closed
loops, tendons, ...) raises :class:`MjcfError` with one sentence (exit code 2).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from validation import report as _report

__all__ = ["MjcfError", "check_mjcf"]


class MjcfError(ValueError):
    """The MJCF file cannot be checked; the message is one sentence naming the reason."""


def check_mjcf(path: str | Path, check: list[str] | None = None, case: list[str] | None = None, quick: bool = False,
               seed: int = 0, claims: Mapping[str, Any] | None = None) -> dict:
    """The validation report of the MJCF file ``path``.

    Parameters
    ----------
    path : MJCF file (hinge, slide, ball and free joints).
    check : claim ids to run (``eq3``, ``eq11``, ``eq12``, ``eq36`` and their ``.corrected``).
    case : keep rows whose case contains one of these strings (a speed or body name).
    quick : fewer random states and trajectory frames.
    seed : seeds the random states and the trajectory.
    claims : ``kane.claims.CLAIMS``, for the statements in the rows.

    Returns
    -------
    dict : :func:`validation.report.build_report` of the results.

    Raises
    ------
    MjcfError : the file is missing, cannot be loaded, or holds an unsupported feature.
    """
    from kane.mjcf import MjcfUnsupported
    from kane.mjcf_checks import run_mjcf_checks

    if not Path(path).is_file():
        what = "is a folder, not a file" if Path(path).is_dir() else "no such file"
        raise MjcfError(f"--mjcf {path}: {what}; pass an MJCF file.")
    try:
        results = run_mjcf_checks(path, claim_ids=check or None, quick=quick, seed=seed)
    except MjcfUnsupported as e:
        raise MjcfError(str(e)) from e
    if case:
        results = [r for r in results if any(c.lower() in r.case.lower() for c in case)]
    return _report.build_report(results, claims)

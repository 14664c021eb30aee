"""Result records of the checks: one frozen dataclass per check outcome, one table of verdicts.

A :class:`CheckResult` says which claim was tried, on which case, by which route, with
which largest residual (or smallest margin) against which tolerance, and the verdict that
follows from comparing the two. Verdicts are never set by hand: use :func:`decide`.
"""

from __future__ import annotations

import enum
import math
from dataclasses import asdict, dataclass, field
from typing import Any


class Verdict(enum.StrEnum):
    """Outcome of one check."""

    HOLDS = "holds"
    REFUTED = "refuted"
    ERROR = "error"


class Route(enum.StrEnum):
    """How a verdict was reached."""

    SYMBOLIC = "symbolic"  # sympy: simplified to zero, or proven inequality
    PINOCCHIO = "pinocchio"  # numeric, against Pinocchio's algorithms
    MUJOCO = "mujoco"  # numeric, along MuJoCo trajectories / MuJoCo quantities
    HYPOTHESIS = "hypothesis"  # property-based search for counterexamples
    CASADI = "casadi"  # ipopt maximisation of (left side - right side)


@dataclass(frozen=True)
class CheckResult:
    """Outcome of one check of one claim on one case by one route.

    Attributes
    ----------
    claim_id : str
        Stable id of the claim (``eq3``, ``lemmaA1``, ..., ``eq12``, or a corrected
        statement ``eq12.corrected``).
    case : str
        The system or setting the claim was tried on (``free_box``, ``cubli``, ...).
    route : str
        One of :class:`Route`.
    verdict : str
        One of :class:`Verdict`; decided by :func:`decide`.
    residual : float
        Largest residual of an equality, or largest violation ``lhs - rhs`` of an
        inequality (negative means a margin), over everything tried.
    tolerance : float
        Largest residual that still counts as ``holds``.
    assumptions : dict
        What the check was tried under (generalized speeds, element shapes, forces, ...).
    counterexample : dict or None
        Replayable data (see :mod:`kane.counterexamples`) when refuted.
    corrected : str or None
        Id of the corrected statement that holds where the paper's one is refuted.
    detail : str
        One line a reader can act on.
    seconds : float
        Wall time of the check.
    clause : str
        Key of the clause of the claim (``kane.claims.Claim.clauses``) that this check tries;
        ``""`` for a claim with a single clause.
    """

    claim_id: str
    case: str
    route: str
    verdict: str
    residual: float
    tolerance: float
    assumptions: dict[str, Any] = field(default_factory=dict)
    counterexample: dict[str, Any] | None = None
    corrected: str | None = None
    detail: str = ""
    seconds: float = 0.0
    clause: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (NaN/inf residuals become ``None``)."""
        d = asdict(self)
        for k in ("residual", "tolerance"):
            if d[k] is not None and not math.isfinite(d[k]):
                d[k] = None
        return d


def decide(residual: float, tolerance: float) -> str:
    """Verdict from a residual: ``holds`` iff finite and ``residual <= tolerance``.

    A NaN residual is an ``error`` (nothing was decided), never a ``holds``.
    """
    if residual is None or (isinstance(residual, float) and math.isnan(residual)):
        return Verdict.ERROR.value
    return Verdict.HOLDS.value if residual <= tolerance else Verdict.REFUTED.value

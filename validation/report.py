"""The machine-readable validation report: one dict built from the check results, written as JSON.

Schema (``mdgs validate --json PATH``)::

    {
      "checks": [
        {"id", "claim", "case", "route", "verdict", "residual", "tolerance",
         "assumptions", "counterexample", "corrected", "detail", "seconds", "clause", "scope"}
      ],
      "claims": [
        {"id", "title", "equation", "statement", "verdict", "scope",
         "clauses": [{"key", "text", "verdict", "cases"}]}
      ],
      "summary": {"checks", "hold", "refuted", "errors"},
      "environment": {"python", "sympy", "pin", "mujoco", "casadi", "torch", "mdgs"}
    }

``counterexample`` is ``null`` or the object that :func:`kane.counterexamples.replay`
(``mdgs validate --replay FILE``) accepts. ``corrected`` is ``null`` or
``{"id", "title", "statement", "verdict", "scope"}``: the corrected statement that ``kane``
offers for a refuted claim, with the verdict of all its checks in the run (``null`` when none
was run). ``clause`` is the key of the clause of the claim that the check tries; ``scope`` is
the claim's one-line scope, "<verdict> for <clause>; ..." from the verdicts of every clause
(:func:`scope_line`), the same line as in ``claims``. A claim's verdict is ``refuted`` when
any of its checks is, ``error`` when any could not decide, ``not run`` when none ran. The
same dict feeds the docs' pages (``docs/hooks.py``).
"""

from __future__ import annotations

import json
import math
import os
import platform
import sys
from collections.abc import Iterable, Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

__all__ = [
    "ENVIRONMENT_PACKAGES",
    "NOT_RUN",
    "combine_verdicts",
    "scope_line",
    "claim_summaries",
    "build_report",
    "summarize",
    "summary_line",
    "environment",
    "exit_code",
    "write_json",
    "result_to_row",
]

# Distribution names whose versions the report records (importlib.metadata names).
ENVIRONMENT_PACKAGES = ("sympy", "pin", "mujoco", "casadi", "torch", "mdgs")


def _field(result: Any, name: str, default: Any = None) -> Any:
    """``result.name`` for a CheckResult, ``result[name]`` for a dict (dataset checks)."""
    if isinstance(result, Mapping):
        return result.get(name, default)
    return getattr(result, name, default)


def _finite_or_none(x: Any) -> float | None:
    if x is None:
        return None
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _jsonable(obj: Any) -> Any:
    """Plain JSON types from numpy arrays/scalars, tuples and non-finite floats (-> None)."""
    if obj is None or isinstance(obj, (bool, str, int)):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set)):
        return [_jsonable(v) for v in obj]
    tolist = getattr(obj, "tolist", None)  # numpy arrays and scalars
    if callable(tolist):
        return _jsonable(tolist())
    return str(obj)


NOT_RUN = "not run"


def combine_verdicts(verdicts: Iterable[str]) -> str:
    """One verdict of several checks: refuted > error > holds; ``not run`` when there are none."""
    v = set(verdicts)
    if not v:
        return NOT_RUN
    for w in ("refuted", "error"):
        if w in v:
            return w
    return "holds"


def _clauses(claim: Any) -> list[tuple[str, str]]:
    fn = getattr(claim, "clause_list", None)
    return list(fn()) if callable(fn) else [("", "every case tried")]


def scope_line(clause_verdicts: Iterable[tuple[str, str]]) -> str:
    """``"refuted for rotational speeds; holds for translational speeds"`` from (text, verdict)
    per clause, in order; neighbouring clauses with the same verdict share it."""
    parts: list[tuple[str, list[str]]] = []
    for text, verdict in clause_verdicts:
        if parts and parts[-1][0] == verdict:
            parts[-1][1].append(text)
        else:
            parts.append((verdict, [text]))
    return "; ".join(f"{v} for {', '.join(texts)}" for v, texts in parts)


def claim_summaries(rows: Iterable[Mapping], claims: Mapping[str, Any]) -> list[dict]:
    """The ``claims`` section: per claim id met in ``rows`` (in order), its verdict, the verdict
    and cases of each clause, and the scope line."""
    rows = list(rows)
    out = []
    for cid in dict.fromkeys(r["id"] for r in rows):
        claim = claims.get(cid)
        mine = [r for r in rows if r["id"] == cid]
        clauses = []
        for key, text in _clauses(claim):
            hit = [r for r in mine if (r.get("clause") or "") == key]
            clauses.append({"key": key, "text": text, "verdict": combine_verdicts(r["verdict"] for r in hit),
                            "cases": [f"{r['case']} ({r['route']})" for r in hit]})
        out.append({
            "id": cid,
            "title": getattr(claim, "title", None) or cid,
            "equation": getattr(claim, "equation", None),
            "statement": getattr(claim, "statement", None),
            "verdict": combine_verdicts(r["verdict"] for r in mine),
            # rows of checks that name no clause (dataset checks) say nothing of the claim's scope
            "scope": (scope_line((c["text"], c["verdict"]) for c in clauses)
                      if any(c["verdict"] != NOT_RUN for c in clauses) else None),
            "clauses": clauses,
        })
    return out


def result_to_row(result: Any, claims: Mapping[str, Any] | None = None, verdicts: Mapping | None = None) -> dict:
    """One ``checks`` entry of the report from a :class:`kane.results.CheckResult` (or a dict).

    Parameters
    ----------
    result : CheckResult or dict
        One check outcome.
    claims : mapping of claim id -> Claim, optional
        ``kane.claims.CLAIMS``; gives the few-word ``claim`` title and the corrected statement.
    verdicts : mapping of claim id -> verdict, optional
        Combined verdicts of the whole run (:func:`combine_verdicts`), to attach the corrected
        claim's own verdict.
    """
    claims = claims or {}
    verdicts = verdicts or {}
    claim_id = str(_field(result, "claim_id", ""))
    case = str(_field(result, "case", ""))
    claim = claims.get(claim_id)
    corrected_id = _field(result, "corrected") or getattr(claim, "corrected_id", None)
    corrected = None
    if corrected_id:
        cclaim = claims.get(corrected_id)
        v = verdicts.get(corrected_id)
        corrected = {
            "id": corrected_id,
            "title": getattr(cclaim, "title", None),
            "statement": getattr(cclaim, "statement", None),
            "verdict": None if v in (None, NOT_RUN) else v,
            "scope": None,
        }
    cex = _field(result, "counterexample")
    return {
        "id": claim_id,
        "claim": getattr(claim, "title", None) or claim_id,
        "case": case,
        "route": str(_field(result, "route", "")),
        "verdict": str(_field(result, "verdict", "error")),
        "residual": _finite_or_none(_field(result, "residual")),
        "tolerance": _finite_or_none(_field(result, "tolerance")),
        "assumptions": _jsonable(_field(result, "assumptions") or {}),
        "counterexample": _jsonable(cex) if cex else None,
        "corrected": corrected,
        "detail": str(_field(result, "detail", "") or ""),
        "seconds": _finite_or_none(_field(result, "seconds", 0.0)),
        "clause": str(_field(result, "clause", "") or ""),
        "scope": None,
    }


def summarize(rows: Iterable[Mapping]) -> dict[str, int]:
    """Counts of verdicts: ``{"checks", "hold", "refuted", "errors"}``."""
    rows = list(rows)
    hold = sum(r["verdict"] == "holds" for r in rows)
    refuted = sum(r["verdict"] == "refuted" for r in rows)
    return {"checks": len(rows), "hold": hold, "refuted": refuted, "errors": len(rows) - hold - refuted}


def summary_line(summary: Mapping[str, int]) -> str:
    """The last line of ``mdgs validate``: ``N checks: H hold, R refuted, E errors`` (singular for 1)."""
    n, h, r, e = summary["checks"], summary["hold"], summary["refuted"], summary["errors"]
    return (
        f"{n} check{'s' if n != 1 else ''}: {h} hold{'s' if h == 1 else ''}, "
        f"{r} refuted, {e} error{'s' if e != 1 else ''}"
    )


def exit_code(summary: Mapping[str, int]) -> int:
    """0 when every check holds, 1 when any is refuted (and none errored), 2 on any error."""
    if summary["errors"]:
        return 2
    if summary["refuted"]:
        return 1
    return 0


def environment() -> dict[str, str | None]:
    """Versions of Python and of :data:`ENVIRONMENT_PACKAGES` (``None`` when not installed)."""
    env: dict[str, str | None] = {"python": platform.python_version()}
    for name in ENVIRONMENT_PACKAGES:
        try:
            env[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            env[name] = None
    return env


def build_report(results: Iterable[Any], claims: Mapping[str, Any] | None = None) -> dict:
    """The report dict (see the module docstring) from check results, in run order."""
    results = list(results)
    claims = claims or {}
    by_claim: dict[str, list[str]] = {}
    for r in results:
        by_claim.setdefault(str(_field(r, "claim_id")), []).append(str(_field(r, "verdict")))
    verdicts = {cid: combine_verdicts(v) for cid, v in by_claim.items()}
    rows = [result_to_row(r, claims, verdicts) for r in results]
    summaries = claim_summaries(rows, claims)
    scope = {c["id"]: c["scope"] for c in summaries}
    for row in rows:
        row["scope"] = scope.get(row["id"])
        if row["corrected"]:
            row["corrected"]["scope"] = scope.get(row["corrected"]["id"])
    return {"checks": rows, "claims": summaries, "summary": summarize(rows), "environment": environment()}


def write_json(report: Mapping, path: str | os.PathLike) -> None:
    """Write ``report`` as JSON to ``path`` atomically (the project's one writer,
    :func:`mdgs.data.io.atomic_path`); ``-`` is stdout.

    Raises
    ------
    OSError
        When the folder of ``path`` does not exist or is not writable.
    """
    text = json.dumps(report, indent=2, allow_nan=False) + "\n"
    if str(path) == "-":
        sys.stdout.write(text)
        sys.stdout.flush()
        return
    from mdgs.data.io import atomic_path

    with atomic_path(Path(path)) as tmp:
        tmp.write_text(text, encoding="utf-8")


def format_number(x: float | None) -> str:
    """A residual, margin or tolerance in 3 significant digits; ``-`` for none."""
    if x is None:
        return "-"
    return f"{x:.3g}"


def _fmt_value(v: Any, depth: int = 0) -> str:
    """Compact one-line rendering of a counterexample value (numbers to 4 significant digits)."""
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}={_fmt_value(x, depth + 1)}" for k, x in v.items()) + "}"
    if isinstance(v, (list, tuple)):
        items = [_fmt_value(x, depth + 1) for x in v[:6]]
        if len(v) > 6:
            items.append(f"... ({len(v)} items)")
        return "[" + ", ".join(items) + "]"
    return str(v)


def counterexample_line(cex: dict | None, width: int = 200) -> str:
    """A counterexample on one line, cut to ``width`` characters."""
    if not cex:
        return ""
    line = ", ".join(f"{k}={_fmt_value(v)}" for k, v in cex.items())
    return line if len(line) <= width else line[: width - 3] + "..."

"""Replay of recorded counterexamples through MuJoCo and Pinocchio.

A counterexample is a JSON-ready dict with ``claim_id`` and ``kind``:

* ``element``: a point-mass element state (``masses``, ``offsets``, ``forces``, ``omega``, ``alpha``). The
  element is rebuilt as a MuJoCo body of small spheres; MuJoCo and Pinocchio each supply
  its mass, inertia and the resultant/moment of the forces (MuJoCo: ``mj_applyFT``), and
  both sides of the claim are evaluated from those engine quantities. This is an
  independent evaluation of the inequality, not a re-run of the sympy expression.
* ``mujoco_geom``: an element that is one MuJoCo geom; its inertia comes from MuJoCo.
* ``trajectory``, ``jacobian``, ``scaling``: re-run the check that recorded them; for Eq. (11)
  and Eq. (23), also evaluate both sides at the recorded frame and speed
  (:func:`kane.claims.counterexample_sides`).
"""

from __future__ import annotations

from kane.engines import ReplayReport, Side, replay_element, replay_geom

__all__ = ["ReplayReport", "Side", "replay"]


def _replay_check(cex: dict) -> ReplayReport:
    from kane.claims import counterexample_sides, run_checks

    res = [r for r in run_checks([cex["claim_id"]], [cex["case"]] if "case" in cex else None) if r.claim_id == cex["claim_id"]]
    same = [r for r in res if r.case == cex.get("case")]  # --case matches substrings: "(RK4)" cases too
    rows = [(r.route, r.residual, r.tolerance) for r in (same or res)]
    context, sides = counterexample_sides(cex) or ([], [])
    return ReplayReport(cex["claim_id"], cex["kind"], rows, "re-ran the recorded check: lhs = residual, rhs = tolerance",
                        context=context, sides=sides)


def replay(cex: dict) -> ReplayReport:
    """Replay a counterexample recorded by a check (see module docstring for kinds).

    Raises
    ------
    ValueError
        the dict is not a counterexample this function understands.
    """
    if not isinstance(cex, dict) or "claim_id" not in cex or "kind" not in cex:
        raise ValueError("a counterexample is a JSON object with 'claim_id' and 'kind' (as written by mdgs validate --json)")
    kind = cex["kind"]
    if kind == "element":
        if "sample" not in cex:
            raise ValueError("an 'element' counterexample needs a 'sample' object")
        return replay_element(cex)
    if kind == "mujoco_geom":
        return replay_geom(cex)
    if kind in ("trajectory", "jacobian", "scaling"):
        return _replay_check(cex)
    raise ValueError(f"unknown counterexample kind {kind!r}; expected element, mujoco_geom, trajectory, jacobian or scaling")

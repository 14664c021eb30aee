"""validation.render: the docs' compact claim forms are the checked margins, the printer names
symbols for reading, and counterexample tables show the numbers the replay prints."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from kane.claims import CLAIMS
from validation import render


@pytest.mark.parametrize("cid", sorted(render.COMPACT))
def test_compact_form_expands_to_the_checked_margin(cid):
    # round-off of sums of ~100 products of O(1) numbers: ~1e-15; 1e-12 leaves room, a wrong
    # coefficient or a missing term is O(1)
    assert render.compact_agrees(cid) < 1e-12


def test_a_wrong_compact_form_is_caught(monkeypatch):
    lhs, rhs = render.COMPACT["eq36"]
    monkeypatch.setitem(render.COMPACT, "eq36", (lhs, rhs * sp.Rational(5, 4)))  # 1/2 instead of 2/5
    assert render.compact_agrees("eq36") > 1e-3


def test_every_claim_has_latex_text_and_clauses():
    for cid, claim in CLAIMS.items():
        assert cid in render.TEXT, cid
        keys = {k for k, _ in claim.clause_list()}
        assert keys <= set(render.TEXT[cid].get("clauses", {"": ""})), cid


@pytest.mark.parametrize("cid", ["eq11", "eq11.corrected", "eq12", "eq17", "eq19", "eq15", "eq34", "eq30"])
def test_statements_print_with_reading_names(cid):
    tex = render.statement_latex(CLAIMS[cid])
    for leak in ("v_{next}", "operatorname", "F_{gamma", "u_{g}", "r_{1 x}", "\\vec"):
        assert leak not in tex, (cid, leak, tex)
    if cid.startswith("eq11"):
        assert "v^{t+1}_{\\gamma,i}" in tex and "u_{\\gamma}" in tex


def test_expanded_lines_are_short_and_are_the_expression():
    expr = CLAIMS["eq35.corrected"].expression()
    lines = render.expanded_lines(expr)
    # 26 glyphs with the name of the row (the rows align after it); an indivisible factor may exceed it a little
    assert max(render._visible(x.replace("&", "")) for x in lines) <= 30
    assert len(lines) > 5


def _element_row(cid):
    from kane.adversarial import casadi_search

    v, s = casadi_search(cid, seed=0, n_starts=1)
    cex = {"claim_id": cid, "kind": "element", "sample": s.to_dict()}
    return {"id": cid, "case": "generic element", "route": "casadi", "residual": v, "tolerance": 1e-9,
            "counterexample": cex, "verdict": "refuted"}


@pytest.mark.parametrize("cid", ["eq34", "eq36"])
def test_counterexample_table_shows_what_replay_prints(cid):
    from kane.counterexamples import replay

    row = _element_row(cid)
    view = render.counterexample_view(row)
    sides = dict(view["sides"])
    printed = str(replay(row["counterexample"]))
    assert f"lhs - rhs = {sides['lhs − rhs']}" in printed
    rel = sides["relative margin (lhs − rhs)/scale"]
    assert f"(lhs - rhs) / scale = {rel}" in printed
    # the relative margin is the report's number (to the 3 digits both print)
    assert rel == f"{row['residual']:.3g}"
    assert view["sentence"] and "..." not in " ".join(v for _, v in view["quantities"])


def test_fmt_shows_round_off_as_zero_and_never_truncates():
    assert render.fmt(3.2e-44) == "0"
    assert render.fmt(-1.826e-1) == "-0.1826"
    assert "times 10^{-5}" in render.fmt(7.58e-5)
    assert render._vec(np.array([2.9, 1e-15, -3e-16])) == "(2.9, 0, 0)"


def test_a_speed_index_0_is_not_printed_as_no():
    """A trajectory counterexample without a recorded point (an older report) lists its fields:
    the speed index 0 is a number, only real bools read yes/no."""
    cex = {"claim_id": "eq11", "kind": "trajectory", "case": "free box in gravity, spinning", "integrator": "Euler",
           "frame": 5, "gamma": 0, "translational": False}
    row = {"id": "eq11", "case": cex["case"], "route": "mujoco", "residual": 2e-3, "tolerance": 1e-10,
           "counterexample": cex, "verdict": "refuted"}
    q = dict(render.counterexample_view(row)["quantities"])
    assert q[r"speed \(\gamma\) (index)"] == "0"
    assert q["translational speed"] == "no"
    assert render._yesno(1) == "1" and render._yesno(True) == "yes"


@pytest.mark.parametrize("cid, case", [("eq23", "free box, 8 elements, rotated"), ("eq11", "free box in gravity, spinning"),
                                       ("eq11", "free box, joint origin offset")])
def test_equality_counterexample_table_shows_what_replay_prints(cid, case):
    """The docs' table of an Eq. (11) or Eq. (23) counterexample: lhs, rhs and lhs - rhs as the
    replay prints them (4 digits) and the relative margin equal to the report's number."""
    from kane.claims import CLAIMS as claims
    from kane.claims import run_checks
    from kane.counterexamples import replay
    from validation.report import build_report

    results = [r for r in run_checks([cid], [case], quick=True) if r.claim_id == cid and r.verdict == "refuted"]
    row = max(build_report(results, claims)["checks"], key=lambda r: r["residual"])
    view = render.counterexample_view(row)
    printed = str(replay(row["counterexample"]))
    values = [(k, v) for k, v in view["sides"]]
    shown = [v for k, v in values if k.startswith(("lhs", "rhs"))]
    assert len(shown) >= 3
    for v in shown:  # lhs, rhs, lhs - rhs: the replay's numbers
        assert v in printed, (v, printed)
    rel = [v for k, v in values if k.startswith("relative margin")]
    assert f"{row['residual']:.3g}" in rel
    assert view["sentence"] and "lhs" in view["sides"][0][0]


def _display_sides():
    for cid, claim in CLAIMS.items():
        if cid in render.COMPACT:
            yield cid, *render.COMPACT[cid]
        elif isinstance(claim.expression(), sp.Eq):
            yield cid, claim.expression().lhs, claim.expression().rhs


@pytest.mark.parametrize("cid, lhs, rhs", list(_display_sides()))
def test_display_rows_fit_a_phone(cid, lhs, rhs):
    """Every row of a claim's display is at most ~28 glyphs (about 330 px of MathJax at a 390 px
    viewport): Eq. (11) printed on one row was 36; and the rows hold every term of both sides."""
    rows = render.relation_lines(lhs, rhs, "=", 26)
    for r in rows:
        assert render._visible(r.replace("&", "").replace(r"\qquad", "").replace(r"\quad", "")) <= 28, (cid, r)
    joined = " ".join(rows)
    for side in (lhs, rhs):
        for term in sp.Add.make_args(side):
            if not isinstance(term, sp.Sum):
                assert render.latex(term).lstrip("- ") in joined, (cid, render.latex(term))

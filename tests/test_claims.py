"""kane.claims: every claim id has a check whose verdict a flip would change; refutations replay in engines."""

import numpy as np
import pytest

from kane.claims import CLAIMS, run_checks
from kane.counterexamples import replay

ISSUE_IDS = [
    "eq3",
    "lemmaA1",
    "eq17",
    "eq19",
    "eq23",
    "eq11",
    "eq30",
    "eq34",
    "eq35",
    "eq36",
    "eq37",
    "eq12",
    "eq15",
]

# Verdicts found by the checks (see the closing note of the kane issue). A test fails if a verdict flips.
EXPECTED = {
    "eq3": "holds",
    "lemmaA1": "holds",
    "eq17": "holds",
    "eq19": "holds",
    "eq15": "holds",
    "eq23": "refuted",
    "eq11": "refuted",
    "eq30": "refuted",
    "eq34": "refuted",
    "eq35": "refuted",
    "eq36": "refuted",
    "eq37": "refuted",
    "eq12": "refuted",
    "eq23.corrected": "holds",
    "eq11.corrected": "holds",
    "eq30.corrected": "holds",
    "eq34.corrected": "holds",
    "eq35.corrected": "holds",
    "eq36.corrected": "holds",
    "eq37.corrected": "holds",
    "eq12.corrected": "holds",
}


@pytest.fixture(scope="module")
def results():
    return run_checks(quick=True, seed=0)


def test_every_issue_claim_has_a_check(results):
    ids = {r.claim_id for r in results}
    assert set(ISSUE_IDS) <= ids
    assert set(ISSUE_IDS) <= set(CLAIMS)


@pytest.mark.parametrize("cid", sorted(EXPECTED))
def test_claim_verdict(results, cid):
    verdicts = {r.verdict for r in results if r.claim_id == cid}
    assert "error" not in verdicts, [r.detail for r in results if r.claim_id == cid]
    overall = "refuted" if "refuted" in verdicts else "holds"
    assert overall == EXPECTED[cid]


def test_refuted_checks_carry_counterexample_and_corrected_statement(results):
    for r in results:
        if r.verdict == "refuted":
            assert r.counterexample is not None and r.counterexample["claim_id"] == r.claim_id
            assert r.corrected and r.corrected in CLAIMS


def test_translational_eq11_holds_to_machine_precision_on_euler_data(results):  # clause (b) of eq11.corrected
    r = [x for x in results if x.claim_id == "eq11.corrected" and "free box" in x.case][0]
    assert r.residual < 1e-12


@pytest.mark.parametrize("cid", ["eq34", "eq35", "eq36", "eq37", "eq12"])
def test_casadi_counterexample_replays_as_violation_in_mujoco_and_pinocchio(results, cid):
    r = [x for x in results if x.claim_id == cid and x.route == "casadi"][0]
    rep = replay(r.counterexample)
    engines = {e: (lhs, rhs) for e, lhs, rhs in rep.rows}
    assert set(engines) == {"mujoco", "pinocchio"}
    for lhs, rhs in engines.values():
        assert lhs > rhs
    # both engines agree on both sides (sphere radius 1e-4 m perturbs the inertia by < 1e-8 relative)
    np.testing.assert_allclose(engines["mujoco"], engines["pinocchio"], rtol=1e-6, atol=1e-9)


def test_solid_disc_exceeds_the_sphere_bound_textbook():
    """Solid disc about its axis: I = m R^2 / 2 (any dynamics textbook) > (2/5) m tau^2 as thickness -> 0."""
    rep = replay(
        {
            "claim_id": "eq36",
            "kind": "mujoco_geom",
            "geom": "cylinder",
            "size": [0.1, 1e-4],
            "density": 1000.0,
        }
    )
    ((_, lhs, rhs),) = rep.rows
    mass = 1000.0 * np.pi * 0.1**2 * 2e-4
    assert lhs == pytest.approx(mass * 0.1**2 / 2, rel=1e-6)
    assert lhs > rhs


def test_ring_attains_the_corrected_inertia_bound():
    """Four equal point masses on a circle of radius tau: I_z = M tau^2, the corrected bound is tight."""
    ring = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], float)
    cex = {
        "claim_id": "eq36.corrected",
        "kind": "element",
        "sample": {
            "masses": [1, 1, 1, 1],
            "offsets": ring.tolist(),
            "forces": np.zeros((4, 3)).tolist(),
            "omega": [0, 0, 0],
            "alpha": [0, 0, 0],
        },
    }
    for _, lhs, rhs in replay(cex).rows:
        assert lhs == pytest.approx(rhs, rel=1e-6)


def test_replay_rejects_malformed_counterexample():
    with pytest.raises(ValueError, match="claim_id"):
        replay({"kind": "element"})
    with pytest.raises(ValueError, match="unknown counterexample kind"):
        replay({"claim_id": "eq12", "kind": "nope"})


def test_unknown_claim_id_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown claim id"):
        run_checks(["eq99"])


# --- issue 20: every clause of every statement is checked, and the checks can fail ----------

from dataclasses import replace  # noqa: E402

from kane import cases, claims  # noqa: E402
from kane.claims import CHECKS  # noqa: E402
from validation.report import build_report  # noqa: E402


def test_every_clause_has_a_quick_check_and_every_check_names_a_clause():
    for cid, claim in CLAIMS.items():
        keys = [k for k, _ in claim.clause_list()]
        specs = [s for s in CHECKS if s.claim_id == cid]
        assert specs, f"{cid} has no check"
        assert {s.clause for s in specs} <= set(keys), cid
        for k in keys:
            assert any(s.clause == k and s.quick for s in specs), f"{cid} clause {k!r} has no quick check"


def test_titles_say_what_each_statement_is():
    for cid, claim in CLAIMS.items():
        assert "(corrected)" not in claim.title, cid
        if cid.endswith(".corrected"):
            assert claim.title != CLAIMS[cid.removesuffix(".corrected")].title


def test_no_corrected_clause_unchecked_or_failing_in_the_quick_run(results):
    rep = build_report(results, CLAIMS)
    for c in rep["claims"]:
        if c["id"].endswith(".corrected"):
            assert [cl["verdict"] for cl in c["clauses"]] == ["holds"] * len(c["clauses"]), c
    for row in rep["checks"]:
        assert row["scope"] and (row["corrected"] is None or row["corrected"]["verdict"] == "holds"), row["id"]


def test_scope_lines_follow_the_verdicts(results):
    scope = {c["id"]: c["scope"] for c in build_report(results, CLAIMS)["claims"]}
    assert scope["eq11"].startswith("refuted for rotational speeds; holds for translational speeds")
    assert scope["eq36"] == "refuted for flat solids (a disc) and point-mass elements; holds for uniform solid boxes, tetrahedra and spheres"
    assert scope["eq12"].startswith("refuted for rotational speeds, external loads only in Psi; holds for")


# Mutation checks: state a clause wrongly and its check must say refuted.

def _run(fn, **kw):
    r = fn(quick=True, seed=0, **kw)
    return r if not isinstance(r, list) else r[0]


@pytest.mark.parametrize("clause, condition", [
    ("a", lambda m, d, g, els: True),  # "every speed is one-hot"
    ("a", lambda m, d, g, els: int(m.jnt_type[m.dof_jntid[g]]) == 2),  # "every slide is", dropping "along a world axis"
    ("b", lambda m, d, g, els: False),  # "no speed is", dropping the "if" direction
])
def test_eq23_corrected_fails_when_its_condition_is_misstated(clause, condition):
    case = "joint chain: slides along x and (1,1,0), hinges, a subtree slide"
    assert _run(claims._eq23_corrected(case, clause)).verdict == "holds"
    assert _run(claims._eq23_corrected(case, clause, condition)).verdict == "refuted"


def test_eq11_corrected_clauses_fail_when_misstated(monkeypatch):
    # (b) "Euler exact" moved to the off-centre body; (d) "RK4 exact" moved to contact
    assert _run(claims._eq11_fs(claims._OFF, "d")).verdict == "refuted"
    assert _run(claims._eq11_fs(claims._PLANE, "d", "RK4")).verdict == "refuted"
    # (e) "not shrinking like delta" moved to the off-centre body under Euler (which is O(delta))
    assert _run(claims._eq11_fs(claims._OFF, "e")).verdict == "refuted"
    # (c) "O(delta), nonzero" moved to the centred body (which is exact)
    real = claims._free_cases()
    monkeypatch.setattr(claims, "_free_cases", lambda: {**real, claims._OFF: replace(real[claims._OFF], offset=(0.0, 0.0, 0.0))})
    assert _run(claims._eq11_fs(claims._OFF, "c")).verdict == "refuted"


def test_offset_free_body_residual_is_first_order_and_rk4_exact():
    """The review's numbers: offset (0.1, 0.05, -0.07) m, Euler, delta = 1e-3: 3.3e-4, halving with delta."""
    p, dts, res = cases.observed_order(cases.FreeSystem(offset=cases.OFFSET), 0.6)
    assert res[0] == pytest.approx(3.3e-4, rel=0.05) and abs(p - 1) < 0.01
    rk4 = cases.record(cases.FreeSystem(offset=cases.OFFSET, integrator="RK4"), 0.6)
    assert cases.eq11_translational(rk4) < 1e-11


def test_eq12_corrected_zero_slack_fails_for_rotational_speeds():
    case = "free box in gravity, spinning"
    assert _run(claims._eq12_translational(case, True)).verdict == "holds"
    assert _run(claims._eq12_translational(case, True, dofs=(3, 4, 5))).verdict == "refuted"


def test_eq36_corrected_box_clauses_fail_when_misstated(monkeypatch):
    # (b) with the paper's sphere constant replaced by a smaller one: solid boxes exceed 0.3
    assert _run(claims._eq36_solid_hyp("box", 0.3, "eq36.corrected", "b")).verdict == "refuted"
    # (c) "point-mass boxes obey (1/3)": the cube's corner masses give 2/3
    name = list(claims._POINT_CASES)[0]
    h, ppa, _ = claims._POINT_CASES[name]
    monkeypatch.setitem(claims._POINT_CASES, name, (h, ppa, 1 / 3))
    assert _run(claims._eq36_points(name, True)).verdict == "refuted"


def test_solid_shapes_against_textbook_ratios():
    """I_max / (M tau^2): box (a^2 + b^2) / 3 / (a^2 + b^2 + c^2); sphere 2/5; regular tetrahedron
    (edge s): I = M s^2 / 20, tau^2 = 3 s^2 / 8, so 2/15 (any dynamics textbook)."""
    assert cases.solid_box_ratio([0.1, 0.2, 0.3]) == pytest.approx((0.2**2 + 0.3**2) / 3 / 0.14, rel=1e-9)
    assert cases.sphere_ratio(0.3) == pytest.approx(0.4, rel=1e-12)
    tet = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    assert cases.tetra_ratio(tet) == pytest.approx(2 / 15, rel=1e-9)
    assert cases.point_box_ratio([1, 1, 1]) == pytest.approx(2 / 3, rel=1e-12)


@pytest.mark.parametrize("cid, case", [("eq23", "free box, 8 elements, rotated"), ("eq11", "free box in gravity, spinning"),
                                       ("eq11", "free box, joint origin offset")])
def test_equality_counterexample_sides_give_back_the_checks_number(cid, case):
    """Both sides at the recorded point (frame, speed, element) reproduce the check's own number:
    the largest |lhs - rhs| over the scale is the Eq. (11) residual or the Eq. (23) deviation, so
    the point is the one the check found; and the replay prints those sides."""
    from kane.claims import counterexample_sides

    refuted = [r for r in run_checks([cid], [case], quick=True) if r.claim_id == cid and r.verdict == "refuted"]
    r = max(refuted, key=lambda x: x.residual)
    context, sides = counterexample_sides(r.counterexample)
    assert max(sd.relative for sd in sides) == pytest.approx(r.residual, rel=1e-9)
    for sd in sides:  # lhs - rhs is the check's own difference, up to round-off of the sides
        np.testing.assert_allclose(np.asarray(sd.lhs, float) - np.asarray(sd.rhs, float), sd.margin, atol=1e-12 * (1 + sd.scale))
    if cid == "eq11":
        assert dict((k, v) for k, v, _ in context)["frame"] == r.counterexample["frame"]
    printed = str(replay(r.counterexample))
    assert "both sides at the recorded point" in printed
    assert f"= {max(sd.relative for sd in sides):.3g}" in printed

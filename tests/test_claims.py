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


def test_translational_eq11_holds_to_machine_precision_on_euler_data(results):
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

"""Tests of kane.crosscheck: Kane's equations (eq3) and Lemma A.1 against Pinocchio and MuJoCo."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import kane.crosscheck as cc
from kane.elements import partition_box_k
from kane.results import CheckResult, decide
from kane.systems import element_union_box, get_system, symbol, undivided_box


def test_kane_residual_matches_pinocchio_rnea_on_double_pendulum_trajectory():
    out = cc.eq3_on_trajectory(get_system("double_pendulum"), n_steps=60, seed=3)
    assert out["pinocchio_rnea"] <= cc.RIGID_RTOL
    assert out["pinocchio_crba"] <= cc.RIGID_RTOL
    assert out["kane_on_motion"] <= cc.RIGID_RTOL


def test_kane_residual_matches_mujoco_inverse_on_cubli_trajectory_with_motor_torques():
    s = get_system("cubli")
    out = cc.eq3_on_trajectory(s, n_steps=60, seed=5)
    assert np.abs(out["trajectory"].actuator_force).max() > 0.05  # motors really act
    for key in (
        "kane_on_motion",
        "mujoco_inverse",
        "mujoco_mass",
        "pinocchio_rnea",
        "pinocchio_crba",
    ):
        assert out[key] <= cc.RIGID_RTOL, key


def test_contact_loads_from_mujoco_close_kane_equations_for_box_thrown_on_plane():
    out = cc.eq3_on_trajectory(get_system("box_on_plane"), n_steps=100, seed=2)
    assert out["contact_steps"] > 20
    assert out["kane_on_motion"] <= cc.CONTACT_RTOL
    assert out["pinocchio_rnea"] <= cc.CONTACT_RTOL
    assert out["mujoco_inverse"] <= cc.CONTACT_RTOL


def test_mujoco_inverse_equals_pinocchio_rnea_after_free_joint_conversion():
    # Field note: converted, pin.rnea equals MuJoCo's qfrc_inverse to about 1e-14.
    s = get_system("free_box")
    m = mujoco.MjModel.from_xml_string(s.mjcf())
    d = mujoco.MjData(m)
    pm = cc.pinocchio_model(s)
    pd = pm.createData()
    rng = np.random.default_rng(11)
    quat = rng.normal(size=4)
    d.qpos[:] = np.r_[rng.normal(size=3), quat / np.linalg.norm(quat)]
    d.qvel[:], d.qacc[:] = rng.normal(size=6), rng.normal(size=6)
    mujoco.mj_inverse(m, d)
    q, v, a, T = cc.mujoco_to_pinocchio(s, d.qpos, d.qvel, d.qacc)
    np.testing.assert_allclose(T.T @ pin.rnea(pm, pd, q, v, a), d.qfrc_inverse, rtol=0, atol=1e-13)


def test_rolling_disc_residual_is_within_soft_contact_tolerance_but_not_exact():
    out = cc.eq3_on_trajectory(get_system("rolling_disc"), n_steps=100, seed=0)
    assert out["kane_on_motion"] <= cc.ROLLING_RTOL
    # MuJoCo contact is soft: the ideal rolling equations do not hold to machine precision
    assert out["kane_on_motion"] > 1e-8
    assert "pinocchio_rnea" not in out  # Pinocchio cannot express rolling
    with pytest.raises(ValueError, match="rolling"):
        cc.pinocchio_model(get_system("rolling_disc"))


def test_rolling_disc_check_rejects_a_ring_instead_of_a_disc():
    # Negative control for the loose rolling tolerance: a thin ring (I = m r^2 about the
    # axis, m r^2 / 2 across) simulated by MuJoCo, evaluated with the disc's equations.
    s = get_system("rolling_disc")
    disc = s.bodies[0]
    m, r = symbol("m"), symbol("r")
    ring = dataclasses.replace(
        s,
        bodies=(
            dataclasses.replace(disc, inertia=(m * r**2 / 2, m * r**2, m * r**2 / 2, 0, 0, 0)),
        ),
    )
    out = cc.eq3_on_trajectory(ring, n_steps=100, seed=0, model=s.symbolic())
    assert out["kane_on_motion"] > cc.ROLLING_RTOL


def test_symbolic_kane_equals_lagrange_for_flywheel_box():
    s = get_system("flywheel_box_planar")
    resid, how = cc._symbolic_lagrange(s, s.symbolic())
    assert resid == 0.0, how


# ---- Lemma A.1 ------------------------------------------------------------------------------


def test_partitioned_box_has_same_mass_matrix_as_undivided_box_symbolically_for_k2():
    resid, how = cc._lemma_symbolic(2, exact_values=False)
    assert resid == 0.0, how


@pytest.mark.parametrize("k", [1, 2, 8, 27])
def test_partitioned_box_has_same_mass_matrix_and_forces_as_undivided_box_in_engines(k):
    h = (0.15, 0.10, 0.05)
    els = partition_box_k(h, k, mass=2.0, rng=np.random.default_rng(k), jitter=1.0)
    out = cc._lemma_numeric(els, h, n_states=5, seed=k)
    for key, v in out.items():
        assert v <= cc.RIGID_RTOL, key


def test_lemma_comparison_detects_a_missing_parallel_axis_term():
    # Negative control: summing the element inertias about their own centroids, without
    # the parallel-axis terms, is not the body's inertia, and the comparison says so.
    h = (0.15, 0.10, 0.05)
    els = partition_box_k(h, 8, mass=2.0)
    whole = undivided_box(els, half_extents=h)
    I_wrong = sum(e.inertia for e in els)
    names = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
    idx = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
    wrong = dataclasses.replace(
        whole, params={**whole.params, **{n: I_wrong[i] for n, i in zip(names, idx, strict=True)}}
    )
    parts = element_union_box(els, half_extents=h)
    pa, pb = cc.pinocchio_model(parts), cc.pinocchio_model(wrong)
    q = pin.randomConfiguration(pa, -np.ones(7), np.ones(7))
    Ma, Mb = pin.crba(pa, pa.createData(), q), pin.crba(pb, pb.createData(), q)
    assert np.abs(Ma - Mb).max() / np.abs(Ma).max() > 1e-3


@settings(max_examples=15)
@given(
    k=st.sampled_from([1, 2, 8, 27]),
    jitter=st.floats(0.0, 3.0),
    seed=st.integers(0, 2**31 - 1),
    mass=st.floats(0.05, 50.0),
    half=st.tuples(*[st.floats(0.02, 0.8)] * 3),
)
def test_element_union_equals_undivided_body_for_random_mass_distributions(
    k, jitter, seed, mass, half
):
    import mujoco

    from kane.systems import undivided_box

    els = partition_box_k(half, k, mass=mass, rng=np.random.default_rng(seed), jitter=jitter)
    out = cc._lemma_numeric(els, half, n_states=2, seed=seed)
    assert max(out["pinocchio_rnea"], out["pinocchio_crba"]) <= cc.RIGID_RTOL
    # MuJoCo's compiler takes a body's inertial frame as its body frame (body_sameframe) when the mass
    # centre's offset is tiny (between 1e-7 and 1e-6 m here), dropping that offset from the undivided
    # body but not from the element model, where it is a child body's position: a residual of order
    # offset / size (found by this test: k=1, jitter=1e-8, half=(0.25, 0.5, 0.75) gives 5.4e-9).
    whole = mujoco.MjModel.from_xml_string(undivided_box(els, half_extents=half).mjcf())
    offset = float(np.abs(whole.body_ipos[1]).max()) if whole.body_sameframe[1] else 0.0
    tol = cc.RIGID_RTOL + 10.0 * offset / min(half)
    assert max(out["mujoco_inverse"], out["mujoco_mass"]) <= tol, (out, offset)


# ---- the public checks ------------------------------------------------------------------------


def _assert_consistent(results):
    for r in results:
        assert isinstance(r, CheckResult)
        assert r.verdict == decide(r.residual, r.tolerance)  # verdicts are decided, never set
        assert r.route in ("symbolic", "pinocchio", "mujoco", "hypothesis", "casadi")


def test_check_eq3_quick_holds_on_every_system_by_every_applicable_route():
    results = cc.check_eq3(quick=True)
    _assert_consistent(results)
    routes = {(r.case, r.route) for r in results}
    for case in cc.EQ3_SYSTEMS:
        assert (case, "mujoco") in routes
        assert (case, "pinocchio") in routes or case == "rolling_disc"
    assert ("double_pendulum", "symbolic") in routes
    assert all(r.verdict == "holds" for r in results), [r for r in results if r.verdict != "holds"]


def test_check_eq3_refutes_with_replayable_counterexample_when_tolerance_is_too_tight(monkeypatch):
    monkeypatch.setattr(cc, "EQ3_SYSTEMS", {"rolling_disc": {}})
    monkeypatch.setattr(cc, "ROLLING_RTOL", 1e-12)
    (r,) = cc.check_eq3(quick=True)
    assert r.verdict == "refuted"
    assert r.counterexample["system"] == "rolling_disc" and "step" in r.counterexample


def test_check_lemmaA1_quick_holds_by_every_route():
    results = cc.check_lemmaA1(quick=True)
    _assert_consistent(results)
    assert {r.route for r in results} == {"symbolic", "pinocchio", "mujoco", "hypothesis"}
    assert all(r.verdict == "holds" for r in results), [r for r in results if r.verdict != "holds"]


@pytest.mark.slow
def test_check_eq3_and_lemmaA1_full_runs_hold():
    results = cc.check_eq3() + cc.check_lemmaA1()
    _assert_consistent(results)
    assert all(r.verdict == "holds" for r in results), [r for r in results if r.verdict != "holds"]

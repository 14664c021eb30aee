"""Tests of kane.systems.bodyframe: the written-out Kane equations agree with sympy's KanesMethod on the built-in trees."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp

from kane.systems import SymbolicModel, get_system
from kane.systems.bodyframe import bodyframe_kane


@pytest.mark.parametrize("name", ["pendulum", "double_pendulum", "free_box", "flywheel_box_planar", "cubli"])
def test_bodyframe_equations_equal_kanes_method_on_the_built_in_trees(name):
    """Two derivations from one description, sharing no kinematics code: mass matrix and
    forcing agree to rounding (1e-12 of the largest term) at random states and inputs."""
    system = get_system(name)
    km = system.symbolic()
    data = bodyframe_kane(system)
    data.pop("partials")
    bf = SymbolicModel(system=system, **data)
    assert [str(s) for s in bf.q] == [str(s) for s in km.q] and [str(s) for s in bf.u] == [str(s) for s in km.u]
    rng = np.random.default_rng(1)
    q, u = rng.uniform(-1.2, 1.2, (20, len(km.q))), rng.normal(size=(20, len(km.u)))
    tau = rng.normal(size=(20, len(km.inputs)))
    M = km.mass(q)
    np.testing.assert_allclose(bf.mass(q), M, rtol=0, atol=1e-12 * np.abs(M).max())
    f = km.force(q, u, tau)
    np.testing.assert_allclose(bf.force(q, u, tau), f, rtol=0, atol=1e-12 * np.abs(f).max())
    qd_bf = sp.lambdify([*bf.q, *bf.u], list(bf.qdot))(*q[0], *u[0])
    qd_km = sp.lambdify([*km.q, *km.u], list(km.qdot))(*q[0], *u[0])
    np.testing.assert_allclose(qd_bf, qd_km, rtol=1e-13, atol=1e-13)  # kinematic differential equations


def test_bodyframe_refuses_external_wrench_inputs():
    with pytest.raises(ValueError, match="without external wrench inputs"):
        bodyframe_kane(get_system("box_on_plane"))

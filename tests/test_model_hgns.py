"""HGNS: the constrained Hamilton equations on an analytic pendulum (no learning), the model, the CLI.

Helpers and the 8-frame cubli-triple data come from tests/test_model_lgns.py.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from test_model_lgns import (
    STEPS,
    G,
    chain_constraints,
    check_cli,
    check_compiled_steps,
    check_one_graph,
    check_overfit,
    check_shapes_and_constraints,
    micro_data,
    position_dependent_mass_case,
)

from mdgs.models.mechanics import hamiltonian_derivatives, rk4

__all__ = ["micro_data"]


def test_pendulum_hamiltonian_matches_analytic_and_conserves_energy():
    """H = |p|^2 / 2m + m g z on a sphere: qdd is the pendulum's; RK4 keeps H and the bar over 2000 steps."""
    l, m = 0.7, torch.tensor([1.3], dtype=torch.float64)

    def H(q, p):
        return 0.5 * (p * p / m[:, None]).sum() + G * (m * q[:, 2]).sum()

    e = np.array([np.sin(1.0), 0.0, -np.cos(1.0)])
    q = torch.tensor(l * e)[None, None]
    t = np.array([0.0, 1.5, 0.0])
    p = torch.tensor(t)[None, None] * m[0]
    cs, jac = chain_constraints(q[0].numpy(), [], np.zeros(3))
    qd, pd, qdd = hamiltonian_derivatives(H, jac, q, p, torch.zeros_like(q))
    g = np.array([0, 0, -G])
    want = g - (e @ g) * e - (t @ t / l) * e
    np.testing.assert_allclose(qdd[0, 0].numpy(), want, atol=1e-10 * np.abs(want).max())
    np.testing.assert_allclose(qd[0, 0].numpy(), t, atol=1e-14)
    e0 = float(H(q[0], p[0]))

    def f(q_, p_):
        a, b, _ = hamiltonian_derivatives(H, jac, q_, p_, torch.zeros_like(q_))
        return a, b
    worst = 0.0
    for _ in range(STEPS):
        q, p = rk4(f, q, p, 2e-3)
        worst = max(worst, abs(float(H(q[0], p[0])) - e0))
    # RK4 is not symplectic: its drift grows ~ h^4 t; measured ~1e-9 J against |H| ~ 6 J
    assert worst < 1e-6
    assert abs(float(torch.linalg.norm(q[0, 0])) - l) < 1e-6


def test_a_position_dependent_mass_gets_the_analytic_acceleration_with_its_mixed_term():
    """``H = |p|^2 / (2 m(q))`` (:func:`test_model_lgns.position_dependent_mass_case`): ``qd = p / m`` and the
    accelerations worked out by hand, through the mixed term ``(d2H/dp dq) qd``, to float64 round-off."""
    m0, q, qd, want, jac = position_dependent_mass_case()
    m = (m0 * (1 + (q[0] ** 2).sum(-1)))[None, :, None]

    def H(q1, p1):
        return 0.5 * ((p1 ** 2).sum(-1) / (m0 * (1 + (q1 ** 2).sum(-1)))).sum()

    qd_out, _, qdd = hamiltonian_derivatives(H, jac, q, m * qd, torch.zeros_like(q))
    torch.testing.assert_close(qd_out, qd, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(qdd[0], want, rtol=1e-12, atol=1e-12)


def test_hgns_shapes_and_constraints(micro_data):
    from mdgs.models.hgns import HGNS

    check_shapes_and_constraints(HGNS, micro_data)


@pytest.mark.slow
def test_hgns_overfits_two_batches(micro_data):
    from mdgs.models.hgns import HGNS

    check_overfit(HGNS, micro_data)


@pytest.mark.slow
def test_the_hgns_step_compiles_and_takes_the_eager_steps(micro_data):
    from mdgs.models.hgns import HGNS

    check_compiled_steps(HGNS, micro_data)


def test_the_hgns_step_traces_as_one_graph(micro_data):
    from mdgs.models.hgns import HGNS

    check_one_graph(HGNS, micro_data)


def test_hgns_cli_end_to_end(micro_data, tmp_path):
    check_cli("hgns", micro_data, tmp_path)


def test_hgns_and_lgns_from_the_same_weights_have_the_same_loss(micro_data):
    """With H = sum |p|^2 / 2m + V and L = sum m |v|^2 / 2 - V from the same MLPs and initial weights,
    both give the same accelerations, so the acceleration loss (and thus training) is the same; the
    small study's lgns and hgns rows differ only through the integrator (docs/peers/hgns.md)."""
    from test_model_lgns import _model

    from mdgs.models.base import batch_of
    from mdgs.models.hgns import HGNS
    from mdgs.models.lgns import LGNS

    (lg, d), (hg, _) = _model(LGNS, micro_data), _model(HGNS, micro_data)
    b = batch_of(d, d.pairs()[:3], "cpu")
    a, h = lg.losses(b)["mse"], hg.losses(b)["mse"]
    assert torch.isfinite(a) and float(a) > 0
    assert float(h) == pytest.approx(float(a), rel=1e-9)
    with torch.no_grad():  # the rollouts do differ: Verlet against RK4
        s = lg.initial_state(d, np.arange(2), 0)
        c = torch.from_numpy(d.ctrl[:2, 0])
        assert not torch.allclose(lg.step(s, c).x, hg.step(hg.initial_state(d, np.arange(2), 0), c).x, rtol=0, atol=1e-12)

"""Rigid twists of element clouds (mdgs.rigid) and the constant-twist reference rollout."""

import mujoco
import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from mdgs.rigid import advance, project, twist

SEG = torch.tensor([0, 0, 0, 0, 0, 1, 1, 1, 2])  # a 5-node body, a 3-node body, a single node


def _random_rigid(seed: int, scale_w: float = 1.0):
    g = torch.Generator().manual_seed(seed)
    N, S = SEG.shape[0], 3
    x = torch.randn(2, N, 3, generator=g, dtype=torch.float64)
    mass = torch.rand(N, generator=g, dtype=torch.float64) + 0.1
    vc = torch.randn(2, S, 3, generator=g, dtype=torch.float64)
    w = scale_w * torch.randn(2, S, 3, generator=g, dtype=torch.float64)
    w[:, 2] = 0  # a single node has no angular velocity
    c = twist(x, torch.zeros_like(x), SEG, S, mass).c
    v = vc[:, SEG] + torch.linalg.cross(w[:, SEG], x - c[:, SEG], dim=-1)
    return x, v, mass, vc, w


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.01, 1000.0))
def test_twist_recovers_the_velocity_and_angular_velocity_of_a_rigid_field(seed, scale_w):
    x, v, mass, vc, w = _random_rigid(seed, scale_w)
    tw = twist(x, v, SEG, 3, mass)
    # tolerance: the Tikhonov term EPS tr(J)/3 biases omega by about EPS cond(J) |omega|; random
    # 3-node objects can be nearly collinear (cond(J) ~ 1e4), so the bound scales with cond(J)
    ev = torch.linalg.eigvalsh(tw.J[:, :2])
    cond = float((ev[..., -1] / ev[..., 0]).max())
    tol = 1e-11 * cond * (1 + scale_w)
    assert torch.allclose(tw.vc, vc, rtol=0, atol=1e-12 * (1 + scale_w))
    assert torch.allclose(tw.omega, w, rtol=0, atol=tol)
    # and projecting the rigid field itself gives the same twist
    a, alpha = project(v, x, tw, SEG, 3, mass)
    assert torch.allclose(a, vc, atol=1e-12 * (1 + scale_w)) and torch.allclose(alpha, w, atol=tol)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_projection_drops_exactly_the_non_rigid_part(seed):
    """d = rigid + deformation orthogonal to every rigid field -> the rigid part alone."""
    x, v, mass, vc, w = _random_rigid(seed)
    tw = twist(x, v, SEG, 3, mass)
    g = torch.Generator().manual_seed(seed + 1)
    e = torch.randn(x.shape, generator=g, dtype=torch.float64)
    ea, ealpha = project(e, x, tw, SEG, 3, mass)
    r = x - tw.c[:, SEG]
    deform = e - ea[:, SEG] - torch.linalg.cross(ealpha[:, SEG], r, dim=-1)
    a, alpha = project(v + deform, x, tw, SEG, 3, mass)
    ev = torch.linalg.eigvalsh(tw.J[:, :2])
    tol = (
        1e-11 * float((ev[..., -1] / ev[..., 0]).max()) + 1e-9
    )  # as above, plus the deformation's rounding
    assert torch.allclose(a[:, :2], vc[:, :2], atol=1e-9) and torch.allclose(
        alpha[:, :2], w[:, :2], atol=tol
    )


def test_advance_keeps_shapes_and_turns_a_flywheel_round_its_circle():
    """10 rad in one step (a Cubli flywheel at 1000 rad/s, 10 ms frames): nodes stay on their circle."""
    ang = torch.linspace(0, 2 * np.pi, 7, dtype=torch.float64)[:-1]
    x = torch.stack([0.03 * torch.cos(ang), 0.03 * torch.sin(ang), torch.zeros_like(ang)], -1)[None]
    seg, mass = torch.zeros(6, dtype=torch.long), torch.ones(6, dtype=torch.float64)
    w = torch.tensor([[[0.0, 0.0, 1000.0]]], dtype=torch.float64)
    v = torch.linalg.cross(w.expand(1, 6, 3), x, dim=-1)
    tw = twist(x, v, seg, 1, mass)
    xn, vn = advance(x, tw, tw.vc, tw.omega, 0.01, seg)
    exp = torch.stack(
        [0.03 * torch.cos(ang + 10.0), 0.03 * torch.sin(ang + 10.0), torch.zeros_like(ang)], -1
    )[None]
    assert torch.allclose(xn, exp, atol=1e-12)
    assert torch.allclose(
        torch.linalg.vector_norm(vn, dim=-1), torch.full((1, 6), 30.0, dtype=torch.float64)
    )


def test_constant_twist_step_matches_mujoco_on_torque_free_spin_about_a_principal_axis():
    """Independent source: MuJoCo, free box, no gravity, spin about its principal z axis (omega constant)."""
    xml = """<mujoco><option gravity="0 0 0" timestep="1e-4" integrator="RK4"/><worldbody>
      <body><freejoint/><geom type="box" size=".1 .05 .02" density="1000"/></body></worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qvel[:] = [0.3, -0.2, 0.1, 0.0, 0.0, 40.0]
    mujoco.mj_forward(m, d)
    body_pts = np.array(
        [[0.1, 0.05, 0.02], [-0.1, 0.05, -0.02], [0.1, -0.05, 0.0], [-0.05, -0.05, 0.02]]
    )
    body_pts = body_pts - body_pts.mean(0)  # symmetric weights -> mass centre at the body origin

    def world(d):
        p = d.xpos[1] + body_pts @ d.xmat[1].reshape(3, 3).T
        w = (
            d.qvel[3:6] @ d.xmat[1].reshape(3, 3).T
        )  # free joint angular velocity is in the body frame
        return p, d.qvel[:3] + np.cross(w, p - d.xpos[1])

    x0, v0 = world(d)
    mujoco.mj_step(m, d, nstep=100)  # 10 ms frame
    x1, v1 = world(d)
    seg, mass = torch.zeros(4, dtype=torch.long), torch.ones(4, dtype=torch.float64)
    x, v = torch.tensor(x0)[None], torch.tensor(v0)[None]
    tw = twist(x, v, seg, 1, mass)
    xn, vn = advance(x, tw, tw.vc, tw.omega, 0.01, seg)
    # RK4 at 1e-4 s integrates this exactly to ~1e-12; the rigid step is exact for constant omega
    assert np.allclose(xn[0].numpy(), x1, atol=1e-9) and np.allclose(vn[0].numpy(), v1, atol=1e-8)


def test_trapezoidal_step_is_exact_for_constant_acceleration_about_a_fixed_axis():
    """A wheel spun up from 200 to 900 rad/s in one 10 ms frame while its centre accelerates:
    angle omega0 t + alpha t^2 / 2 and centre v0 t + a t^2 / 2, exactly."""
    ang = torch.linspace(0, 2 * np.pi, 7, dtype=torch.float64)[:-1]
    r0 = torch.stack([0.03 * torch.cos(ang), 0.03 * torch.sin(ang), torch.zeros_like(ang)], -1)[
        None
    ]
    seg, mass = torch.zeros(6, dtype=torch.long), torch.ones(6, dtype=torch.float64)
    w0, w1, dt = 200.0, 900.0, 0.01
    vc0, vc1 = (
        torch.tensor([0.1, 0.0, 0.0], dtype=torch.float64),
        torch.tensor([0.3, 0.0, -0.2], dtype=torch.float64),
    )
    x = r0 + 1.0
    v = vc0 + torch.linalg.cross(
        torch.tensor([0.0, 0.0, w0], dtype=torch.float64).expand(1, 6, 3), r0, dim=-1
    )
    tw = twist(x, v, seg, 1, mass)
    xn, _ = advance(
        x,
        tw,
        vc1.view(1, 1, 3),
        torch.tensor([[[0.0, 0.0, w1]]], dtype=torch.float64),
        dt,
        seg,
        trapezoidal=True,
    )
    th = w0 * dt + (w1 - w0) / 2 * dt
    exp = torch.stack(
        [0.03 * torch.cos(ang + th), 0.03 * torch.sin(ang + th), torch.zeros_like(ang)], -1
    )[None]
    exp = exp + 1.0 + (vc0 + vc1) / 2 * dt
    assert torch.allclose(xn, exp, atol=1e-12)


def test_rodrigues_rotation_equals_the_matrix_exponential():
    """rotation_matrix (closed form) against torch.linalg.matrix_exp of the skew matrix: angles from
    1e-12 rad (the Taylor branch) through 1e-4 (the switch) to several turns, float64 round-off."""
    from mdgs.rigid import _skew_mat, rotation_matrix

    g = torch.Generator().manual_seed(0)
    axes = torch.nn.functional.normalize(torch.randn(64, 3, generator=g, dtype=torch.float64), dim=-1)
    angles = torch.cat([torch.logspace(-12, 1.3, 60, dtype=torch.float64), torch.tensor([0.0, 1e-4, 9.99e-5, 3.14159])])
    phi = axes * angles[:, None]
    R = rotation_matrix(phi)
    torch.testing.assert_close(R, torch.linalg.matrix_exp(_skew_mat(phi)), rtol=0, atol=1e-14)
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(64, 3, 3),
                               rtol=0, atol=1e-14)


def test_rodrigues_rotation_has_finite_gradients_at_zero_rotation():
    """A body that does not turn (phi = 0 exactly, e.g. an untrained zero-output model on a translating
    body) must not poison training with NaN gradients; d R / d phi at 0 is the skew generator."""
    from mdgs.rigid import rotation_matrix

    phi = torch.zeros(2, 3, dtype=torch.float64, requires_grad=True)
    R = rotation_matrix(phi)
    (R * torch.arange(9, dtype=torch.float64).view(3, 3)).sum().backward()
    assert torch.isfinite(phi.grad).all()
    # sum_ij W_ij dR_ij/dphi at 0 with R = I + [phi]_x: (W_32 - W_23, W_13 - W_31, W_21 - W_12)
    torch.testing.assert_close(phi.grad[0], torch.tensor([7.0 - 5.0, 2.0 - 6.0, 3.0 - 1.0], dtype=torch.float64))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), log_cond=st.floats(0.0, 8.0))
def test_closed_form_3x3_solve_and_det_agree_with_lapack(seed, log_cond):
    """solve3/det3 (LDL^T and triple product, written out so that torch.compile fuses them) against LAPACK's LU on
    symmetric positive-definite matrices of condition number 10^log_cond, like the regularised
    inertia tensors they solve: the relative difference stays below cond * 1e-14 (both are backward
    stable to a few ulps of float64, so their solutions may differ by cond * eps)."""
    from mdgs.structure import det3, solve3

    g = torch.Generator().manual_seed(seed)
    Q, _ = torch.linalg.qr(torch.randn(64, 3, 3, generator=g, dtype=torch.float64))
    eig = torch.stack([torch.ones(64, dtype=torch.float64), 10 ** (-log_cond * torch.rand(64, generator=g, dtype=torch.float64)),
                       torch.full((64,), 10 ** -log_cond, dtype=torch.float64)], -1)
    A = Q @ torch.diag_embed(eig) @ Q.transpose(-1, -2)
    b = torch.randn(64, 3, generator=g, dtype=torch.float64)
    x = solve3(A, b)
    ref = torch.linalg.solve(A, b.unsqueeze(-1)).squeeze(-1)
    assert ((x - ref).norm(dim=-1) / ref.norm(dim=-1)).max() < 10 ** log_cond * 1e-14
    M = torch.randn(64, 3, 3, generator=g, dtype=torch.float64)
    torch.testing.assert_close(det3(M), torch.linalg.det(M), rtol=1e-12, atol=1e-14)

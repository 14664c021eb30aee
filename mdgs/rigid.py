"""Rigid-body kinematics of element clouds: twists, their least-squares projection, and one exact step.

Each rigid object ``s`` is a cloud of element centroids ``x_i`` with masses ``m_i``. Its
mass centre, linear and angular velocity follow from the nodes by mass-weighted least squares,

    c   = sum_i m_i x_i / sum_i m_i,          v_c = sum_i m_i v_i / sum_i m_i,
    r_i = x_i - c,   J = sum_i m_i (|r_i|^2 1 - r_i r_i^T)   (point-mass inertia about c),
    omega = argmin sum_i m_i |v_i - v_c - omega x r_i|^2 = J^-1 sum_i m_i r_i x (v_i - v_c),

which is exact for a rigid velocity field. :func:`project` applies the same map to any node
vector field (e.g. predicted velocity increments) and :func:`advance` moves every node with the
exact rigid motion of a twist over ``dt`` (rotation by the matrix exponential), so a flywheel
turning 10 rad per frame is carried round its circle instead of along a tangent.

Shapes: nodes ``[B, N, 3]``, objects ``[B, S, 3]``, ``seg`` [N] object id of each node.
Computations run in float64 (J of a thin object is close to singular).
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from mdgs.structure import segment_mean, segment_sum, solve3

__all__ = ["rotation_matrix", "Twist", "twist", "project", "advance", "perturb"]

#: Relative Tikhonov term added to J before solving: ``J + EPS * tr(J)/3 * 1``. Directions in which
#: an object's nodes give no lever arm (a rod's axis, a single node) get zero angular velocity.
EPS = 1e-12


class Twist(NamedTuple):
    """Rigid twist of each object (float64)."""

    c: torch.Tensor  #: mass centre [B, S, 3], m
    vc: torch.Tensor  #: velocity of the mass centre [B, S, 3], m/s
    omega: torch.Tensor  #: angular velocity [B, S, 3], rad/s
    J: torch.Tensor  #: point-mass inertia about c [B, S, 3, 3], kg m^2


def _skew_mat(r: torch.Tensor) -> torch.Tensor:
    """``[..., 3] -> [..., 3, 3]`` with ``skew(r) @ a = r x a``."""
    z = torch.zeros_like(r[..., 0])
    return torch.stack([
        torch.stack([z, -r[..., 2], r[..., 1]], -1),
        torch.stack([r[..., 2], z, -r[..., 0]], -1),
        torch.stack([-r[..., 1], r[..., 0], z], -1),
    ], -2)


def rotation_matrix(phi: torch.Tensor) -> torch.Tensor:
    """``exp([phi]_x)`` for rotation vectors ``phi`` [..., 3] -> [..., 3, 3] (Rodrigues' formula).

    ``R = I + a K + b K^2`` with ``K = [phi]_x``, ``a = sin(t) / t``, ``b = (1 - cos(t)) / t^2``,
    ``t = |phi|``; below ``t = 1e-4`` the Taylor series ``a = 1 - t^2/6``, ``b = 1/2 - t^2/24``
    (error under t^4/120 ~ 1e-18). Equal to ``torch.linalg.matrix_exp`` to float64 round-off, at a
    fraction of its cost, with finite gradients at ``phi = 0`` (tests/test_rigid.py).

    ``K^2`` is written as ``phi phi^T - t^2 I`` (the square of a skew matrix), elementwise: a compiled step then
    has no matrix-product library call here, and with none at all its buffers can live on the stack
    (:func:`mdgs.models.compile_step`, ``"aot"``).
    """
    K = _skew_mat(phi)
    t2 = (phi * phi).sum(-1)
    small = t2 < 1e-8  # t < 1e-4
    ts = torch.where(small, torch.ones_like(t2), t2).sqrt()  # no sqrt at 0: its gradient would be inf (NaN through where)
    a = torch.where(small, 1 - t2 / 6, torch.sin(ts) / ts)
    b = torch.where(small, 0.5 - t2 / 24, (1 - torch.cos(ts)) / (ts * ts))
    eye = torch.eye(3, dtype=phi.dtype, device=phi.device)
    K2 = phi.unsqueeze(-1) * phi.unsqueeze(-2) - t2[..., None, None] * eye
    return eye + a[..., None, None] * K + b[..., None, None] * K2


def _solve(J: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``(J + EPS tr(J)/3 1)^-1 b`` for [B, S, 3, 3], [B, S, 3]; 0 where J = 0 (one-node objects)."""
    tr = torch.diagonal(J, dim1=-2, dim2=-1).sum(-1)
    none = tr <= 0  # one-node objects: J is exactly 0 (see twist)
    reg = torch.where(none, 1.0, EPS * tr / 3)[..., None, None] * torch.eye(3, dtype=J.dtype, device=J.device)
    return torch.where(none[..., None], 0.0, solve3(J + reg, b))


def _angular(J: torch.Tensor, r: torch.Tensor, u: torch.Tensor, seg: torch.Tensor, n_seg: int,
             mass: torch.Tensor) -> torch.Tensor:
    """``J^-1 sum_i m_i r_i x u_i`` per object -> [B, S, 3]."""
    L = segment_sum(mass[None, :, None] * torch.linalg.cross(r, u, dim=-1), seg, n_seg)
    return _solve(J, L)


def twist(x: torch.Tensor, v: torch.Tensor, seg: torch.Tensor, n_seg: int, mass: torch.Tensor) -> Twist:
    """Least-squares rigid twist of every object from node positions and velocities ``[B, N, 3]``."""
    m = mass.to(torch.float64)
    x, v = x.to(torch.float64), v.to(torch.float64)
    c = segment_mean(x, seg, n_seg, m)
    vc = segment_mean(v, seg, n_seg, m)
    # node count per object, in float64 (an integer index_add is not fused by torch.compile)
    count = segment_sum(torch.ones_like(m), seg, n_seg, dim=0)
    r = torch.where((count[seg] > 1)[None, :, None], x - c[:, seg], 0.0)  # exactly 0 for one-node objects
    rr = (r * r).sum(-1)[..., None, None] * torch.eye(3, dtype=r.dtype, device=r.device) - r.unsqueeze(-1) * r.unsqueeze(-2)
    J = segment_sum(m[None, :, None, None] * rr, seg, n_seg)
    return Twist(c, vc, _angular(J, r, v - vc[:, seg], seg, n_seg, m), J)


def project(d: torch.Tensor, x: torch.Tensor, tw: Twist, seg: torch.Tensor, n_seg: int,
            mass: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rigid part ``(a, alpha)`` [B, S, 3] of a node field ``d`` [B, N, 3]: ``d_i ~ a + alpha x r_i``."""
    m = mass.to(torch.float64)
    d = d.to(torch.float64)
    a = segment_mean(d, seg, n_seg, m)
    r = x.to(torch.float64) - tw.c[:, seg]
    return a, _angular(tw.J, r, d - a[:, seg], seg, n_seg, m)


def advance(x: torch.Tensor, tw: Twist, vc_new: torch.Tensor, omega_new: torch.Tensor, dt: float,
            seg: torch.Tensor, dc: torch.Tensor | None = None,
            dtheta: torch.Tensor | None = None, trapezoidal: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Move every object rigidly by its new twist over ``dt`` (semi-implicit Euler on SE(3)).

    ``c' = c + dt v_c' + dc``, ``r_i' = exp([dt omega' + dtheta]_x) r_i``, ``x_i' = c' + r_i'``,
    ``v_i' = v_c' + omega' x r_i'``; ``dc``, ``dtheta`` [B, S, 3] are optional position
    corrections (translation, rotation vector). ``trapezoidal``: move with the mean of the old
    and new twist instead of the new one (exact for a constant acceleration over the step).
    Returns ``x', v'`` [B, N, 3] in ``x``'s dtype.
    """
    r = x.to(torch.float64) - tw.c[:, seg]
    vc_move, w_move = ((tw.vc + vc_new) / 2, (tw.omega + omega_new) / 2) if trapezoidal else (vc_new, omega_new)
    c_new = tw.c + dt * vc_move + (0 if dc is None else dc)
    phi = dt * w_move + (0 if dtheta is None else dtheta)
    R = rotation_matrix(phi)  # [B, S, 3, 3]
    r_new = (R[:, seg] @ r.unsqueeze(-1)).squeeze(-1)
    x_new = c_new[:, seg] + r_new
    v_new = vc_new[:, seg] + torch.linalg.cross(omega_new[:, seg], r_new, dim=-1)
    return x_new.to(x.dtype), v_new.to(x.dtype)


def perturb(x: torch.Tensor, v: torch.Tensor, nx: torch.Tensor, nv: torch.Tensor, seg: torch.Tensor, n_seg: int,
            mass: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Move each object by the rigid part of node noise ``nx`` (m) and change its twist by that of ``nv`` (m/s).

    The perturbed state stays a rigid placement of each object with a rigid velocity field (what a
    rigid rollout produces), unlike independent per-node noise. All [B, N, 3].
    """
    tw = twist(x, v, seg, n_seg, mass)
    dc, dth = project(nx, x, tw, seg, n_seg, mass)
    dvc, dw = project(nv, x, tw, seg, n_seg, mass)
    return advance(x, tw, tw.vc + dvc, tw.omega + dw, 0.0, seg, dc, dth)

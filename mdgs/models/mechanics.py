"""Shared machinery of the energy-based peers LGNS and HGNS: node-coordinate constraints, energy MLPs, solvers.

Both peers (:mod:`mdgs.models.lgns`, :mod:`mdgs.models.hgns`) simulate the element nodes of a
scene as particles in Cartesian coordinates ``q`` (the ``n`` moving nodes, ``[n, 3]``) whose
rigid bodies and joints are **holonomic constraints** ``Phi(q) = 0`` enforced with Lagrange
multipliers, the approach Bhattoo et al. (NeurIPS 2022) take for chains of rigid bars.
Every formula used by both lives here, once:

Constraints (:class:`ConstraintSet`, built from a split by :func:`build_constraints`)
    Each scalar constraint reads ``phi = U_k - c`` (a component ``k`` of ``U``) or
    ``phi = U . V - c``, where ``U = P_1 - P_2`` and ``V = P_3 - P_4`` are differences of
    *attachments*: points or vectors fixed in one body, written in its node coordinates
    (``P = w x_a + E(x) c + const`` with ``E`` the body's anchor edges, see
    :func:`_frames`), or constants for the world. Rigidity of a body is a minimal set:
    the distances between its 2-4 anchor nodes and, for every other node, the three linear
    equations "x_i is the fixed affine combination of the anchors". Joints add candidate
    equations (point coincidence, axis alignment, distances of nodes to the joint axis),
    and a maximal independent subset is kept by rank at the reference configuration, so
    ``J M^-1 J^T`` is invertible.

Energies (:class:`NodeMass`, :class:`NodePotential`, :class:`EdgePotential`)
    Small MLPs with SquarePlus activations (Barron 2021; used by Bhattoo et al.):
    kinetic energy ``T = sum_i m_i |v_i|^2 / 2`` with learned positive masses
    ``m_i = MLP(k_i)``, potential ``V = sum_i V_i(x_i, k_i) + sum_(i,j) V_ij(|x_i - x_j|, k_i, k_j)``.

Non-conservative forces (:class:`ExternalForces`)
    What a Lagrangian or Hamiltonian of the nodes cannot hold (drag, contact and friction,
    actuation): learned node forces added to the generalised forces, as Bhattoo et al. add a
    learned drag term.

Solvers
    :func:`lagrangian_acceleration`: ``M qdd = dL/dq - (d2L/dv dq) qd + Y + J^T lambda``
    with ``M = d2L/dv2`` and ``J qdd + Jdot qd = 0``; :func:`hamiltonian_derivatives`:
    ``qd = dH/dp``, ``pd = -dH/dq + Y + J^T lambda`` with ``d2 Phi/dt2 = 0``. All derivatives
    by automatic differentiation (:mod:`torch.func`), in float64.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn
from torch.func import jacrev, vmap

__all__ = ["squareplus", "MLP", "NodeMass", "NodePotential", "EdgePotential", "ExternalForces",
           "ConstraintSet", "build_constraints", "lagrangian_acceleration", "hamiltonian_derivatives",
           "solve_multipliers", "velocity_verlet", "rk4", "JOINT_FREE", "JOINT_BALL", "JOINT_SLIDE", "JOINT_HINGE"]

#: MuJoCo joint types (mjtJoint).
JOINT_FREE, JOINT_BALL, JOINT_SLIDE, JOINT_HINGE = 0, 1, 2, 3

#: Relative rank tolerance (of the largest singular value) when selecting independent constraints.
RANK_TOL = 1e-8
#: A body's nodes span a line/plane/space when their spread off the lower-dimensional fit exceeds
#: this fraction of the body's size (element centroids are exact in float64, so 1e-6 is safe).
SPAN_TOL = 1e-6


def squareplus(x: torch.Tensor, b: float = 4.0) -> torch.Tensor:
    """SquarePlus ``(x + sqrt(x^2 + b)) / 2`` (Barron 2021): smooth, all derivatives finite (needed twice)."""
    return 0.5 * (x + torch.sqrt(x * x + b))


class MLP(nn.Module):
    """``[d_in, hidden x depth, d_out]`` with SquarePlus between layers, none after the last."""

    def __init__(self, d_in: int, d_out: int, hidden: int = 10, depth: int = 1):
        super().__init__()
        dims = [d_in] + [hidden] * depth + [d_out]
        self.lins = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:], strict=True))

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        for k, lin in enumerate(self.lins):
            h = lin(h)
            if k < len(self.lins) - 1:
                h = squareplus(h)
        return h


class NodeMass(nn.Module):
    """Learned positive node masses ``m_i = m_scale * softplus(MLP(k_i) + s0)``, s0 so that m_i = m_scale at 0."""

    def __init__(self, d_k: int, m_scale: float, hidden: int, depth: int):
        super().__init__()
        self.mlp = MLP(d_k, 1, hidden, depth)
        self.m_scale = m_scale
        self.s0 = float(np.log(np.expm1(1.0)))

    def forward(self, k: torch.Tensor) -> torch.Tensor:
        """``k`` [N, d_k] normalised node properties -> [N] masses, kg."""
        return self.m_scale * nn.functional.softplus(self.mlp(k)[..., 0] + self.s0)


class NodePotential(nn.Module):
    """``V_i = V_scale * MLP([(x_i - x_mean) / x_std, k_i])``: gravity and any position-only field."""

    def __init__(self, d_k: int, v_scale: float, hidden: int, depth: int):
        super().__init__()
        self.mlp = MLP(3 + d_k, 1, hidden, depth)
        self.v_scale = v_scale

    def forward(self, xn: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
        """``xn`` [..., N, 3] normalised positions, ``k`` [N, d_k] -> [...] summed potential, J."""
        kk = k.expand(*xn.shape[:-1], k.shape[-1])
        return self.v_scale * self.mlp(torch.cat([xn, kk], -1))[..., 0].sum(-1)


class EdgePotential(nn.Module):
    """``V_ij = V_scale * MLP([|x_i - x_j| / l, k_i + k_j, k_i * k_j])`` on undirected edges (symmetric in i, j)."""

    def __init__(self, d_k: int, v_scale: float, length: float, hidden: int, depth: int):
        super().__init__()
        self.mlp = MLP(1 + 2 * d_k, 1, hidden, depth)
        self.v_scale = v_scale
        self.length = length

    def forward(self, x: torch.Tensor, k: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
        """``x`` [..., N, 3] (m), ``edges`` [E, 2] -> [...] summed potential, J."""
        if edges.shape[0] == 0:
            return x.new_zeros(x.shape[:-2])
        d = x[..., edges[:, 0], :] - x[..., edges[:, 1], :]
        r = torch.sqrt((d * d).sum(-1, keepdim=True) + 1e-30) / self.length
        ki, kj = k[edges[:, 0]], k[edges[:, 1]]
        feat = torch.cat([r, (ki + kj).expand(*r.shape[:-1], -1), (ki * kj).expand(*r.shape[:-1], -1)], -1)
        return self.v_scale * self.mlp(feat)[..., 0].sum(-1)


class ExternalForces(nn.Module):
    """Learned non-conservative node forces ``Y`` [B, N, 3], N (not derivable from L or H).

    - node term (drag, floor contact and friction): ``F_scale * MLP([v_i / v_std, (x_i - x_mean) / x_std, k_i, a_i])``
      where ``a_i`` are the node's actuation features (below); Bhattoo et al.'s learned drag
      is the ``v_i`` dependence of this term.
    - contact term (only when the scene can have contact): on contact edges (different
      objects, centroids closer than ``r``, :func:`mdgs.graphs.contact_edges`)
      ``f_ij = F_scale * MLP([d_ij / r, |d_ij| / r, (v_j - v_i) / v_std, k_i, k_j])``, applied
      antisymmetrically (``(f_ij - f_ji) / 2`` on i), so contact conserves momentum.
    - actuation features: for every actuator ``k`` with a hinge (slide) joint, node ``i``
      gets ``sign_ki u_k (a_k x (x_i - A_k)) / l`` (``sign_ki u_k a_k``), ``a_k``, ``A_k`` the joint's
      axis and anchor as attached to the moving side, ``sign`` the control map (+ driven body,
      - its parent): the direction in which a joint torque pushes each node.
    """

    def __init__(self, d_k: int, f_scale: float, contact: bool, hidden: int, depth: int):
        super().__init__()
        self.node = MLP(3 + 3 + d_k + 3, 3, hidden, depth)
        self.contact = MLP(3 + 1 + 3 + 2 * d_k, 3, hidden, depth) if contact else None
        self.f_scale = f_scale

    def forward(self, vn: torch.Tensor, xn: torch.Tensor, k: torch.Tensor, act: torch.Tensor,
                edges: torch.Tensor | None, x: torch.Tensor, v: torch.Tensor, radius: float,
                v_std: float, mask: torch.Tensor | None = None) -> torch.Tensor:
        """Node forces [B, N, 3] from normalised velocities ``vn``, positions ``xn`` [B, N, 3], properties ``k``
        [N, d_k], actuation features ``act`` [B, N, 3] and the contact ``edges`` [2, E] over the batched node index
        ``b N + i`` (both directions, sorted by source then target). With ``mask`` [E] bool the edges are
        candidates of a fixed number and only those it marks act (the others' forces are zero): the forces of the
        edge list of the marked ones to round-off, with no data-dependent shape (a step that compiles as one graph)."""
        B, N, _ = x.shape
        kk = k.expand(B, N, -1)
        f = self.f_scale * self.node(torch.cat([vn, xn, kk, act], -1))
        if self.contact is not None and edges is not None and edges.shape[1]:
            xf, vf, kf = x.reshape(B * N, 3), v.reshape(B * N, 3), kk.reshape(B * N, -1)
            i, j = edges[0], edges[1]
            d = (xf[j] - xf[i]) / radius
            feat = torch.cat([d, torch.linalg.norm(d, dim=-1, keepdim=True), (vf[j] - vf[i]) / v_std, kf[i], kf[j]], -1)
            fij = 0.5 * self.f_scale * self.contact(feat)
            if mask is not None:
                fij = torch.where(mask[:, None], fij, 0.0)
            fc = torch.zeros_like(xf).index_add_(0, i, fij).index_add_(0, j, -fij)
            f = f + fc.view(B, N, 3)
        return f


# --- constraints ---------------------------------------------------------------------------------

@dataclass
class ConstraintSet:
    """Holonomic constraints ``Phi(x) = 0`` over all nodes ``x`` [..., N, 3] (module docstring).

    Attachments (``K`` of them): ``P = w * x[a0] + E c + const``, ``E = [e1, e2, e3]`` with
    ``e1 = x[a1] - x[a0]``, ``e2 = x[a2] - x[a0]``, ``e3 = x[a3] - x[a0]`` (rank 3) or
    ``e1 x e2`` (rank 2); unused anchors repeat ``a0`` (their edges vanish).
    Rows (``m``): ``U = P[u1] - P[u2]``, ``V = P[v1] - P[v2]``; ``phi = U[comp] - c0`` where
    ``comp >= 0``, else ``U . V - c0``.

    Attributes
    ----------
    anchors : [K, 4] int64.  rank : [K] int64.  coef : [K, 3].  w : [K].  const : [K, 3].
    u1, u2, v1, v2, comp : [m] int64.  c0 : [m].
    kinds : [m] list of str (what each row is: "rigid", "hinge", ... for reports).
    notes : sentences on joints that could be written only in part (or not at all).
    act_anchor, act_axis : [nu] attachment ids of each actuator's joint anchor and unit axis
        (-1: the actuator drives no hinge or slide joint, or its axis is not expressible).
    act_slide : [nu] bool, the actuator drives a slide joint (a force along the axis).
    """

    anchors: torch.Tensor
    rank: torch.Tensor
    coef: torch.Tensor
    w: torch.Tensor
    const: torch.Tensor
    u1: torch.Tensor
    u2: torch.Tensor
    v1: torch.Tensor
    v2: torch.Tensor
    comp: torch.Tensor
    c0: torch.Tensor
    kinds: list
    notes: list
    act_anchor: torch.Tensor = field(default_factory=lambda: torch.zeros(0, dtype=torch.long))
    act_axis: torch.Tensor = field(default_factory=lambda: torch.zeros(0, dtype=torch.long))
    act_slide: torch.Tensor = field(default_factory=lambda: torch.zeros(0, dtype=torch.bool))

    @property
    def m(self) -> int:
        return int(self.c0.shape[0])

    def subset(self, rows) -> ConstraintSet:
        """The constraints ``rows`` (a list of row indices) only; attachments and actuators kept."""
        idx = torch.as_tensor(list(rows), dtype=torch.long)
        ids = [self.u1[idx], self.u2[idx], self.v1[idx], self.v2[idx]]
        used = torch.unique(torch.cat(ids + [self.act_anchor[self.act_anchor >= 0], self.act_axis[self.act_axis >= 0]]))
        remap = torch.full((self.anchors.shape[0] + 1,), -1, dtype=torch.long)
        remap[used] = torch.arange(used.numel())
        return ConstraintSet(self.anchors[used], self.rank[used], self.coef[used], self.w[used], self.const[used],
                             *[remap[i] for i in ids], self.comp[idx], self.c0[idx],
                             [self.kinds[i] for i in idx.tolist()], list(self.notes), remap[self.act_anchor],
                             remap[self.act_axis], self.act_slide)

    def to(self, device, dtype=torch.float64) -> ConstraintSet:
        kw = {}
        for k, v in self.__dict__.items():
            if isinstance(v, torch.Tensor):
                kw[k] = v.to(device=device, dtype=dtype if v.is_floating_point() else v.dtype)
            else:
                kw[k] = v
        return ConstraintSet(**kw)

    def attachments(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` [..., N, 3] -> attachment points/vectors [..., K, 3]."""
        xa = x[..., self.anchors, :]  # [..., K, 4, 3]
        e1 = xa[..., 1, :] - xa[..., 0, :]
        e2 = xa[..., 2, :] - xa[..., 0, :]
        e3 = torch.where((self.rank == 2)[:, None], torch.linalg.cross(e1, e2, dim=-1), xa[..., 3, :] - xa[..., 0, :])
        c = self.coef
        return (self.w[:, None] * xa[..., 0, :] + c[:, 0:1] * e1 + c[:, 1:2] * e2 + c[:, 2:3] * e3
                + self.const)

    def _parts(self, x: torch.Tensor, dx: torch.Tensor, ddx: torch.Tensor | None = None):
        """Attachments ``P`` [B, K, 3], first variations ``dP`` [B, T, K, 3] along tangents ``dx`` [B, T, N, 3],
        and the second variation ``d2P`` [B, K, 3] along ``ddx`` [B, N, 3] (P is affine in x but for
        ``e1 x e2``, whose second variation is ``2 de1 x de2``)."""
        a = self.anchors
        xa, da = x[:, a], dx[:, :, a]  # [B, K, 4, 3], [B, T, K, 4, 3]
        e1, e2 = xa[..., 1, :] - xa[..., 0, :], xa[..., 2, :] - xa[..., 0, :]
        d1, d2 = da[..., 1, :] - da[..., 0, :], da[..., 2, :] - da[..., 0, :]
        r2 = (self.rank == 2)[:, None]
        e3 = torch.where(r2, torch.linalg.cross(e1, e2, dim=-1), xa[..., 3, :] - xa[..., 0, :])
        d3 = torch.where(r2, torch.linalg.cross(d1, e2[:, None].expand_as(d1), dim=-1)
                         + torch.linalg.cross(e1[:, None].expand_as(d2), d2, dim=-1), da[..., 3, :] - da[..., 0, :])
        c = self.coef
        P = self.w[:, None] * xa[..., 0, :] + c[:, 0:1] * e1 + c[:, 1:2] * e2 + c[:, 2:3] * e3 + self.const
        dP = self.w[:, None] * da[..., 0, :] + c[:, 0:1] * d1 + c[:, 1:2] * d2 + c[:, 2:3] * d3
        d2P = None
        if ddx is not None:
            g = ddx[:, a]
            g1, g2 = g[..., 1, :] - g[..., 0, :], g[..., 2, :] - g[..., 0, :]
            d2P = torch.where(r2, 2.0 * c[:, 2:3] * torch.linalg.cross(g1, g2, dim=-1), torch.zeros_like(g1))
        return P, dP, d2P

    def jacobian(self, x: torch.Tensor, mov: torch.Tensor, qd: torch.Tensor):
        """``(J, Jdot qd)`` at all-node positions ``x`` [B, N, 3], closed form (no autodiff).

        ``J`` [B, m, 3n] is ``dPhi/dq`` over the moving nodes ``mov`` [n]; ``Jdot qd`` [B, m] is
        the second variation of ``Phi`` along the moving-node velocities ``qd`` [B, n, 3]:
        for ``U_k`` it is ``d2U_k``, for ``U . V`` it is ``d2U . V + 2 dU . dV + U . d2V``.
        """
        B, N, _ = x.shape
        n = mov.shape[0]
        D = 3 * n
        basis = torch.zeros(D, N, 3, dtype=x.dtype, device=x.device)
        ar = torch.arange(D, device=x.device)
        basis[ar, mov.repeat_interleave(3), ar % 3] = 1.0
        vfull = torch.zeros_like(x).index_copy(1, mov, qd)
        tang = torch.cat([basis.expand(B, D, N, 3), vfull[:, None]], 1)  # tangents: basis, then qd
        P, dP, d2P = self._parts(x, tang, vfull)
        U = P[:, self.u1] - P[:, self.u2]
        V = P[:, self.v1] - P[:, self.v2]
        dU = dP[:, :, self.u1] - dP[:, :, self.u2]  # [B, D+1, m, 3]
        dV = dP[:, :, self.v1] - dP[:, :, self.v2]
        d2U = d2P[:, self.u1] - d2P[:, self.u2]
        d2V = d2P[:, self.v1] - d2P[:, self.v2]
        is_comp = self.comp >= 0
        sel = torch.nn.functional.one_hot(self.comp.clamp_min(0), 3).to(x.dtype)  # [m, 3]
        Jc = (dU * sel).sum(-1)
        Jd = (dU * V[:, None]).sum(-1) + (U[:, None] * dV).sum(-1)
        Jall = torch.where(is_comp, Jc, Jd)  # [B, D+1, m]
        Dd = (d2U * sel).sum(-1)
        Dt = (d2U * V).sum(-1) + 2 * (dU[:, -1] * dV[:, -1]).sum(-1) + (U * d2V).sum(-1)
        return Jall[:, :D].transpose(1, 2), torch.where(is_comp, Dd, Dt)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """``Phi(x)`` [..., m]."""
        if self.m == 0:
            return x.new_zeros(*x.shape[:-2], 0)
        P = self.attachments(x)
        U = P[..., self.u1, :] - P[..., self.u2, :]
        V = P[..., self.v1, :] - P[..., self.v2, :]
        comp = U.gather(-1, self.comp.clamp_min(0).expand(*U.shape[:-1]).unsqueeze(-1))[..., 0]
        dot = (U * V).sum(-1)
        return torch.where(self.comp >= 0, comp, dot) - self.c0


class _Builder:
    """Accumulates attachments and candidate rows in numpy (float64) at the reference configuration."""

    def __init__(self, xref: np.ndarray):
        self.x = xref
        self.att: list[tuple] = []  # (anchors[4], rank, coef[3], w, const[3])
        self.rows: list[tuple] = []  # (u1, u2, v1, v2, comp, kind)

    def attach(self, anchors, rank, coef, w, const) -> int:
        self.att.append((list(anchors), int(rank), np.asarray(coef, float), float(w), np.asarray(const, float)))
        return len(self.att) - 1

    def node(self, i: int) -> int:
        return self.attach([i] * 4, 0, np.zeros(3), 1.0, np.zeros(3))

    def const(self, p) -> int:
        return self.attach([0] * 4, 0, np.zeros(3), 0.0, p)

    def value(self, k: int, x: np.ndarray | None = None) -> np.ndarray:
        x = self.x if x is None else x
        a, r, c, w, const = self.att[k]
        xa = x[a]
        e1, e2 = xa[1] - xa[0], xa[2] - xa[0]
        e3 = np.cross(e1, e2) if r == 2 else xa[3] - xa[0]
        return w * xa[0] + c[0] * e1 + c[1] * e2 + c[2] * e3 + const


@dataclass
class _Body:
    """A body's node frame: anchors (a0..a3), rank 0-3, its nodes; or the world (constants)."""

    nodes: np.ndarray
    anchors: list
    rank: int
    world: bool = False

    def edges(self, x: np.ndarray) -> np.ndarray:
        a = x[self.anchors]
        e = np.zeros((3, 3))
        if self.rank >= 1:
            e[0] = a[1] - a[0]
        if self.rank >= 2:
            e[1] = a[2] - a[0]
            e[2] = np.cross(e[0], e[1]) if self.rank == 2 else a[3] - a[0]
        return e


def _frames(nodes: np.ndarray, x: np.ndarray) -> _Body:
    """Choose well-conditioned anchors of a body's nodes and its rank (0 point, 1 line, 2 plane, 3 space)."""
    p = x[nodes]
    if len(nodes) == 1:
        return _Body(nodes, [int(nodes[0])] * 4, 0)
    c = p.mean(0)
    size = max(float(np.linalg.norm(p - c, axis=1).max()), 1e-12)
    tol = SPAN_TOL * size
    i0 = int(np.argmin(np.linalg.norm(p - c, axis=1)))
    d1 = np.linalg.norm(p - p[i0], axis=1)
    i1 = int(np.argmax(d1))
    if d1[i1] <= tol:
        return _Body(nodes, [int(nodes[i0])] * 4, 0)
    u = (p[i1] - p[i0]) / d1[i1]
    off = (p - p[i0]) - np.outer((p - p[i0]) @ u, u)
    d2 = np.linalg.norm(off, axis=1)
    i2 = int(np.argmax(d2))
    if d2[i2] <= tol:
        return _Body(nodes, [int(nodes[i0]), int(nodes[i1]), int(nodes[i0]), int(nodes[i0])], 1)
    n = np.cross(p[i1] - p[i0], p[i2] - p[i0])
    n /= np.linalg.norm(n)
    d3 = np.abs((p - p[i0]) @ n)
    i3 = int(np.argmax(d3))
    if d3[i3] <= tol:
        return _Body(nodes, [int(nodes[i0]), int(nodes[i1]), int(nodes[i2]), int(nodes[i0])], 2)
    return _Body(nodes, [int(nodes[i]) for i in (i0, i1, i2, i3)], 3)


def _express(b: _Body, x: np.ndarray, target: np.ndarray, point: bool, bld: _Builder) -> int | None:
    """Attachment of ``target`` (a world point or vector at the reference) to body ``b``; None if not expressible.

    The world (and bodies welded to it) holds any point or vector as a constant; a body of rank 3
    or 2 any point or vector; a line (rank 1) only points on it and vectors along it; a single
    node only its own position.
    """
    if b.world:
        return bld.attach([0] * 4, 0, np.zeros(3), 0.0, target)
    rhs = target - x[b.anchors[0]] if point else np.asarray(target, float)
    E = b.edges(x)[: min(b.rank, 3)] if b.rank < 2 else b.edges(x)
    coef = np.zeros(3)
    if b.rank == 0:
        resid = float(np.linalg.norm(rhs))
    else:
        sol, *_ = np.linalg.lstsq(E.T, rhs, rcond=None)
        coef[: len(sol)] = sol
        resid = float(np.linalg.norm(E.T @ sol - rhs))
    size = float(np.abs(x[b.nodes] - x[b.nodes].mean(0)).max()) if len(b.nodes) > 1 else 0.0
    if resid > 1e-7 * max(float(np.linalg.norm(rhs)), size, 1e-9):
        return None
    return bld.attach(b.anchors, b.rank, coef, 1.0 if point else 0.0, np.zeros(3))


def _perp(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.eye(3)[int(np.argmin(np.abs(u)))]
    w1 = np.cross(u, a)
    w1 /= np.linalg.norm(w1)
    return w1, np.cross(u, w1)


def build_constraints(split, xref: np.ndarray | None = None) -> tuple[ConstraintSet, dict]:
    """Rigid-body and joint constraints of a split's scene in node coordinates (module docstring).

    Parameters
    ----------
    split : :class:`~mdgs.data.split.SplitData` (its MJCF gives the joints; ``qpos[0, 0]`` the
        reference configuration, at which node positions are rebuilt in float64 from MuJoCo's
        body poses and ``node_centroid``).
    xref : [N, 3], optional override of the reference node positions (tests).

    Returns
    -------
    (constraints, info): ``info`` holds ``dof`` (3 n_moving - rank), ``mujoco_dof`` (MuJoCo's
    ``nv`` of moving bodies), ``rows`` per kind and ``notes``.
    """
    import mujoco

    m = mujoco.MjModel.from_xml_string(split.mjcf)
    d = mujoco.MjData(m)
    st = split.static
    nb = np.asarray(st["node_body"], int)
    static = np.asarray(st["node_static"], bool)
    d.qpos[:] = np.asarray(split.qpos[0, 0], float) if split.qpos is not None else m.qpos0
    mujoco.mj_kinematics(m, d)
    if xref is None:
        c = np.asarray(st["node_centroid"], float)
        xref = np.einsum("nij,nj->ni", d.xmat[nb].reshape(-1, 3, 3), c) + d.xpos[nb]
    bld = _Builder(xref)
    notes: list[str] = []
    bodies: dict[int, _Body] = {}
    for b in range(m.nbody):
        nodes = np.where(nb == b)[0]
        if b == 0 or (len(nodes) and static[nodes].all()):
            bodies[b] = _Body(nodes, [0] * 4, 3, world=True)
        elif len(nodes):
            bodies[b] = _frames(nodes, xref)
    # rigidity: anchor distances + affine combinations of the anchors (linear)
    for body in bodies.values():
        if body.world or len(body.nodes) < 2:
            continue
        a = body.anchors[: body.rank + 1]
        ids = {i: bld.node(i) for i in set(a)}
        for p in range(len(a)):
            for q in range(p + 1, len(a)):
                bld.rows.append((ids[a[p]], ids[a[q]], ids[a[p]], ids[a[q]], -1, "rigid"))
        E = body.edges(xref)[: body.rank]
        for i in body.nodes:
            if i in a:
                continue
            sol, *_ = np.linalg.lstsq(E.T, xref[i] - xref[a[0]], rcond=None)
            coef = np.zeros(3)
            coef[: len(sol)] = sol
            anc = body.anchors if body.rank != 2 else [a[0], a[1], a[2], a[0]]
            k = bld.attach(anc, 3 if body.rank == 2 else body.rank, coef, 1.0, np.zeros(3))  # linear part only
            ni = bld.node(int(i))
            for comp in range(3):
                bld.rows.append((ni, k, ni, k, comp, "rigid"))
    # joints
    n_rigid = len(bld.rows)
    for b in range(1, m.nbody):
        if b not in bodies or bodies[b].world:
            continue
        par = int(m.body_parentid[b])
        while par not in bodies and par != 0:  # bodies without nodes: attach to the nearest ancestor with nodes
            par = int(m.body_parentid[par])
        child, parent = bodies[b], bodies.get(par, bodies[0])
        jn, ja = int(m.body_jntnum[b]), int(m.body_jntadr[b])
        types = [int(m.jnt_type[ja + k]) for k in range(jn)]
        name = m.body(b).name or f"body {b}"
        if JOINT_FREE in types:
            continue
        if jn == 0:
            kind, anchor, axis = "weld", d.xpos[b].copy(), np.array([0.0, 0.0, 1.0])
        elif jn == 1:
            kind = {JOINT_BALL: "ball", JOINT_SLIDE: "slide", JOINT_HINGE: "hinge"}[types[0]]
            anchor, axis = d.xanchor[ja].copy(), d.xaxis[ja].copy()
        else:
            anc = d.xanchor[ja:ja + jn]
            if all(t in (JOINT_HINGE, JOINT_BALL) for t in types) and np.ptp(anc, axis=0).max() < 1e-9:
                kind, anchor, axis = "ball", anc[0].copy(), np.array([0.0, 0.0, 1.0])
                notes.append(f"{name}: {jn} rotational joints at one anchor are constrained as a ball joint "
                             "(the missing rotation limit is left to the learned forces)")
            else:
                notes.append(f"{name}: {jn} joints of types {types} in series are not written as constraints "
                             "(left to the learned forces)")
                continue
        before = len(bld.rows)
        _joint_rows(bld, child, parent, kind, anchor, axis, xref)
        if len(bld.rows) == before:
            notes.append(f"{name}: its {kind} joint cannot be written in the node coordinates of its bodies")
    # actuators: anchor and axis of the driven joint, attached to the driven body (else its parent)
    act = []
    for k in range(m.nu):
        aa = ax = -1
        slide = False
        if int(m.actuator_trntype[k]) in (int(mujoco.mjtTrn.mjTRN_JOINT), int(mujoco.mjtTrn.mjTRN_JOINTINPARENT)):
            j = int(m.actuator_trnid[k, 0])
            jt, b = int(m.jnt_type[j]), int(m.jnt_bodyid[j])
            if jt in (JOINT_HINGE, JOINT_SLIDE):
                slide = jt == JOINT_SLIDE
                par = int(m.body_parentid[b])
                for side in (bodies.get(b), bodies.get(par, bodies[0])):
                    if side is None:
                        continue
                    pa = _express(side, xref, d.xanchor[j], True, bld)
                    pv = _express(side, xref, d.xaxis[j] / np.linalg.norm(d.xaxis[j]), False, bld)
                    if pa is not None and pv is not None:
                        aa, ax = pa, pv
                        break
        act.append((aa, ax, slide))
    cs, kinds = _select(bld, n_rigid, static, act)
    kept = {}
    for k in kinds:
        kept[k] = kept.get(k, 0) + 1
    n_mov = int((~static).sum())
    dof_mj = sum(int(m.body_dofnum[b]) for b in range(1, m.nbody) if b in bodies and not bodies[b].world)
    if 3 * n_mov - cs.m > dof_mj:
        notes.append(f"the node coordinates keep {3 * n_mov - cs.m - dof_mj} more degrees of freedom than MuJoCo's "
                     f"{dof_mj}: rotations of bodies whose nodes lie on one line cannot be seen by their nodes, "
                     "so joints hanging on them are written only in part")
    info = {"dof": 3 * n_mov - cs.m, "mujoco_dof": dof_mj, "rows": kept, "notes": notes, "xref": xref}
    cs.notes = notes
    return cs, info


def _joint_rows(bld: _Builder, child: _Body, parent: _Body, kind: str, anchor: np.ndarray, axis: np.ndarray,
                x: np.ndarray) -> None:
    """Candidate rows of one joint (redundant; :func:`_select` keeps an independent subset)."""
    u = axis / np.linalg.norm(axis)
    size = max(float(np.abs(x[child.nodes] - x[child.nodes].mean(0)).max()), 1e-3)
    w1, w2 = _perp(u)
    pts = [anchor, anchor + size * u] if kind in ("hinge", "weld") else [anchor]
    if kind == "weld":
        pts += [anchor + size * w1, anchor + size * w2]
    rows = bld.rows
    # point coincidence (hinge: two axis points; ball: the anchor; weld: four points)
    if kind != "slide":
        for p in pts:
            pc, pp = _express(child, x, p, True, bld), _express(parent, x, p, True, bld)
            if pc is not None and pp is not None:
                for comp in range(3):
                    rows.append((pc, pp, pc, pp, comp, kind))
        # distances of each side's nodes to the other side's fixed points (a point mass / line on a joint)
        for side, other in ((child, parent), (parent, child)):
            if side.world:
                continue
            for p in pts:
                po = _express(other, x, p, True, bld)
                if po is None:
                    continue
                for i in side.nodes:
                    ni = bld.node(int(i))
                    rows.append((ni, po, ni, po, -1, kind))
    # directions: child vectors vs parent vectors (hinge: axis stays axis; slide/weld: frames locked)
    vecs = {"hinge": [(u, w1), (u, w2), (w1, u), (w2, u)],
            "slide": [(u, w1), (u, w2), (w1, u), (w2, u), (w1, w2), (w2, w1)],
            "weld": [(u, w1), (u, w2), (w1, w2), (w1, u), (w2, u), (w2, w1)], "ball": []}[kind]
    zero = None
    for vc, vp in vecs:
        ac, ap = _express(child, x, vc, False, bld), _express(parent, x, vp, False, bld)
        if ac is not None and ap is not None:
            if zero is None:
                zero = bld.const(np.zeros(3))
            rows.append((ac, zero, ap, zero, -1, kind))
    if kind == "slide":  # the child's anchor stays on the parent's axis line
        pc, pp = _express(child, x, anchor, True, bld), _express(parent, x, anchor, True, bld)
        for wv in (w1, w2):
            for side in (parent, child):
                aw = _express(side, x, wv, False, bld)
                if pc is not None and pp is not None and aw is not None:
                    if zero is None:
                        zero = bld.const(np.zeros(3))
                    rows.append((pc, pp, aw, zero, -1, kind))


def _select(bld: _Builder, n_rigid: int, static: np.ndarray, act: list) -> tuple[ConstraintSet, list]:
    """A maximal independent subset of the rows (rigid rows first), by rank of J at the reference."""
    att = bld.att
    K = len(att)
    anchors = torch.tensor([a[0] for a in att], dtype=torch.long).reshape(K, 4) if K else torch.zeros(0, 4, dtype=torch.long)
    cs = ConstraintSet(
        anchors=anchors,
        rank=torch.tensor([a[1] for a in att], dtype=torch.long),
        coef=torch.tensor(np.array([a[2] for a in att]).reshape(K, 3)),
        w=torch.tensor([a[3] for a in att], dtype=torch.float64),
        const=torch.tensor(np.array([a[4] for a in att]).reshape(K, 3)),
        u1=torch.tensor([r[0] for r in bld.rows], dtype=torch.long),
        u2=torch.tensor([r[1] for r in bld.rows], dtype=torch.long),
        v1=torch.tensor([r[2] for r in bld.rows], dtype=torch.long),
        v2=torch.tensor([r[3] for r in bld.rows], dtype=torch.long),
        comp=torch.tensor([r[4] for r in bld.rows], dtype=torch.long),
        c0=torch.zeros(len(bld.rows), dtype=torch.float64),
        kinds=[r[5] for r in bld.rows], notes=[],
        act_anchor=torch.tensor([a[0] for a in act], dtype=torch.long).reshape(-1),
        act_axis=torch.tensor([a[1] for a in act], dtype=torch.long).reshape(-1),
        act_slide=torch.tensor([a[2] for a in act], dtype=torch.bool).reshape(-1))
    x = torch.tensor(bld.x)
    if cs.m == 0:
        return cs.subset([]), []
    cs.c0 = cs(x).detach()
    mov = torch.from_numpy(np.where(~static)[0])
    J = cs.jacobian(x[None], mov, torch.zeros(1, len(mov), 3, dtype=x.dtype))[0][0].numpy()  # [m, 3 n_moving]
    keep: list[int] = []
    basis = np.zeros((0, J.shape[1]))
    scale = max(np.linalg.norm(J, axis=1).max(), 1e-300)
    for r in range(cs.m):
        row = J[r] / max(np.linalg.norm(J[r]), 1e-300)
        if np.linalg.norm(J[r]) < RANK_TOL * scale:
            continue
        res = row - basis.T @ (basis @ row)
        res = res - basis.T @ (basis @ res)
        nr = np.linalg.norm(res)
        if nr > 1e-6 or r < n_rigid and nr > 1e-9:
            keep.append(r)
            basis = np.vstack([basis, res / nr])
    out = cs.subset(keep)
    return out, out.kinds


# --- solvers -----------------------------------------------------------------------------------------

#: Relative ridge (of the mean absolute diagonal) with which a system whose LU factorisation meets an exactly zero pivot
#: is solved again (:func:`_solve`). For a symmetric positive semi-definite system with a consistent right-hand side the
#: solution then differs from the pseudo-inverse's minimum-norm one by about the ridge over the smallest non-zero
#: eigenvalue, relative (5e-9 for two copies of one constraint, tests/test_model_lgns.py).
SINGULAR_RIDGE = 1e-8


def _solve(A: torch.Tensor, B: torch.Tensor) -> torch.Tensor:
    """``A^-1 B`` ([b, k, k], [b, k, r]); a sample whose LU factorisation meets an exactly zero pivot is solved again
    with :data:`SINGULAR_RIDGE` times its mean absolute diagonal added to the diagonal, instead of raising.

    Branch-free, so a compiled step holding it stays one graph (a check on the host, ``if info.any()``, broke the
    energy peers' compiled steps into one region per solve): every system is factorised twice, the second time with
    the ridge where the first met a zero pivot and unchanged elsewhere (adding zero), so a solvable system's solution
    is the plain solve's to the bit. The first factorisation's result is used only for its pivot check, so no
    infinite value of a singular sample reaches the solution or its gradient."""
    bad = torch.linalg.lu_factor_ex(A).info != 0
    ridge = SINGULAR_RIDGE * A.diagonal(dim1=-2, dim2=-1).abs().mean(-1).clamp_min(1e-300)
    eye = torch.eye(A.shape[-1], dtype=A.dtype, device=A.device)
    return torch.linalg.solve_ex(A + torch.where(bad, ridge, 0.0)[:, None, None] * eye, B)[0]


def solve_multipliers(Minv_JT: torch.Tensor, J: torch.Tensor, rhs: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """``lambda`` of ``(J M^-1 J^T) lambda = rhs`` ([B, m]); a relative ``eps`` ridge keeps it solvable
    where the constraints become dependent (a damped pseudo-inverse). Where the factorisation still
    meets an exactly zero pivot (seen on a GPU at batch 256 and 4096 with the CPU's states solving
    fine; why is not established), that sample is solved again with a larger ridge (:func:`_solve`), which gives
    close to the minimum-norm multipliers (:data:`SINGULAR_RIDGE`)."""
    A = J @ Minv_JT
    if A.shape[-1] == 0:
        return rhs
    ridge = eps * A.diagonal(dim1=-2, dim2=-1).abs().mean(-1).clamp_min(1e-300)
    A = A + ridge[:, None, None] * torch.eye(A.shape[-1], dtype=A.dtype, device=A.device)
    return _solve(A, rhs.unsqueeze(-1))[..., 0]


def lagrangian_acceleration(L, jac, q: torch.Tensor, qd: torch.Tensor, force: torch.Tensor) -> torch.Tensor:
    """Accelerations ``qdd`` [B, n, 3] of the constrained Euler-Lagrange equations (Bhattoo et al. 2022).

    ``L(q, qd) -> scalar`` acts on one sample (``[n, 3]`` each); ``jac(q, qd) -> (J [B, m, 3n],
    Jdot qd [B, m])`` on the batch (:meth:`ConstraintSet.jacobian`); ``force`` [B, n, 3] are the
    non-conservative generalised forces ``Y``::

        M = d2L/dqd2,  f = dL/dq - (d2L/dqd dq) qd + Y                     (Euler-Lagrange)
        J = dPhi/dq,   J qdd = -Jdot qd                                    (holonomic, twice differentiated)
        qdd = M^-1 (f + J^T lambda),  (J M^-1 J^T) lambda = -Jdot qd - J M^-1 f

    Second derivatives by reverse mode over reverse mode (``jacrev`` of ``jacrev``), the mixed term as the
    product of ``d2L/dqd dq`` with ``qd``: ``torch.compile`` traces these (forward mode over reverse mode, ``jacfwd``
    and ``jvp``, failed an internal assertion of torch 2.13 while dynamo traced them), and eagerly they cost less, with
    the same accelerations to the bit (``benchmarks/mdgs_probes/peer_derivatives.py``).
    """
    B, n, _ = q.shape
    D = 3 * n
    dLdv = jacrev(L, argnums=1)

    def one(q1, qd1):
        gq = jacrev(L, argnums=0)(q1, qd1)
        M = jacrev(dLdv, argnums=1)(q1, qd1).reshape(D, D)
        mixed = jacrev(dLdv, argnums=0)(q1, qd1).reshape(D, D) @ qd1.reshape(D)  # (d2L/dqd dq) qd
        return gq.reshape(D) - mixed, M

    f, M = vmap(one)(q, qd)
    J, Jdqd = jac(q, qd)
    f = f + force.reshape(B, D)
    rhs = torch.cat([f.unsqueeze(-1), J.transpose(1, 2)], -1)
    sol = _solve(M, rhs)  # a singular M (not reached with the peers' positive masses) is solved with a ridge
    Minv_f, Minv_JT = sol[..., 0], sol[..., 1:]
    if J.shape[1]:
        lam = solve_multipliers(Minv_JT, J, -Jdqd - (J @ Minv_f.unsqueeze(-1))[..., 0])
        Minv_f = Minv_f + (Minv_JT @ lam.unsqueeze(-1))[..., 0]
    return Minv_f.view(B, n, 3)


def hamiltonian_derivatives(H, jac, q: torch.Tensor, p: torch.Tensor, force: torch.Tensor):
    """``(qd, pd, qdd)`` [B, n, 3] of the constrained Hamilton equations (Bishnoi et al. 2023).

    ``H(q, p) -> scalar`` acts on one sample, ``jac`` as in :func:`lagrangian_acceleration`; ``force`` = ``Y``::

        qd = dH/dp,  pd = -dH/dq + Y + J^T lambda,  with d2Phi/dt2 = J qdd + Jdot qd = 0,
        qdd = (d2H/dp2) pd + (d2H/dp dq) qd
        => (J H_pp J^T) lambda = -Jdot qd - J H_pq qd - J H_pp (-dH/dq + Y)

    ``qdd`` is returned for the training loss (the acceleration the data measures). Second derivatives by reverse mode
    twice, as :func:`lagrangian_acceleration`'s.
    """
    B, n, _ = q.shape
    D = 3 * n
    dHdp = jacrev(H, argnums=1)

    def one(q1, p1):
        Hq = jacrev(H, argnums=0)(q1, p1)
        qd1 = dHdp(q1, p1).reshape(D)
        Hpp = jacrev(dHdp, argnums=1)(q1, p1).reshape(D, D)
        mixed = jacrev(dHdp, argnums=0)(q1, p1).reshape(D, D) @ qd1  # H_pq qd
        return qd1, Hq.reshape(D), Hpp, mixed

    qd, Hq, Hpp, mixed = vmap(one)(q, p)
    J, Jdqd = jac(q, qd.view(B, n, 3))
    base = -Hq + force.reshape(B, D)
    if J.shape[1]:
        Hpp_JT = Hpp @ J.transpose(1, 2)
        rhs = -Jdqd - (J @ (mixed + (Hpp @ base.unsqueeze(-1))[..., 0]).unsqueeze(-1))[..., 0]
        lam = solve_multipliers(Hpp_JT, J, rhs)
        pd = base + (J.transpose(1, 2) @ lam.unsqueeze(-1))[..., 0]
    else:
        pd = base
    qdd = (Hpp @ pd.unsqueeze(-1))[..., 0] + mixed
    return qd.view(B, n, 3), pd.view(B, n, 3), qdd.view(B, n, 3)


# --- integrators ------------------------------------------------------------------------------------

def velocity_verlet(acc, q: torch.Tensor, qd: torch.Tensor, h: float) -> tuple[torch.Tensor, torch.Tensor]:
    """One velocity Verlet step (LGNS): ``q' = q + h qd + h^2 a / 2``, ``qd' = qd + h (a + a') / 2``.

    ``acc(q, qd) -> qdd``; ``a' = acc(q', qd + h a)`` (the end velocity predicted explicitly,
    so velocity-dependent forces keep the step explicit; for forces of ``q`` alone this is the
    symplectic velocity Verlet).
    """
    a0 = acc(q, qd)
    q1 = q + h * qd + 0.5 * h * h * a0
    a1 = acc(q1, qd + h * a0)
    return q1, qd + 0.5 * h * (a0 + a1)


def rk4(f, q: torch.Tensor, p: torch.Tensor, h: float) -> tuple[torch.Tensor, torch.Tensor]:
    """One classical Runge-Kutta 4 step of ``(q, p)' = f(q, p)`` (HGNS)."""
    k1 = f(q, p)
    k2 = f(q + 0.5 * h * k1[0], p + 0.5 * h * k1[1])
    k3 = f(q + 0.5 * h * k2[0], p + 0.5 * h * k2[1])
    k4 = f(q + h * k3[0], p + h * k3[1])
    return (q + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]),
            p + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]))

"""Training losses: L_mse (Eq. 10) and the Kane constraint L_cst = L_sup + L_inf (Eqs. 11-15).

The constraint is evaluated only through the torch functions that :func:`kane.terms.loss_functions`
generates from the sympy expressions the checks verify (one source for each formula):

    S_gamma = sum_i eq11_term(F_{gamma,i}, M_i, v^{t+1}_{gamma,i}, v^t_{gamma,i}, delta, u_gamma)   (Eq. 11)
    B_gamma = sum_i bound_term(...)                                   paper (Eq. 12) or corrected bound
    L_cst   = sum_gamma mean_graphs loss_cst(S_gamma, B_gamma)        (Eqs. 13-15)

Generalized speeds are the translations x, y, z of Appendix B.1.2 (``u_gamma = 1``);
variant ``mdgs-sc`` keeps only x. The state prediction enters detached, so the gradient
of L_cst reaches only the force networks (Section 3.4: "L_cst will only be used to update
g^F- and g^F~").
"""

from __future__ import annotations

import torch

from kane.terms import loss_functions
from mdgs.structure import segment_mean

__all__ = ["mse_loss", "angular_rate", "constraint_sums", "constraint_loss", "speeds_of"]


def speeds_of(variant: str) -> tuple[int, ...]:
    """Generalized speeds constrained by a variant: mdgs -> (x, y, z); mdgs-sc -> (x,); mdgs-nc -> ()."""
    return {"mdgs": (0, 1, 2), "mdgs-sc": (0,), "mdgs-nc": ()}[variant]


def mse_loss(x: torch.Tensor, v: torch.Tensor, x_true: torch.Tensor, v_true: torch.Tensor,
             moving: torch.Tensor | None = None, dx_scale: float = 1.0, dv_scale: float = 1.0) -> torch.Tensor:
    """Eq. (10): MSE between predicted and true ``Z^(t+1) = [x || v]`` over moving nodes.

    Positions are divided by ``dx_scale`` (m) and velocities by ``dv_scale`` (m/s) so both
    halves of Z weigh alike; with the defaults it is the plain MSE. Shapes ``[B, N, 3]``;
    ``moving`` [N] bool (static nodes are excluded: they are not predicted).
    """
    return (_scaled_residual(x, v, x_true, v_true, moving, dx_scale, dv_scale) ** 2).mean()


def _scaled_residual(x, v, x_true, v_true, moving, dx_scale, dv_scale) -> torch.Tensor:
    """``[(x - x_true) / dx_scale || (v - v_true) / dv_scale]`` over the moving nodes: [B, N_moving, 6]."""
    d = torch.cat([(x - x_true) / dx_scale, (v - v_true) / dv_scale], -1)
    return d if moving is None else d[:, moving]


def pair_mse(x: torch.Tensor, v: torch.Tensor, x_true: torch.Tensor, v_true: torch.Tensor,
             moving: torch.Tensor | None = None, dx_scale: float = 1.0, dv_scale: float = 1.0) -> torch.Tensor:
    """Eq. (10) for each graph of the batch separately: [B]; its mean is :func:`mse_loss`."""
    return (_scaled_residual(x, v, x_true, v_true, moving, dx_scale, dv_scale) ** 2).mean((1, 2))


def huber_loss(x: torch.Tensor, v: torch.Tensor, x_true: torch.Tensor, v_true: torch.Tensor,
               moving: torch.Tensor | None = None, dx_scale: float = 1.0, dv_scale: float = 1.0,
               delta: float = 1.0) -> torch.Tensor:
    """Eq. (10) with the square replaced by the Huber function (quadratic up to ``delta``, in the
    scaled units, linear beyond): a rare large residual pulls no harder than ``delta`` per component."""
    d = _scaled_residual(x, v, x_true, v_true, moving, dx_scale, dv_scale)
    return torch.nn.functional.huber_loss(d, torch.zeros_like(d), delta=delta)


def angular_rate(x: torch.Tensor, v: torch.Tensor, seg: torch.Tensor, n_seg: int, mass: torch.Tensor,
                 tau: torch.Tensor) -> torch.Tensor:
    """Angular speed of each node's object, Appendix B.1.2: ``omega = |v_i - v_0| / |x_i - x_0|``, max over the object.

    The "central particle" 0 is the object's mass centre (mass-weighted mean of centroids and
    velocities); elements closer to it than ``tau_i / 100`` are skipped (division by ~0).
    For a rigid body this is ``|omega| sin(angle)`` maximised over its elements, i.e. a lower
    estimate of ``|omega|`` that is exact when an element lies off the rotation axis.

    Shapes: x, v [B, N, 3]; seg [N]; mass, tau [N] -> [B, N] (rad/s).
    """
    xc = segment_mean(x, seg, n_seg, mass)[:, seg]
    vc = segment_mean(v, seg, n_seg, mass)[:, seg]
    r = torch.linalg.vector_norm(x - xc, dim=-1)
    dv = torch.linalg.vector_norm(v - vc, dim=-1)
    ok = r > (tau.to(r.dtype) / 100)[None]
    w = torch.where(ok, dv / torch.where(ok, r, torch.ones_like(r)), torch.zeros_like(r))
    B = x.shape[0]
    wmax = w.new_zeros(B, n_seg).scatter_reduce_(1, seg[None].expand(B, -1), w, "amax", include_self=True)
    return wmax[:, seg]


def constraint_sums(force: torch.Tensor, x: torch.Tensor, v: torch.Tensor, x_next: torch.Tensor,
                    v_next: torch.Tensor, mass: torch.Tensor, tau: torch.Tensor, seg: torch.Tensor, n_seg: int,
                    delta: float, moving: torch.Tensor | None = None, bound: str = "paper",
                    speeds: tuple[int, ...] = (0, 1, 2), group: torch.Tensor | None = None,
                    n_group: int | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-graph sums ``S`` (Eq. 11) and ``B`` (bound) for each constrained speed.

    Parameters
    ----------
    force : [B, N, 3] F_i of Eq. (7), N.  x, v, x_next, v_next : [B, N, 3] state at t and t+1.
    mass, tau : [N] kg, m.  seg : [N] object ids, ``n_seg`` objects (for the angular rates).
    delta : time step between frames, s.  moving : [N] bool, nodes counted (default all).
    bound : "paper" -> Eq. (12) with w_g = |omega| (B.1.2) and tau the largest element radius;
        "corrected" -> kane's corrected bound, w_g = 0 for translational speeds.
    group : [N] optional ids of node groups summed separately (default: the whole graph).

    Returns
    -------
    S, B : [B, G, len(speeds)] (G = 1 without ``group``).
    """
    fns = loss_functions("torch")
    eq11 = fns["eq11_term"][1]
    Bn, N, _ = force.shape
    dt = force.dtype
    m = torch.ones(N, dtype=torch.bool, device=force.device) if moving is None else moving.to(force.device)
    wt = m.to(dt)[None]  # [1, N]
    M = (mass.to(force.device, dt) * m.to(dt))[None]
    tau_i = tau.to(force.device, dt)[None].expand(Bn, N)
    g = torch.zeros(N, dtype=torch.long, device=force.device) if group is None else group.to(force.device)
    G = 1 if group is None else (int(g.max()) + 1 if n_group is None else n_group)
    w_t = angular_rate(x, v, seg, n_seg, mass.to(dt), tau.to(dt))
    w_n = angular_rate(x_next, v_next, seg, n_seg, mass.to(dt), tau.to(dt))
    wdot = (w_n - w_t).abs() / delta  # rad/s^2, "variant within coordinates"
    R_norm = torch.linalg.vector_norm(force, dim=-1) * wt  # |R_i| = |f_i| (B.1.2)
    if bound == "paper":
        tau_max = tau_i.masked_fill(~m[None], 0).amax(dim=1, keepdim=True).expand(Bn, N)
        bterm = fns["paper_bound_term"][1](tau_max, R_norm, w_t, M, wdot)
    elif bound == "corrected":
        # translational speeds: partial angular velocity omega_{i,gamma} = 0 (kane.claims eq12.corrected)
        bterm = fns["corrected_bound_term"][1](torch.zeros_like(w_t), tau_i, R_norm, M, wdot, w_t)
    else:
        raise ValueError(f"bound must be 'paper' or 'corrected', got {bound!r}")
    bterm = bterm * wt
    S, Bd = [], []
    for k in speeds:
        term = eq11(force[..., k] * wt, M, v_next[..., k], v[..., k], delta, 1.0)  # [B, N]
        S.append(force.new_zeros(Bn, G).index_add_(1, g, term))
        Bd.append(force.new_zeros(Bn, G).index_add_(1, g, bterm))
    return torch.stack(S, -1), torch.stack(Bd, -1)


def constraint_loss(force: torch.Tensor, x: torch.Tensor, v: torch.Tensor, x_next: torch.Tensor,
                    v_next: torch.Tensor, mass: torch.Tensor, tau: torch.Tensor, seg: torch.Tensor, n_seg: int,
                    delta: float, moving: torch.Tensor | None = None, bound: str = "paper",
                    speeds: tuple[int, ...] = (0, 1, 2), scale: float = 1.0,
                    group: torch.Tensor | None = None, n_group: int | None = None) -> torch.Tensor:
    """Eq. (15): ``L_cst = L_sup + L_inf`` summed over speeds, mean over graphs (and groups), divided by ``scale``.

    ``x_next``, ``v_next`` (the state network's prediction) are detached here, so the
    gradient reaches only the force networks. ``scale`` (N) makes the loss O(1) (training
    uses ``force_scale * number of moving nodes``); ``loss_cst`` is positively homogeneous,
    so dividing the result equals evaluating it on ``S / scale, B / scale``. Arguments as in
    :func:`constraint_sums`. Returns a scalar (0 for no speeds).
    """
    if not speeds:
        return force.new_zeros(())
    S, B = constraint_sums(force, x, v, x_next.detach(), v_next.detach(), mass, tau, seg, n_seg, delta,
                           moving, bound, speeds, group, n_group)
    cst = loss_functions("torch")["loss_cst"][1]
    return cst(S, B).sum(-1).mean() / scale

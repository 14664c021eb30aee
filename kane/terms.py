"""Kane terms of element sets (Appendix A of the paper), symbolic and numeric.

Notation follows the paper. For element ``c_i`` of a rigid body with point masses
``m_{i,l}`` at offsets ``r_{i,l}`` from its centroid, generalized speed ``gamma``:

* partial velocity of the centroid ``u_{i,gamma}``, partial angular velocity ``omega_{i,gamma}``;
* resultant ``R_i = sum_l F_{i,l}`` (Eq. 20), moment ``M_i = sum_l r_{i,l} x F_{i,l}``;
* inertia torque ``L*_i = sum_l r_{i,l} x m_{i,l} a_{i,l}`` (Eq. 19) = ``I_i alpha + omega x I_i omega``;
* generalized active force ``K_gamma = sum_i R_i . u_{i,gamma} + M_i . omega_{i,gamma}`` (Eq. 17);
* generalized inertia force ``K*_gamma = -sum_i M_i a_i . u_{i,gamma} - L*_i . omega_{i,gamma}`` (Eq. 19);
* disturbance ``Psi_gamma = sum_i (M_i - L*_i) . omega_{i,gamma}`` (Eq. 29).

The sympy expressions of the constraint loss (Eqs. 11-15) are defined once here;
:mod:`kane.codegen` turns them into numpy/torch/CasADi functions, which the checks and
the MDGS training loss both evaluate.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import sympy as sp

from kane.elements import Element

__all__ = [
    "LOSS_SYMBOLS",
    "eq11_element_term",
    "paper_bound_element_term",
    "corrected_bound_element_term",
    "loss_sup",
    "loss_inf",
    "loss_cst",
    "loss_functions",
    "ElementKinematics",
    "element_kinematics",
    "ElementLoads",
    "kane_terms",
    "KaneTerms",
    "free_body_partials",
    "symbolic_element_identities",
]

# ---------------------------------------------------------------------------------------
# Symbolic expressions of Eqs. (11)-(15), one per element, reduced by summation.
# ---------------------------------------------------------------------------------------

#: Per-element symbols (all real). F_g: predicted force of element i along speed gamma (N);
#: M: element mass (kg); v_next, v: velocity component along gamma at t+1 and t (m/s);
#: delta: time step (s); u_g: unit speed along gamma (1); tau: largest element radius (m);
#: R_norm: |R_i| (N); w_g: partial angular velocity magnitude omega_gamma (1/m for a
#: translational speed, 1 for a rotational one); wdot: angular acceleration magnitude of
#: the element (rad/s^2); w_abs: |omega_i| (rad/s); F_abs_sum: sum_l |F_{i,l}| (N).
LOSS_SYMBOLS = {
    name: sp.Symbol(name, real=True)
    for name in ("F_g", "M", "v_next", "v", "delta", "u_g", "tau", "R_norm", "w_g", "wdot", "w_abs", "F_abs_sum", "S", "B")
}
_s = LOSS_SYMBOLS

#: Eq. (11), element summand: F_{gamma,i} u_gamma - M_i (v_gamma^{t+1} - v_gamma^t) u_gamma / delta.
eq11_element_term = _s["F_g"] * _s["u_g"] - _s["M"] * (_s["v_next"] - _s["v"]) / _s["delta"] * _s["u_g"]

#: Eq. (12), element summand of the paper's bound on |Psi|: tau |R_i| omega_gamma + (2/5) M_i tau^2 wdot_i.
paper_bound_element_term = _s["tau"] * _s["R_norm"] * _s["w_g"] + sp.Rational(2, 5) * _s["M"] * _s["tau"] ** 2 * _s["wdot"]

#: Corrected bound (``eq12.corrected``), element summand:
#: |omega_{i,gamma}| (tau_i sum_l |F_{i,l}| + M_i tau_i^2 (|alpha_i| + |omega_i|^2 / 2)).
#: For translational generalized speeds omega_{i,gamma} = 0 and the slack vanishes.
corrected_bound_element_term = _s["w_g"] * (
    _s["tau"] * _s["F_abs_sum"] + _s["M"] * _s["tau"] ** 2 * (_s["wdot"] + _s["w_abs"] ** 2 / 2)
)

#: Eq. (13): L_sup = ReLU(S - B) with S = sum of Eq. (11) summands, B = sum of bound summands.
loss_sup = sp.Max(0, _s["S"] - _s["B"])
#: Eq. (14): L_inf = ReLU(-S - B).
loss_inf = sp.Max(0, -_s["S"] - _s["B"])
#: Eq. (15): L_cst = L_sup + L_inf.
loss_cst = loss_sup + loss_inf

_TERM_ARGS = {
    "eq11_term": (("F_g", "M", "v_next", "v", "delta", "u_g"), eq11_element_term),
    "paper_bound_term": (("tau", "R_norm", "w_g", "M", "wdot"), paper_bound_element_term),
    "corrected_bound_term": (("w_g", "tau", "F_abs_sum", "M", "wdot", "w_abs"), corrected_bound_element_term),
    "loss_sup": (("S", "B"), loss_sup),
    "loss_inf": (("S", "B"), loss_inf),
    "loss_cst": (("S", "B"), loss_cst),
}


@lru_cache(maxsize=4)
def loss_functions(backend: str = "numpy") -> dict:
    """Generated functions of the loss expressions, by name.

    Parameters
    ----------
    backend : {"numpy", "torch", "casadi"}

    Returns
    -------
    dict name -> (arg_names, function). Names: ``eq11_term``, ``paper_bound_term``,
    ``corrected_bound_term`` (element-wise; sum them per graph and gamma), ``loss_sup``,
    ``loss_inf``, ``loss_cst`` (of the sums ``S`` and ``B``).
    """
    from kane import codegen

    gen = {"numpy": codegen.to_numpy, "torch": codegen.to_torch, "casadi": codegen.to_casadi}.get(backend)
    if gen is None:
        raise ValueError(f"backend must be numpy, torch or casadi, got {backend!r}")
    return {k: (names, gen([_s[n] for n in names], expr)) for k, (names, expr) in _TERM_ARGS.items()}


# ---------------------------------------------------------------------------------------
# Numeric Kane terms of element sets.
# ---------------------------------------------------------------------------------------


def _cross(a, b):
    return np.cross(a, b)


@dataclass(frozen=True)
class ElementKinematics:
    """World-frame kinematics of the elements of one rigid body at one instant.

    Shapes: n elements, L_i point masses in element i.

    Attributes
    ----------
    centroid : [n, 3] element centroids, m
    velocity : [n, 3] centroid velocities, m/s
    acceleration : [n, 3] centroid accelerations, m/s^2
    offsets : list of [L_i, 3] world-frame r_{i,l}, m
    point_acc : list of [L_i, 3] accelerations of the point masses, m/s^2
    omega, alpha : [3] body angular velocity (rad/s) and acceleration (rad/s^2)
    inertia : [n, 3, 3] world-frame element inertia about the centroid, kg m^2
    """

    centroid: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    offsets: list
    point_acc: list
    omega: np.ndarray
    alpha: np.ndarray
    inertia: np.ndarray


def element_kinematics(elements: list[Element], rot, origin, v_origin, a_origin, omega, alpha) -> ElementKinematics:
    """Rigid-body kinematics of every element and point mass (world frame).

    ``x_l = x_O + R p_l``; ``v = v_O + omega x r``; ``a = a_O + alpha x r + omega x (omega x r)``
    for a body-fixed point at world offset ``r`` from the body-frame origin O.

    Parameters
    ----------
    rot : [3, 3] body-to-world rotation; origin, v_origin, a_origin : [3] body-frame origin
    position (m), velocity (m/s), acceleration (m/s^2); omega, alpha : [3] world (rad/s, rad/s^2).
    """
    R = np.asarray(rot, float)
    w = np.asarray(omega, float)
    al = np.asarray(alpha, float)

    def acc(r):
        return a_origin + _cross(al, r) + _cross(w, _cross(w, r))

    cs = np.array([R @ e.centroid for e in elements])  # offsets of centroids from O, world
    centroid = origin + cs
    velocity = v_origin + _cross(w, cs)
    acceleration = acc(cs)
    offsets = [e.offsets @ R.T for e in elements]
    point_acc = [acceleration[i] + _cross(al, r) + _cross(w, _cross(w, r)) for i, r in enumerate(offsets)]
    inertia = np.array([R @ e.inertia @ R.T for e in elements])
    return ElementKinematics(centroid, velocity, acceleration, offsets, point_acc, w, al, inertia)


@dataclass(frozen=True)
class ElementLoads:
    """Loads on the elements, world frame.

    Attributes
    ----------
    point_forces : list of [L_i, 3]
        F_{i,l}, force on each point mass (e.g. gravity m_{i,l} g), N.
    extra_points : list of [P_i, 3] or None
        World positions of further load points of element i (e.g. contact points), m.
    extra_forces : list of [P_i, 3] or None
        Forces at those points, N.
    couples : [n, 3] or None
        Pure couples on each element (e.g. a motor's reaction torque), N m.
    """

    point_forces: list
    extra_points: list | None = None
    extra_forces: list | None = None
    couples: np.ndarray | None = None


@dataclass(frozen=True)
class KaneTerms:
    """Per-element, per-speed Kane terms (n elements, d speeds).

    Attributes
    ----------
    R : [n, 3] resultants (Eq. 20); Mc : [n, 3] moments about the centroids;
    Lstar : [n, 3] inertia torques L*_i (Eq. 19); mass : [n]; tau : [n];
    K : [d] generalized active forces, element form (Eq. 17);
    K_points : [d] the same from point masses directly (Eq. 16);
    Kstar : [d] generalized inertia forces, element form (Eq. 19);
    Kstar_points : [d] the same from point masses (Eq. 18);
    psi : [d] disturbance term (Eq. 29);
    F_abs_sum : [n] sum_l |F_{i,l}| including extra loads, N;
    force_moment_bound : [n] tau_i sum_l |F_{i,l}| (couples counted as |C| / tau_i... see code), N m.
    """

    R: np.ndarray
    Mc: np.ndarray
    Lstar: np.ndarray
    mass: np.ndarray
    tau: np.ndarray
    K: np.ndarray
    K_points: np.ndarray
    Kstar: np.ndarray
    Kstar_points: np.ndarray
    psi: np.ndarray
    F_abs_sum: np.ndarray
    moment_bound: np.ndarray


def kane_terms(elements: list[Element], kin: ElementKinematics, loads: ElementLoads, u_partial, w_partial) -> KaneTerms:
    """Kane terms of an element set, by elements (Eqs. 17, 19, 29) and by point masses (Eqs. 16, 18).

    Parameters
    ----------
    u_partial : [n, d, 3]
        Partial velocities of the element centroids u_{i,gamma}.
    w_partial : [n, d, 3]
        Partial angular velocities omega_{i,gamma}.
    """
    n = len(elements)
    u_partial = np.asarray(u_partial, float)
    w_partial = np.asarray(w_partial, float)
    d = u_partial.shape[1]
    R = np.zeros((n, 3))
    Mc = np.zeros((n, 3))
    Lstar = np.zeros((n, 3))
    F_abs = np.zeros(n)
    mom_bound = np.zeros(n)
    K_pts = np.zeros(d)
    Ks_pts = np.zeros(d)
    for i, e in enumerate(elements):
        r = kin.offsets[i]
        F = np.asarray(loads.point_forces[i], float)
        # point-mass partial velocities u_{i,l,gamma} = u_{i,gamma} + omega_{i,gamma} x r_{i,l}: [L, d, 3]
        u_l = u_partial[i][None] + np.cross(w_partial[i][None], r[:, None, :])
        K_pts += np.einsum("lk,ldk->d", F, u_l)  # Eq. (16)
        ma = e.masses[:, None] * kin.point_acc[i]
        Ks_pts += -np.einsum("lk,ldk->d", ma, u_l)  # Eq. (18)
        R[i] = F.sum(0)
        Mc[i] = np.cross(r, F).sum(0)
        F_abs[i] = np.linalg.norm(F, axis=1).sum()
        mom_bound[i] = (np.linalg.norm(r, axis=1) * np.linalg.norm(F, axis=1)).sum()
        if loads.extra_points is not None and loads.extra_points[i] is not None and len(loads.extra_points[i]):
            rp = np.asarray(loads.extra_points[i], float) - kin.centroid[i]
            Fp = np.asarray(loads.extra_forces[i], float)
            u_p = u_partial[i][None] + np.cross(w_partial[i][None], rp[:, None, :])
            K_pts += np.einsum("lk,ldk->d", Fp, u_p)
            R[i] += Fp.sum(0)
            Mc[i] += np.cross(rp, Fp).sum(0)
            F_abs[i] += np.linalg.norm(Fp, axis=1).sum()
            mom_bound[i] += (np.linalg.norm(rp, axis=1) * np.linalg.norm(Fp, axis=1)).sum()
        if loads.couples is not None:
            C = np.asarray(loads.couples[i], float)
            K_pts += w_partial[i] @ C
            Mc[i] += C
            mom_bound[i] += np.linalg.norm(C)
        Lstar[i] = np.cross(r, ma).sum(0)  # Eq. (19): sum_l r_{i,l} x m_{i,l} a_{i,l}
    mass = np.array([e.mass for e in elements])
    tau = np.array([e.tau for e in elements])
    K = np.einsum("ik,idk->d", R, u_partial) + np.einsum("ik,idk->d", Mc, w_partial)  # Eq. (17)
    Kstar = -np.einsum("i,ik,idk->d", mass, kin.acceleration, u_partial) - np.einsum("ik,idk->d", Lstar, w_partial)
    psi = np.einsum("ik,idk->d", Mc - Lstar, w_partial)  # Eq. (29)
    return KaneTerms(R, Mc, Lstar, mass, tau, K, K_pts, Kstar, Ks_pts, psi, F_abs, mom_bound)


def free_body_partials(kin: ElementKinematics, com) -> tuple[np.ndarray, np.ndarray]:
    """Partial velocities of a free rigid body with speeds (v_com in world axes, omega in world axes).

    u_{i,gamma} = e_gamma (gamma < 3) or e_{gamma-3} x (c_i - com) (gamma >= 3);
    omega_{i,gamma} = 0 (gamma < 3) or e_{gamma-3}. Shapes [n, 6, 3] each.
    """
    n = kin.centroid.shape[0]
    eye = np.eye(3)
    p = kin.centroid - np.asarray(com, float)
    u = np.zeros((n, 6, 3))
    w = np.zeros((n, 6, 3))
    u[:, :3, :] = eye[None]
    u[:, 3:, :] = np.cross(eye[None, :, :], p[:, None, :])
    w[:, 3:, :] = eye[None]
    return u, w


# ---------------------------------------------------------------------------------------
# Symbolic identities of one generic element (proof route of Eqs. 17, 19 and the
# inertia-torque identity used by Eq. 35).
# ---------------------------------------------------------------------------------------


def symbolic_element_identities(n_points: int = 3) -> dict[str, sp.Expr]:
    """Residuals (should simplify to 0) of the element identities, for generic symbols.

    One element with ``n_points`` point masses ``m_l`` at centroid offsets ``r_l`` (the last
    offset eliminated by ``sum_l m_l r_l = 0``), generic forces ``F_l``, partial velocity
    ``u``, partial angular velocity ``w``, rigid kinematics (``a``, ``omega``, ``alpha``).

    Returns
    -------
    dict with ``eq17`` (sum_l F_l . (u + w x r_l) - R . u - M . w), ``eq19``
    (sum_l -m_l a_l . (u + w x r_l) + M a . u + L* . w) and ``Lstar`` (L* - I alpha - omega x I omega),
    each a list of 3 components or a scalar, already passed through ``sympy.expand``.
    """
    V = sp.Matrix

    def vec(name):
        return V(sp.symbols(f"{name}_x {name}_y {name}_z", real=True))

    m = sp.symbols(f"m_1:{n_points + 1}", positive=True)
    r = [vec(f"r{l}") for l in range(1, n_points)]
    r.append(-sum((m[l] * r[l] for l in range(n_points - 1)), V([0, 0, 0])) / m[-1])
    F = [vec(f"F{l}") for l in range(1, n_points + 1)]
    u, w, a, om, al = vec("u"), vec("w"), vec("a"), vec("omega"), vec("alpha")
    M = sum(m)
    R = sum(F, V([0, 0, 0]))
    Mc = sum((r[l].cross(F[l]) for l in range(n_points)), V([0, 0, 0]))
    acc = [a + al.cross(r[l]) + om.cross(om.cross(r[l])) for l in range(n_points)]
    Ls = sum((r[l].cross(m[l] * acc[l]) for l in range(n_points)), V([0, 0, 0]))
    I = sum((m[l] * ((r[l].T * r[l])[0] * sp.eye(3) - r[l] * r[l].T) for l in range(n_points)), sp.zeros(3))
    lhs17 = sum(F[l].dot(u + w.cross(r[l])) for l in range(n_points))
    lhs19 = sum((-m[l] * acc[l]).dot(u + w.cross(r[l])) for l in range(n_points))
    return {
        "eq17": sp.simplify(sp.expand(lhs17 - (R.dot(u) + Mc.dot(w)))),
        "eq19": sp.simplify(sp.expand(lhs19 - (-M * a.dot(u) - Ls.dot(w)))),
        "Lstar": [sp.simplify(sp.expand(c)) for c in (Ls - I * al - om.cross(I * om))],
    }

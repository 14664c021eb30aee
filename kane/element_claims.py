"""The inequalities of Appendix A.2 on one element, as sympy expressions of generic point masses.

One element with ``L`` point masses ``m_l`` at centroid offsets ``r_l`` (``sum_l m_l r_l = 0``),
external point forces ``F_l``, rigid motion (``omega``, ``alpha``) and, WLOG, the rotational
generalized speed about ``e_z`` (partial angular velocity ``omega_{i,gamma} = e_z``, unit
value ``omega_gamma = 1``). Each claim is a *margin* ``lhs - rhs`` that the claim says is
``<= 0``; the CasADi route maximises it, the hypothesis route samples it, and the counterexample
replay evaluates its two sides from MuJoCo's and Pinocchio's quantities.

Readings where the paper is ambiguous (recorded as assumptions of every check):

* ``I_i w'_i`` of Eq. (35) is read as ``|I_i alpha_i|`` (the torque needed for ``alpha``).
* ``w'_i`` of Eqs. (12), (36), (37) is ``|alpha_i|``; ``omega_gamma`` is ``|omega_{i,gamma}|``.
* ``R_i`` is the resultant of the external point forces (Eq. 20).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import sympy as sp

__all__ = ["ElementModel", "element_model", "MARGINS", "margin_expression"]

N_POINTS = 4  # generic point masses per element in the symbolic model


@dataclass(frozen=True)
class ElementModel:
    """Symbols and derived sympy quantities of one generic element."""

    m: tuple  # [L] masses
    r: tuple  # [L] 3-vectors (Matrix) offsets
    F: tuple  # [L] 3-vectors forces
    omega: sp.Matrix
    alpha: sp.Matrix
    tau: sp.Symbol
    M: sp.Expr
    R: sp.Matrix
    Mc: sp.Matrix
    I: sp.Matrix
    Lstar: sp.Matrix
    psi: sp.Expr  # Eq. (29) for the rotational speed about e_z
    args: tuple  # flat argument list for generated functions: m, r, F, omega, alpha, tau


def _norm(v: sp.Matrix) -> sp.Expr:
    return sp.sqrt(v.dot(v))


@lru_cache(maxsize=2)
def element_model(n_points: int = N_POINTS) -> ElementModel:
    """Build the generic element (cached)."""
    m = tuple(sp.symbols(f"m_1:{n_points + 1}", positive=True))
    r = tuple(sp.Matrix(sp.symbols(f"r_{l}_x r_{l}_y r_{l}_z", real=True)) for l in range(1, n_points + 1))
    F = tuple(sp.Matrix(sp.symbols(f"F_{l}_x F_{l}_y F_{l}_z", real=True)) for l in range(1, n_points + 1))
    omega = sp.Matrix(sp.symbols("omega_x omega_y omega_z", real=True))
    alpha = sp.Matrix(sp.symbols("alpha_x alpha_y alpha_z", real=True))
    tau = sp.Symbol("tau", positive=True)
    zero = sp.zeros(3, 1)
    M = sum(m)
    R = sum(F, zero)  # Eq. (20)
    Mc = sum((r[l].cross(F[l]) for l in range(n_points)), zero)
    I = sum((m[l] * ((r[l].T * r[l])[0] * sp.eye(3) - r[l] * r[l].T) for l in range(n_points)), sp.zeros(3))
    # L*_i = I alpha + omega x I omega (identity proven by kane.terms.symbolic_element_identities)
    Lstar = I * alpha + omega.cross(I * omega)
    psi = Mc[2] - Lstar[2]  # Eq. (29), omega_{i,gamma} = e_z
    args = (*m, *[c for v in r for c in v], *[c for v in F for c in v], *omega, *alpha, tau)
    return ElementModel(m, r, F, omega, alpha, tau, M, R, Mc, I, Lstar, psi, args)


def _margins(e: ElementModel) -> dict[str, sp.Expr]:
    tau, M = e.tau, e.M
    F_abs = sum(_norm(f) for f in e.F)
    a_abs, w_abs = _norm(e.alpha), _norm(e.omega)
    return {
        # Eq. (34), upper side (the lower side is the same with F -> -F)
        "eq34": e.Mc[2] - tau * _norm(e.R),
        "eq34.corrected": e.Mc[2] - tau * F_abs,
        # Eq. (35)
        "eq35": e.Lstar[2] - _norm(e.I * e.alpha),
        "eq35.corrected": e.Lstar[2] - (_norm(e.I * e.alpha) + M * tau**2 * w_abs**2 / 2),
        # Eq. (36): moment of inertia about the axis e_z vs the sphere of radius tau
        "eq36": e.I[2, 2] - sp.Rational(2, 5) * M * tau**2,
        "eq36.corrected": e.I[2, 2] - M * tau**2,
        # Eq. (37)
        "eq37": e.Lstar[2] - sp.Rational(2, 5) * M * tau**2 * a_abs,
        "eq37.corrected": e.Lstar[2] - M * tau**2 * (a_abs + w_abs**2 / 2),
        # Eq. (12), upper side, rotational generalized speed, external loads
        "eq12": e.psi - (tau * _norm(e.R) + sp.Rational(2, 5) * M * tau**2 * a_abs),
        "eq12.corrected": e.psi - (tau * F_abs + M * tau**2 * (a_abs + w_abs**2 / 2)),
    }


#: claim id -> sympy margin (claim says margin <= 0), for the generic element.
MARGINS: dict[str, sp.Expr] = {}


def margin_expression(claim_id: str) -> sp.Expr:
    """The sympy margin ``lhs - rhs`` of an Appendix A.2 inequality (or its corrected form)."""
    if not MARGINS:
        MARGINS.update(_margins(element_model()))
    return MARGINS[claim_id]

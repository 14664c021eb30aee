"""The paper's claims (Section 3, Appendix A), their corrected statements, and the checks that decide them.

Every claim has a stable id (``eq3`` ... ``eq15``); a refuted claim links to a corrected
statement ``<id>.corrected`` that is checked by the same routes. :func:`run_checks` runs
the checks and returns :class:`kane.results.CheckResult` records; verdicts come only from
comparing a measured residual with a stated tolerance (:func:`kane.results.decide`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import sympy as sp

from kane import adversarial, terms
from kane.element_claims import element_model, margin_expression
from kane.results import CheckResult, Route, decide

__all__ = ["Claim", "CLAIMS", "build_claims", "CheckSpec", "CHECKS", "run_checks", "claim_ids", "case_names"]


@dataclass(frozen=True)
class Claim:
    """One claim of the paper, or a corrected statement of one.

    ``expression()`` returns the sympy object the checks evaluate; ``latex()`` renders it.
    """

    id: str
    title: str
    statement: str
    equation: str
    expression: Callable[[], object] = field(repr=False, default=lambda: None)
    corrected_id: str | None = None
    #: (key, text) per clause: the parts of a corrected statement, or the settings in which a
    #: paper claim is tried; every check names one key (``CheckSpec.clause``) and the verdict's
    #: scope line reads "<verdict> for <text>" per clause. Empty: one clause, :data:`EVERY_CASE`.
    clauses: tuple = ()

    def clause_list(self) -> list[tuple[str, str]]:
        """The clauses, ``[("", EVERY_CASE)]`` for a single-clause claim."""
        return list(self.clauses) or [("", EVERY_CASE)]

    def latex(self) -> str:
        """LaTeX of the verified sympy expression (``<= 0`` for margins)."""
        e = self.expression()
        if e is None:
            return ""
        if isinstance(e, sp.Basic) and not isinstance(e, sp.core.relational.Relational):
            return sp.latex(e) + r" \le 0" if self.id in _MARGIN_CLAIMS else sp.latex(e)
        return sp.latex(e)


EVERY_CASE = "every case tried"

_MARGIN_CLAIMS = {c for base in ("eq34", "eq35", "eq36", "eq37", "eq12") for c in (base, base + ".corrected")}
_S = terms.LOSS_SYMBOLS


def _psi_scaling(corrected: bool):
    e = element_model()
    s = sp.Symbol("s", positive=True)
    sub = {c: s * c for v in e.r for c in v}
    psi_s = e.psi.xreplace(sub)
    if corrected:  # Psi(s r) = s * (moment term) - s^2 * (inertia term)
        return sp.expand(psi_s - (s * e.Mc[2] - s**2 * e.Lstar[2]))
    return sp.expand(psi_s - s * e.psi)  # proportionality: Psi(s r) = s Psi(r)


def _identity(kind: str):
    """Display form of the element identities whose difference ``symbolic_element_identities`` proves zero."""
    l, i = sp.symbols("l i", integer=True)
    Lp = sp.Symbol("L_i", integer=True)
    F, r, m, a = (sp.IndexedBase(x) for x in ("F", "r", "m", "a"))
    u, w = sp.Symbol(r"\vec{u}_{i,\gamma}", commutative=False), sp.Symbol(r"\vec{\omega}_{i,\gamma}", commutative=False)
    R, Mm, Ls = (sp.Symbol(x, commutative=False) for x in (r"\vec{R}_i", r"\vec{M}_i", r"\vec{L}^*_i"))
    M, ai = sp.Symbol("M_i"), sp.Symbol(r"\vec{a}_i", commutative=False)
    cross = sp.Function("cross")
    dot = sp.Function("dot")
    if kind == "eq17":
        return sp.Eq(sp.Sum(dot(F[l], u + cross(w, r[l])), (l, 1, Lp)), dot(R, u) + dot(Mm, w))
    return sp.Eq(sp.Sum(dot(-m[l] * a[l], u + cross(w, r[l])), (l, 1, Lp)), -M * dot(ai, u) - dot(Ls, w))


def _eq11_expr(translational: bool = False):
    i, n = sp.symbols("i n", integer=True)
    Fi, Mi, vn, v = (sp.IndexedBase(x) for x in ("F_gamma", "M", "v_next", "v"))
    term = terms.eq11_element_term.xreplace({_S["F_g"]: Fi[i], _S["M"]: Mi[i], _S["v_next"]: vn[i], _S["v"]: v[i]})
    if translational:
        return sp.Eq(sp.Sum(term, (i, 1, n)), 0)
    return sp.Eq(sp.Sum(term, (i, 1, n)) + sp.Symbol("Psi"), 0)


def _eq12_expr(corrected: bool):
    i, n = sp.symbols("i n", integer=True)
    expr = terms.corrected_bound_element_term if corrected else terms.paper_bound_element_term
    idx = {k: sp.IndexedBase(str(v))[i] for k, v in _S.items() if k in ("M", "R_norm", "wdot", "F_abs_sum", "w_abs")}
    if corrected:
        idx["tau"] = sp.IndexedBase("tau")[i]
        idx["w_g"] = sp.IndexedBase("w_g")[i]
    body = expr.xreplace({_S[k]: v for k, v in idx.items()})
    return sp.Le(sp.Abs(sp.Symbol("Psi")), sp.Sum(body, (i, 1, n)))



_ROT = ("rot", "rotational speeds")
_POINT4 = (("", "a rotational speed of a generic element of 4 point masses"),)


def build_claims() -> dict[str, Claim]:
    """Every claim of the paper this toolkit checks, and each corrected statement, by id (:data:`CLAIMS`)."""
    C = [
        Claim("eq3", "Kane's equation", "K_gamma + K*_gamma = 0 for every generalized speed gamma.", "(3)",
              lambda: sp.Eq(sp.Symbol("K_gamma") + sp.Symbol("K^*_gamma"), 0)),
        Claim("lemmaA1", "elements give the same EOM", "Dividing rigid bodies into elements of point masses gives the same equations of motion as the undivided system.", "Lemma A.1"),
        Claim("eq17", "K_gamma as element sum", "K_gamma = sum_i R_i . u_{i,gamma} + M_i . omega_{i,gamma}.", "(17)",
              lambda: _identity("eq17")),
        Claim("eq19", "K*_gamma as element sum", "K*_gamma = -sum_i M_i a_i . u_{i,gamma} - L*_i . omega_{i,gamma}.", "(19)",
              lambda: _identity("eq19")),
        Claim("eq23", "one-hot partial velocities", "The partial velocity of every element centroid w.r.t. every independent speed is a one-hot vector.", "(22)-(23)",
              lambda: sp.Eq(sp.Symbol(r"\vec{u}'_{i,\gamma}"), sp.Symbol(r"\vec{e}_\gamma")), "eq23.corrected",
              (("rot", "rotational and joint speeds"), ("trans", "the world-axis translational speeds of a free base"))),
        Claim("eq23.corrected", "one-hot exactly for world-axis translations of a base carrying every element",
              "At any configuration, u_{i,gamma} = +-e_k (the same k for every element i) and omega_{i,gamma} = 0 "
              "if and only if gamma is the speed of a translation along a world coordinate axis by a joint that carries "
              "every element: (a) such speeds (MuJoCo's free-joint qvel[0:3], which are world axes; a slide joint whose axis "
              "is a world axis) are one-hot; (b) no other speed is: rotations, joints of a subtree, and translations along "
              "non-coordinate or body-fixed axes (Pinocchio's free-flyer velocity is in the body frame, one-hot only while "
              "the base is axis-aligned).", "(23)*",
              lambda: sp.And(sp.Eq(sp.Symbol(r"\vec{u}'_{i,\gamma}"), sp.Symbol(r"\vec{e}_\gamma")),
                             sp.Eq(sp.Symbol(r"\vec{\omega}_{i,\gamma}"), 0)), None,
              (("a", "(a) world-axis translations of a joint carrying every element are one-hot"),
               ("b", "(b) no other speed is one-hot (rotations, subtree joints, oblique or body-frame axes)"))),
        Claim("eq11", "Theorem 3.1", "sum_i F_{gamma,i} - sum_i M_i (v_gamma^{t+1} - v_gamma^t)/delta + Psi = 0 for every independent speed gamma.", "(11)",
              _eq11_expr, "eq11.corrected",
              (_ROT, ("trans", "translational speeds (Psi = 0) of a single free body centred on its joint origin (Euler)"),
               ("fd", "translational speeds of off-centre or articulated bodies (Euler, O(delta)) or with contact (RK4)"))),
        Claim("eq11.corrected", "Newton's law for translational speeds; when the forward difference is exact",
              "For the world-axis translational speeds gamma of a free base carrying every body (Eq. 23*), omega_{i,gamma} = 0, "
              "so Psi = 0 and (a) sum_i F_{gamma,i} = sum_i M_i a_{gamma,i} exactly with the elements' true accelerations "
              "(single, off-centre and articulated free bodies, with contact). With the forward difference "
              "(v^{t+1} - v^t)/delta for a on MuJoCo data: (b) semi-implicit Euler is exact to round-off for a single free "
              "rigid body whose joint origin is its centre of mass, with or without contact; (c) Euler leaves a residual "
              "that shrinks like delta, nonzero while the body spins, when the joint origin is off the centre of mass or "
              "the body is articulated; (d) RK4 is exact to "
              "round-off without contact (gravity only), off-centre and articulated bodies included; (e) RK4 with contact is "
              "not exact, and its residual, made at contact onset, does not shrink like delta.", "(11)*",
              lambda: _eq11_expr(True), None,
              (("a", "(a) Newton exact with true accelerations"),
               ("b", "(b) Euler forward difference exact for a centred single free body"),
               ("c", "(c) Euler forward difference O(delta), nonzero, for spinning off-centre or articulated bodies"),
               ("d", "(d) RK4 forward difference exact without contact"),
               ("e", "(e) RK4 forward difference with contact not exact, not O(delta)"))),
        Claim("eq30", "Psi proportional to radii", "Psi is proportional to sum_i sum_l |r_{i,l}|.", "(30)",
              lambda: _psi_scaling(False), "eq30.corrected"),
        Claim("eq30.corrected", "Psi = s (moment term) - s^2 (inertia term) under r -> s r",
              "Under scaling r -> s r of the elements, Psi = s (moment term) - s^2 (inertia term): linear plus quadratic, vanishing as tau -> 0.", "(30)*",
              lambda: sp.Eq(sp.Function("Psi")(sp.Symbol("s") * sp.Symbol("r")),
                            sp.Symbol("s") * sp.Symbol("M_z") - sp.Symbol("s") ** 2 * sp.Symbol("L^*_z"))),
        Claim("eq15", "L_cst = 0 on ground truth", "The constraint loss L_sup + L_inf of Eqs. (13)-(15) is zero on exact ground-truth data.", "(15)",
              lambda: sp.Eq(sp.Symbol("L_cst"), terms.loss_cst), None,
              (("", "the paper's translational x, y, z constraints on a centred free body (Euler)"),)),
    ]
    ineq = {
        "eq34": ("moment of forces bound", "|sum_l (r_l x F_l) . omega_gamma| <= tau |R_i| omega_gamma.",
                 "moment of forces <= tau sum_l |F_l|",
                 "|sum_l (r_l x F_l) . omega_{i,gamma}| <= |omega_{i,gamma}| tau_i sum_l |F_l| (magnitudes summed, not the resultant).",
                 _POINT4, _POINT4),
        "eq35": ("inertia torque <= I w'", "sum_l (r_l x m_l a_l) . omega_gamma <= I_i w'_i.",
                 "inertia torque <= |I alpha| + M tau^2 |omega|^2/2 (gyroscopic term)",
                 "|L*_i . omega_{i,gamma}| <= |omega_{i,gamma}| (|I_i alpha_i| + M_i tau^2 |omega_i|^2 / 2) (gyroscopic term included).",
                 _POINT4, _POINT4),
        "eq36": ("I_i <= (2/5) m tau^2", "The element's moment of inertia is at most that of a solid sphere of radius tau: I_i <= (2/5) M_i tau^2.",
                 "I_i <= M_i tau^2 (tight: a ring); (1/3) M_i tau^2 for uniform solid boxes only",
                 "(a) I_i <= M_i tau^2 for any mass distribution within radius tau of the centroid, attained by a ring; "
                 "(b) a uniform solid (continuum) box has I_i <= (1/3) M_i tau^2; (c) boxes of point masses, the element model "
                 "of the paper and of partition_box, do not: 8 corner masses give (2/3) M_i tau^2 for a cube and flat cells "
                 "approach M_i tau^2.",
                 (("flat", "flat solids (a disc) and point-mass elements"), ("solid", "uniform solid boxes, tetrahedra and spheres")),
                 (("a", "(a) I <= M tau^2 for any distribution, attained by a ring"),
                  ("b", "(b) I <= (1/3) M tau^2 for uniform solid boxes"),
                  ("c", "(c) point-mass boxes reach (2/3) M tau^2 (cube) and approach M tau^2 (flat)"))),
        "eq37": ("inertia torque sphere bound", "|sum_l (r_l x m_l a_l) . omega_gamma| <= (2/5) M_i tau^2 w'_i.",
                 "inertia torque <= M tau^2 (|alpha| + |omega|^2/2)",
                 "|L*_i . omega_{i,gamma}| <= |omega_{i,gamma}| M_i tau^2 (|alpha_i| + |omega_i|^2 / 2).",
                 _POINT4, _POINT4),
        "eq12": ("Theorem 3.2", "|Psi| <= tau sum_i |R_i| omega_gamma + sum_i (2/5) M_i tau^2 w'_i.",
                 "|Psi| <= sum of force magnitudes and gyroscopic inertia terms; zero for translational speeds",
                 "(a) |Psi| <= sum_i |omega_{i,gamma}| (tau_i sum_l |F_{i,l}| + M_i tau_i^2 (|alpha_i| + |omega_i|^2/2)) for every "
                 "speed, with external loads in Psi; (b) for the world-axis translational speeds (Eq. 23*) omega_{i,gamma} = 0, "
                 "so Psi = 0 and the bound is 0: the constraint of Eqs. (13)-(15) becomes the equality of Eq. (11)*.",
                 (("rot", "rotational speeds, external loads only in Psi"),
                  ("internal", "rotational speeds with the inter-element forces in Psi (Psi = 0)"),
                  ("trans", "the translational speeds MDGS trains with (Psi = 0; true but loose)")),
                 (("a", "(a) the bound for rotational speeds"), ("b", "(b) Psi = 0 = bound for world-axis translational speeds"))),
    }
    for cid, (title, st, ctitle, corr, scope, cscope) in ineq.items():
        C.append(Claim(cid, title, st, f"({cid[2:]})", (lambda c=cid: margin_expression(c)), cid + ".corrected", scope))
        C.append(Claim(cid + ".corrected", ctitle, corr, f"({cid[2:]})*", (lambda c=cid: margin_expression(c + ".corrected")),
                       None, cscope))
    return {c.id: c for c in C}


CLAIMS: dict[str, Claim] = build_claims()
"""The claim registry: id -> :class:`Claim` (built once by :func:`build_claims`)."""


# ---------------------------------------------------------------------------------------
# Checks
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CheckSpec:
    """A check: which claim (and which of its clauses), on which case, by which route;
    ``quick`` marks the fast subset."""

    claim_id: str
    case: str
    route: str
    fn: Callable[..., CheckResult | list[CheckResult]]
    quick: bool = True
    clause: str = ""


CHECKS: list[CheckSpec] = []


def _check(claim_id: str, case: str, route: Route, quick: bool = True, clause: str = ""):
    def deco(fn):
        CHECKS.append(CheckSpec(claim_id, case, route.value, fn, quick, clause))
        return fn

    return deco


def _result(claim_id, case, route, residual, tol, assumptions, detail, counterexample=None, seconds=0.0):
    verdict = decide(float(residual), tol)
    corrected = CLAIMS[claim_id].corrected_id if claim_id in CLAIMS and verdict == "refuted" else None
    return CheckResult(claim_id, case, route.value if isinstance(route, Route) else route, verdict, float(residual), tol,
                       assumptions, counterexample if verdict == "refuted" else None, corrected, detail, seconds)


# --- symbolic identities (Eqs. 17, 19) ---------------------------------------------------

_GENERIC = {"element": "generic: 3 point masses, symbolic masses/offsets/forces", "speeds": "generic partial velocities u, omega",
            "forces": "arbitrary point forces"}


@_check("eq17", "generic element", Route.SYMBOLIC)
def _eq17_sym(**_):
    r = terms.symbolic_element_identities()["eq17"]
    return _result("eq17", "generic element", Route.SYMBOLIC, 0.0 if r == 0 else np.inf, 0.0, _GENERIC,
                   "sum_l F_l.(u + w x r_l) - R.u - M.w simplifies to 0")


@_check("eq19", "generic element", Route.SYMBOLIC)
def _eq19_sym(**_):
    ids = terms.symbolic_element_identities()
    ok = ids["eq19"] == 0 and all(c == 0 for c in ids["Lstar"])
    return _result("eq19", "generic element", Route.SYMBOLIC, 0.0 if ok else np.inf, 0.0,
                   {**_GENERIC, "centroid": "sum_l m_l r_l = 0 substituted"},
                   "Eq. (19) residual and L* - (I alpha + omega x I omega) simplify to 0")


# --- hypothesis: element vs point-mass forms; partition invariance (Lemma A.1) ------------

def _random_body(rng, k: int, jitter: float):
    from kane.elements import partition_box_k

    h = rng.uniform(0.05, 0.5, 3)
    return partition_box_k(h, k, mass=float(rng.uniform(0.5, 5)), points_per_axis=2, rng=rng, jitter=jitter)


def _random_terms(rng, els):
    from kane.elements import Element

    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    import mujoco

    Rm = np.zeros(9)
    mujoco.mju_quat2Mat(Rm, q)
    Rm = Rm.reshape(3, 3)
    w, al, v, a = (rng.standard_normal(3) for _ in range(4))
    whole = Element(np.concatenate([e.masses for e in els]), np.concatenate([e.points for e in els]))
    kin = terms.element_kinematics(els, Rm, rng.standard_normal(3), v, a, w, al)
    com = rng.standard_normal(3) * 0 + kin.centroid.T @ np.array([e.mass for e in els]) / whole.mass
    forces = [rng.standard_normal((len(e.masses), 3)) for e in els]
    u, wp = terms.free_body_partials(kin, com)
    t = terms.kane_terms(els, kin, terms.ElementLoads(forces), u, wp)
    kin1 = terms.element_kinematics([whole], Rm, np.zeros(3) + kin.centroid[0] * 0 + rng.standard_normal(3) * 0, v, a, w, al)
    return t, whole, kin, kin1


def _hyp_lemma(claim_id: str, quick: bool, seed: int):
    """Random bodies (k in 1, 2, 8, 27 elements, jittered masses), random motion and point forces."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    worst = {"r": 0.0, "n": 0, "cex": None}

    @settings(max_examples=30 if quick else 150, database=None, deadline=None, derandomize=True)
    @given(st.integers(0, 2**31 - 1), st.sampled_from([1, 2, 8, 27]), st.floats(0.0, 1.0))
    def prop(s, k, jitter):
        rng = np.random.default_rng(s + seed)
        els = _random_body(rng, k, jitter)
        t, whole, kin, _ = _random_terms(rng, els)
        if claim_id == "eq17":
            num, scale = np.abs(t.K - t.K_points).max(), np.abs(t.K_points).max() + 1
        elif claim_id == "eq19":
            num, scale = np.abs(t.Kstar - t.Kstar_points).max(), np.abs(t.Kstar_points).max() + 1
        else:  # lemmaA1: generalized inertia force of the elements == that of the undivided body
            from kane import terms as T

            kin_w = T.element_kinematics([whole], np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
            del kin_w
            num, scale = np.abs(t.Kstar - t.Kstar_points).max(), np.abs(t.Kstar_points).max() + 1
        rel = num / scale
        worst["n"] += 1
        if rel > worst["r"]:
            worst.update(r=rel, cex={"seed": int(s + seed), "k": int(k), "jitter": float(jitter)})

    prop()
    return worst


@_check("eq17", "random bodies, k=1..27 elements", Route.HYPOTHESIS)
def _eq17_hyp(quick=True, seed=0, **_):
    w = _hyp_lemma("eq17", quick, seed)
    return _result("eq17", "random bodies, k=1..27 elements", Route.HYPOTHESIS, w["r"], 1e-12,
                   {"speeds": "free body: v_com (3) + omega (3), world", "elements": "box cells, jittered point masses",
                    "forces": "random point forces", "examples": w["n"]}, "Eq. (17) element form vs Eq. (16) point form", w["cex"])


@_check("eq19", "random bodies, k=1..27 elements", Route.HYPOTHESIS)
def _eq19_hyp(quick=True, seed=0, **_):
    w = _hyp_lemma("eq19", quick, seed)
    return _result("eq19", "random bodies, k=1..27 elements", Route.HYPOTHESIS, w["r"], 1e-12,
                   {"speeds": "free body: v_com (3) + omega (3), world", "elements": "box cells, jittered point masses",
                    "motion": "random omega, alpha, a", "examples": w["n"]}, "Eq. (19) element form vs Eq. (18) point form", w["cex"])


# --- Appendix A.2 inequalities: CasADi and hypothesis -------------------------------------

_ELEMENT_ASSUMPTIONS = {
    "element": "4 point masses, masses in [0.05, 2] kg, offsets within tau of the centroid",
    "speed": "rotational generalized speed (omega_{i,gamma} = e_z, omega_gamma = 1)",
    "forces": "external point forces |F_l| <= 1 N (no inter-element forces)",
    "motion": "|omega| <= 1 rad/s, |alpha| <= 1 rad/s^2 (element embedded in a larger rigid body)",
    "readings": "I_i w'_i := |I_i alpha_i|; w'_i := |alpha_i|; R_i := resultant of external point forces",
    "margin": "relative: (lhs - rhs) / (tau sum|F| + M tau^2 (|alpha| + |omega|^2 + 1))",
}


def _ineq_casadi(cid: str):
    def fn(quick=True, seed=0, **_):
        v, s = adversarial.casadi_search(cid, seed=seed, n_starts=2 if quick else 6)
        cex = {"claim_id": cid, "kind": "element", "sample": s.to_dict()} if s is not None else None
        return _result(cid, "generic element", Route.CASADI, v, adversarial.REL_TOL, _ELEMENT_ASSUMPTIONS,
                       "ipopt maximum of (lhs - rhs)", cex)

    return fn


def _ineq_hyp(cid: str):
    def fn(quick=True, seed=0, **_):
        v, s, n = adversarial.hypothesis_search(cid, seed=seed, max_examples=100 if quick else 400)
        cex = {"claim_id": cid, "kind": "element", "sample": s.to_dict()} if s is not None else None
        return _result(cid, "generic element", Route.HYPOTHESIS, v, adversarial.REL_TOL,
                       {**_ELEMENT_ASSUMPTIONS, "examples": n}, "largest (lhs - rhs) found; shrunk example kept", cex)

    return fn


_GENERIC_CLAUSE = {"eq36": "flat", "eq36.corrected": "a", "eq12": "rot", "eq12.corrected": "a"}
for _cid in ("eq34", "eq35", "eq36", "eq37", "eq12"):
    for _c in (_cid, _cid + ".corrected"):
        _k = _GENERIC_CLAUSE.get(_c, "")
        CHECKS.append(CheckSpec(_c, "generic element", Route.CASADI.value, _ineq_casadi(_c), True, _k))
        CHECKS.append(CheckSpec(_c, "generic element", Route.HYPOTHESIS.value, _ineq_hyp(_c), False, _k))


# --- Eq. (30): proportionality of Psi to the radii ------------------------------------------

def _eq30(corrected: bool):
    def fn(seed=0, **_):
        cid = "eq30.corrected" if corrected else "eq30"
        expr = _psi_scaling(corrected)
        zero = sp.simplify(expr) == 0
        cex = None
        resid = 0.0
        if not zero:
            e = element_model()
            s = sp.Symbol("s", positive=True)
            rng = np.random.default_rng(seed)
            smp = adversarial.Sample(np.full(4, 0.5), adversarial.centred(np.full(4, 0.5), rng.uniform(-1, 1, (4, 3))),
                                     rng.uniform(-1, 1, (4, 3)), rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3))
            f = sp.lambdify([*e.args, s], expr)
            psi = sp.lambdify(list(e.args), e.psi)
            resid = abs(float(f(*smp.flat(), 2.0))) / (abs(float(psi(*smp.flat()))) + 1e-300)
            cex = {"claim_id": cid, "kind": "scaling", "sample": smp.to_dict(), "s": 2.0,
                   "note": "Psi(2 r) / Psi(r) differs from 2"}
        return _result(cid, "generic element", Route.SYMBOLIC, resid, 1e-12,
                       {"element": "4 symbolic point masses", "scaling": "r_{i,l} -> s r_{i,l}, forces and motion fixed"},
                       "Psi(s r) - s Psi(r) simplifies to 0" if zero else "Psi(s r) - s Psi(r) is not identically 0 (relative value at s=2 shown)",
                       cex)

    return fn


CHECKS.append(CheckSpec("eq30", "generic element", Route.SYMBOLIC.value, _eq30(False), True))
CHECKS.append(CheckSpec("eq30.corrected", "generic element", Route.SYMBOLIC.value, _eq30(True), True))


# --- Eq. (23): one-hot partial velocities (MuJoCo and Pinocchio Jacobians) -------------------

_ONEHOT_SEEN = 1e-9  # a speed "looks one-hot" when its deviation is below this (round-off ~1e-16)


def _onehot_rows(m, d, els, condition) -> list[tuple[int, bool, float]]:
    """(dof, the statement's condition, deviation from one-hot) for every dof of a MuJoCo model."""
    from kane import cases

    u, w = cases.mujoco_partials(m, d, els)
    return [(g, bool(condition(m, d, g, els)), cases.onehot_deviation(u[g], w[g])) for g in range(m.nv)]


def _mj_model(xml: str, qpos=None):
    import mujoco

    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    if qpos is not None:
        d.qpos[:] = qpos
    mujoco.mj_forward(m, d)
    els = [b for b in range(1, m.nbody) if m.body(b).name.startswith("e")]
    return m, d, els


def _free_box_rotated():
    from kane.mjscene import BoxBodySpec, box_body_mjcf

    q = np.array([0.9, 0.2, -0.3, 0.25])
    q /= np.linalg.norm(q)
    return _mj_model(box_body_mjcf(BoxBodySpec(quat0=tuple(q))))


_EQ23_CASES = {
    "free box, 8 elements, rotated": _free_box_rotated,
    "joint chain: slides along x and (1,1,0), hinges, a subtree slide": lambda: _mj_model(
        __import__("kane.cases", fromlist=["x"]).joint_zoo_mjcf(), [0.1, 0.2, 0.3, 0.4, 0.05]),
}


def _clause_residual(rows, clause: str):
    """Clause (a): largest deviation over the dofs that meet the condition; clause (b): number
    of dofs outside the condition that look one-hot. Returns (residual, tolerance, cex row)."""
    if clause == "a":
        hits = [(dev, g) for g, cond, dev in rows if cond]
        worst = max(hits, default=(0.0, None))
        return worst[0], 1e-12, worst[1], len(hits)
    bad = [g for g, cond, dev in rows if not cond and dev <= _ONEHOT_SEEN]
    return float(len(bad)), 0.0, (bad[0] if bad else None), sum(not c for _, c, _ in rows)


def _eq23_corrected(case: str, clause: str, condition=None):
    """Eq. (23)* clause (a) or (b) on a MuJoCo model; ``condition`` defaults to the statement's
    :func:`kane.cases.world_axis_translation` (a test passes a broken one to see the check fail)."""

    def fn(**_):
        from kane import cases

        m, d, els = _EQ23_CASES[case]()
        rows = _onehot_rows(m, d, els, condition or cases.world_axis_translation)
        r, tol, g, n = _clause_residual(rows, clause)
        cex = None if g is None else {"claim_id": "eq23.corrected", "kind": "jacobian", "case": case, "dof": int(g),
                                      "deviation": float(dict((k, dv) for k, _, dv in rows)[g])}
        what = ("largest deviation from one-hot over the speeds that meet the condition" if clause == "a"
                else "number of speeds outside the condition whose partial velocities look one-hot (deviation <= 1e-9)")
        return _result("eq23.corrected", case, Route.MUJOCO, r, tol,
                       {"speeds": f"{n} of {m.nv} dofs " + ("meet" if clause == "a" else "fail") + " the condition",
                        "condition": "translation along a world coordinate axis by a joint carrying every element (model structure)",
                        "source": "mujoco.mj_jac at element centroids"}, what, cex)

    return fn


def _eq23(clause: str):
    def fn(**_):
        m, d, els = _free_box_rotated()
        rows = _onehot_rows(m, d, els, lambda *_: True)
        dofs = range(3) if clause == "trans" else range(3, 6)  # MuJoCo free joint: 0-2 world translations, 3-5 rotations
        worst = max((rows[g][2], g) for g in dofs)
        cex = {"claim_id": "eq23", "kind": "jacobian", "case": "free box, 8 elements, rotated", "dof": int(worst[1]),
               "deviation": float(worst[0])}
        return _result("eq23", "free box, 8 elements, rotated", Route.MUJOCO, worst[0], 1e-12,
                       {"speeds": "MuJoCo free joint " + ("translational dofs (world axes)" if clause == "trans" else "rotational dofs"),
                        "source": "mujoco.mj_jac at element centroids"},
                       "largest deviation of a partial velocity from one-hot (or of omega_{i,gamma} from 0)", cex)

    return fn


def _eq23_pinocchio(clause: str):
    """Pinocchio's free flyer: its translational speeds are the body-frame linear velocity, so
    their partial velocities are the base's axes in the world: one-hot while the base is
    axis-aligned (clause a), not once it is rotated (clause b); rotations never (clause b)."""

    def fn(**_):
        from kane import cases

        pts = np.array([[0.1, 0.05, -0.07], [-0.1, 0.2, 0.1], [0.05, -0.15, 0.2]])
        q = np.array([0.9, 0.2, -0.3, 0.25])
        q /= np.linalg.norm(q)
        from kane.mjscene import mat_from_quat

        rows = []
        for label, R in (("axis-aligned", np.eye(3)), ("rotated", mat_from_quat(q))):
            u, w = cases.pinocchio_partials(R, pts)
            for g in range(6):
                axis = R[:, g] if g < 3 else None  # the statement's condition: a world coordinate axis
                cond = axis is not None and abs(np.abs(axis).max() - 1.0) < cases.ONEHOT_TOL
                rows.append((f"{label} base, speed {g}", cond, cases.onehot_deviation(u[g], w[g])))
        r, tol, g, n = _clause_residual(rows, clause)
        cex = None if g is None else {"claim_id": "eq23.corrected", "kind": "jacobian", "case": "pinocchio free flyer", "speed": g}
        return _result("eq23.corrected", "Pinocchio free flyer (body-frame speeds), axis-aligned and rotated base", Route.PINOCCHIO,
                       r, tol, {"speeds": f"{n} of 12 (6 speeds x 2 orientations) " + ("meet" if clause == "a" else "fail") + " the condition",
                                "source": "pinocchio.getFrameJacobian(LOCAL_WORLD_ALIGNED) at 3 points"},
                       "clause (a): largest deviation where the condition holds; (b): speeds outside it that look one-hot", cex)

    return fn


def _eq23_hyp(clause: str):
    """Random trees of 1-4 bodies on random slide/hinge/ball/free joints at random configurations."""

    def fn(quick=True, seed=0, **_):
        import mujoco
        from hypothesis import given, settings
        from hypothesis import strategies as st

        from kane import cases

        worst = {"r": 0.0, "n": 0, "dofs": 0, "cex": None}

        @settings(max_examples=25 if quick else 120, database=None, deadline=None, derandomize=True)
        @given(st.integers(0, 2**31 - 1), st.integers(1, 4))
        def prop(s, nb):
            rng = np.random.default_rng(s + seed)
            xml = cases.random_tree_mjcf(rng, nb)
            m = mujoco.MjModel.from_xml_string(xml)
            d = mujoco.MjData(m)
            d.qpos[:] = m.qpos0 + 0.0
            for j in range(m.njnt):  # random configuration: slides and hinges move, balls/free stay valid
                if m.jnt_type[j] in (mujoco.mjtJoint.mjJNT_SLIDE, mujoco.mjtJoint.mjJNT_HINGE):
                    d.qpos[m.jnt_qposadr[j]] = rng.uniform(-1, 1)
            mujoco.mj_forward(m, d)
            els = list(range(1, m.nbody))
            rows = _onehot_rows(m, d, els, cases.world_axis_translation)
            r, _, g, n = _clause_residual(rows, clause)
            worst["n"] += 1
            worst["dofs"] += n
            if r > worst["r"]:
                worst.update(r=r, cex={"claim_id": "eq23.corrected", "kind": "jacobian", "seed": int(s + seed), "bodies": int(nb),
                                       "dof": int(g), "mjcf": xml})

        prop()
        tol = 1e-12 if clause == "a" else 0.0
        return _result("eq23.corrected", "random trees of 1-4 bodies, random joints and configurations", Route.HYPOTHESIS,
                       worst["r"], tol, {"examples": worst["n"], "speeds tried": worst["dofs"],
                                         "joints": "free, slide (coordinate or random axis), hinge, ball; root unrotated half the time"},
                       "clause (a): largest deviation where the condition holds; (b): largest count of other speeds that look one-hot",
                       worst["cex"])

    return fn


CHECKS.append(CheckSpec("eq23", "free box, 8 elements, rotated", Route.MUJOCO.value, _eq23("rot"), True, "rot"))
CHECKS.append(CheckSpec("eq23", "free box, 8 elements, rotated", Route.MUJOCO.value, _eq23("trans"), True, "trans"))
for _case in _EQ23_CASES:
    for _k in ("a", "b"):
        CHECKS.append(CheckSpec("eq23.corrected", _case, Route.MUJOCO.value, _eq23_corrected(_case, _k), True, _k))
for _k in ("a", "b"):
    CHECKS.append(CheckSpec("eq23.corrected", "Pinocchio free flyer (body-frame speeds), axis-aligned and rotated base",
                            Route.PINOCCHIO.value, _eq23_pinocchio(_k), True, _k))
    CHECKS.append(CheckSpec("eq23.corrected", "random trees of 1-4 bodies, random joints and configurations",
                            Route.HYPOTHESIS.value, _eq23_hyp(_k), False, _k))


# --- Eq. (11), Eq. (15), Eq. (12) along MuJoCo trajectories ---------------------------------

_TRAJ_CASES = {
    "free box in gravity, spinning": dict(floor=False, half_extents=(0.1, 0.15, 0.25), divisions=(2, 1, 1),
                                          omega0=(1.0, 2.0, 3.0)),
    "box striking a plane": dict(floor=True, half_extents=(0.1, 0.15, 0.25), height=0.4, v0=(0.5, 0.0, -1.0),
                                 omega0=(0.5, 2.0, 0.0)),
}


_TOL_NOTE = ("1e-10 relative (double precision) without contact; 1e-5 with contact: on rare frames MuJoCo's "
             "efc_force and qacc disagree by ~4e-7 of the force scale (solver iterate), measured independently of kane")


def _tol(case: str) -> float:
    return 1e-5 if _TRAJ_CASES[case].get("floor") else 1e-10


@lru_cache(maxsize=16)
def _traj(case: str, integrator: str = "Euler", steps: int = 600):
    from kane.mjscene import BoxBodySpec, simulate_elements

    return simulate_elements(BoxBodySpec(integrator=integrator, **_TRAJ_CASES[case]), steps)


def _eq11_sides(tr, translational: bool):
    """Eq. (11) per frame and speed (world axes): ``(F, Ma, psi, S, scale)``, [T-1, 3] each but the
    scale: ``F = sum_i F_{gamma,i}`` (the paper's reading for a rotational speed:
    ``R_i . e_gamma``), ``Ma = sum_i M_i (v' - v)_gamma / delta``, the disturbance ``psi``
    (0 for translational speeds; else ``sum_i (M_i - L*_i) . e_gamma``), the generated
    ``eq11_term`` summed over elements ``S = F - Ma`` and the force scale ``max_t sum |F|``. The
    claim reads ``F + psi = Ma``; its residual is ``|S + psi| / scale``."""
    eq11_term = terms.loss_functions("numpy")["eq11_term"][1]  # F_{gamma,i} u - M_i (v' - v) u / delta
    S = eq11_term(tr.force[:-1], tr.mass[None, :, None], tr.v[1:], tr.v[:-1], tr.dt, 1.0).sum(1)  # [T-1, 3]
    scale = np.abs(tr.force[:-1]).sum((1, 2)).max() + 1e-300
    F = tr.force[:-1].sum(1)
    if translational:
        return F, F - S, np.zeros_like(S), S, scale  # Psi = 0: omega_{i,gamma} = 0
    # rotational speeds, the paper's reading: F_{gamma,i} = R_i . e_gamma, Psi = sum_i (M_i - L*_i) . e_gamma
    I = tr.inertia[:-1]
    Ls = np.einsum("tnab,tb->tna", I, tr.alpha[:-1]) + np.cross(tr.omega[:-1, None, :], np.einsum("tnab,tb->tna", I, tr.omega[:-1]))
    psi = (tr.moment[:-1] - Ls).sum(1)
    return F, F - S, psi, S, scale


def _eq11_residuals(tr, translational: bool):
    """Eq. (11) residual per frame and speed (world axes), relative to the force scale."""
    _, _, psi, S, scale = _eq11_sides(tr, translational)
    return np.abs(S) / scale if translational else np.abs(S + psi) / scale


def _eq11(case: str, translational: bool, integrator: str = "Euler", corrected: bool = False):
    label = case if integrator == "Euler" else f"{case} ({integrator})"

    def fn(quick=True, **_):
        cid = "eq11.corrected" if corrected else "eq11"
        steps = 300 if quick else 800
        tr = _traj(case, integrator, steps)
        r = _eq11_residuals(tr, translational)
        t, g = np.unravel_index(np.argmax(r), r.shape)
        tol = _tol(case)
        cex = {"claim_id": cid, "kind": "trajectory", "case": label, "integrator": integrator, "frame": int(t), "gamma": int(g),
               "translational": translational, "steps": steps}
        return _result(cid, label, Route.MUJOCO, r.max(), tol,
                       {"speeds": "translational (x, y, z)" if translational else "rotational (about x, y, z)",
                        "integrator": integrator, "dt": tr.dt, "elements": "box cells (2x1x1 or 2x2x2), MuJoCo mass properties",
                        "forces": "gravity" + (" + contact (mj_contactForce)" if _TRAJ_CASES[case].get("floor") else ""),
                        "tolerance": _TOL_NOTE},
                       "largest |eq. (11) residual| / (sum |F|) over frames and speeds", cex)

    return fn


for _case in _TRAJ_CASES:
    CHECKS.append(CheckSpec("eq11.corrected", _case, Route.MUJOCO.value, _eq11(_case, True, corrected=True), True, "b"))
    CHECKS.append(CheckSpec("eq11", _case, Route.MUJOCO.value, _eq11(_case, False), _case.startswith("free"), "rot"))
    CHECKS.append(CheckSpec("eq11", _case, Route.MUJOCO.value, _eq11(_case, True), _case.startswith("free"), "trans"))
CHECKS.append(CheckSpec("eq11", "box striking a plane (RK4)", Route.MUJOCO.value,
                        _eq11("box striking a plane", True, "RK4"), False, "fd"))


# --- Eq. (11)*: true accelerations, off-centre and articulated bodies, Euler vs RK4 ---------

def _free_cases():
    from kane.cases import OFFSET, FreeSystem

    return {
        "free box, joint origin offset (0.1, 0.05, -0.07) m from its centre of mass": FreeSystem(offset=OFFSET),
        "free box with a hinged flap (articulated)": FreeSystem(flap=True),
        "box striking a plane": FreeSystem(floor=True, height=0.4, v0=(0.5, 0.0, -1.0), omega0=(0.5, 2.0, 0.0)),
    }


_FREE_NAMES = list(_free_cases())
_OFF, _FLAP, _PLANE = _FREE_NAMES
_ORDER_TOL = 0.1  # |p - 1| of the fitted order: the O(delta^2) term shifts p by ~delta/T_dyn ~ 1e-3 here
_EXACT_FLOOR = 1e-8  # a residual below this is round-off (exact), not an O(delta) term


def _fs_assumptions(s, **extra):
    return {"system": "box 0.2 x 0.3 x 0.5 m in 2 cells" + (" + hinged flap" if s.flap else ""),
            "joint origin to centre of mass": "offset " + str(tuple(s.offset)) + " m (body frame)" if any(s.offset) else "at the box's centre of mass",
            "speeds": "translational x, y, z (MuJoCo free joint, world axes)", "forces": "gravity" + (" + contact" if s.floor else ""),
            "integrator": s.integrator, "tolerance": _TOL_NOTE if s.floor else "1e-10 relative (double precision)", **extra}


def _eq11_fs(case: str, clause: str, integrator: str = "Euler", cid: str = "eq11.corrected"):
    """Eq. (11) translational on a :class:`kane.cases.FreeSystem`: clause ``a`` true accelerations;
    ``d`` (or ``fd``) forward differences at delta = 1e-3; ``c``/``e`` fitted order over 3 deltas."""
    from dataclasses import replace

    label = case + ("" if integrator == "Euler" else f" ({integrator})")

    def fn(quick=True, **_):
        from kane import cases

        s = replace(_free_cases()[case], integrator=integrator)
        dur = 0.3 if quick else 0.6
        cex = {"claim_id": cid, "kind": "trajectory", "case": label, "integrator": integrator}
        if clause in ("c", "e"):
            p, dts, res = cases.observed_order(s, dur)
            if clause == "c":  # O(delta): a first-order residual, not round-off
                r, tol = (abs(p - 1.0) if min(res) > _EXACT_FLOOR else np.inf), _ORDER_TOL
                what = "|p - 1|, p the fitted order of the forward-difference residual r ~ delta^p"
            else:  # not exact and not shrinking like delta
                r, tol = (p if min(res) > 1e-3 else np.inf), 0.5
                what = "fitted order p of the residual (<= 0.5: not shrinking like delta; every r > 1e-3: not exact)"
            return _result(cid, label, Route.MUJOCO, r, tol,
                           _fs_assumptions(s, deltas=dts, residuals=[float(f"{x:.4g}") for x in res], order=round(p, 4)),
                           what, {**cex, "deltas": dts, "residuals": res})
        true_acc = clause == "a"
        r, t, g = cases.eq11_translational(cases.record(s, dur), true_acc=true_acc, where=True)
        cex.update(frame=t, gamma=g, translational=True, duration=dur, true_acc=true_acc)
        tol = 1e-5 if s.floor else 1e-10
        what = ("largest |sum F - sum M a| / sum|F| with MuJoCo's true centroid accelerations (mj_objectAcceleration)" if true_acc
                else "largest |eq. (11) residual| / sum|F| with (v^{t+1} - v^t)/delta, delta = 1e-3")
        return _result(cid, label, Route.MUJOCO, r, tol, _fs_assumptions(s, delta=s.dt), what, cex)

    return fn


for _case in (_OFF, _FLAP, _PLANE):
    CHECKS.append(CheckSpec("eq11.corrected", _case, Route.MUJOCO.value, _eq11_fs(_case, "a"), _case != _PLANE, "a"))
for _case in (_OFF, _FLAP):
    CHECKS.append(CheckSpec("eq11.corrected", _case, Route.MUJOCO.value, _eq11_fs(_case, "c"), True, "c"))
    CHECKS.append(CheckSpec("eq11.corrected", _case + " (RK4)", Route.MUJOCO.value, _eq11_fs(_case, "d", "RK4"), True, "d"))
    CHECKS.append(CheckSpec("eq11", _case, Route.MUJOCO.value, _eq11_fs(_case, "d", cid="eq11"), _case == _OFF, "fd"))
CHECKS.append(CheckSpec("eq11.corrected", "box striking a plane (RK4)", Route.MUJOCO.value, _eq11_fs(_PLANE, "e", "RK4"), True, "e"))


_AXES = "xyz"


def counterexample_sides(cex: dict) -> tuple[list, list] | None:
    """Both sides of Eq. (11) or Eq. (23) at a recorded ``trajectory`` or ``jacobian``
    counterexample, re-evaluated by the very functions the check used: ``(context, sides)``,
    ``context`` a list of (name, value) saying where, ``sides`` a list of
    :class:`kane.engines.Side`. ``None`` for counterexamples that record no single point
    (fitted orders, random systems, Pinocchio speeds, reports written before frames were recorded).

    * Eq. (23), a MuJoCo case: the partial velocity ``u'_{i,gamma}`` of the element whose
      deviation is largest against the nearest one-hot ``+-e_k``, and its partial angular
      velocity against 0; the largest entry of ``|lhs - rhs|`` is the check's deviation.
    * Eq. (11): ``sum_i F_{gamma,i} + Psi_gamma`` against ``sum_i M_i a_{gamma,i}`` at the
      recorded frame and speed; ``|lhs - rhs| / scale`` is the check's residual.
    """
    from kane import cases
    from kane.engines import Side

    kind = cex.get("kind")
    if kind == "jacobian" and cex.get("case") in _EQ23_CASES and "dof" in cex:
        m, d, els = _EQ23_CASES[cex["case"]]()
        g = int(cex["dof"])
        u, w = cases.mujoco_partials(m, d, els)
        k = cases.nearest_onehot(u[g])
        i = int(np.argmax(cases.onehot_deviation(u[g], w[g], per_element=True)))
        rhs = np.zeros(3)
        rhs[k] = 1.0 if u[g, i, k] >= 0 else -1.0
        e = f"{'+' if rhs[k] > 0 else '-'}e_{_AXES[k]}"
        context = [("case", cex["case"], ""), ("speed (MuJoCo dof)", g, ""),
                   ("element with the largest deviation", f"{i} of {len(els)}", ""), ("nearest one-hot vector", e, "")]
        sides = [Side("partial_velocity", f"u'_(i,gamma) of element {i}", e, u[g, i].copy(), rhs, u[g, i] - rhs, 1.0, "|e_k|"),
                 Side("partial_angular_velocity", f"omega_(i,gamma) of element {i}", "0", w[g, i].copy(), np.zeros(3), w[g, i].copy(),
                      1.0, "|e_k|")]
        return context, sides
    if kind != "trajectory" or "frame" not in cex or "gamma" not in cex or not cex.get("claim_id", "").startswith("eq11"):
        return None
    t, g, integrator = int(cex["frame"]), int(cex["gamma"]), cex.get("integrator", "Euler")
    base = cex["case"].removesuffix(f" ({integrator})")
    translational = bool(cex.get("translational", True))
    if "duration" in cex and base in _FREE_NAMES:
        from dataclasses import replace

        s = replace(_free_cases()[base], integrator=integrator)
        F, Ma, S, scale = cases.eq11_sides(cases.record(s, float(cex["duration"])), bool(cex.get("true_acc", False)))
        psi, dt, frames = 0.0, s.dt, f"{float(cex['duration']):g} s"
    elif "steps" in cex and base in _TRAJ_CASES:
        tr = _traj(base, integrator, int(cex["steps"]))
        F, Ma, P, S, scale = _eq11_sides(tr, translational)
        psi, dt, frames = float(P[t, g]), tr.dt, f"{int(cex['steps'])} steps"
    else:
        return None
    speed = (f"translation along {_AXES[g]}" if translational else f"rotation about {_AXES[g]}")
    acc = "true accelerations" if cex.get("true_acc") else "(v^{t+1} - v^t)/delta"
    context = [("case", cex["case"], ""), ("integrator", integrator, ""), ("delta", dt, "s"), ("recorded", frames, ""), ("frame", t, ""),
               ("time", t * dt, "s"), ("speed gamma", f"{g}, {speed}", "")]
    if not translational:  # the left side is sum_i F_(gamma,i) + Psi_gamma: both parts
        context += [("sum_i F_(gamma,i)", float(F[t, g]), "N"), ("Psi_gamma", psi, "N m")]
    lhs = "sum_i F_(gamma,i)" + ("" if translational else " + Psi_gamma")
    sides = [Side("force_balance", lhs, f"sum_i M_i a_(gamma,i), a = {acc}", float(F[t, g] + psi), float(Ma[t, g]),
                  float(S[t, g] + psi), float(scale), "max_t sum_i |F_i|", "N" if translational else "")]
    return context, sides


def _eq11_hyp(clause: str):
    """Random free systems: box size, cells, offset, flap, initial motion (clause a, b, c or d)."""

    def fn(quick=True, seed=0, **_):
        from hypothesis import given, settings
        from hypothesis import strategies as st

        from kane import cases

        worst = {"r": -np.inf, "n": 0, "cex": None}
        fl = st.floats(-1.0, 1.0)

        @settings(max_examples=8 if quick else 25, database=None, deadline=None, derandomize=True)
        @given(st.tuples(st.floats(0.05, 0.3), st.floats(0.05, 0.3), st.floats(0.05, 0.3)), st.sampled_from([(1, 1, 1), (2, 1, 1), (2, 2, 1)]),
               st.tuples(fl, fl, fl), st.booleans(), st.tuples(fl, fl, fl), st.tuples(fl, fl, fl))
        def prop(h, div, off, flap, w0, v0):
            off = np.asarray(off) * 0.2
            if clause == "b":
                off, flap = np.zeros(3), False  # the clause's condition: a centred single body
            if clause == "c" and not flap and np.linalg.norm(off) < 0.02:
                off = np.array([0.02, 0.0, 0.0])  # the clause's condition: off-centre (or articulated)
            if clause == "c" and np.linalg.norm(w0) < 0.2:
                w0 = (0.2, 0.0, 0.0)  # ... and spinning
            s = cases.FreeSystem(half_extents=h, divisions=div, offset=tuple(off), flap=flap, omega0=tuple(4 * np.asarray(w0)),
                                 v0=v0, integrator="RK4" if clause == "d" else "Euler")
            if clause == "c":  # at most first order: p >= 1 - tol where the residual is not round-off
                p, _, res = cases.observed_order(s, 0.1)
                r = 1.0 - p if min(res) > _EXACT_FLOOR else 0.0
            else:
                r = cases.eq11_translational(cases.record(s, 0.1), true_acc=clause == "a")
            worst["n"] += 1
            if r > worst["r"]:
                worst.update(r=r, cex={"claim_id": "eq11.corrected", "kind": "trajectory", "half_extents": list(h), "divisions": list(div),
                                       "offset": off.tolist(), "flap": bool(flap), "omega0": list(s.omega0), "v0": list(v0),
                                       "integrator": s.integrator})

        prop()
        tol = _ORDER_TOL if clause == "c" else 1e-10
        return _result("eq11.corrected", "random free systems (size, cells, offset, flap, motion)", Route.HYPOTHESIS, worst["r"], tol,
                       {"examples": worst["n"], "duration": "0.1 s at delta = 1e-3 (and 5e-4, 2.5e-4 for the order)",
                        "clause condition": {"a": "any", "b": "centred single body, Euler", "c": "off-centre or flap, Euler",
                                             "d": "any, RK4, no contact"}[clause]},
                       {"a": "largest Newton residual with true accelerations", "b": "largest Euler forward-difference residual",
                        "c": "largest 1 - p of the fitted order p (the residual shrinks at least like delta)", "d": "largest RK4 forward-difference residual"}[clause], worst["cex"])

    return fn


for _k in ("a", "b", "c", "d"):
    CHECKS.append(CheckSpec("eq11.corrected", "random free systems (size, cells, offset, flap, motion)", Route.HYPOTHESIS.value,
                            _eq11_hyp(_k), False, _k))


def _eq15(case: str, bound: str):
    def fn(quick=True, **_):
        tr = _traj(case, "Euler", 300 if quick else 800)
        f = terms.loss_functions("numpy")
        T = tr.v.shape[0] - 1
        worst = 0.0
        for g in range(3):  # translational x, y, z (Appendix B.1.2)
            e11 = f["eq11_term"][1](tr.force[:-1, :, g], tr.mass[None, :], tr.v[1:, :, g], tr.v[:-1, :, g], tr.dt, 1.0)
            Rn = np.linalg.norm(tr.force[:-1], axis=2)
            wdot = np.linalg.norm(tr.alpha[:-1], axis=1)[:, None] * np.ones_like(Rn)
            if bound == "paper":
                # B.1.2 reading: omega_gamma := |omega| (largest angular velocity), the most generous slack
                wg = np.linalg.norm(tr.omega[:-1], axis=1)[:, None] * np.ones_like(Rn)
                b = f["paper_bound_term"][1](tr.tau[None, :], Rn, wg, tr.mass[None, :], wdot)
            else:
                wabs = np.linalg.norm(tr.omega[:-1], axis=1)[:, None] * np.ones_like(Rn)
                b = f["corrected_bound_term"][1](0.0, tr.tau[None, :], tr.force_abs[:-1], tr.mass[None, :], wdot, wabs)
            S, B = e11.sum(1), np.broadcast_to(b, e11.shape).sum(1)
            L = f["loss_cst"][1](S, B)
            worst = max(worst, float(np.max(L / (np.abs(tr.force[:-1]).sum((1, 2)) + 1e-300))))
        tol = _tol(case)
        return _result("eq15", case, Route.MUJOCO, worst, tol,
                       {"speeds": "translational x, y, z (Appendix B.1.2)", "bound": bound, "integrator": "Euler", "frames": T,
                        "forces": "true element resultants from MuJoCo", "evaluated": "kane.terms.loss_functions('numpy')"},
                       "largest L_cst / sum|F| over frames", None)

    return fn


for _case in _TRAJ_CASES:
    for _b in ("paper", "corrected"):
        CHECKS.append(CheckSpec("eq15", f"{_case} [{_b} bound]", Route.MUJOCO.value, _eq15(_case, _b), _b == "paper"))


def _eq12_traj(corrected: bool, internal: bool = False):
    """Cube spinning about its diagonal (torque-free, alpha = 0) split into 2 elements.

    ``internal``: include in Psi the moments of the forces between elements (MuJoCo's
    ``cfrc_int``), i.e. read F_{i,l} of Eq. (29) as *all* forces on the element's points.
    """

    def fn(quick=True, **_):
        from kane.mjscene import BoxBodySpec, simulate_elements

        cid = "eq12.corrected" if corrected else "eq12"
        w = 5.0 / np.sqrt(3)
        tr = simulate_elements(BoxBodySpec(divisions=(2, 1, 1), gravity=(0, 0, 0), omega0=(w, w, w)), 50)
        I = tr.inertia
        Ls = np.einsum("tnab,tb->tna", I, tr.alpha) + np.cross(tr.omega[:, None, :], np.einsum("tnab,tb->tna", I, tr.omega))
        moment = tr.moment + (tr.internal_moment if internal else 0.0)
        force = tr.force + (tr.internal_force if internal else 0.0)
        psi = (moment - Ls).sum(1)  # [T, 3]: rotational speeds about x, y, z (omega_{i,gamma} = e_gamma)
        a = np.linalg.norm(tr.alpha, axis=1)[:, None]
        f = terms.loss_functions("numpy")  # the bounds of Eq. (12) and its corrected form, one source
        if corrected:
            wabs = np.linalg.norm(tr.omega, axis=1)[:, None]
            rhs = f["corrected_bound_term"][1](1.0, tr.tau[None], tr.force_abs, tr.mass[None], a, wabs).sum(1)
        else:  # omega_gamma = |omega_{i,gamma}| = 1 for a rotational speed
            rhs = f["paper_bound_term"][1](tr.tau[None], np.linalg.norm(force, axis=2), 1.0, tr.mass[None], a).sum(1)
        scale = (tr.mass * tr.tau**2).sum() * (np.linalg.norm(tr.omega, axis=1).max() ** 2 + 1)
        margin = (np.abs(psi).max(1) - rhs) / scale
        t = int(np.argmax(margin))
        cex = {"claim_id": cid, "kind": "trajectory", "case": "cube spinning about its diagonal, 2 elements", "frame": t, "psi": psi[t].tolist(),
               "rhs": float(rhs[t]), "alpha": tr.alpha[t].tolist(), "omega": tr.omega[t].tolist()}
        case = "cube spinning about its diagonal, 2 elements" + (", inter-element forces in Psi" if internal else "")
        cex["case"] = case
        return _result(cid, case, Route.MUJOCO, margin.max(), 1e-9,
                       {"speeds": "rotational (about x, y, z)", "forces": "none (space)", "elements": "2 half-cubes, MuJoCo inertia",
                        "loads in Psi": ("external + inter-element forces (MuJoCo cfrc_int): each element then obeys Euler's "
                                         "equation and Psi = 0") if internal else "external loads only (Lemma A.1 wording)",
                        "alpha": "from MuJoCo (= 0 for a cube)"},
                       "largest (|Psi| - bound) / (sum M tau^2 (|omega|^2 + 1))", cex)

    return fn


CHECKS.append(CheckSpec("eq12", "cube spinning about its diagonal, 2 elements", Route.MUJOCO.value, _eq12_traj(False), True, "rot"))
CHECKS.append(CheckSpec("eq12.corrected", "cube spinning about its diagonal, 2 elements", Route.MUJOCO.value, _eq12_traj(True), True, "a"))
CHECKS.append(CheckSpec("eq12", "cube spinning about its diagonal, 2 elements, inter-element forces in Psi", Route.MUJOCO.value,
                        _eq12_traj(False, internal=True), True, "internal"))


def _eq12_translational(case: str, corrected: bool, dofs: tuple = (0, 1, 2)):
    """Eq. (12) for the translational speeds x, y, z along a MuJoCo trajectory: Psi of Eq. (29) with
    MuJoCo's partial angular velocities omega_{i,gamma} (mj_jac at each frame), against the
    paper's bound (B.1.2 reading omega_gamma := |omega|) or the corrected one (|omega_{i,gamma}|).
    ``dofs``: the free joint's dofs taken as the speeds (a test passes rotational ones)."""

    def fn(quick=True, **_):
        import mujoco

        from kane.mjscene import BoxBodySpec, box_body_mjcf, mat_from_quat

        cid = "eq12.corrected" if corrected else "eq12"
        steps = 300 if quick else 800
        spec = BoxBodySpec(**_TRAJ_CASES[case])
        tr = _traj(case, "Euler", steps)
        m = mujoco.MjModel.from_xml_string(box_body_mjcf(spec))
        d = mujoco.MjData(m)
        d.qvel[:3] = spec.v0
        d.qvel[3:6] = mat_from_quat(spec.quat0).T @ np.asarray(spec.omega0, float)
        els = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"e{i}") for i in range(len(tr.mass))]
        jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        f = terms.loss_functions("numpy")
        worst, slack = -np.inf, np.inf
        scale = np.abs(tr.force).sum((1, 2)).max()
        for t in range(steps):  # the same Euler steps as simulate_elements: the states agree frame by frame
            mujoco.mj_forward(m, d)
            wg = np.zeros((len(dofs), len(els), 3))  # [gamma, element, 3]: partial angular velocities
            for i, b in enumerate(els):
                mujoco.mj_jac(m, d, jp, jr, d.xipos[b], b)
                wg[:, i] = jr[:, list(dofs)].T
            I = tr.inertia[t]
            Ls = np.einsum("nab,b->na", I, tr.alpha[t]) + np.cross(tr.omega[t], np.einsum("nab,b->na", I, tr.omega[t]))
            psi = np.einsum("na,gna->g", tr.moment[t] - Ls, wg)
            a, wabs = np.linalg.norm(tr.alpha[t]), np.linalg.norm(tr.omega[t])
            if corrected:
                wgn = np.linalg.norm(wg, axis=2)  # |omega_{i,gamma}| [gamma, element]
                B = f["corrected_bound_term"][1](wgn, tr.tau[None], tr.force_abs[t][None], tr.mass[None], a, wabs).sum(1)
            else:
                B = f["paper_bound_term"][1](tr.tau[None], np.linalg.norm(tr.force[t], axis=1)[None], wabs, tr.mass[None], a).sum(1)
                B = np.broadcast_to(B, (len(dofs),))
            # corrected: Psi = 0 and B = 0 (zero slack); paper: |Psi| <= B
            r = (np.abs(psi).max() + np.abs(B).max()) if corrected else (np.abs(psi) - B).max()
            worst = max(worst, float(r) / scale)
            slack = min(slack, float(B.min()) / scale)
            mujoco.mj_Euler(m, d)
        tol = _tol(case)
        return _result(cid, case, Route.MUJOCO, worst, tol,
                       {"speeds": "translational x, y, z (MuJoCo free joint)", "omega_{i,gamma}": "mujoco.mj_jac at element centroids",
                        "loads in Psi": "external (gravity" + (" + contact)" if spec.floor else ")"), "integrator": "Euler", "frames": steps,
                        "bound": "corrected (|omega_{i,gamma}|)" if corrected else "paper's (omega_gamma := |omega|, B.1.2 reading)",
                        "tolerance": _TOL_NOTE},
                       ("largest (|Psi| + bound) / sum|F|: both vanish" if corrected else
                        f"largest (|Psi| - bound) / sum|F|; smallest slack bound / sum|F| = {slack:.3g} (true but loose)"), None)

    return fn


for _case in _TRAJ_CASES:
    CHECKS.append(CheckSpec("eq12", _case, Route.MUJOCO.value, _eq12_translational(_case, False), _case.startswith("free"), "trans"))
    CHECKS.append(CheckSpec("eq12.corrected", _case, Route.MUJOCO.value, _eq12_translational(_case, True), _case.startswith("free"), "b"))


def _eq36_disc(corrected: bool):
    def fn(**_):
        import mujoco

        cid = "eq36.corrected" if corrected else "eq36"
        Rr, hh = 0.05, 0.0025  # flywheel disc radius, half thickness (m)
        m = mujoco.MjModel.from_xml_string(
            f'<mujoco><worldbody><body><freejoint/><geom type="cylinder" size="{Rr} {hh}" density="7800"/></body></worldbody></mujoco>')
        mass, I = float(m.body_mass[1]), m.body_inertia[1].copy()
        tau = float(np.hypot(Rr, hh))
        rhs = (1.0 if corrected else 0.4) * mass * tau**2
        margin = (I.max() - rhs) / (mass * tau**2)
        cex = {"claim_id": cid, "kind": "mujoco_geom", "geom": "cylinder", "size": [Rr, hh], "density": 7800.0,
               "inertia": I.tolist(), "mass": mass, "tau": tau}
        return _result(cid, "flywheel disc element (MuJoCo cylinder)", Route.MUJOCO, margin, 1e-12,
                       {"element": "uniform solid disc, radius 5 cm, thickness 5 mm (a Cubli flywheel as one element)",
                        "source": "MuJoCo's own inertia of the geom"}, "(I_max - bound) / (M tau^2)", cex)

    return fn


CHECKS.append(CheckSpec("eq36", "flywheel disc element (MuJoCo cylinder)", Route.MUJOCO.value, _eq36_disc(False), True, "flat"))
CHECKS.append(CheckSpec("eq36.corrected", "flywheel disc element (MuJoCo cylinder)", Route.MUJOCO.value, _eq36_disc(True), True, "a"))


def _point_cell(h, points_per_axis: int = 2):
    """(masses, centred offsets) of one partition_box cell of half extents h."""
    from kane.elements import partition_box

    (e,) = partition_box(h, (1, 1, 1), mass=1.0, points_per_axis=points_per_axis)
    return e.masses, e.offsets


def _inertia_ratio_engines(masses, offsets) -> list[tuple[str, float]]:
    """I_zz / (M tau^2) of a point-mass element from MuJoCo and Pinocchio (kane.counterexamples replay)."""
    from kane.engines import replay_element

    cex = {"claim_id": "eq36.corrected", "kind": "element",
           "sample": {"masses": list(map(float, masses)), "offsets": np.asarray(offsets).tolist(),
                      "forces": np.zeros((len(masses), 3)).tolist(), "omega": [0, 0, 0], "alpha": [0, 0, 0]}}
    return [(eng, lhs / rhs) for eng, lhs, rhs in replay_element(cex).rows]  # rhs = M tau^2 for eq36.corrected


_POINT_CASES = {  # case -> (half extents, points per axis, target ratio I_zz / (M tau^2), reason of the tolerance)
    "8 corner masses of a cube cell (partition_box)": ((1.0, 1.0, 1.0), 2, 2 / 3),
    "8 corner masses of a flat cell 1 : 1 : 1e-4 (partition_box)": ((1.0, 1.0, 1e-4), 2, 1.0),
}
#: replay spheres of radius 1e-4 m add (2/5)(1e-4)^2 / tau^2 <= 8e-9 (tau >= 0.7 m); the flat
#: cell's ratio is below 1 by (c/2)^2 / tau^2 = 5e-9
_POINT_TOL = 1e-7


def _eq36_points(case: str, corrected: bool):
    def fn(**_):
        h, ppa, target = _POINT_CASES[case]
        masses, offs = _point_cell(h, ppa)
        ratios = _inertia_ratio_engines(masses, offs)
        cid = "eq36.corrected" if corrected else "eq36"
        cex = {"claim_id": cid, "kind": "element", "sample": {"masses": masses.tolist(), "offsets": offs.tolist(),
               "forces": np.zeros((len(masses), 3)).tolist(), "omega": [0, 0, 0], "alpha": [0, 0, 0]}}
        if corrected:  # clause (c): the ratio the statement names
            r = max(abs(x - target) for _, x in ratios)
            return _result(cid, case, Route.MUJOCO, r, _POINT_TOL,
                           {"element": f"{len(masses)} equal point masses at +-h/2 in a cell of half extents h = {tuple(h)} m",
                            "statement": f"I_zz / (M tau^2) = {target:.6g}", "engines": {e: round(x, 9) for e, x in ratios}},
                           "largest |I_zz / (M tau^2) - stated ratio| over MuJoCo and Pinocchio", None)
        r = max(x for _, x in ratios) - 0.4
        return _result(cid, case, Route.MUJOCO, r, 1e-12,
                       {"element": f"{len(masses)} equal point masses (the paper's element model)", "engines": {e: round(x, 9) for e, x in ratios}},
                       "I_zz / (M tau^2) - 2/5", cex)

    return fn


CHECKS.append(CheckSpec("eq36", list(_POINT_CASES)[0], Route.MUJOCO.value, _eq36_points(list(_POINT_CASES)[0], False), True, "flat"))
for _case in _POINT_CASES:
    CHECKS.append(CheckSpec("eq36.corrected", _case, Route.MUJOCO.value, _eq36_points(_case, True), True, "c"))


def _eq36_ring(**_):
    ring = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], float)
    ratios = _inertia_ratio_engines(np.ones(4), ring)
    return _result("eq36.corrected", "ring of 4 equal point masses (bound attained)", Route.MUJOCO, max(abs(x - 1) for _, x in ratios),
                   _POINT_TOL, {"element": "4 point masses on a circle of radius 1 m", "engines": {e: round(x, 9) for e, x in ratios}},
                   "|I_zz / (M tau^2) - 1|: the bound M tau^2 is attained", None)


CHECKS.append(CheckSpec("eq36.corrected", "ring of 4 equal point masses (bound attained)", Route.MUJOCO.value, _eq36_ring, True, "a"))


def _eq36_sphere(**_):
    from kane import cases

    r = cases.sphere_ratio(0.1) - 0.4
    return _result("eq36", "uniform solid sphere (MuJoCo)", Route.MUJOCO, r, 1e-12,
                   {"element": "uniform solid sphere of radius tau = 0.1 m", "source": "MuJoCo's geom inertia"},
                   "I / (M tau^2) - 2/5 (the sphere attains the paper's bound)", None)


CHECKS.append(CheckSpec("eq36", "uniform solid sphere (MuJoCo)", Route.MUJOCO.value, _eq36_sphere, True, "solid"))


def _eq36_solid_hyp(kind: str, k: float, cid: str, clause: str):
    """Hypothesis over uniform solid boxes (half extents) or tetrahedra (vertices): I_max / (M tau^2) - k."""

    def fn(quick=True, seed=0, **_):
        from hypothesis import assume, given, settings
        from hypothesis import strategies as st

        from kane import cases

        worst = {"r": -np.inf, "n": 0, "cex": None}
        side = st.floats(1e-3, 1.0)
        pt = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1))
        strat = st.tuples(side, side, side) if kind == "box" else st.tuples(pt, pt, pt, pt)

        @settings(max_examples=60 if quick else 300, database=None, deadline=None, derandomize=True)
        @given(strat)
        def prop(x):
            if kind == "box":
                ratio = cases.solid_box_ratio(x)
            else:
                v = np.asarray(x, float)
                assume(abs(np.linalg.det(v[1:] - v[0])) > 1e-3)  # a solid, not a degenerate sliver
                ratio = cases.tetra_ratio(v)
            worst["n"] += 1
            if ratio - k > worst["r"]:
                worst.update(r=ratio - k, cex={"claim_id": cid, "kind": "mujoco_solid", kind: np.asarray(x).tolist()})

        prop()
        case = "uniform solid boxes, random aspect ratios (MuJoCo)" if kind == "box" else "uniform solid tetrahedra, random vertices (MuJoCo)"
        return _result(cid, case, Route.HYPOTHESIS, worst["r"], 1e-12,
                       {"examples": worst["n"], "source": "MuJoCo's geom/mesh inertia", "tau": "largest distance from the mass centre to the solid's boundary",
                        "bound": f"{k:.6g} M tau^2"}, f"largest I_max / (M tau^2) - {k:.6g}", worst["cex"])

    return fn


CHECKS.append(CheckSpec("eq36", "uniform solid boxes, random aspect ratios (MuJoCo)", Route.HYPOTHESIS.value,
                        _eq36_solid_hyp("box", 0.4, "eq36", "solid"), True, "solid"))
CHECKS.append(CheckSpec("eq36", "uniform solid tetrahedra, random vertices (MuJoCo)", Route.HYPOTHESIS.value,
                        _eq36_solid_hyp("tetra", 0.4, "eq36", "solid"), False, "solid"))
CHECKS.append(CheckSpec("eq36.corrected", "uniform solid boxes, random aspect ratios (MuJoCo)", Route.HYPOTHESIS.value,
                        _eq36_solid_hyp("box", 1 / 3, "eq36.corrected", "b"), True, "b"))


def _eq36_casadi(which: str):
    """ipopt over half extents a, b, c in [1e-3, 1]: ``box`` maximises the continuum box ratio
    (sympy integral) minus 1/3 (clause b); ``corners`` maximises the ratio of 8 corner point
    masses (sympy sum over the points), which clause (c) says approaches 1 (and clause a: <= 1)."""

    def fn(quick=True, seed=0, **_):
        import casadi as ca

        from kane import cases, codegen

        if which == "box":
            args, expr = cases.continuum_box_ratio_expr()
        else:
            a, b, c = args = sp.symbols("a b c", positive=True)
            pts = [sp.Matrix([sx * a, sy * b, sz * c]) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
            expr = sum(p[0] ** 2 + p[1] ** 2 for p in pts) / (8 * pts[0].dot(pts[0]))  # M = 8; tau = |corner| (all equal)
        f = codegen.to_casadi(args, expr)
        rng = np.random.default_rng(seed)
        best, arg = -np.inf, None
        for _ in range(3 if quick else 8):
            opti = ca.Opti()
            x = opti.variable(3)
            opti.subject_to(opti.bounded(1e-3, x, 1.0))
            opti.minimize(-f(x[0], x[1], x[2]))
            opti.set_initial(x, rng.uniform(0.05, 1.0, 3))
            opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes", "max_iter": 300})
            try:
                sol = opti.solve()
                xv = np.asarray(sol.value(x)).ravel()
            except RuntimeError:
                xv = np.asarray(opti.debug.value(x)).ravel()
            v = float(f(*xv))
            if v > best:
                best, arg = v, xv
        if which == "box":
            return _result("eq36.corrected", "uniform solid box, any aspect ratio (sympy integral)", Route.CASADI, best - 1 / 3, 1e-9,
                           {"element": "continuum box, density 1, half extents in [1e-3, 1] m", "inertia": "sympy integral of x^2 + y^2 over the box",
                            "argmax": arg.tolist()}, "ipopt maximum of I_zz / (M tau^2) - 1/3", None)
        return _result("eq36.corrected", "8 corner point masses, any aspect ratio (sympy sum)", Route.CASADI, 1.0 - best, 1e-5,
                       {"element": "8 equal masses at (+-a, +-b, +-c), a, b, c in [1e-3, 1] m", "argmax": arg.tolist(),
                        "tolerance": "c >= 1e-3 keeps the ratio below 1 by up to (c/a)^2 / 2 = 5e-7"},
                       f"1 - ipopt maximum of I_zz / (M tau^2) (maximum {best:.9g}; clause a bounds it by 1)", None)

    return fn


CHECKS.append(CheckSpec("eq36.corrected", "uniform solid box, any aspect ratio (sympy integral)", Route.CASADI.value, _eq36_casadi("box"), True, "b"))
CHECKS.append(CheckSpec("eq36.corrected", "8 corner point masses, any aspect ratio (sympy sum)", Route.CASADI.value, _eq36_casadi("corners"), True, "c"))


# --- Eq. (3), Lemma A.1: analytic systems vs Pinocchio and MuJoCo (kane.crosscheck) -------

def _crosscheck(name: str):
    def fn(quick=True, **_):
        from kane import crosscheck

        return getattr(crosscheck, f"check_{name}")(quick=quick)

    return fn


CHECKS.append(CheckSpec("eq3", "analytic systems", "pinocchio+mujoco", _crosscheck("eq3"), True))
CHECKS.append(CheckSpec("lemmaA1", "partitioned box k=1,2,8,27", "pinocchio+mujoco", _crosscheck("lemmaA1"), True))


# ---------------------------------------------------------------------------------------


def claim_ids() -> list[str]:
    """Ids of all claims and corrected statements that have checks."""
    return sorted({c.claim_id for c in CHECKS})


def case_names() -> list[str]:
    """Names of all cases."""
    return sorted({c.case for c in CHECKS})


def run_checks(claim_ids: list[str] | None = None, cases: list[str] | None = None, quick: bool = False, seed: int = 0,
               on_progress: Callable[[int, int, str], None] | None = None) -> list[CheckResult]:
    """Run the selected checks.

    Parameters
    ----------
    claim_ids
        ids to run (a base id such as ``eq12`` also selects ``eq12.corrected``); None: all.
    cases
        case names (substring match); None: all.
    quick
        only the fast subset (and fewer examples/frames).
    seed
        seed of the adversarial searches.
    on_progress
        called as ``on_progress(done, total, label)`` after each check.

    Raises
    ------
    ValueError
        an unknown claim id or case.
    """
    specs = list(CHECKS)
    if claim_ids:
        known = set(claim_ids_all := [c.claim_id for c in CHECKS])
        for cid in claim_ids:
            if cid not in known and not any(k.startswith(cid + ".") for k in known):
                raise ValueError(f"unknown claim id {cid!r}; valid ids: {', '.join(sorted(set(claim_ids_all)))}")
        specs = [s for s in specs if s.claim_id in claim_ids or s.claim_id.split(".")[0] in claim_ids]
    if cases:
        for c in cases:
            if not any(c.lower() in s.case.lower() for s in CHECKS):
                raise ValueError(f"unknown case {c!r}; valid cases: {', '.join(case_names())}")
        specs = [s for s in specs if any(c.lower() in s.case.lower() for c in cases)]
    if quick:
        specs = [s for s in specs if s.quick]
    out: list[CheckResult] = []
    for k, s in enumerate(specs):
        t0 = time.perf_counter()
        try:
            res = s.fn(quick=quick, seed=seed)
            res = res if isinstance(res, list) else [res]
        except Exception as exc:  # an error is a verdict of its own: nothing was decided
            res = [CheckResult(s.claim_id, s.case, s.route, "error", float("nan"), float("nan"), {}, None, None,
                               f"{type(exc).__name__}: {exc}")]
        dt = time.perf_counter() - t0
        for r in res:
            out.append(CheckResult(**{**r.__dict__, "seconds": r.seconds or dt / len(res), "clause": r.clause or s.clause}))
        if on_progress:
            on_progress(k + 1, len(specs), f"{s.claim_id} / {s.case}")
    return out

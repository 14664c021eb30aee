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

import numpy as np
import sympy as sp

from kane import adversarial, terms
from kane.element_claims import element_model, margin_expression
from kane.results import CheckResult, Route, decide

__all__ = ["Claim", "CLAIMS", "CheckSpec", "CHECKS", "run_checks", "claim_ids", "case_names"]


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

    def latex(self) -> str:
        """LaTeX of the verified sympy expression (``<= 0`` for margins)."""
        e = self.expression()
        if e is None:
            return ""
        if isinstance(e, sp.Basic) and not isinstance(e, sp.core.relational.Relational):
            return sp.latex(e) + r" \le 0" if self.id in _MARGIN_CLAIMS else sp.latex(e)
        return sp.latex(e)


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


def _claims() -> dict[str, Claim]:
    C = [
        Claim("eq3", "Kane's equation", "K_gamma + K*_gamma = 0 for every generalized speed gamma.", "(3)",
              lambda: sp.Eq(sp.Symbol("K_gamma") + sp.Symbol("K^*_gamma"), 0)),
        Claim("lemmaA1", "elements give the same EOM", "Dividing rigid bodies into elements of point masses gives the same equations of motion as the undivided system.", "Lemma A.1"),
        Claim("eq17", "K_gamma as element sum", "K_gamma = sum_i R_i . u_{i,gamma} + M_i . omega_{i,gamma}.", "(17)",
              lambda: _identity("eq17")),
        Claim("eq19", "K*_gamma as element sum", "K*_gamma = -sum_i M_i a_i . u_{i,gamma} - L*_i . omega_{i,gamma}.", "(19)",
              lambda: _identity("eq19")),
        Claim("eq23", "one-hot partial velocities", "The partial velocity of every element centroid w.r.t. every independent speed is a one-hot vector.", "(22)-(23)",
              lambda: sp.Eq(sp.Symbol(r"\vec{u}'_{i,\gamma}"), sp.Symbol(r"\vec{e}_\gamma")), "eq23.corrected"),
        Claim("eq23.corrected", "one-hot for translational speeds", "u_{i,gamma} = e_gamma and omega_{i,gamma} = 0 exactly when gamma is a translational speed of a free (or prismatic) base carrying every body.", "(23)*",
              lambda: sp.And(sp.Eq(sp.Symbol(r"\vec{u}'_{i,\gamma}"), sp.Symbol(r"\vec{e}_\gamma")),
                             sp.Eq(sp.Symbol(r"\vec{\omega}_{i,\gamma}"), 0))),
        Claim("eq11", "Theorem 3.1", "sum_i F_{gamma,i} - sum_i M_i (v_gamma^{t+1} - v_gamma^t)/delta + Psi = 0 for every independent speed gamma.", "(11)",
              _eq11_expr, "eq11.corrected"),
        Claim("eq11.corrected", "Theorem 3.1, translational", "For translational speeds Psi = 0 and sum_i F_{gamma,i} = sum_i M_i a_{gamma,i} exactly; with finite differences (v^{t+1}-v^t)/delta it is exact only for a single free rigid body on Euler-integrated data (O(delta) for multibody systems or other integrators); for rotational speeds only Kane's form with partial velocities holds.", "(11)*",
              lambda: _eq11_expr(True)),
        Claim("eq30", "Psi proportional to radii", "Psi is proportional to sum_i sum_l |r_{i,l}|.", "(30)",
              lambda: _psi_scaling(False), "eq30.corrected"),
        Claim("eq30.corrected", "Psi = O(tau)", "Under scaling r -> s r of the elements, Psi = s (moment term) - s^2 (inertia term): linear plus quadratic, vanishing as tau -> 0.", "(30)*",
              lambda: sp.Eq(sp.Function("Psi")(sp.Symbol("s") * sp.Symbol("r")),
                            sp.Symbol("s") * sp.Symbol("M_z") - sp.Symbol("s") ** 2 * sp.Symbol("L^*_z"))),
        Claim("eq15", "L_cst = 0 on ground truth", "The constraint loss L_sup + L_inf of Eqs. (13)-(15) is zero on exact ground-truth data.", "(15)",
              lambda: sp.Eq(sp.Symbol("L_cst"), terms.loss_cst)),
    ]
    ineq = {
        "eq34": ("moment of forces bound", "|sum_l (r_l x F_l) . omega_gamma| <= tau |R_i| omega_gamma.",
                 "|sum_l (r_l x F_l) . omega_{i,gamma}| <= |omega_{i,gamma}| tau_i sum_l |F_l| (magnitudes summed, not the resultant)."),
        "eq35": ("inertia torque <= I w'", "sum_l (r_l x m_l a_l) . omega_gamma <= I_i w'_i.",
                 "|L*_i . omega_{i,gamma}| <= |omega_{i,gamma}| (|I_i alpha_i| + M_i tau^2 |omega_i|^2 / 2) (gyroscopic term included)."),
        "eq36": ("I_i <= (2/5) m tau^2", "The element's moment of inertia is at most that of a solid sphere of radius tau: I_i <= (2/5) M_i tau^2.",
                 "I_i <= M_i tau^2 for any mass distribution within radius tau (tight: a ring); (1/3) M_i tau^2 for uniform boxes."),
        "eq37": ("inertia torque sphere bound", "|sum_l (r_l x m_l a_l) . omega_gamma| <= (2/5) M_i tau^2 w'_i.",
                 "|L*_i . omega_{i,gamma}| <= |omega_{i,gamma}| M_i tau^2 (|alpha_i| + |omega_i|^2 / 2)."),
        "eq12": ("Theorem 3.2", "|Psi| <= tau sum_i |R_i| omega_gamma + sum_i (2/5) M_i tau^2 w'_i.",
                 "|Psi| <= sum_i |omega_{i,gamma}| (tau_i sum_l |F_{i,l}| + M_i tau_i^2 (|alpha_i| + |omega_i|^2/2)); zero slack for translational speeds."),
    }
    for cid, (title, st, corr) in ineq.items():
        C.append(Claim(cid, title, st, f"({cid[2:]})", (lambda c=cid: margin_expression(c)), cid + ".corrected"))
        C.append(Claim(cid + ".corrected", title + " (corrected)", corr, f"({cid[2:]})*", (lambda c=cid: margin_expression(c + ".corrected"))))
    C.append(Claim("eq12.corrected.translational", "Theorem 3.2 slack for translational speeds", "For translational speeds the corrected bound is 0 and the constraint is an equality.", "(12)*",
                   lambda: _eq12_expr(True)))
    return {c.id: c for c in C}


CLAIMS: dict[str, Claim] = _claims()


# ---------------------------------------------------------------------------------------
# Checks
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CheckSpec:
    """A check: which claim, on which case, by which route; ``quick`` marks the fast subset."""

    claim_id: str
    case: str
    route: str
    fn: Callable[..., CheckResult | list[CheckResult]]
    quick: bool = True


CHECKS: list[CheckSpec] = []


def _check(claim_id: str, case: str, route: Route, quick: bool = True):
    def deco(fn):
        CHECKS.append(CheckSpec(claim_id, case, route.value, fn, quick))
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


for _cid in ("eq34", "eq35", "eq36", "eq37", "eq12"):
    for _c in (_cid, _cid + ".corrected"):
        CHECKS.append(CheckSpec(_c, "generic element", Route.CASADI.value, _ineq_casadi(_c), True))
        CHECKS.append(CheckSpec(_c, "generic element", Route.HYPOTHESIS.value, _ineq_hyp(_c), False))


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


# --- Eq. (23): one-hot partial velocities (MuJoCo Jacobians) --------------------------------

def _eq23(corrected: bool):
    def fn(**_):
        import mujoco

        from kane.mjscene import BoxBodySpec, box_body_mjcf

        cid = "eq23.corrected" if corrected else "eq23"
        q = np.array([0.9, 0.2, -0.3, 0.25])
        q /= np.linalg.norm(q)
        m = mujoco.MjModel.from_xml_string(box_body_mjcf(BoxBodySpec(quat0=tuple(q))))
        d = mujoco.MjData(m)
        mujoco.mj_forward(m, d)
        worst = 0.0
        cex = None
        jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        for b in range(2, m.nbody):
            mujoco.mj_jac(m, d, jp, jr, d.xipos[b], b)
            # MuJoCo free joint: dofs 0-2 translate (world axes), 3-5 rotate (body axes)
            dofs = range(3) if corrected else range(6)
            for g in dofs:
                col = jp[:, g]
                onehot = np.zeros(3)
                onehot[np.argmax(np.abs(col))] = 1.0
                dev = max(np.abs(np.abs(col) - onehot).max(), np.abs(jr[:, g]).max())
                if dev > worst:
                    worst = dev
                    cex = {"claim_id": cid, "kind": "jacobian", "body": int(b), "dof": int(g), "u_partial": col.tolist(),
                           "omega_partial": jr[:, g].tolist()}
        return _result(cid, "free box, 8 elements, rotated", Route.MUJOCO, worst, 1e-12,
                       {"speeds": "translational dofs only" if corrected else "all 6 free-joint dofs (MuJoCo qvel)",
                        "source": "mujoco.mj_jac at element centroids"},
                       "largest deviation of a partial velocity from one-hot (or of omega_{i,gamma} from 0)", cex)

    return fn


CHECKS.append(CheckSpec("eq23", "free box, 8 elements, rotated", Route.MUJOCO.value, _eq23(False), True))
CHECKS.append(CheckSpec("eq23.corrected", "free box, 8 elements, rotated", Route.MUJOCO.value, _eq23(True), True))


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


def _traj(case: str, integrator: str = "Euler", steps: int = 600):
    from kane.mjscene import BoxBodySpec, simulate_elements

    return simulate_elements(BoxBodySpec(integrator=integrator, **_TRAJ_CASES[case]), steps)


def _eq11_residuals(tr, translational: bool):
    """Eq. (11) residual per frame and speed (world axes), relative to the force scale."""
    eq11_term = terms.loss_functions("numpy")["eq11_term"][1]  # F_{gamma,i} u - M_i (v' - v) u / delta
    S = eq11_term(tr.force[:-1], tr.mass[None, :, None], tr.v[1:], tr.v[:-1], tr.dt, 1.0).sum(1)  # [T-1, 3]
    scale = np.abs(tr.force[:-1]).sum((1, 2)).max() + 1e-300
    if translational:
        return np.abs(S) / scale  # Psi = 0: omega_{i,gamma} = 0
    # rotational speeds, the paper's reading: F_{gamma,i} = R_i . e_gamma, Psi = sum_i (M_i - L*_i) . e_gamma
    I = tr.inertia[:-1]
    Ls = np.einsum("tnab,tb->tna", I, tr.alpha[:-1]) + np.cross(tr.omega[:-1, None, :], np.einsum("tnab,tb->tna", I, tr.omega[:-1]))
    psi = (tr.moment[:-1] - Ls).sum(1)
    return np.abs(S + psi) / scale


def _eq11(case: str, translational: bool, integrator: str = "Euler", corrected: bool = False):
    label = case if integrator == "Euler" else f"{case} ({integrator})"

    def fn(quick=True, **_):
        cid = "eq11.corrected" if corrected else "eq11"
        tr = _traj(case, integrator, 300 if quick else 800)
        r = _eq11_residuals(tr, translational)
        t, g = np.unravel_index(np.argmax(r), r.shape)
        tol = _tol(case)
        cex = {"claim_id": cid, "kind": "trajectory", "case": label, "integrator": integrator, "frame": int(t), "gamma": int(g),
               "translational": translational}
        return _result(cid, label, Route.MUJOCO, r.max(), tol,
                       {"speeds": "translational (x, y, z)" if translational else "rotational (about x, y, z)",
                        "integrator": integrator, "dt": tr.dt, "elements": "box cells (2x1x1 or 2x2x2), MuJoCo mass properties",
                        "forces": "gravity" + (" + contact (mj_contactForce)" if _TRAJ_CASES[case].get("floor") else ""),
                        "tolerance": _TOL_NOTE},
                       "largest |eq. (11) residual| / (sum |F|) over frames and speeds", cex)

    return fn


for _case in _TRAJ_CASES:
    CHECKS.append(CheckSpec("eq11.corrected", _case, Route.MUJOCO.value, _eq11(_case, True, corrected=True), True))
    CHECKS.append(CheckSpec("eq11", _case, Route.MUJOCO.value, _eq11(_case, False), _case.startswith("free")))
CHECKS.append(CheckSpec("eq11", "box striking a plane (RK4)", Route.MUJOCO.value,
                        _eq11("box striking a plane", True, "RK4"), False))


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


CHECKS.append(CheckSpec("eq12", "cube spinning about its diagonal, 2 elements", Route.MUJOCO.value, _eq12_traj(False), True))
CHECKS.append(CheckSpec("eq12.corrected", "cube spinning about its diagonal, 2 elements", Route.MUJOCO.value, _eq12_traj(True), True))
CHECKS.append(CheckSpec("eq12", "cube spinning about its diagonal, 2 elements, inter-element forces in Psi", Route.MUJOCO.value,
                        _eq12_traj(False, internal=True), False))


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


CHECKS.append(CheckSpec("eq36", "flywheel disc element (MuJoCo cylinder)", Route.MUJOCO.value, _eq36_disc(False), True))
CHECKS.append(CheckSpec("eq36.corrected", "flywheel disc element (MuJoCo cylinder)", Route.MUJOCO.value, _eq36_disc(True), True))


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
    claim_ids : ids to run (a base id such as ``eq12`` also selects ``eq12.corrected``); None: all.
    cases : case names (substring match); None: all.
    quick : only the fast subset (and fewer examples/frames).
    seed : seed of the adversarial searches.
    on_progress : called as ``on_progress(done, total, label)`` after each check.

    Raises
    ------
    ValueError : an unknown claim id or case.
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
            out.append(r if r.seconds else CheckResult(**{**r.__dict__, "seconds": dt / len(res)}))
        if on_progress:
            on_progress(k + 1, len(specs), f"{s.claim_id} / {s.case}")
    return out

"""Cross-checks of Kane's equations (claim ``eq3``) and of Lemma A.1 against Pinocchio and MuJoCo.

``eq3`` is the paper's Eq. (3), ``K_gamma + K*_gamma = 0`` (Kane & Levinson 1985): for each
system of :mod:`kane.systems` the sympy residual ``fr + frstar`` is evaluated along a
MuJoCo trajectory (random initial state and controls), and the inverse dynamics it
implies, ``-(fr + frstar)`` with the actuator inputs removed, is compared with MuJoCo's
``mj_inverse`` and Pinocchio's ``rnea`` (and the mass matrix with ``mj_fullM`` and
``crba``), at the trajectory's accelerations and at random ones. For the holonomic trees
whose speeds are dq/dt, Kane's mass matrix and forcing are also compared symbolically with
sympy's ``LagrangesMethod``.

``lemmaA1`` (Appendix A.1): dividing a rigid body into elements gives the same equations
of motion as the undivided body. Checked symbolically (sympy, k = 2 with symbolic element
masses, centroids and inertias; k = 1, 2, 8, 27 with exact rational values), numerically
in Pinocchio and MuJoCo (k-element model against the single body built from
:func:`kane.elements.body_mass_properties`), and by a hypothesis search over random
element mass distributions.

Residuals are relative: the largest absolute difference, divided by the largest term of
the equation compared (``max(|forcing|, |M udot|)`` for force residuals, ``max |M|`` for
mass matrices) over everything tried. Verdicts come from :func:`kane.results.decide`.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Sequence
from functools import lru_cache

import numpy as np
import sympy as sp

from kane.results import CheckResult, decide
from kane.systems import AnalyticSystem, SymbolicModel, Trajectory, get_system, simulate, symbol

__all__ = [
    "RIGID_RTOL",
    "CONTACT_RTOL",
    "ROLLING_RTOL",
    "SYMBOLIC_RTOL",
    "EQ3_SYSTEMS",
    "check_eq3",
    "check_lemmaA1",
    "eq3_on_trajectory",
    "pinocchio_model",
    "mujoco_to_pinocchio",
]

#: Rigid-body algorithms in double precision (sympy-lambdified Kane terms, RNEA, CRBA):
#: eps = 2.2e-16, a few digits lost to cancellation along the chain and to the
#: quaternion -> Euler-angle conversion; 1e-9 keeps 6 orders of headroom while any
#: modelling error (wrong sign, inertia, parallel-axis term, frame) gives >= 1e-4.
RIGID_RTOL = 1e-9
#: Contact loads (box on plane): the loads enter exactly (mj_contactForce is a linear map
#: of efc_force), but MuJoCo's qacc satisfies M qacc = qfrc_smooth + J^T f only up to the
#: constraint solver's termination (opt.tolerance = 1e-12 in these scenes); 1e-8 leaves
#: 4 orders of margin over that.
CONTACT_RTOL = 1e-8
#: Rolling disc: the nonholonomic Kane equations assume ideal rolling (no slip, no
#: penetration), which MuJoCo's soft contact only approximates (solref time constant
#: 5 ms; the contact point creeps at 1e-4 to 1e-3 m/s). The tolerance bounds that model
#: mismatch (1 % of the largest term), it is not a numerical-error bound. Measured on
#: seeds 0-9 (200 steps): 4e-4 to 6e-3 for the disc; a disc with a 10 % inertia error
#: gives 1.5e-2 to 4.5e-2 and a ring (I = m r^2 about the axis) 1e-1 to 3e-1.
ROLLING_RTOL = 1e-2
#: Symbolic routes: difference simplified to zero gives residual 0; otherwise the
#: difference is evaluated at random points and must vanish to double-precision level.
SYMBOLIC_RTOL = 1e-12

#: system name -> factory keyword arguments for check_eq3.
EQ3_SYSTEMS: dict[str, dict] = {
    "particle": {},
    "pendulum": {},
    "double_pendulum": {},
    "free_box": {"gravity": True},
    "free_box_no_gravity": {"gravity": False},
    "partitioned_box": {"k": 8},
    "flywheel_box_planar": {},
    "cubli": {},
    "rolling_disc": {},
    "box_on_plane": {},
}


def _system(case: str) -> AnalyticSystem:
    kwargs = EQ3_SYSTEMS[case]
    name = "free_box" if case.startswith("free_box") else case
    return get_system(name, **kwargs)


def _tolerance(system: AnalyticSystem) -> float:
    if system.derivation == "rolling_disc":
        return ROLLING_RTOL
    return CONTACT_RTOL if system.has_contact else RIGID_RTOL


# --------------------------------------------------------------------------------------
# Pinocchio
# --------------------------------------------------------------------------------------


@lru_cache(maxsize=64)
def _pinocchio_cached(xml: str, g: float):
    import pinocchio as pin

    with tempfile.NamedTemporaryFile("w", suffix=".xml") as fh:
        fh.write(xml)
        fh.flush()
        model = pin.buildModelFromMJCF(fh.name)
    model.gravity.linear = np.array([0.0, 0.0, -g])
    return model


def pinocchio_model(system: AnalyticSystem):
    """Pinocchio model of ``system`` read from its MJCF (gravity set from ``params['g']``).

    Raises
    ------
    ValueError
        For the rolling disc: Pinocchio has no rolling contact (nonholonomic constraint).
    """
    if system.derivation == "rolling_disc":
        raise ValueError(
            f"system {system.name!r}: Pinocchio cannot express rolling contact; use the MuJoCo route"
        )
    return _pinocchio_cached(system.mjcf(), system.value(symbol("g")))


def _free_blocks(system: AnalyticSystem) -> list[tuple[int, int]]:
    """(qpos address, qvel address) of each free joint, MuJoCo layout."""
    out, ip, iv = [], 0, 0
    for _, j in system.joints:
        if j.kind == "free":
            out.append((ip, iv))
            ip, iv = ip + 7, iv + 6
        else:
            ip, iv = ip + 1, iv + 1
    return out


def _quat_to_R(wxyz: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(wxyz, scalar_first=True).as_matrix()


def mujoco_to_pinocchio(system: AnalyticSystem, qpos, qvel, qacc=None):
    """MuJoCo (qpos, qvel, qacc) -> Pinocchio (q, v, a) for one state.

    Free joints: quaternion (w, x, y, z) -> (x, y, z, w); ``v_lin = R^T v_world``;
    ``a_lin = R^T a_world - w_body x v_lin`` (Pinocchio's local-frame velocity and its
    time derivative). Hinge/slide coordinates are equal.

    Returns
    -------
    q : ndarray [nq]; v : ndarray [nv]; a : ndarray [nv] or None;
    T : ndarray [nv, nv], ``v = T qvel`` (so ``qfrc = T^T tau_pin`` and ``M_mj = T^T M_pin T``).
    """
    q = np.array(qpos, float)
    v = np.array(qvel, float)
    a = None if qacc is None else np.array(qacc, float)
    T = np.eye(len(v))
    for ip, iv in _free_blocks(system):
        wxyz = q[ip + 3 : ip + 7].copy()
        q[ip + 3 : ip + 7] = [wxyz[1], wxyz[2], wxyz[3], wxyz[0]]
        R = _quat_to_R(wxyz)
        T[iv : iv + 3, iv : iv + 3] = R.T
        vl = R.T @ np.asarray(qvel)[iv : iv + 3]
        v[iv : iv + 3] = vl
        if a is not None:
            a[iv : iv + 3] = R.T @ np.asarray(qacc)[iv : iv + 3] - np.cross(
                np.asarray(qvel)[iv + 3 : iv + 6], vl
            )
    return q, v, a, T


def _pin_fext(system: AnalyticSystem, pmodel, qpos, wrench):
    """Contact wrenches (world force at body origin, world torque) as Pinocchio local-frame forces."""
    import pinocchio as pin

    fext = [pin.Force.Zero() for _ in range(pmodel.njoints)]
    free_qpos = dict(
        zip(
            (b for b, j in system.joints if j.kind == "free"),
            (ip for ip, _ in _free_blocks(system)),
            strict=True,
        )
    )
    for k, name in enumerate(system.wrench_bodies):
        if name not in free_qpos:
            raise ValueError(
                f"system {system.name!r}: external wrenches are supported on free bodies only ({name!r})"
            )
        jid = pmodel.getJointId(next(j.name for b, j in system.joints if b == name))
        ip = free_qpos[name]
        R = _quat_to_R(np.asarray(qpos)[ip + 3 : ip + 7])  # world from body
        fext[jid] = pin.Force(R.T @ wrench[k, :3], R.T @ wrench[k, 3:])
    return fext


# --------------------------------------------------------------------------------------
# eq3 on one system
# --------------------------------------------------------------------------------------


def _full_mass(model, data, out: np.ndarray) -> np.ndarray:
    """Dense mass matrix [nv, nv] (``mj_fullM``; MuJoCo >= 3.3 signature, else the older one)."""
    import mujoco

    try:
        mujoco.mj_fullM(model, data, out)
    except TypeError:  # MuJoCo < 3.3: mj_fullM(m, dst, qM)
        mujoco.mj_fullM(model, out, data.qM)
    return out


def _rel(diff: np.ndarray, scale: float) -> float:
    return float(np.max(np.abs(diff)) / scale) if diff.size else 0.0


def eq3_on_trajectory(
    system: AnalyticSystem, n_steps: int = 200, seed: int = 0, model: SymbolicModel | None = None
) -> dict:
    """Kane residual and engine comparisons along one MuJoCo trajectory of ``system``.

    Parameters
    ----------
    system : AnalyticSystem
    n_steps : int
        Trajectory length T.
    seed : int
        Seeds the initial state, controls and the random test accelerations.
    model : SymbolicModel, optional
        Defaults to ``system.symbolic()``.

    Returns
    -------
    dict with relative residuals
        ``kane_on_motion``: max |fr + frstar| on MuJoCo's motion (actuator and contact
        inputs applied); ``mujoco_inverse``: -(fr + frstar) without actuator inputs against
        ``qfrc_inverse``, at the trajectory accelerations (contact on) and at random
        accelerations (constraints off); ``mujoco_mass``: mass matrix against
        ``mj_fullM``; ``pinocchio_rnea`` and ``pinocchio_crba`` likewise (absent for the
        rolling disc); ``worst``: the sample with the largest residual per key; ``scale``;
        ``trajectory``; ``contact_steps`` (steps with at least one contact); ``slip``
        (rolling disc: max horizontal speed of the disc's contact point, m/s).
    """
    import mujoco

    sm = model or system.symbolic()
    tr: Trajectory = simulate(system, n_steps=n_steps, seed=seed)
    q, u, ud = system.mujoco_to_kane(tr.qpos, tr.qvel, tr.qacc)
    inputs = tr.kane_inputs()
    rng = np.random.default_rng(seed + 7919)
    M = sm.mass(q)
    f = sm.force(q, u, inputs)
    scale = max(np.abs(f).max(), np.abs(np.einsum("tij,tj->ti", M, ud)).max(), 1e-300)
    res = sm.residual(q, u, ud, inputs)
    out: dict = {
        "scale": scale,
        "trajectory": tr,
        "worst": {},
        "contact_steps": int((tr.n_contacts > 0).sum()),
    }

    def record(key, diff, rel, t):
        out[key] = max(out.get(key, 0.0), rel)
        if rel >= out["worst"].get(key, {}).get("residual", -1.0):
            out["worst"][key] = {"residual": rel, "step": int(t), "diff": np.asarray(diff).tolist()}

    for t in range(len(tr.time)):
        record("kane_on_motion", res[t], _rel(res[t], scale), t)
    if system.derivation == "rolling_disc":
        from kane.systems.rolling_disc import _rot_zxy

        R = np.stack([_quat_to_R(x) for x in tr.qpos[:, 3:7]])
        w = np.einsum("tij,tj->ti", R, tr.qvel[:, 3:6])
        _, L = _rot_zxy(q[:, 0], q[:, 1], q[:, 2])
        vP = tr.qvel[:, :3] + np.cross(w, -system.value(symbol("r")) * L[:, :, 2])
        out["slip"] = float(np.abs(vP[:, :2]).max())
        return out

    mjm = mujoco.MjModel.from_xml_string(system.mjcf())
    mjd = mujoco.MjData(mjm)
    mjm_free = mujoco.MjModel.from_xml_string(system.mjcf())
    mjm_free.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    mjd_free = mujoco.MjData(mjm_free)
    pm = pinocchio_model(system)
    import pinocchio as pin

    pd = pm.createData()
    inputs_contact = tr.kane_inputs(actuators=False)
    a_rand = ud + rng.normal(size=ud.shape) * np.maximum(1.0, np.abs(ud))
    tau_traj = sm.inverse_dynamics(q, u, ud, inputs_contact)
    tau_rand = sm.inverse_dynamics(q, u, a_rand, None)
    Mn = np.abs(M).max()
    Mfull = np.zeros((mjm.nv, mjm.nv))
    for t in range(len(tr.time)):
        # MuJoCo inverse dynamics at the trajectory acceleration (contacts as simulated)
        mjd.qpos[:], mjd.qvel[:], mjd.qacc[:] = tr.qpos[t], tr.qvel[t], tr.qacc[t]
        mujoco.mj_inverse(mjm, mjd)
        record(
            "mujoco_inverse",
            tau_traj[t] - mjd.qfrc_inverse,
            _rel(tau_traj[t] - mjd.qfrc_inverse, scale),
            t,
        )
        # ... and at a random acceleration, constraints off
        mjd_free.qpos[:], mjd_free.qvel[:], mjd_free.qacc[:] = tr.qpos[t], tr.qvel[t], a_rand[t]
        mujoco.mj_inverse(mjm_free, mjd_free)
        d = tau_rand[t] - mjd_free.qfrc_inverse
        record("mujoco_inverse", d, _rel(d, scale), t)
        _full_mass(mjm_free, mjd_free, Mfull)
        record("mujoco_mass", M[t] - Mfull, _rel(M[t] - Mfull, Mn), t)
        # Pinocchio
        pq, pv, pa, T = mujoco_to_pinocchio(system, tr.qpos[t], tr.qvel[t], tr.qacc[t])
        if system.wrench_bodies:
            tau_p = pin.rnea(
                pm, pd, pq, pv, pa, _pin_fext(system, pm, tr.qpos[t], tr.contact_wrench[t])
            )
        else:
            tau_p = pin.rnea(pm, pd, pq, pv, pa)
        d = tau_traj[t] - T.T @ tau_p
        record("pinocchio_rnea", d, _rel(d, scale), t)
        _, _, pa2, _ = mujoco_to_pinocchio(system, tr.qpos[t], tr.qvel[t], a_rand[t])
        d = tau_rand[t] - T.T @ pin.rnea(pm, pd, pq, pv, pa2)
        record("pinocchio_rnea", d, _rel(d, scale), t)
        Mp = pin.crba(pm, pd, pq)
        Mp = np.triu(Mp) + np.triu(Mp, 1).T  # crba fills the upper triangle only
        d = M[t] - T.T @ Mp @ T
        record("pinocchio_crba", d, _rel(d, Mn), t)
    return out


def _symbolic_lagrange(system: AnalyticSystem, model: SymbolicModel) -> tuple[float, str]:
    """Kane mass matrix/forcing minus Lagrange's, simplified; (relative residual, how)."""
    from sympy.physics.mechanics import dynamicsymbols

    lm, kin = system.lagranges_method()
    t = dynamicsymbols._t
    rep = {qq.diff(t): us for qq, us in zip(kin["q"], model.u, strict=True)}  # u = dq/dt
    rep2 = dict(zip(kin["q"], model.q, strict=True))
    ML = lm.mass_matrix.xreplace(rep).xreplace(rep2)
    fL = lm.forcing.xreplace(rep).xreplace(rep2)
    dM = (model.mass_matrix - ML).applyfunc(lambda e: sp.simplify(sp.expand(e)))
    df = (model.forcing - fL).applyfunc(lambda e: sp.simplify(sp.expand(e)))
    if all(e == 0 for e in dM) and all(e == 0 for e in df):
        return 0.0, "Kane minus Lagrange mass matrix and forcing simplify to 0"
    # not simplified to zero: evaluate at random points
    rng = np.random.default_rng(0)
    args = [*model.q, *model.u, *model.inputs, *model.params]
    fD = sp.lambdify(args, list(dM) + list(df))
    fS = sp.lambdify(args, list(model.mass_matrix) + list(model.forcing))
    worst = 0.0
    for _ in range(20):
        x = [*rng.normal(size=len(model.q) + len(model.u) + len(model.inputs)), *model.param_values]
        worst = max(worst, np.abs(fD(*x)).max() / max(np.abs(fS(*x)).max(), 1e-300))
    return float(worst), "difference did not simplify to 0; evaluated at 20 random points"


def check_eq3(quick: bool = False) -> list[CheckResult]:
    """Check Eq. (3), K_gamma + K*_gamma = 0, on every system of :data:`EQ3_SYSTEMS`.

    Routes and tolerances (relative residuals, see module docstring):

    * ``mujoco``: the largest of (a) |fr + frstar| on MuJoCo's motion with its actuator
      forces and contact wrenches as inputs, (b) -(fr + frstar) without actuator inputs
      against ``mj_inverse`` at the trajectory accelerations and at random accelerations
      (constraints off), (c) the mass matrix against ``mj_fullM``. Tolerance
      :data:`RIGID_RTOL` (1e-9) for systems without contact, :data:`CONTACT_RTOL` (1e-8)
      for the box on the plane (solver termination), :data:`ROLLING_RTOL` (1e-2) for the
      rolling disc (soft contact only approximates rolling; only (a) applies, since its
      Kane equations have 3 independent speeds against MuJoCo's 6).
    * ``pinocchio``: -(fr + frstar) against ``rnea`` (contact wrenches as ``fext``) at the
      same accelerations, and the mass matrix against ``crba`` (upper triangle mirrored);
      same tolerances. Not run for the rolling disc: Pinocchio has no rolling contact.
    * ``symbolic`` (holonomic trees whose speeds are dq/dt: particle, pendulum,
      double_pendulum, flywheel_box_planar): KanesMethod mass matrix and forcing minus
      LagrangesMethod's simplify to zero; tolerance :data:`SYMBOLIC_RTOL`.

    Parameters
    ----------
    quick : bool
        One seed of 60 steps per system (else three seeds of 200 steps).

    Returns
    -------
    list of CheckResult (claim_id ``eq3``)
    """
    seeds = [0] if quick else [0, 1, 2]
    n_steps = 60 if quick else 200
    results: list[CheckResult] = []
    for case in EQ3_SYSTEMS:
        t0 = time.perf_counter()
        try:
            system = _system(case)
            sm = system.symbolic()
            tol = _tolerance(system)
            agg: dict = {}
            worst: dict = {}
            slip = 0.0
            contact_steps = 0
            for seed in seeds:
                out = eq3_on_trajectory(system, n_steps=n_steps, seed=seed, model=sm)
                slip = max(slip, out.get("slip", 0.0))
                contact_steps += out["contact_steps"]
                for k, v in out.items():
                    if k in ("scale", "trajectory", "worst", "slip", "contact_steps"):
                        continue
                    if v >= agg.get(k, -1.0):
                        worst[k] = {**out["worst"][k], "seed": seed}
                    agg[k] = max(agg.get(k, 0.0), v)
            base_assumptions = {
                "generalized_speeds": "hinge/slide: dq/dt; free joint: world linear velocity of the body origin "
                "and body-frame angular velocity (MuJoCo qvel); rolling disc: angular velocity in the lean frame",
                "integrator": "MuJoCo Euler, no damping/armature",
                "timestep_s": system.timestep,
                "n_steps": n_steps,
                "seeds": seeds,
                "params": dict(system.params),
            }
            seconds = time.perf_counter() - t0
            mj_keys = [k for k in ("kane_on_motion", "mujoco_inverse", "mujoco_mass") if k in agg]
            extra = (
                f"; contact in {contact_steps} of {n_steps * len(seeds)} steps"
                if system.has_contact
                else ""
            )
            if system.derivation == "rolling_disc":
                extra += f"; max contact-point slip {slip:.2e} m/s"
            results.append(
                _result(
                    "eq3",
                    case,
                    "mujoco",
                    agg,
                    worst,
                    mj_keys,
                    tol,
                    base_assumptions,
                    seconds,
                    system,
                    extra=extra,
                )
            )
            if system.derivation != "rolling_disc":
                results.append(
                    _result(
                        "eq3",
                        case,
                        "pinocchio",
                        agg,
                        worst,
                        ["pinocchio_rnea", "pinocchio_crba"],
                        tol,
                        base_assumptions,
                        0.0,
                        system,
                    )
                )
            if system.derivation == "tree" and not any(j.kind == "free" for _, j in system.joints):
                t1 = time.perf_counter()
                resid, how = _symbolic_lagrange(system, sm)
                results.append(
                    CheckResult(
                        "eq3",
                        case,
                        "symbolic",
                        decide(resid, SYMBOLIC_RTOL),
                        resid,
                        SYMBOLIC_RTOL,
                        {"method": "sympy KanesMethod vs LagrangesMethod", "speeds": "u = dq/dt"},
                        None,
                        None,
                        how,
                        time.perf_counter() - t1,
                    )
                )
        except Exception as exc:  # one broken system must not hide the others
            results.append(
                CheckResult(
                    "eq3",
                    case,
                    "mujoco",
                    "error",
                    math.nan,
                    math.nan,
                    {},
                    None,
                    None,
                    f"{type(exc).__name__}: {exc}",
                    time.perf_counter() - t0,
                )
            )
    return results


def _result(
    claim, case, route, agg, worst, keys, tol, assumptions, seconds, system, extra=""
) -> CheckResult:
    resid = max(agg[k] for k in keys)
    verdict = decide(resid, tol)
    detail = (
        ", ".join(f"{k} {agg[k]:.2e}" for k in keys) + f" (relative; tolerance {tol:.0e})" + extra
    )
    counterexample = None
    if verdict == "refuted":
        k = max(keys, key=lambda k: agg[k])
        counterexample = {
            "system": system.name,
            "params": dict(system.params),
            "check": k,
            **worst[k],
        }
    return CheckResult(
        claim,
        case,
        route,
        verdict,
        float(resid),
        float(tol),
        assumptions,
        counterexample,
        None,
        detail,
        seconds,
    )


# --------------------------------------------------------------------------------------
# Lemma A.1
# --------------------------------------------------------------------------------------


def _union_body_expressions(masses, coms, inertias):
    """Mass, mass centre and inertia about it of a rigid union (parallel-axis theorem).

    Parameters are sympy expressions: masses [n], coms [n][3], inertias [n][6] in the
    ``(Ixx, Iyy, Izz, Ixy, Ixz, Iyz)`` order. Returns (M, com[3], inertia[6]).
    """
    M = sum(masses, sp.S.Zero)
    c = [
        sum((m * ci[a] for m, ci in zip(masses, coms, strict=True)), sp.S.Zero) / M
        for a in range(3)
    ]
    Itot = sp.zeros(3, 3)
    for m, ci, I6 in zip(masses, coms, inertias, strict=True):
        ixx, iyy, izz, ixy, ixz, iyz = I6
        Ii = sp.Matrix([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        d = sp.Matrix([ci[a] - c[a] for a in range(3)])
        Itot += Ii + m * ((d.T * d)[0] * sp.eye(3) - d * d.T)
    return M, c, (Itot[0, 0], Itot[1, 1], Itot[2, 2], Itot[0, 1], Itot[0, 2], Itot[1, 2])


def _lemma_symbolic(k: int, exact_values: bool) -> tuple[float, str]:
    """Element-box Kane model minus undivided-box model with the union's mass properties."""
    from kane.systems import BodySpec, JointSpec

    parted = get_system("partitioned_box", k=k)  # element i: parameters m_e<i>, cx_e<i>, ...
    ms = [symbol(f"m_e{i}") for i in range(k)]
    cs = [[symbol(f"{a}_e{i}") for a in ("cx", "cy", "cz")] for i in range(k)]
    Is = [
        [symbol(f"{n}_e{i}") for n in ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")] for i in range(k)
    ]
    M, c, I6 = _union_body_expressions(ms, cs, Is)
    whole = AnalyticSystem(
        f"lemma_whole_k{k}",
        dict(parted.params),
        (
            BodySpec(
                "box", None, joints=(JointSpec("root", "free"),), mass=M, com=tuple(c), inertia=I6
            ),
        ),
    )
    A, B = parted.symbolic(), whole.symbolic()
    diffs = list(A.mass_matrix - B.mass_matrix) + list(A.forcing - B.forcing)
    if exact_values:
        vals = {s: sp.Rational(v) for s, v in parted.symbol_values.items()}  # exact binary values
        diffs = [sp.expand(d.xreplace(vals)) for d in diffs]
        ok = all(d == 0 for d in diffs)
        how = f"k={k}: difference expands to 0 with the elements' exact (rational) values"
    else:
        diffs = [sp.cancel(sp.together(sp.expand(d))) for d in diffs]
        ok = all(d == 0 for d in diffs)
        how = f"k={k}: difference simplifies to 0 with symbolic element masses, centroids and inertias"
    if ok:
        return 0.0, how
    fD = sp.lambdify([*A.q, *A.u, *A.params], diffs)
    fS = sp.lambdify([*A.q, *A.u, *A.params], list(A.mass_matrix) + list(A.forcing))
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(20):
        x = [*rng.normal(size=len(A.q) + len(A.u)), *A.param_values]
        worst = max(
            worst, np.abs(np.array(fD(*x), float)).max() / np.abs(np.array(fS(*x), float)).max()
        )
    return float(worst), how.replace("expands to 0", "did not expand to 0").replace(
        "simplifies to 0", "did not simplify to 0"
    )


def _lemma_numeric(elements, half_extents, n_states: int, seed: int) -> dict:
    """k-element model vs undivided model in Pinocchio and MuJoCo at random states.

    Returns relative residuals ``pinocchio_rnea``, ``pinocchio_crba``, ``mujoco_inverse``,
    ``mujoco_mass`` (max over states; scale: largest entry of the undivided body's
    inverse dynamics / mass matrix).
    """
    import mujoco
    import pinocchio as pin

    from kane.systems import element_union_box, undivided_box

    parts = element_union_box(elements, half_extents=half_extents)
    whole = undivided_box(elements, half_extents=half_extents)
    pmA, pmB = pinocchio_model(parts), pinocchio_model(whole)
    pdA, pdB = pmA.createData(), pmB.createData()
    mA, mB = (
        mujoco.MjModel.from_xml_string(parts.mjcf()),
        mujoco.MjModel.from_xml_string(whole.mjcf()),
    )
    dA, dB = mujoco.MjData(mA), mujoco.MjData(mB)
    rng = np.random.default_rng(seed)
    out = dict.fromkeys(("pinocchio_rnea", "pinocchio_crba", "mujoco_inverse", "mujoco_mass"), 0.0)
    MA, MB = np.zeros((6, 6)), np.zeros((6, 6))
    for _ in range(n_states):
        quat = rng.normal(size=4)
        quat /= np.linalg.norm(quat)
        qpos = np.r_[rng.normal(size=3), quat]
        qvel, qacc = rng.normal(0, 3, 6), rng.normal(0, 3, 6)
        q, v, a, _ = mujoco_to_pinocchio(parts, qpos, qvel, qacc)
        tA, tB = pin.rnea(pmA, pdA, q, v, a), pin.rnea(pmB, pdB, q, v, a)
        out["pinocchio_rnea"] = max(out["pinocchio_rnea"], _rel(tA - tB, np.abs(tB).max()))
        cA, cB = pin.crba(pmA, pdA, q), pin.crba(pmB, pdB, q)
        out["pinocchio_crba"] = max(
            out["pinocchio_crba"], _rel(np.triu(cA) - np.triu(cB), np.abs(np.triu(cB)).max())
        )
        for m, d in ((mA, dA), (mB, dB)):
            d.qpos[:], d.qvel[:], d.qacc[:] = qpos, qvel, qacc
            mujoco.mj_inverse(m, d)
        out["mujoco_inverse"] = max(
            out["mujoco_inverse"],
            _rel(dA.qfrc_inverse - dB.qfrc_inverse, np.abs(dB.qfrc_inverse).max()),
        )
        _full_mass(mA, dA, MA)
        _full_mass(mB, dB, MB)
        out["mujoco_mass"] = max(out["mujoco_mass"], _rel(MA - MB, np.abs(MB).max()))
    return out


def _lemma_trajectory(k: int, n_steps: int, seed: int) -> float:
    """Kane residual of the k-element sympy model along a MuJoCo trajectory of the undivided box."""
    from kane.elements import partition_box_k
    from kane.systems import undivided_box

    part = get_system("partitioned_box", k=k)
    h = (part.params["a"], part.params["b"], part.params["c"])
    whole = undivided_box(partition_box_k(h, k, mass=part.params["m"]), half_extents=h)
    sm = part.symbolic()
    tr = simulate(whole, n_steps=n_steps, seed=seed)
    q, u, ud = whole.mujoco_to_kane(tr.qpos, tr.qvel, tr.qacc)
    r = sm.residual(q, u, ud)
    scale = max(np.abs(sm.force(q, u)).max(), np.abs(np.einsum("tij,tj->ti", sm.mass(q), ud)).max())
    return float(np.abs(r).max() / scale)


def check_lemmaA1(quick: bool = False) -> list[CheckResult]:
    """Check Lemma A.1: a body divided into k elements has the undivided body's equations.

    Routes and tolerances:

    * ``symbolic``: Kane mass matrix and forcing of the k-element box (each element a
      RigidBody fixed in the box frame) minus those of one body with the union's mass
      properties (parallel-axis theorem). k = 2 with symbolic element masses, centroids and
      inertias (difference cancels to 0); k = 1, 2, 8, 27 with the elements' exact
      rational values (expands to 0; full run only). Tolerance :data:`SYMBOLIC_RTOL`.
    * ``pinocchio`` / ``mujoco``: the k-element MJCF (elements as welded child bodies)
      against the undivided body from :func:`kane.elements.body_mass_properties`: rnea /
      ``mj_inverse`` and crba / ``mj_fullM`` at random states, k = 1, 2, 8, 27, uniform and
      non-uniform (jitter 1.0) masses; the mujoco route also evaluates the k-element
      sympy Kane residual along a MuJoCo trajectory of the undivided box. Tolerance
      :data:`RIGID_RTOL` (1e-9): both sides are double-precision rigid-body algorithms.
    * ``hypothesis``: the same Pinocchio/MuJoCo comparison over random k, box sizes, total
      masses and log-normal point-mass distributions; tolerance :data:`RIGID_RTOL`.

    Parameters
    ----------
    quick : bool
        Fewer states, examples and symbolic cases.

    Returns
    -------
    list of CheckResult (claim_id ``lemmaA1``)
    """
    from kane.elements import partition_box_k

    results: list[CheckResult] = []
    ks = (1, 2, 8, 27)
    # symbolic
    sym_cases = [(2, False)] + ([] if quick else [(k, True) for k in ks])
    for k, exact in sym_cases:
        t0 = time.perf_counter()
        try:
            resid, how = _lemma_symbolic(k, exact)
            results.append(
                CheckResult(
                    "lemmaA1",
                    f"partitioned_box_k{k}" + ("_exact" if exact else "_symbolic"),
                    "symbolic",
                    decide(resid, SYMBOLIC_RTOL),
                    resid,
                    SYMBOLIC_RTOL,
                    {
                        "elements": "rigid bodies fixed in the box frame",
                        "k": k,
                        "element_parameters": "exact rationals" if exact else "symbols",
                    },
                    None,
                    None,
                    how,
                    time.perf_counter() - t0,
                )
            )
        except Exception as exc:
            results.append(
                CheckResult(
                    "lemmaA1",
                    f"partitioned_box_k{k}",
                    "symbolic",
                    "error",
                    math.nan,
                    SYMBOLIC_RTOL,
                    {},
                    None,
                    None,
                    f"{type(exc).__name__}: {exc}",
                    time.perf_counter() - t0,
                )
            )
    # numeric, engines
    n_states = 5 if quick else 30
    box = get_system("partitioned_box", k=1).params
    h, mass = (box["a"], box["b"], box["c"]), box["m"]
    for k in ks:
        for jitter in (0.0, 1.0):
            t0 = time.perf_counter()
            els = partition_box_k(h, k, mass=mass, rng=np.random.default_rng(k), jitter=jitter)
            out = _lemma_numeric(els, h, n_states, seed=k)
            traj = _lemma_trajectory(k, 30 if quick else 100, seed=k) if jitter == 0.0 else None
            sec = time.perf_counter() - t0
            case = f"partitioned_box_k{k}" + ("_jitter" if jitter else "")
            assumptions = {
                "k": k,
                "jitter": jitter,
                "half_extents": h,
                "mass": mass,
                "n_states": n_states,
            }
            for route, keys in (
                ("pinocchio", ("pinocchio_rnea", "pinocchio_crba")),
                ("mujoco", ("mujoco_inverse", "mujoco_mass")),
            ):
                agg = {kk: out[kk] for kk in keys}
                if route == "mujoco" and traj is not None:
                    agg["kane_k_elements_on_undivided_motion"] = traj
                resid = max(agg.values())
                verdict = decide(resid, RIGID_RTOL)
                detail = (
                    ", ".join(f"{kk} {v:.2e}" for kk, v in agg.items())
                    + f" (relative; tolerance {RIGID_RTOL:.0e})"
                )
                cex = {"k": k, "jitter": jitter, "seed": k, **agg} if verdict == "refuted" else None
                results.append(
                    CheckResult(
                        "lemmaA1",
                        case,
                        route,
                        verdict,
                        resid,
                        RIGID_RTOL,
                        assumptions,
                        cex,
                        None,
                        detail,
                        sec / 2,
                    )
                )
    results.append(_lemma_hypothesis(max_examples=10 if quick else 60))
    return results


def _lemma_hypothesis(max_examples: int) -> CheckResult:
    """Hypothesis search for a point-mass distribution whose element model differs from the body."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from kane.elements import partition_box_k

    t0 = time.perf_counter()
    worst = {"residual": 0.0}
    failure: dict = {}

    @settings(
        max_examples=max_examples,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(
        k=st.sampled_from([1, 2, 8, 27]),
        half=st.tuples(*[st.floats(0.01, 1.0)] * 3),
        mass=st.floats(0.01, 100.0),
        jitter=st.floats(0.0, 3.0),
        seed=st.integers(0, 2**31 - 1),
        ppa=st.sampled_from([2, 3]),
    )
    def prop(k, half, mass, jitter, seed, ppa):
        els = partition_box_k(
            half, k, mass=mass, points_per_axis=ppa, rng=np.random.default_rng(seed), jitter=jitter
        )
        out = _lemma_numeric(els, half, n_states=2, seed=seed)
        r = max(out.values())
        if r > worst["residual"]:
            worst.update(
                residual=r,
                k=k,
                half_extents=half,
                mass=mass,
                jitter=jitter,
                seed=seed,
                points_per_axis=ppa,
            )
        if r > RIGID_RTOL:
            failure.update(worst)
            raise AssertionError(f"element model differs from the body by {r:.2e}")

    try:
        prop()
    except AssertionError:
        pass
    resid = float(failure.get("residual", worst["residual"]))
    verdict = decide(resid, RIGID_RTOL)
    detail = (
        f"{max_examples} examples (k, box size, total mass, log-normal point masses with jitter <= 3, "
        f"2 or 3 points per axis); largest relative difference {resid:.2e} (tolerance {RIGID_RTOL:.0e})"
    )
    return CheckResult(
        "lemmaA1",
        "random_element_masses",
        "hypothesis",
        verdict,
        resid,
        RIGID_RTOL,
        {
            "routes": "pinocchio rnea/crba and mujoco mj_inverse/mj_fullM",
            "max_examples": max_examples,
        },
        dict(failure) if verdict == "refuted" else None,
        None,
        detail,
        time.perf_counter() - t0,
    )


def summarize(results: Sequence[CheckResult]) -> str:
    """One line per result: claim, case, route, verdict, residual / tolerance."""
    return "\n".join(
        f"{r.claim_id:8s} {r.case:28s} {r.route:10s} {r.verdict:8s} {r.residual:.2e} / {r.tolerance:.0e}  {r.detail}"
        for r in results
    )

"""The claim registry's checks that apply to a user's MJCF tree: Eq. (3) three ways, Eq. (11) per speed, Theorem 3.2 and the element bounds with one element per body.

:func:`run_mjcf_checks` returns :class:`kane.results.CheckResult` records, like
:func:`kane.claims.run_checks`, so that the same report and verdict table render them:

* ``eq3`` (Kane's equation): ``mujoco`` (mass matrix, bias + passive forces, actuator
  map, inverse dynamics on random states), ``pinocchio`` (``crba``, ``rnea``) and
  ``symbolic`` (the explicit partial-velocity derivation against sympy's ``KanesMethod``)
  from :func:`kane.mjcf.crosscheck_mjcf`; tolerance :data:`EQ3_RTOL`.
* ``eq11`` per generalized speed: the paper's Eq. (11) with finite-difference
  accelerations along a MuJoCo Euler trajectory; ``eq11.corrected`` per speed: with
  instantaneous accelerations (translational speeds: Psi = 0; rotational: Kane's form with
  partial velocities, the corrected statement).
* ``eq12`` / ``eq12.corrected`` per rotational speed: |Psi_gamma| against the paper's and
  the corrected bound (:func:`kane.terms.loss_functions`, one source with the MDGS loss).
* ``eq36`` / ``eq36.corrected`` per body: largest principal inertia against
  (2/5) M tau^2 and M tau^2.

The trajectory checks use the partition of one element per body (a body's elements would
need mass properties MuJoCo does not hold), and run the mechanism under gravity alone:
MuJoCo's constraints, actuation, damping, springs and armature are switched off on a copy
of the model, so that every load is a point force at a mass centre (the setting of the
paper's Section 3). Partial velocities ``u_{i,gamma}``, ``omega_{i,gamma}`` are the columns
of MuJoCo's Jacobians at each mass centre (``mj_jacBodyCom``), exact for MuJoCo's speeds;
instantaneous accelerations add ``mj_jacDot``.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from kane import terms
from kane.mjcf import MjcfModel, crosscheck_mjcf, from_mjcf
from kane.results import CheckResult, Route, decide

__all__ = ["EQ3_RTOL", "TRAJ_RTOL", "BOUND_TOL", "run_mjcf_checks", "element_trajectory"]

#: Eq. (3) on random states: double-precision rigid-body algorithms agree to ~1e-15 of the
#: largest term (measured on the example models); 1e-10 is the issue's bar and leaves five
#: orders of headroom, while a 1 % mass or a sign error gives >= 1e-3.
EQ3_RTOL = 1e-10
#: Eq. (11) along the trajectory, relative to the speed's force scale: instantaneous
#: accelerations make it an identity up to rounding (~1e-15); 1e-10 as for Eq. (3).
TRAJ_RTOL = 1e-10
#: Bounds (Eq. 12, Eq. 36): margins relative to sum M tau^2 (|omega|^2 + 1); a bound holds
#: when the margin is <= 1e-9 (rounding of the inertia torques; a violation is O(1)).
BOUND_TOL = 1e-9


def _result(cid, case, route, residual, tol, assumptions, detail, cex=None, seconds=0.0) -> CheckResult:
    verdict = decide(float(residual), tol)
    corrected = f"{cid}.corrected" if verdict == "refuted" and cid in ("eq11", "eq12", "eq36") else None
    return CheckResult(cid, case, route.value if isinstance(route, Route) else route, verdict, float(residual), tol,
                       assumptions, cex if verdict == "refuted" else None, corrected, detail, seconds)


# --------------------------------------------------------------------------------------
# Element-level ground truth of a MuJoCo tree under gravity alone
# --------------------------------------------------------------------------------------


def _gravity_only(m):
    """``m`` (a fresh copy, changed in place) with constraints, actuation, damping, springs and armature off."""
    import mujoco

    g = m
    g.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT) | int(mujoco.mjtDisableBit.mjDSBL_ACTUATION)
    g.dof_damping[:] = 0.0
    g.jnt_stiffness[:] = 0.0
    g.dof_armature[:] = 0.0
    return g


def _body_radius(m, d, b: int) -> float:
    """Element radius tau of body ``b`` (m): the largest distance of its geoms' bounding
    spheres from its mass centre, and at least sqrt(tr I / 2M) (then I <= M tau^2 holds for
    any inertia, since I_max <= tr I / 2)."""
    tr = float(m.body_inertia[b].sum())
    tau = np.sqrt(tr / (2 * m.body_mass[b]))
    for gid in range(m.body_geomadr[b], m.body_geomadr[b] + m.body_geomnum[b]):
        tau = max(tau, float(np.linalg.norm(d.geom_xpos[gid] - d.xipos[b]) + m.geom_rbound[gid]))
    return float(tau)


def element_trajectory(path: str, n_steps: int = 200, seed: int = 0) -> dict:
    """Per-body (element) quantities along a MuJoCo Euler trajectory under gravity alone.

    Returns
    -------
    dict of arrays: ``mass`` [n], ``tau`` [n] (m), ``I`` [T, n, 3, 3] (world, about the mass
    centre), ``v``, ``a`` [T, n, 3] (mass-centre velocity, instantaneous acceleration),
    ``omega``, ``alpha`` [T, n, 3] (world), ``Jp``, ``Jr`` [T, n, 3, nv] (partial velocities
    and partial angular velocities, columns = MuJoCo speeds), ``F`` [T, n, 3] (gravity, N),
    ``dt`` (s), ``bodies`` (names).
    """
    import mujoco

    from kane.mjcf import load_model, random_states

    m = _gravity_only(load_model(path))
    d = mujoco.MjData(m)
    qpos, qvel, _ = random_states(m, 1, seed)
    d.qpos[:], d.qvel[:] = qpos[0], qvel[0]
    bodies = [b for b in range(1, m.nbody) if m.body_mass[b] > 0 and m.body_weldid[b] != 0]  # massive, moving
    n, nv, T = len(bodies), m.nv, n_steps
    out = {k: np.zeros((T, n, 3)) for k in ("v", "a", "omega", "alpha", "F")}
    out["I"] = np.zeros((T, n, 3, 3))
    out["Jp"], out["Jr"] = np.zeros((T, n, 3, nv)), np.zeros((T, n, 3, nv))
    jp, jr, jdp, jdr = (np.zeros((3, nv)) for _ in range(4))
    mujoco.mj_forward(m, d)
    tau = np.array([_body_radius(m, d, b) for b in bodies])
    mass = m.body_mass[bodies].copy()
    g = np.asarray(m.opt.gravity, float)
    for t in range(T):
        mujoco.mj_forward(m, d)
        for i, b in enumerate(bodies):
            mujoco.mj_jacBodyCom(m, d, jp, jr, b)
            mujoco.mj_jacDot(m, d, jdp, jdr, d.xipos[b], b)
            out["Jp"][t, i], out["Jr"][t, i] = jp, jr
            out["v"][t, i], out["omega"][t, i] = jp @ d.qvel, jr @ d.qvel
            out["a"][t, i] = jp @ d.qacc + jdp @ d.qvel
            out["alpha"][t, i] = jr @ d.qacc + jdr @ d.qvel
            R = d.ximat[b].reshape(3, 3)
            out["I"][t, i] = R @ np.diag(m.body_inertia[b]) @ R.T
            out["F"][t, i] = mass[i] * g
        mujoco.mj_Euler(m, d)
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}" for b in bodies]
    return {**out, "mass": mass, "tau": tau, "dt": float(m.opt.timestep), "bodies": names}


def _speed_names(mm: MjcfModel) -> list[str]:
    return [str(s)[2:] for s in mm.explicit.u]


# --------------------------------------------------------------------------------------
# The checks
# --------------------------------------------------------------------------------------


def _eq3(mm: MjcfModel, case: str, quick: bool, seed: int) -> list[CheckResult]:
    t0 = time.perf_counter()
    r = crosscheck_mjcf(mm, n_states=10 if quick else 50, seed=seed)
    sec = time.perf_counter() - t0
    base = {"states": f"{r['n_states']} random (q, u, udot, actuator forces)", "constraints": "off (contacts, limits, dry friction)",
            "speeds": "MuJoCo qvel (ball/free rotations: local angular velocity; free translation: world velocity)",
            "derivation_s": {k: round(v, 2) for k, v in mm.timing.items()}}
    mj_keys = [k for k in ("mujoco_mass", "mujoco_bias", "mujoco_actuator", "mujoco_inverse") if k in r]
    out = [_result("eq3", case, Route.MUJOCO, max(r[k] for k in mj_keys), EQ3_RTOL, base,
                   "; ".join(f"{k.removeprefix('mujoco_')} {r[k]:.1e}" for k in mj_keys), seconds=sec)]
    if "pinocchio_crba" in r:
        det = f"crba {r['pinocchio_crba']:.1e}; rnea {r['pinocchio_rnea']:.1e} (passive loads off)"
        if "pinocchio_note" in r:
            det += f"; {r['pinocchio_note']}"
        out.append(_result("eq3", case, Route.PINOCCHIO, max(r["pinocchio_crba"], r["pinocchio_rnea"]), EQ3_RTOL,
                           {**base, "dofs_compared": r["pinocchio_dofs"]}, det))
    else:
        out.append(CheckResult("eq3", case, Route.PINOCCHIO.value, "error", float("nan"), EQ3_RTOL, base, None, None,
                               r.get("pinocchio_note", "Pinocchio route not run")))
    if "kanes_method" not in r:  # too deep for sympy's KanesMethod: the engines decide alone
        out[0] = dataclasses.replace(out[0], detail=out[0].detail + "; " + r["kanes_method_note"])
        return out
    out.append(_result("eq3", case, Route.SYMBOLIC, r["kanes_method"], EQ3_RTOL,
                       {"routes": "explicit partial velocities vs sympy KanesMethod", "evaluated": "mass matrix and forcing at the same states"},
                       f"explicit {mm.timing.get('explicit', 0):.2f} s, KanesMethod {mm.timing.get('kanes_method', 0):.2f} s to derive"))
    return out


def _trajectory_checks(mm: MjcfModel, case: str, quick: bool, seed: int) -> list[CheckResult]:
    t0 = time.perf_counter()
    tr = element_trajectory(mm.path, n_steps=100 if quick else 400, seed=seed)
    f = terms.loss_functions("numpy")
    eq11_term = f["eq11_term"][1]
    Jp, Jr = tr["Jp"][:-1], tr["Jr"][:-1]  # [T-1, n, 3, nv]
    mass, tau, dt = tr["mass"], tr["tau"], tr["dt"]
    F, v, a = tr["F"][:-1], tr["v"], tr["a"][:-1]
    I, w, al = tr["I"][:-1], tr["omega"][:-1], tr["alpha"][:-1]
    Lstar = np.einsum("tnab,tnb->tna", I, al) + np.cross(w, np.einsum("tnab,tnb->tna", I, w))  # I alpha + w x I w
    # per element and speed: F_{gamma,i} = R_i . u_{i,gamma}, v_gamma = v_i . u_{i,gamma}, L*_i . omega_{i,gamma}
    Fg = np.einsum("tna,tnag->tng", F, Jp)
    vg_next = np.einsum("tna,tnag->tng", v[1:], Jp)
    vg = np.einsum("tna,tnag->tng", v[:-1], Jp)
    ag = np.einsum("tna,tnag->tng", a, Jp)
    Lg = np.einsum("tna,tnag->tng", Lstar, Jr)
    psi = -Lg.sum(1)  # [T-1, nv]: Psi_gamma = sum_i (M_i - L*_i) . omega_{i,gamma}, M_i = 0 (gravity at the mass centre)
    S_fd = eq11_term(Fg, mass[None, :, None], vg_next, vg, dt, 1.0).sum(1)  # Eq. (11) summands, finite differences
    S_inst = (Fg - mass[None, :, None] * ag).sum(1)
    # force scale: the largest summand magnitude over frames, elements and speeds (one scale
    # for all speeds: a speed along which no force acts, e.g. a free body's horizontal
    # translation, has no scale of its own)
    scale = np.full(Fg.shape[-1], (np.abs(Fg) + np.abs(mass[None, :, None] * ag) + np.abs(Lg)).sum(1).max() + 1e-300)
    w_g = np.linalg.norm(Jr, axis=2)  # |omega_{i,gamma}| [T-1, n, nv]
    rotational = w_g.max((0, 1)) > 0
    sec = (time.perf_counter() - t0) / max(1, Jp.shape[-1])
    names = _speed_names(mm)
    common = {"elements": "one per body (mass centre, MuJoCo inertia)", "loads": "gravity only (constraints, actuation, damping, springs, armature off)",
              "integrator": "MuJoCo Euler", "dt": dt, "frames": int(Jp.shape[0]),
              "partial velocities": "columns of mj_jacBodyCom at each mass centre"}
    out = []
    for g, name in enumerate(names):
        c = f"{case}: speed {name}"
        kind = "rotational" if rotational[g] else "translational"
        r_fd = np.abs(S_fd[:, g] + psi[:, g]) / scale[g]
        t = int(np.argmax(r_fd))
        out.append(_result("eq11", c, Route.MUJOCO, r_fd.max(), TRAJ_RTOL, {**common, "speed": kind, "accelerations": "(v[t+1] - v[t]) / delta"},
                           "largest |Eq. (11) + Psi| / force scale over frames",
                           {"claim_id": "eq11", "kind": "trajectory", "case": c, "frame": t, "gamma": name}, sec))
        r_in = np.abs(S_inst[:, g] + psi[:, g]) / scale[g]
        if not rotational[g]:
            r_in = np.maximum(r_in, np.abs(psi[:, g]) / scale[g])  # and Psi = 0 itself
        out.append(_result("eq11.corrected", c, Route.MUJOCO, r_in.max(), TRAJ_RTOL,
                           {**common, "speed": kind, "accelerations": "instantaneous (J qacc + dJ/dt qvel)"},
                           "translational: |sum F - sum M a| and |Psi|" if not rotational[g] else "rotational: Kane's form, |sum (F - M a) . u + Psi|",
                           seconds=sec))
        if rotational[g]:
            wabs = np.linalg.norm(w, axis=2)
            aabs = np.linalg.norm(al, axis=2)
            Fn = np.linalg.norm(F, axis=2)
            bscale = (mass * tau**2).sum() * (wabs.max() ** 2 + 1)
            paper = f["paper_bound_term"][1](tau[None], Fn, w_g[:, :, g], mass[None], aabs).sum(1)
            corr = f["corrected_bound_term"][1](w_g[:, :, g], tau[None], Fn, mass[None], aabs, wabs).sum(1)
            for cid, B in (("eq12", paper), ("eq12.corrected", corr)):
                margin = (np.abs(psi[:, g]) - B) / bscale
                t = int(np.argmax(margin))
                out.append(_result(cid, c, Route.MUJOCO, margin.max(), BOUND_TOL,
                                   {**common, "tau": "element radius: geoms' bounding spheres about the mass centre, >= sqrt(tr I / 2M)",
                                    "w'_i": "|alpha_i|", "omega_gamma": "|omega_{i,gamma}|"},
                                   "largest (|Psi| - bound) / (sum M tau^2 (|omega|^2 + 1))",
                                   {"claim_id": cid, "kind": "trajectory", "case": c, "frame": t, "psi": float(psi[t, g]), "bound": float(B[t])},
                                   sec))
    return out


def _eq36(mm: MjcfModel, case: str) -> list[CheckResult]:
    import mujoco

    m = mm.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    out = []
    for b in range(1, m.nbody):
        M = float(m.body_mass[b])
        if M <= 0:
            continue
        tau = _body_radius(m, d, b)
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or f"body{b}"
        Imax = float(m.body_inertia[b].max())
        for cid, k in (("eq36", 0.4), ("eq36.corrected", 1.0)):
            margin = (Imax - k * M * tau**2) / (M * tau**2)
            out.append(_result(cid, f"{case}: body {name}", Route.MUJOCO, margin, 1e-12,
                               {"element": "the whole body (MuJoCo's mass and inertia)", "tau": "geoms' bounding spheres about the mass centre, >= sqrt(tr I / 2M)"},
                               "(I_max - bound) / (M tau^2)", {"claim_id": cid, "kind": "mujoco_body", "body": name, "inertia": m.body_inertia[b].tolist(),
                                                                "mass": M, "tau": tau}))
    return out


def run_mjcf_checks(path: str | Path, claim_ids: list[str] | None = None, quick: bool = False, seed: int = 0,
                    model: MjcfModel | None = None) -> list[CheckResult]:
    """Every check of the claim registry that applies to the MJCF tree in ``path``.

    Parameters
    ----------
    path : MJCF file.
    claim_ids : only these claims (a base id such as ``eq12`` also selects ``eq12.corrected``).
    quick : fewer random states (10 instead of 50) and frames (100 instead of 400).
    seed : seeds the random states and the trajectory's initial state.
    model : an already built :func:`kane.mjcf.from_mjcf` of ``path``.

    Raises
    ------
    kane.mjcf.MjcfUnsupported : the file cannot be loaded or is not a plain joint tree.
    """
    mm = model or from_mjcf(path)
    case = Path(path).name
    want = (lambda cid: True) if not claim_ids else (lambda cid: cid in claim_ids or cid.split(".")[0] in claim_ids)
    out: list[CheckResult] = []
    if want("eq3"):
        out += _eq3(mm, case, quick, seed)
    if any(want(c) for c in ("eq11", "eq11.corrected", "eq12", "eq12.corrected")):
        out += [r for r in _trajectory_checks(mm, case, quick, seed) if want(r.claim_id)]
    if want("eq36") or want("eq36.corrected"):
        out += [r for r in _eq36(mm, case) if want(r.claim_id)]
    return out

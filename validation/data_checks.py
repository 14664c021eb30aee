"""Residuals of the Kane claims along ground-truth trajectories of a dataset file.

Two checks per dataset (``mdgs validate --data FILE``):

- ``newton`` (per body): ``m_b g + F_contact + F_actuator + F_joint`` (the recorded frame
  loads) against ``m_b (v_b[t+1] - v_b[t]) / delta`` (finite-difference acceleration of
  the body's centre of mass, ``delta = frame_dt``).
- ``eq11`` (per free-floating system, the translational form of the paper's Eq. (11)):
  for each direction gamma in x, y, z,
  ``sum_i F_gamma,i - sum_i M_i (v_gamma,i[t+1] - v_gamma,i[t]) / delta`` over the
  elements of the system, with ``F_i = M_i g + node_contact_force + node_joint_force``.
  Joint forces between bodies of the system cancel in the sum, so this is the
  system's momentum balance seen through its elements. ``Psi = 0`` here: an element's
  linear momentum is exactly ``M_i`` times its centroid velocity (rigid element,
  uniform density), so Theorem 3.2's disturbance only enters rotational directions.

Tolerance. MuJoCo's Euler integrator is exact in generalized coordinates
(``qvel[s+1] = qvel[s] + h qacc[s]``), not in Cartesian velocities: a body's centre
of mass velocity is ``J(q) qvel`` and ``J`` changes within a step, so the finite
difference of ``v_b`` differs from MuJoCo's acceleration by ``O(h)`` (zero for a free
root body whose origin is its centre of mass). The files record MuJoCo's own
acceleration per body (``body_acc``, frame mean), so the residual splits into

    residual <= |sum loads - m a_mujoco|  +  |m (FD(v) - a_mujoco)|
                 (load bookkeeping)           (integrator discretization, D)

and the tolerance is ``D + 1e-9 * S`` with ``S`` the largest ``|m a| + m |g|`` of the
file: the verdict is 'holds' iff the recorded loads explain MuJoCo's accelerations to
nine digits, and ``D`` is reported alongside as the integrator's share.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["check_dataset"]

_REL = 1e-9  # bookkeeping tolerance relative to the file's force scale


def check_dataset(path: str | Path) -> list[dict]:
    """Newton and Eq. (11) residuals of a dataset file (see the module docstring).

    Raises :class:`mdgs.data.schema.DatasetError` if the file is not a usable dataset.
    """
    from mdgs.data.io import open_dataset

    with open_dataset(path, verify=True) as ds:
        st, a = ds.static, ds.attrs
        delta = float(a["frame_dt"])
        g = np.asarray(a["gravity"], float)
        mass = st["body_mass"]
        moving = ~st["body_static"] & (mass > 0)
        body_ids = st["body_id"]
        col = {int(b): i for i, b in enumerate(body_ids)}
        systems = [int(b) for b, free in zip(body_ids, st["body_free"], strict=True) if free]
        node_body, node_mass = st["node_body"], st["node_mass"]
        node_moving = ~st["node_static"]

        newton_res = np.zeros(len(body_ids))
        newton_bk = np.zeros(len(body_ids))
        newton_D = np.zeros(len(body_ids))
        eq_res = {s: 0.0 for s in systems}
        eq_bk = {s: 0.0 for s in systems}
        eq_D = {s: 0.0 for s in systems}
        scale = 0.0
        overflow = 0
        for t in range(ds.n_traj):
            v = ds.frames("body_linvel", t)  # [F, B, 3]
            acc = ds.frames("body_acc", t)
            loads = (
                mass[None, :, None] * g
                + ds.frames("body_contact_force", t)
                + ds.frames("body_actuator_force", t)
                + ds.frames("body_joint_force", t)
            )
            ma_fd = mass[None, :, None] * np.diff(v, axis=0) / delta
            ma = mass[None, :, None] * acc
            scale = max(
                scale,
                float(np.abs(ma).max(initial=0.0) + (mass * np.linalg.norm(g)).max(initial=0.0)),
            )
            newton_res = np.maximum(newton_res, np.abs(loads[:-1] - ma_fd).max(axis=(0, 2)))
            newton_bk = np.maximum(newton_bk, np.abs(loads - ma).max(axis=(0, 2)))
            newton_D = np.maximum(newton_D, np.abs(ma_fd - ma[:-1]).max(axis=(0, 2)))
            overflow += int(ds.frames("contact_overflow", t).sum())
            if systems:
                nv = ds.frames("node_vel", t)  # [F, N, 3]
                nf = (
                    node_mass[None, :, None] * g
                    + ds.frames("node_contact_force", t)
                    + ds.frames("node_joint_force", t)
                )
                for s in systems:
                    sel = node_moving & np.isin(node_body, _system_bodies(st, s))
                    F = nf[:, sel].sum(1)  # [F, 3]
                    P = (node_mass[sel][None, :, None] * nv[:, sel]).sum(1)
                    bsel = [col[b] for b in _system_bodies(st, s)]
                    Ma = (mass[bsel][None, :, None] * acc[:, bsel]).sum(1)
                    dP = np.diff(P, axis=0) / delta
                    eq_res[s] = max(eq_res[s], float(np.abs(F[:-1] - dP).max(initial=0.0)))
                    eq_bk[s] = max(eq_bk[s], float(np.abs(F - Ma).max(initial=0.0)))
                    eq_D[s] = max(eq_D[s], float(np.abs(dP - Ma[:-1]).max(initial=0.0)))

        case = str(a["scene"])
        names = st["body_names"]
        floor = _REL * scale
        assumptions = {
            "integrator": f"{a['integrator']} (semi-implicit, exact in generalized coordinates)",
            "dt": float(a["dt"]),
            "frame_dt": delta,
            "loads": "frame means over the substeps (impulse / frame_dt)",
            "tolerance": "integrator discretization D (from MuJoCo's recorded accelerations) + 1e-9 x force scale",
            "force_scale_N": scale,
        }
        out = []
        mv = np.flatnonzero(moving)
        if len(mv):
            worst = mv[np.argmax(newton_res[mv])]
            tol = float(newton_D[mv].max() + floor)
            per_body = {
                str(names[i]): {
                    "residual": float(newton_res[i]),
                    "bookkeeping": float(newton_bk[i]),
                    "discretization": float(newton_D[i]),
                }
                for i in mv
            }
            res = float(newton_res[mv].max())
            out.append(
                _result(
                    "newton",
                    case,
                    res,
                    tol,
                    assumptions,
                    f"largest residual {res:.3g} N on body '{names[worst]}'; loads vs MuJoCo's acceleration {float(newton_bk[mv].max()):.3g} N; "
                    f"integrator discretization {float(newton_D[mv].max()):.3g} N; per body: {per_body}",
                )
            )
        for s in systems:
            tol = eq_D[s] + floor
            detail = (
                f"system rooted at '{names[col[s]]}' ({len(_system_bodies(st, s))} bodies); largest residual {eq_res[s]:.3g} N; "
                f"element loads vs MuJoCo's momentum rate {eq_bk[s]:.3g} N; integrator discretization {eq_D[s]:.3g} N"
            )
            if overflow:
                detail += f"; {overflow} body-substeps had more contacts than slots (their smallest contacts act at the net-force centre)"
            out.append(
                _result(
                    "eq11",
                    case,
                    eq_res[s],
                    tol,
                    {
                        **assumptions,
                        "Psi": "0 (translational directions)",
                        "system_root": str(names[col[s]]),
                    },
                    detail,
                )
            )
        return out


def _system_bodies(st: dict, root: int) -> list[int]:
    return [int(b) for b, r in zip(st["body_id"], st["body_root"], strict=True) if int(r) == root]


def _result(
    claim: str, case: str, residual: float, tol: float, assumptions: dict, detail: str
) -> dict:
    return {
        "claim_id": claim,
        "case": case,
        "route": "mujoco",
        "residual": float(residual),
        "tolerance": float(tol),
        "verdict": "holds" if residual <= tol else "refuted",
        "assumptions": dict(assumptions),
        "detail": detail,
    }

"""Residuals of the Kane claims along ground-truth trajectories of a dataset file.

Checks per dataset (``mdgs validate --data FILE``); tolerance ``1e-9 * S`` throughout, with
``S = (sum of the moving bodies' masses) * max(|g|, 1 m/s^2)`` in N: nine digits of the
model's weight (of its mass times 1 m/s^2 without gravity). ``S`` is set by the model
(the file's static body table and gravity), never by the trajectories it judges: a
blown-up simulation's huge forces must not widen its own tolerance. Round-off of the
recorded sums stays near ``1e-16`` of the forces, so forces up to ``1e6`` times the weight
still pass, while a missing load of a micronewton per kilogram does not.

- ``newton`` (per body): the recorded frame loads ``m_b g + F_contact + F_actuator + F_joint``
  against ``m_b a_b`` with MuJoCo's recorded body acceleration (``body_acc``, frame mean).
  This says the files' loads are complete and consistent.
- ``eq11`` (per free-floating system): the paper's Eq. (11) in translational directions,
  ``sum_i F_gamma,i - sum_i M_i (v_gamma,i[t+1] - v_gamma,i[t]) / delta`` over the system's
  elements, with ``F_i = M_i g + node_contact_force + node_joint_force`` (``Psi = 0`` in
  translational directions). Finite differences are exact only for a single free body
  whose origin is its centre of mass: MuJoCo's Euler integrator is exact in generalized
  coordinates, and a child body's Cartesian velocity ``J(q) qvel`` changes with ``J``
  within a step, so multibody systems leave an ``O(h)`` residual (halving with h) and the
  paper's exact equality is refuted there, by the integrator's share reported in the detail.
- ``eq11.corrected``: the same balance with MuJoCo's recorded accelerations in place of
  finite differences (the corrected statement: exact with instantaneous accelerations).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["check_dataset", "force_scale"]

_REL = 1e-9  # bookkeeping tolerance relative to the model's force scale (module docstring)
_G_FLOOR = 1.0  # m/s^2: the acceleration that sets the force scale of a model without gravity


def force_scale(static: dict, gravity: np.ndarray) -> float:
    """``S`` of the module docstring, in N: the moving bodies' mass times ``max(|g|, 1 m/s^2)``."""
    moving = ~np.asarray(static["body_static"], bool)
    mass = float(np.asarray(static["body_mass"], float)[moving].sum())
    return mass * max(float(np.linalg.norm(gravity)), _G_FLOOR)


def check_dataset(path: str | Path) -> list[dict]:
    """Newton and Eq. (11) residuals of a dataset file (see the module docstring).

    Raises :class:`mdgs.data.schema.DatasetError` if the file is not a usable dataset.
    """
    from mdgs.data.io import open_dataset
    from mdgs.data.schema import DatasetError

    with open_dataset(path, verify=True) as ds:
        st, a = ds.static, ds.attrs
        delta = float(a["frame_dt"])
        g = np.asarray(a["gravity"], float)
        mass = st["body_mass"]
        moving = ~st["body_static"] & (mass > 0)
        if not moving.any():
            raise DatasetError(
                f"{path} has no moving body, so there is nothing to check; generate a scene with at least one joint"
            )
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
        data_scale = 0.0  # reported only: the tolerance must not depend on it
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
            data_scale = max(
                data_scale,
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
        scale = force_scale(st, g)
        floor = _REL * scale
        assumptions = {
            "integrator": f"{a['integrator']} (semi-implicit, exact in generalized coordinates)",
            "dt": float(a["dt"]),
            "frame_dt": delta,
            "loads": "frame means over the substeps (impulse / frame_dt)",
            "tolerance": "1e-9 x the model's force scale S = moving mass x max(|g|, 1 m/s^2); set by the model, not by the data",
            "force_scale_N": scale,
            "largest_force_in_data_N": data_scale,
        }
        out = []
        mv = np.flatnonzero(moving)
        if len(mv):
            worst = mv[np.argmax(newton_bk[mv])]
            per_body = {
                str(names[i]): {
                    "loads_vs_mujoco_acc": float(newton_bk[i]),
                    "loads_vs_finite_difference": float(newton_res[i]),
                    "discretization": float(newton_D[i]),
                }
                for i in mv
            }
            out.append(
                _result(
                    "newton",
                    case,
                    float(newton_bk[mv].max()),
                    floor,
                    {**assumptions, "acceleration": "MuJoCo's recorded body acceleration (frame mean)"},
                    f"largest |sum of recorded loads - m a| {float(newton_bk[mv].max()):.3g} N on body '{names[worst]}'; "
                    f"against finite differences of v instead: {float(newton_res[mv].max()):.3g} N, of which the integrator's "
                    f"O(h) share is {float(newton_D[mv].max()):.3g} N; per body: {per_body}",
                )
            )
        for s in systems:
            base = (
                f"system rooted at '{names[col[s]]}' ({len(_system_bodies(st, s))} bodies); element loads vs MuJoCo's "
                f"momentum rate {eq_bk[s]:.3g} N; vs finite differences {eq_res[s]:.3g} N (integrator share {eq_D[s]:.3g} N)"
            )
            if overflow:
                base += f"; {overflow} substeps had more contacts than slots (element contact forces incomplete there)"
            common = {**assumptions, "Psi": "0 (translational directions)", "system_root": str(names[col[s]])}
            # the paper's Eq. (11): finite-difference velocities, exact equality
            out.append(_result("eq11", case, eq_res[s], floor,
                               {**common, "acceleration": "finite differences of element velocities (the paper's form)"}, base))
            # the corrected statement: instantaneous accelerations (exact); finite differences only O(h)
            out.append(_result("eq11.corrected", case, eq_bk[s], floor,
                               {**common, "acceleration": "MuJoCo's recorded accelerations (frame mean)"}, base))
        return out


def _system_bodies(st: dict, root: int) -> list[int]:
    return [int(b) for b, r in zip(st["body_id"], st["body_root"], strict=True) if int(r) == root]


def _result(
    claim: str, case: str, residual: float, tol: float, assumptions: dict, detail: str
) -> dict:
    from kane.results import decide

    return {
        "claim_id": claim,
        "case": case,
        "route": "mujoco",
        "residual": float(residual),
        "tolerance": float(tol),
        "verdict": decide(float(residual), float(tol)),
        "assumptions": dict(assumptions),
        "detail": detail,
    }

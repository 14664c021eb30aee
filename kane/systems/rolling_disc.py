"""Kinematics of the rolling disc (nonholonomic, Kane & Levinson 1985) and its MuJoCo coordinate maps.

Coordinates ``(yaw, lean, spin, x, y)`` with ``R = Rz(yaw) Rx(lean) Ry(spin)``; independent
speeds are the disc's angular velocity in the lean frame; the contact point's velocity
(dx/dt, dy/dt) is eliminated with the two rolling constraints.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import sympy as sp
from sympy.physics import mechanics as me

from kane.systems.specs import symbol

#: The system description (:class:`kane.systems.system.AnalyticSystem`), named for annotations only:
#: ``system`` imports this module, so importing it back (even for type checkers) would make a cycle.
AnalyticSystem = Any


def _rolling_disc_kinematics(system: AnalyticSystem) -> dict:
    """Rolling disc, Kane & Levinson (1985); contact point coordinates kept, rolling as
    two velocity constraints on the dependent speeds (dx/dt, dy/dt)."""
    dyn = me.dynamicsymbols
    t = dyn._t
    disc = system.bodies[0]
    r, g = symbol("r"), symbol("g")
    m = sp.sympify(disc.mass)
    q1, q2, q3, q4, q5 = dyn("q_yaw q_lean q_spin q_x q_y")
    u1, u2, u3, u4, u5 = dyn("u_1 u_2 u_3 u_x u_y")
    N = me.ReferenceFrame("N")
    Y = N.orientnew("Y", "Axis", [q1, N.z])
    L = Y.orientnew("L", "Axis", [q2, Y.x])
    R = L.orientnew("R", "Axis", [q3, L.y])
    w_qd = R.ang_vel_in(N)
    R.set_ang_vel(N, u1 * L.x + u2 * L.y + u3 * L.z)
    O = me.Point("O")
    O.set_vel(N, 0)
    C = O.locatenew("C", q4 * N.x + q5 * N.y)  # geometric contact point on the ground
    C.set_vel(N, u4 * N.x + u5 * N.y)
    D = C.locatenew("D", r * L.z)  # disc centre
    D.v2pt_theory(C, N, L)
    P = D.locatenew("P", -r * L.z)  # material point of the disc at the contact
    P.v2pt_theory(D, N, R)
    vc = [P.vel(N).dot(N.x), P.vel(N).dot(N.y)]
    kd = [(R.ang_vel_in(N) - w_qd).dot(e) for e in (L.x, L.y, L.z)] + [
        q4.diff(t) - u4,
        q5.diff(t) - u5,
    ]
    ixx, iyy, izz, ixy, ixz, iyz = (sp.sympify(x) for x in disc.inertia)
    Idy = me.inertia(R, ixx, iyy, izz, ixy, iyz, ixz)
    body = me.RigidBody("disc", D, R, m, (Idy, D))
    Fx, Fy, Fz, Tx, Ty, Tz = (
        sp.Symbol(f"disc_{c}", real=True) for c in ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
    )
    loads = [
        (D, -m * g * N.z),
        (D, Fx * N.x + Fy * N.y + Fz * N.z),
        (R, Tx * N.x + Ty * N.y + Tz * N.z),
    ]
    return {
        "frame": N,
        "q": [q1, q2, q3, q4, q5],
        "u": [u1, u2, u3],
        "u_dep": [u4, u5],
        "kd": kd,
        "vc": vc,
        "bodies": [body],
        "loads": loads,
        "inputs": [Fx, Fy, Fz, Tx, Ty, Tz],
        "names": {"q": ["yaw", "lean", "spin", "x", "y"], "u": ["1", "2", "3"]},
    }


def _rot_zxy(q1, q2, q3):
    """World-from-body rotation ``Rz(q1) Rx(q2) Ry(q3)`` and the lean frame ``Rz(q1) Rx(q2)``."""
    from scipy.spatial.transform import Rotation

    L = Rotation.from_euler("ZX", np.stack([q1, q2], -1)).as_matrix()
    Rm = Rotation.from_euler("ZXY", np.stack([q1, q2, q3], -1)).as_matrix()
    return Rm, L


def _rolling_disc_from_mujoco(system, qpos, qvel, qacc):
    from scipy.spatial.transform import Rotation

    qpos, qvel = np.asarray(qpos, float), np.asarray(qvel, float)
    r = system.value(symbol("r"))
    quat = qpos[..., 3:7]
    rot = Rotation.from_quat(quat.reshape(-1, 4), scalar_first=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ang = rot.as_euler("ZXY").reshape(*quat.shape[:-1], 3)
    Rm = rot.as_matrix().reshape(*quat.shape[:-1], 3, 3)
    _, L = _rot_zxy(ang[..., 0], ang[..., 1], ang[..., 2])
    Lz = L[..., :, 2]
    contact = qpos[..., 0:3] - r * Lz
    q = np.concatenate([ang, contact[..., 0:2]], axis=-1)
    w_w = np.einsum("...ij,...j->...i", Rm, qvel[..., 3:6])
    u = np.einsum("...ji,...j->...i", L, w_w)  # components in L
    udot = None
    if qacc is not None:
        qacc = np.asarray(qacc, float)
        a_w = np.einsum("...ij,...j->...i", Rm, qacc[..., 3:6])  # d/dt(R w_b) = R dw_b/dt
        # Euler rates from w_world = yawdot * z + leandot * Lx + spindot * Ly
        ez = np.broadcast_to(np.array([0.0, 0.0, 1.0]), Lz.shape)
        Amat = np.stack([ez, L[..., :, 0], L[..., :, 1]], axis=-1)
        rates = np.linalg.solve(Amat, w_w[..., None])[..., 0]
        w_L = rates[..., 0:1] * ez + rates[..., 1:2] * L[..., :, 0]
        # u = L^T w  =>  du/dt = L^T (a - w_L x w)
        udot = np.einsum("...ji,...j->...i", L, a_w - np.cross(w_L, w_w))
    return q, u, udot


def _rolling_disc_to_mujoco(system, q, u):
    from scipy.spatial.transform import Rotation

    q, u = np.asarray(q, float), np.asarray(u, float)
    r = system.value(symbol("r"))
    Rm, L = _rot_zxy(q[0], q[1], q[2])
    Lz = L[:, 2]
    centre = np.array([q[3], q[4], 0.0]) + r * Lz
    w_w = L @ u
    v = np.cross(w_w, r * Lz)  # rolling: v_P = v_D + w x (-r Lz) = 0
    quat = Rotation.from_matrix(Rm).as_quat(scalar_first=True)
    return np.concatenate([centre, quat]), np.concatenate([v, Rm.T @ w_w])

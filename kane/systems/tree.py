"""Kinematics of a joint tree (hinge, slide and free joints) for Kane's method, and its MuJoCo coordinate maps.

:func:`_tree_kinematics` builds the frames, points, rigid bodies and loads of a tree of
:class:`~kane.systems.specs.BodySpec`; :func:`_tree_from_mujoco` and
:func:`_tree_to_mujoco` map MuJoCo ``qpos``/``qvel`` to the sympy coordinates and speeds
(free joint: Z-Y-X Euler angles, see :mod:`kane.systems`).
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

import numpy as np
import sympy as sp
from sympy.physics import mechanics as me

from kane.systems.specs import symbol

if TYPE_CHECKING:
    from kane.systems.system import AnalyticSystem


def _exact(x) -> sp.Expr:
    """Sympify, turning Python floats into exact rationals (0.0/1.0 axes stay 0/1, no Float noise)."""
    return sp.Rational(x) if isinstance(x, float) else sp.sympify(x)


def _vec(frame: me.ReferenceFrame, c) -> me.Vector:
    return sum(
        (_exact(ci) * e for ci, e in zip(c, (frame.x, frame.y, frame.z), strict=True)), me.Vector(0)
    )


def _tree_kinematics(system: AnalyticSystem, speeds: str = "u") -> dict:
    """Frames, points, bodies and loads of a joint tree.

    ``speeds='u'``: generalized speeds are new dynamicsymbols (Kane); angular velocities
    are set explicitly in them. ``speeds='qdot'``: u = dq/dt and sympy derives every
    angular velocity from the orientations itself (Lagrange route, independent check).
    """
    dyn = me.dynamicsymbols
    t = dyn._t
    N = me.ReferenceFrame("N")
    O = me.Point("O")
    O.set_vel(N, 0)
    g = symbol("g")
    frames: dict[str | None, me.ReferenceFrame] = {None: N}
    origins: dict[str | None, me.Point] = {None: O}
    q, u, kd, bodies, loads, inputs = [], [], [], [], [], []
    names = {"q": [], "u": []}
    joint_frames: dict[
        str, tuple
    ] = {}  # joint -> (frame before, frame after, point before, point after, axis)

    def new(name):
        qq = dyn(f"q_{name}")
        uu = qq.diff(t) if speeds == "qdot" else dyn(f"u_{name}")
        return qq, uu

    seen = {None}
    for b in system.bodies:
        if b.parent not in seen:
            raise ValueError(
                f"system {system.name!r}: body {b.name!r} listed before its parent {b.parent!r}"
            )
        seen.add(b.name)
        P, Op = frames[b.parent], origins[b.parent]
        F = P
        pt = Op.locatenew(f"{b.name}_joint", _vec(P, b.pos))
        pt.v2pt_theory(Op, N, P)
        for j in b.joints:
            if j.kind == "free":
                if b.parent is not None or len(b.joints) != 1:
                    raise ValueError(
                        f"system {system.name!r}: free joint {j.name!r} must be the only joint of a top-level body"
                    )
                comps = ["x", "y", "z", "yaw", "pitch", "roll"]
                qs = [dyn(f"q_{j.name}_{c}") for c in comps]
                us = [dyn(f"u_{j.name}_{c}") for c in ["vx", "vy", "vz", "wx", "wy", "wz"]]
                names["q"] += [f"{j.name}_{c}" for c in comps]
                names["u"] += [f"{j.name}_{c}" for c in ["vx", "vy", "vz", "wx", "wy", "wz"]]
                B = N.orientnew(f"{b.name}_frame", "Body", qs[3:], "ZYX")
                B.set_ang_vel(N, us[3] * B.x + us[4] * B.y + us[5] * B.z)
                newpt = O.locatenew(f"{b.name}_origin", qs[0] * N.x + qs[1] * N.y + qs[2] * N.z)
                newpt.set_vel(N, us[0] * N.x + us[1] * N.y + us[2] * N.z)
                kd += [qs[i].diff(t) - us[i] for i in range(3)]
                # Z-Y-X Euler rates from body rates (p, q, r) = (wx, wy, wz), solved in closed
                # form so that KanesMethod need not invert the 3x3 trigonometric system:
                # yaw' = (q sin(roll) + r cos(roll)) / cos(pitch), pitch' = q cos(roll) - r sin(roll),
                # roll' = p + (q sin(roll) + r cos(roll)) tan(pitch)
                _, pitch, roll = qs[3:]
                s_ = us[4] * sp.sin(roll) + us[5] * sp.cos(roll)
                kd += [
                    qs[3].diff(t) - s_ / sp.cos(pitch),
                    qs[4].diff(t) - (us[4] * sp.cos(roll) - us[5] * sp.sin(roll)),
                    qs[5].diff(t) - (us[3] + s_ * sp.tan(pitch)),
                ]
                q += qs
                u += us
                F, pt = B, newpt
                continue
            qq, uu = new(j.name)
            names["q"].append(j.name)
            names["u"].append(j.name)
            q.append(qq)
            u.append(uu)
            if speeds == "u":
                kd.append(qq.diff(t) - uu)
            a = _vec(F, j.axis)
            if j.kind == "hinge":
                Fn = F.orientnew(f"{b.name}_{j.name}", "Axis", [qq, a])
                if speeds == "u":
                    Fn.set_ang_vel(F, uu * a)
                joint_frames[j.name] = (F, Fn, pt, pt, a)
                F = Fn
            elif j.kind == "slide":
                newpt = pt.locatenew(f"{b.name}_{j.name}", qq * a)
                newpt.set_vel(F, uu * a)
                newpt.v1pt_theory(pt, N, F)
                joint_frames[j.name] = (F, F, pt, newpt, a)
                pt = newpt
            else:
                raise ValueError(
                    f"system {system.name!r}: joint {j.name!r} has unknown kind {j.kind!r}; use hinge, slide or free"
                )
        frames[b.name], origins[b.name] = F, pt
        mass = sp.sympify(b.mass)
        if mass != 0:
            G = pt.locatenew(f"{b.name}_com", _vec(F, b.com))
            G.v2pt_theory(pt, N, F)
            ixx, iyy, izz, ixy, ixz, iyz = (sp.sympify(x) for x in b.inertia)
            Idy = me.inertia(F, ixx, iyy, izz, ixy, iyz, ixz)
            bodies.append(me.RigidBody(b.name, G, F, mass, (Idy, G)))
            loads.append((G, -mass * g * N.z))
    # actuators: equal and opposite torque (force) on the two sides of the joint
    for act in system.actuators:
        if act.joint not in joint_frames:
            raise ValueError(
                f"system {system.name!r}: actuator {act.name!r} drives unknown joint {act.joint!r}"
            )
        Fb, Fa, pb, pa, a = joint_frames[act.joint]
        tau = sp.Symbol(f"tau_{act.name}", real=True)
        inputs.append(tau)
        if Fb is Fa:  # slide
            loads += [(pa, tau * a), (pb, -tau * a)]
        else:
            loads += [(Fa, tau * a), (Fb, -tau * a)]
    for b in system.bodies:
        if b.external_wrench:
            Fx, Fy, Fz, Tx, Ty, Tz = (
                sp.Symbol(f"{b.name}_{c}", real=True) for c in ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
            )
            inputs += [Fx, Fy, Fz, Tx, Ty, Tz]
            loads += [
                (origins[b.name], Fx * N.x + Fy * N.y + Fz * N.z),
                (frames[b.name], Tx * N.x + Ty * N.y + Tz * N.z),
            ]
    return {
        "frame": N,
        "q": q,
        "u": u,
        "kd": kd,
        "bodies": bodies,
        "loads": loads,
        "inputs": inputs,
        "names": names,
    }


# --------------------------------------------------------------------------------------
# Free-joint orientation: MuJoCo quaternion <-> Z-Y-X Euler angles
# --------------------------------------------------------------------------------------


def _quat_wxyz_to_zyx(quat: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    quat = np.asarray(quat, float)
    rot = Rotation.from_quat(quat.reshape(-1, 4), scalar_first=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gimbal lock: angles still recompose R
        return rot.as_euler("ZYX").reshape(*quat.shape[:-1], 3)


def _zyx_to_quat_wxyz(ang: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("ZYX", np.asarray(ang, float)).as_quat(scalar_first=True)


def _tree_from_mujoco(system: AnalyticSystem, qpos, qvel, qacc=None):
    """MuJoCo state of a joint tree as sympy ``(q, u, udot)`` (see :meth:`AnalyticSystem.mujoco_to_kane`)."""
    qpos, qvel = np.asarray(qpos, float), np.asarray(qvel, float)
    qs, us = [], []
    ip = iv = 0
    for _, j in system.joints:
        if j.kind == "free":
            qs += [qpos[..., ip : ip + 3], _quat_wxyz_to_zyx(qpos[..., ip + 3 : ip + 7])]
            us.append(qvel[..., iv : iv + 6])
            ip, iv = ip + 7, iv + 6
        else:
            qs.append(qpos[..., ip : ip + 1])
            us.append(qvel[..., iv : iv + 1])
            ip, iv = ip + 1, iv + 1
    q = np.concatenate(qs, axis=-1)
    u = np.concatenate(us, axis=-1)
    udot = None if qacc is None else np.asarray(qacc, float).copy()
    return q, u, udot


def _tree_to_mujoco(system: AnalyticSystem, q, u) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`_tree_from_mujoco` for a state: ``(qpos [nq], qvel [nv])``."""
    q, u = np.asarray(q, float), np.asarray(u, float)
    qpos, qvel = [], []
    i = 0
    for _, j in system.joints:
        if j.kind == "free":
            qpos += [q[i : i + 3], _zyx_to_quat_wxyz(q[i + 3 : i + 6])]
            qvel.append(u[i : i + 6])
            i += 6
        else:
            qpos.append(q[i : i + 1])
            qvel.append(u[i : i + 1])
            i += 1
    return np.concatenate(qpos), np.concatenate(qvel)

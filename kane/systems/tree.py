"""Kinematics of a joint tree (hinge, slide, ball and free joints) for Kane's method, and its MuJoCo coordinate maps.

:func:`_tree_kinematics` builds the frames, points, rigid bodies and loads of a tree of
:class:`~kane.systems.specs.BodySpec`; :func:`_tree_from_mujoco` and
:func:`_tree_to_mujoco` map MuJoCo ``qpos``/``qvel`` to the sympy coordinates and speeds
(free joint: Z-Y-X Euler angles, see :mod:`kane.systems`).
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import sympy as sp
from sympy.physics import mechanics as me

from kane.systems.specs import Expr, symbol

#: The system description (:class:`kane.systems.system.AnalyticSystem`), named for annotations only:
#: ``system`` imports this module, so importing it back (even for type checkers) would make a cycle.
AnalyticSystem = Any


def _exact(x) -> sp.Expr:
    """Sympify, turning Python floats into exact rationals (0.0/1.0 axes stay 0/1, no Float noise)."""
    return sp.Rational(x) if isinstance(x, float) else sp.sympify(x)


def _vec(frame: me.ReferenceFrame, c) -> me.Vector:
    return sum(
        (_exact(ci) * e for ci, e in zip(c, (frame.x, frame.y, frame.z), strict=True)), me.Vector(0)
    )


def _zyx_rates(qs, us, t) -> list:
    """Kinematic differential equations of body-fixed Z-Y-X angles (yaw, pitch, roll).

    Rates from body rates (p, q, r) = ``us``, solved in closed form so that KanesMethod
    need not invert the 3x3 trigonometric system: yaw' = (q sin(roll) + r cos(roll)) /
    cos(pitch), pitch' = q cos(roll) - r sin(roll), roll' = p + (q sin(roll) + r
    cos(roll)) tan(pitch).
    """
    _, pitch, roll = qs
    s_ = us[1] * sp.sin(roll) + us[2] * sp.cos(roll)
    return [
        qs[0].diff(t) - s_ / sp.cos(pitch),
        qs[1].diff(t) - (us[1] * sp.cos(roll) - us[2] * sp.sin(roll)),
        qs[2].diff(t) - (us[0] + s_ * sp.tan(pitch)),
    ]


def _quat_dcm(quat) -> sp.Matrix:
    """Rotation matrix of the constant unit quaternion ``(w, x, y, z)`` (MJCF ``quat``):
    columns are the rotated frame's axes in the parent frame.

    Evaluated in floating point; entries below 1e-15 in magnitude are set to 0 (float noise
    of axis-aligned rotations such as a quarter turn), entries 0, 1, -1 are exact.
    """
    w, x, y, z = (float(c) for c in quat)
    n = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    R[np.abs(R) < 1e-15] = 0.0
    return sp.Matrix(3, 3, [_exact(float(v)) if v in (0.0, 1.0, -1.0) else sp.Float(v, 17) for v in R.ravel()])


def _fixed_rotation(parent: me.ReferenceFrame, name: str, quat) -> me.ReferenceFrame:
    """Frame rotated from ``parent`` by the constant unit quaternion ``quat`` (:func:`_quat_dcm`)."""
    F = me.ReferenceFrame(name)
    F.orient_explicit(parent, _quat_dcm(quat))  # F.dcm(parent) = R^T: F's axes are R's columns in parent
    return F


def _is_identity_quat(quat) -> bool:
    return tuple(float(c) for c in quat) == (1.0, 0.0, 0.0, 0.0)


def _nonzero(x) -> bool:
    return sp.sympify(x) != 0


def _tree_kinematics(system: AnalyticSystem, speeds: str = "u") -> dict:
    """Frames, points, bodies and loads of a joint tree.

    ``speeds='u'``: generalized speeds are new dynamicsymbols (Kane); angular velocities
    are set explicitly in them. ``speeds='qdot'``: u = dq/dt and sympy derives every
    angular velocity from the orientations itself (Lagrange route, independent check).

    Joints compose as in MuJoCo's ``mj_kinematics``: a hinge rotates the body by
    ``q - ref`` about its axis through the anchor ``pos``; a slide translates it by
    ``(q - ref) axis``; a ball rotates it about the anchor by body-fixed Z-Y-X angles
    (speeds: angular velocity relative to the parent in the body's components, MuJoCo's
    ball ``qvel``). Passive joint loads enter as equal and opposite torques (forces) on the
    two sides of the joint: damping ``-d u``, stiffness ``-k (q - springref)`` (hinge and
    slide). Armature is returned as ``armature``: ``(speed index, value)`` pairs that
    :func:`kane.systems.derive._plain_model_data` adds to the mass matrix diagonal.
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
    armature: list[tuple[int, Expr]] = []
    names = {"q": [], "u": []}
    joint_frames: dict[
        str, tuple
    ] = {}  # joint -> (frame before, frame after, point before, point after, axis)

    def new(name):
        qq = dyn(f"q_{name}")
        uu = qq.diff(t) if speeds == "qdot" else dyn(f"u_{name}")
        return qq, uu

    def refuse(msg):
        raise ValueError(f"system {system.name!r}: {msg}")

    seen = {None}
    for b in system.bodies:
        if b.parent not in seen:
            refuse(f"body {b.name!r} listed before its parent {b.parent!r}")
        seen.add(b.name)
        P, Op = frames[b.parent], origins[b.parent]
        F = P
        pt = Op.locatenew(f"{b.name}_joint", _vec(P, b.pos))
        pt.v2pt_theory(Op, N, P)
        if not _is_identity_quat(b.quat):
            F = _fixed_rotation(P, f"{b.name}_fixed", b.quat)
        for jk, j in enumerate(b.joints):
            if j.kind == "free":
                if b.parent is not None or len(b.joints) != 1:
                    refuse(f"free joint {j.name!r} must be the only joint of a top-level body")
                if _nonzero(j.stiffness):
                    refuse(f"free joint {j.name!r} has stiffness, which the tree derivation does not model")
                comps = ["x", "y", "z", "yaw", "pitch", "roll"]
                ucomps = ["vx", "vy", "vz", "wx", "wy", "wz"]
                qs = [dyn(f"q_{j.name}_{c}") for c in comps]
                us = [dyn(f"u_{j.name}_{c}") for c in ucomps]
                names["q"] += [f"{j.name}_{c}" for c in comps]
                names["u"] += [f"{j.name}_{c}" for c in ucomps]
                B = N.orientnew(f"{b.name}_frame", "Body", qs[3:], "ZYX")
                B.set_ang_vel(N, us[3] * B.x + us[4] * B.y + us[5] * B.z)
                newpt = O.locatenew(f"{b.name}_origin", qs[0] * N.x + qs[1] * N.y + qs[2] * N.z)
                newpt.set_vel(N, us[0] * N.x + us[1] * N.y + us[2] * N.z)
                kd += [qs[i].diff(t) - us[i] for i in range(3)]
                kd += _zyx_rates(qs[3:], us[3:], t)
                if _nonzero(j.damping):
                    d = sp.sympify(j.damping)
                    loads += [
                        (newpt, -d * (us[0] * N.x + us[1] * N.y + us[2] * N.z)),
                        (B, -d * (us[3] * B.x + us[4] * B.y + us[5] * B.z)),
                    ]
                if _nonzero(j.armature):
                    armature += [(len(u) + i, sp.sympify(j.armature)) for i in range(6)]
                q += qs
                u += us
                F, pt = B, newpt
                continue
            if j.kind == "ball":
                if speeds == "qdot":
                    refuse(f"ball joint {j.name!r}: its speeds are angular velocities, not dq/dt")
                if jk != len(b.joints) - 1:
                    refuse(f"ball joint {j.name!r} must be the last joint of body {b.name!r}")
                if _nonzero(j.stiffness):
                    refuse(f"ball joint {j.name!r} has stiffness, which the tree derivation does not model")
                comps, ucomps = ["yaw", "pitch", "roll"], ["wx", "wy", "wz"]
                qs = [dyn(f"q_{j.name}_{c}") for c in comps]
                us = [dyn(f"u_{j.name}_{c}") for c in ucomps]
                names["q"] += [f"{j.name}_{c}" for c in comps]
                names["u"] += [f"{j.name}_{c}" for c in ucomps]
                Fn = F.orientnew(f"{b.name}_{j.name}", "Body", qs, "ZYX")
                w_rel = us[0] * Fn.x + us[1] * Fn.y + us[2] * Fn.z
                Fn.set_ang_vel(F, w_rel)
                kd += _zyx_rates(qs, us, t)
                if any(_nonzero(c) for c in j.pos):
                    A = pt.locatenew(f"{b.name}_{j.name}_anchor", _vec(F, j.pos))
                    A.v2pt_theory(pt, N, F)
                    newpt = A.locatenew(f"{b.name}_{j.name}_origin", -_vec(Fn, j.pos))
                    newpt.v2pt_theory(A, N, Fn)
                    pt = newpt
                if _nonzero(j.damping):
                    d = sp.sympify(j.damping)
                    loads += [(Fn, -d * w_rel), (F, d * w_rel)]
                if _nonzero(j.armature):
                    armature += [(len(u) + i, sp.sympify(j.armature)) for i in range(3)]
                joint_frames[j.name] = None  # not drivable by a motor
                q += qs
                u += us
                F = Fn
                continue
            qq, uu = new(j.name)
            names["q"].append(j.name)
            names["u"].append(j.name)
            q.append(qq)
            u.append(uu)
            if speeds == "u":
                kd.append(qq.diff(t) - uu)
            a = _vec(F, j.axis)
            ref = _exact(j.ref)
            disp = qq - ref if ref != 0 else qq
            if j.kind == "hinge":
                Fn = F.orientnew(f"{b.name}_{j.name}", "Axis", [disp, a])
                if speeds == "u":
                    Fn.set_ang_vel(F, uu * a)
                if any(_nonzero(c) for c in j.pos):
                    A = pt.locatenew(f"{b.name}_{j.name}_anchor", _vec(F, j.pos))
                    A.v2pt_theory(pt, N, F)
                    newpt = A.locatenew(f"{b.name}_{j.name}_origin", -_vec(Fn, j.pos))
                    newpt.v2pt_theory(A, N, Fn)
                else:
                    newpt = pt
                joint_frames[j.name] = (F, Fn, pt, newpt, a)
                passive = (Fn, F)
                F, pt = Fn, newpt
            elif j.kind == "slide":
                newpt = pt.locatenew(f"{b.name}_{j.name}", disp * a)
                newpt.set_vel(F, uu * a)
                newpt.v1pt_theory(pt, N, F)
                joint_frames[j.name] = (F, F, pt, newpt, a)
                passive = (newpt, pt)
                pt = newpt
            else:
                refuse(f"joint {j.name!r} has unknown kind {j.kind!r}; use hinge, slide, ball or free")
            gen = sp.S.Zero  # passive generalized load along the joint axis
            if _nonzero(j.damping):
                gen += -sp.sympify(j.damping) * uu
            if _nonzero(j.stiffness):
                gen += -sp.sympify(j.stiffness) * (qq - sp.sympify(j.springref))
            if gen != 0:
                loads += [(passive[0], gen * a), (passive[1], -gen * a)]
            if _nonzero(j.armature):
                armature.append((len(u) - 1, sp.sympify(j.armature)))
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
        if joint_frames.get(act.joint) is None:
            refuse(f"actuator {act.name!r} drives {act.joint!r}, which is not a hinge or slide joint")
        Fb, Fa, pb, pa, a = joint_frames[act.joint]
        tau = sp.Symbol(f"tau_{act.name}", real=True)
        inputs.append(tau)
        if act.gear != 1:
            a = _exact(float(act.gear)) * a
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
        "armature": armature,
    }


# --------------------------------------------------------------------------------------
# Free- and ball-joint orientation: MuJoCo quaternion <-> Z-Y-X Euler angles
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
        elif j.kind == "ball":
            qs.append(_quat_wxyz_to_zyx(qpos[..., ip : ip + 4]))
            us.append(qvel[..., iv : iv + 3])
            ip, iv = ip + 4, iv + 3
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
        elif j.kind == "ball":
            qpos.append(_zyx_to_quat_wxyz(q[i : i + 3]))
            qvel.append(u[i : i + 3])
            i += 3
        else:
            qpos.append(q[i : i + 1])
            qvel.append(u[i : i + 1])
            i += 1
    return np.concatenate(qpos), np.concatenate(qvel)

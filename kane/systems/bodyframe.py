"""Kane's equations of a joint tree written out in body-frame components: partial velocities, generalized active and inertia forces, without sympy's KanesMethod.

Kane & Levinson (1985), Ch. 5-6: with generalized speeds ``u``, every velocity is linear in
``u``, ``v = V u`` and ``omega = W u``; the columns of ``V`` and ``W`` are the partial
velocities and partial angular velocities. Accelerations are ``a = V udot + a0`` and
``alpha = W udot + alpha0``. Kane's equations ``F_r + F*_r = 0`` read

    F_r  = sum_bodies V_G^T (m g) + passive + actuator generalized forces,
    F*_r = -sum_bodies [V_G^T m (V_G udot + a0_G) + W^T (I (W udot + alpha0) + omega x I omega)],

so ``M = sum m V_G^T V_G + W^T I W`` and ``forcing = F_r - sum (m V_G^T a0_G + W^T (I alpha0 +
omega x I omega))``. Every vector is kept in the components of the frame it belongs to and
carried from parent to child by one joint rotation at a time (the recursion of Featherstone
2008, Ch. 5, in Kane's variables), so expressions stay nested instead of multiplying out
long chains of direction cosines; no time derivative is ever taken symbolically:

* offset by ``r`` (fixed in the frame): ``V <- V - [r]x W``, ``a0 <- a0 + alpha0 x r + omega x (omega x r)``;
* rotation by ``R`` (columns: new axes in the old frame): every column ``x <- R^T x``;
* hinge about unit axis ``s`` by ``q - ref`` (Rodrigues' ``R``): ``W <- R^T W + s e_k^T``,
  ``alpha0 <- R^T alpha0 + (R^T omega) x s u_k``;
* slide along ``s`` by ``q - ref``: offset ``d = (q - ref) s``, then ``V <- V + s e_k^T``,
  ``a0 <- a0 + 2 omega x s u_k``;
* ball (body-fixed Z-Y-X angles, speeds = relative angular velocity ``w`` in the child's
  components): ``W <- R^T W + [e_kx e_ky e_kz]``, ``alpha0 <- R^T alpha0 + (R^T omega) x w``;
* free (top level, Z-Y-X angles; speeds: world linear velocity, body angular velocity):
  ``V = R^T [e_vx e_vy e_vz]``, ``W = [e_wx e_wy e_wz]``, ``a0 = alpha0 = 0``.

Same description and conventions as :func:`kane.systems.tree._tree_kinematics` (which feeds
sympy's ``KanesMethod``), same plain symbols as :class:`kane.systems.SymbolicModel`, so that
the two derivations can be compared term by term.
"""

from __future__ import annotations

from typing import Any

import sympy as sp

from kane.systems.specs import symbol
from kane.systems.tree import _exact, _is_identity_quat, _nonzero, _quat_dcm

#: The system description (:class:`kane.systems.system.AnalyticSystem`), named for annotations only:
#: ``system`` imports this module, so importing it back (even for type checkers) would make a cycle.
AnalyticSystem = Any

__all__ = ["bodyframe_kane"]


def _skew(r: sp.Matrix) -> sp.Matrix:
    return sp.Matrix([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])


def _col(c) -> sp.Matrix:
    return sp.Matrix([_exact(x) for x in c])


def _rodrigues(s: sp.Matrix, th) -> sp.Matrix:
    """Rotation by ``th`` about unit axis ``s`` (columns: rotated axes in the old frame)."""
    c, sn = sp.cos(th), sp.sin(th)
    return c * sp.eye(3) + sn * _skew(s) + (1 - c) * (s * s.T)


def _rot_zyx(yaw, pitch, roll) -> sp.Matrix:
    """``Rz(yaw) Ry(pitch) Rx(roll)``: body-fixed Z-Y-X rotation (sympy's 'Body', 'ZYX')."""
    cz, sz, cy, sy, cx, sx = sp.cos(yaw), sp.sin(yaw), sp.cos(pitch), sp.sin(pitch), sp.cos(roll), sp.sin(roll)
    Rz = sp.Matrix([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    Ry = sp.Matrix([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = sp.Matrix([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return Rz * Ry * Rx


def _zyx_rates(q3, u3) -> list:
    """Z-Y-X angle rates from body rates, as :func:`kane.systems.tree._zyx_rates`."""
    _, pitch, roll = q3
    s_ = u3[1] * sp.sin(roll) + u3[2] * sp.cos(roll)
    return [s_ / sp.cos(pitch), u3[1] * sp.cos(roll) - u3[2] * sp.sin(roll), u3[0] + s_ * sp.tan(pitch)]


class _Frame:
    """Kinematic state of one frame in its own components: V, W [3, n]; a0, alpha0 [3, 1]; gravity [3, 1]."""

    def __init__(self, V, W, a0, al0, grav):
        self.V, self.W, self.a0, self.al0, self.grav = V, W, a0, al0, grav

    def omega(self, u: sp.Matrix) -> sp.Matrix:
        return self.W * u

    def offset(self, r: sp.Matrix, u) -> _Frame:
        if all(x == 0 for x in r):
            return self
        w = self.omega(u)
        return _Frame(self.V - _skew(r) * self.W, self.W, self.a0 + self.al0.cross(r) + w.cross(w.cross(r)), self.al0, self.grav)

    def rotate(self, R: sp.Matrix) -> _Frame:
        Rt = R.T
        return _Frame(Rt * self.V, Rt * self.W, Rt * self.a0, Rt * self.al0, Rt * self.grav)


def bodyframe_kane(system: AnalyticSystem) -> dict:
    """Kane's equations of a joint tree in body-frame components (see the module docstring).

    Parameters
    ----------
    system : AnalyticSystem with ``derivation == 'tree'`` and no external wrench inputs.

    Returns
    -------
    dict with the fields of :class:`kane.systems.SymbolicModel` (``q``, ``u``, ``udot``,
    ``inputs``, ``params``, ``fr``, ``frstar``, ``mass_matrix``, ``forcing``, ``qdot``) and
    ``partials``: ``(body, V_G, W)`` per massive body, the partial velocities of its mass
    centre and partial angular velocities (columns: speeds) in the body's own components.
    """
    if system.derivation != "tree" or system.wrench_bodies:
        raise ValueError(f"system {system.name!r}: the body-frame derivation takes joint trees without external wrench inputs")
    qs, us, qdot, names = [], [], [], []
    for _, j in system.joints:
        if j.kind == "free":
            qn = [f"{j.name}_{c}" for c in ("x", "y", "z", "yaw", "pitch", "roll")]
            un = [f"{j.name}_{c}" for c in ("vx", "vy", "vz", "wx", "wy", "wz")]
        elif j.kind == "ball":
            qn = [f"{j.name}_{c}" for c in ("yaw", "pitch", "roll")]
            un = [f"{j.name}_{c}" for c in ("wx", "wy", "wz")]
        else:
            qn = un = [j.name]
        qs += [sp.Symbol(f"q_{n}", real=True) for n in qn]
        names += un
    us = [sp.Symbol(f"u_{n}", real=True) for n in names]
    uds = [sp.Symbol(f"ud_{n}", real=True) for n in names]
    n = len(us)
    u = sp.Matrix(us)
    g = symbol("g")
    zero3, zero3n = sp.zeros(3, 1), sp.zeros(3, n)
    world = _Frame(zero3n, zero3n, zero3, zero3, sp.Matrix([0, 0, -g]))
    frames: dict = {None: world}
    fr = sp.zeros(n, 1)
    M = sp.zeros(n, n)
    fstar = sp.zeros(n, 1)
    partials = []
    iq = iu = 0
    joint_speed: dict[str, int] = {}

    def e(k: int) -> sp.Matrix:
        col = sp.zeros(1, n)
        col[0, k] = 1
        return col

    for b in system.bodies:
        F = frames[b.parent].offset(_col(b.pos), u)
        if not _is_identity_quat(b.quat):
            F = F.rotate(_quat_dcm(b.quat))
        for j in b.joints:
            if j.kind == "free":
                x, y, z, yaw, pitch, roll = qs[iq : iq + 6]
                R = _rot_zyx(yaw, pitch, roll)
                E = sp.zeros(3, n)
                Ew = sp.zeros(3, n)
                for c in range(3):
                    E[c, iu + c] = 1
                    Ew[c, iu + 3 + c] = 1
                F = _Frame(R.T * E, Ew, zero3, zero3, R.T * world.grav)
                qdot += [us[iu], us[iu + 1], us[iu + 2], *_zyx_rates((yaw, pitch, roll), us[iu + 3 : iu + 6])]
                if _nonzero(j.damping):
                    fr[iu : iu + 6, 0] = fr[iu : iu + 6, 0] - sp.sympify(j.damping) * u[iu : iu + 6, 0]
                if _nonzero(j.armature):
                    for c in range(6):
                        M[iu + c, iu + c] += sp.sympify(j.armature)
                iq, iu = iq + 6, iu + 6
                continue
            pos = _col(j.pos)
            if j.kind in ("hinge", "ball"):
                F = F.offset(pos, u)
            if j.kind == "ball":
                R = _rot_zyx(*qs[iq : iq + 3])
                w_rel = u[iu : iu + 3, 0]
                w_par = R.T * F.omega(u)
                E = sp.zeros(3, n)
                for c in range(3):
                    E[c, iu + c] = 1
                F = F.rotate(R)
                F = _Frame(F.V, F.W + E, F.a0, F.al0 + w_par.cross(w_rel), F.grav)
                qdot += _zyx_rates(qs[iq : iq + 3], us[iu : iu + 3])
                ks = range(iu, iu + 3)
                iq, iu = iq + 3, iu + 3
            else:
                s = _col(j.axis)
                th = qs[iq] - _exact(j.ref) if _nonzero(j.ref) else qs[iq]
                if j.kind == "hinge":
                    R = _rodrigues(s, th)
                    w_par = R.T * F.omega(u)
                    F = F.rotate(R)
                    F = _Frame(F.V, F.W + s * e(iu), F.a0, F.al0 + w_par.cross(s * us[iu]), F.grav)
                elif j.kind == "slide":
                    w = F.omega(u)
                    F = F.offset(th * s, u)
                    F = _Frame(F.V + s * e(iu), F.W, F.a0 + 2 * w.cross(s * us[iu]), F.al0, F.grav)
                else:
                    raise ValueError(f"system {system.name!r}: joint {j.name!r} has unknown kind {j.kind!r}")
                if _nonzero(j.stiffness):
                    fr[iu] += -sp.sympify(j.stiffness) * (qs[iq] - sp.sympify(j.springref))
                joint_speed[j.name] = iu
                qdot.append(us[iu])
                ks = [iu]
                iq, iu = iq + 1, iu + 1
            if j.kind in ("hinge", "ball"):
                F = F.offset(-pos, u)
            for k in ks:
                if _nonzero(j.damping):
                    fr[k] += -sp.sympify(j.damping) * us[k]
                if _nonzero(j.armature):
                    M[k, k] += sp.sympify(j.armature)
        frames[b.name] = F
        m = sp.sympify(b.mass)
        if m == 0:
            continue
        c = sp.Matrix([sp.sympify(x) for x in b.com])
        G = F.offset(c, u)
        ixx, iyy, izz, ixy, ixz, iyz = (sp.sympify(x) for x in b.inertia)
        I = sp.Matrix([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        w = F.omega(u)
        partials.append((b.name, G.V, F.W))
        M += m * G.V.T * G.V + F.W.T * I * F.W
        fstar += -(m * G.V.T * G.a0) - F.W.T * (I * F.al0 + w.cross(I * w))
        fr += G.V.T * (m * F.grav)
    inputs = []
    for act in system.actuators:
        tau = sp.Symbol(f"tau_{act.name}", real=True)
        inputs.append(tau)
        fr[joint_speed[act.joint]] += _exact(float(act.gear)) * tau if act.gear != 1 else tau
    ud = sp.Matrix(uds)
    return {
        "q": tuple(qs),
        "u": tuple(us),
        "udot": tuple(uds),
        "inputs": tuple(inputs),
        "params": tuple(sorted((symbol(k) for k in system.params), key=str)),
        "fr": fr,
        "frstar": fstar - M * ud,
        "mass_matrix": M,
        "forcing": fr + fstar,
        "qdot": tuple(qdot),
        "partials": partials,
    }

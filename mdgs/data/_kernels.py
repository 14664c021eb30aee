"""Compiled per-step reductions of :class:`mdgs.data.record.FrameReducer` (numba).

MuJoCo records a few hundred numbers per body and integrator step; the recorder turns
them into frame means. Done in numpy this took more time than MuJoCo's own load
computation (a dozen passes over ``[frames, steps, bodies, 3]`` arrays per frame, each
with its temporaries); these loops make one pass, in C, and use no temporaries.

Every loop runs over one frame's ``k`` steps in a fixed order (no ``fastmath``, no
parallel reductions), so a frame's values never depend on how many frames or
trajectories a call holds: batches, workers and shards give the same bits. Layouts
follow :meth:`mujoco.batch.Batch.rollout`: per-step fields are ``[X, k, nbody, ...]``
(``X`` frames of ``k`` steps), wrenches are ``[torque; force]``.

The formulas are those documented in :mod:`mdgs.data.record`; they are compiled on
first use and cached on disk (numba ``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

_JIT = {"cache": True, "nogil": True, "error_model": "numpy"}


@njit(**_JIT)
def _moment(pts, xipos, x, s, i, b, fx, fy, fz):  # pragma: no cover
    """``(c - com) x f`` at step ``s``, ``c = pts[x, s, i]``: the torque about body ``b``'s
    centre of mass of a force ``f`` acting at ``c`` (what moving a wrench from ``c`` to the
    centre of mass adds to its torque)."""
    rx = pts[x, s, i, 0] - xipos[x, s, b, 0]
    ry = pts[x, s, i, 1] - xipos[x, s, b, 1]
    rz = pts[x, s, i, 2] - xipos[x, s, b, 2]
    return ry * fz - rz * fy, rz * fx - rx * fz, rx * fy - ry * fx


@njit(**_JIT)
def joint_loads(cint, xipos, sub, root, child_ptr, child_idx, k, joint, fint):  # pragma: no cover
    """Joint wrenches of every body about its centre of mass, frame means.

    ``cint [X, k, nb, 6]``: ``cfrc_int`` (about the tree's reference point ``sub[root]``);
    ``child_ptr [nb+1]``, ``child_idx``: children of each body (CSR). Out ``joint
    [X, nb-1, 6]``: the parent's wrench on ``b`` minus what ``b`` passes to its children,
    torque moved to ``xipos[b]`` at every step (``tau + (c - com) x f``); ``fint
    [X, nb-1, 3]``: the mean force the parent exerts on ``b``.
    """
    X, nb = cint.shape[0], cint.shape[2]
    W = np.empty((nb, 6))
    for x in range(X):
        for b in range(1, nb):
            for i in range(6):
                acc = 0.0
                for s in range(k):
                    acc += cint[x, s, b, i]
                W[b, i] = acc
        for b in range(1, nb):
            rt = root[b]
            c0 = c1 = c2 = 0.0
            for s in range(k):
                fx, fy, fz = cint[x, s, b, 3], cint[x, s, b, 4], cint[x, s, b, 5]
                for ci in range(child_ptr[b], child_ptr[b + 1]):
                    c = child_idx[ci]
                    fx -= cint[x, s, c, 3]
                    fy -= cint[x, s, c, 4]
                    fz -= cint[x, s, c, 5]
                m0, m1, m2 = _moment(sub, xipos, x, s, rt, b, fx, fy, fz)
                c0 += m0
                c1 += m1
                c2 += m2
            cr = (c0, c1, c2)
            for i in range(6):
                w = W[b, i]
                for ci in range(child_ptr[b], child_ptr[b + 1]):
                    w -= W[child_idx[ci], i]
                joint[x, b - 1, i] = (w + cr[i]) / k if i < 3 else w / k
            for i in range(3):
                fint[x, b - 1, i] = W[b, 3 + i] / k


@njit(**_JIT)
def step_means(sd, lin0, B, g, k, acc):  # pragma: no cover
    """MuJoCo's centre-of-mass accelerations (``framelinacc`` columns from ``lin0``), frame
    means plus ``g`` (``acc [X, B, 3]``: what the loads must balance, ``a - g``)."""
    X = sd.shape[0]
    for x in range(X):
        for j in range(3 * B):
            a = 0.0
            for s in range(k):
                a += sd[x, s, lin0 + j]
            acc[x, j // 3, j % 3] = a / k + g[j % 3]


@njit(**_JIT)
def actuator_loads(qfrc, xaxis, xanchor, xipos, dof, jnt, body, parent, slide, k, gen, arm_b, arm_p):  # pragma: no cover  # fmt: skip
    """Actuator loads of scalar joints ``j``, frame means.

    ``gen [X, J, 3]``: generalized force times the joint's world axis (a torque for
    hinges, a force for slides); for slides, ``arm_b``/``arm_p [X, J, 3]``: the torque of
    that force at the anchor about the body's / the parent's centre of mass.
    """
    X, J = qfrc.shape[0], len(dof)
    for x in range(X):
        for j in range(J):
            g0 = g1 = g2 = 0.0
            a0 = a1 = a2 = p0 = p1 = p2 = 0.0
            for s in range(k):
                t = qfrc[x, s, dof[j]]
                v0, v1, v2 = (
                    xaxis[x, s, jnt[j], 0] * t,
                    xaxis[x, s, jnt[j], 1] * t,
                    xaxis[x, s, jnt[j], 2] * t,
                )
                g0 += v0
                g1 += v1
                g2 += v2
                if slide[j]:
                    m0, m1, m2 = _moment(xanchor, xipos, x, s, jnt[j], body[j], v0, v1, v2)
                    a0 += m0
                    a1 += m1
                    a2 += m2
                    m0, m1, m2 = _moment(xanchor, xipos, x, s, jnt[j], parent[j], v0, v1, v2)
                    p0 += m0
                    p1 += m1
                    p2 += m2
            gen[x, j, 0], gen[x, j, 1], gen[x, j, 2] = g0 / k, g1 / k, g2 / k
            arm_b[x, j, 0], arm_b[x, j, 1], arm_b[x, j, 2] = a0 / k, a1 / k, a2 / k
            arm_p[x, j, 0], arm_p[x, j, 1], arm_p[x, j, 2] = p0 / k, p1 / k, p2 / k


@njit(**_JIT)
def _nearest(px, py, pz, c, lo, h, res, table, table_off, node_lo, node_hi):  # pragma: no cover
    """Index (into ``c``) of the centroid of one body nearest to a point of its frame:
    the lookup grid's answer where its voxel has one, else the exact search."""
    i0 = int(np.floor((px - lo[0]) / h[0]))
    i1 = int(np.floor((py - lo[1]) / h[1]))
    i2 = int(np.floor((pz - lo[2]) / h[2]))
    if 0 <= i0 < res and 0 <= i1 < res and 0 <= i2 < res:
        hit = table[table_off + (i0 * res + i1) * res + i2]
        if hit >= 0:
            return node_lo + hit
    best, arg = np.inf, node_lo
    for n in range(node_lo, node_hi):
        d = (px - c[n, 0]) ** 2 + (py - c[n, 1]) ** 2 + (pz - c[n, 2]) ** 2
        if d < best:
            best, arg = d, n
    return arg


@njit(**_JIT)
def contact_loads(rows, sdc, cext, xpos, xquat, xipos, sub, root, cb, slot0, nslot, k, loc_c, loc_node, loc_lo, loc_h, loc_res, loc_table, loc_toff, loc_noff, wrench, count, overflow, node_cf):  # pragma: no cover  # fmt: skip
    """Contact loads of the frames ``rows`` (the others had none).

    ``sdc [Xs, k, nsd]``, ``cext [Xs, k, nb, 6]``: the model's sensordata and
    ``cfrc_ext`` for those frames; ``xpos``, ``xquat``, ``xipos``, ``sub``: the records of
    all frames ``[X, k, nb, ...]``. Out, at ``rows``: ``wrench [X, nb-1, 6]`` each body's
    mean contact wrench about its centre of mass; ``count [X]`` contacts per step (reported
    ones), ``overflow [X]`` (step, body) pairs with more contacts than ``nslot``;
    ``node_cf [X, N, 3]``: each reported contact's force on the body, on the node nearest
    its point, and a body's unreported rest at the mean of its reported points (so that
    node forces sum to the body's). Locator arrays: per sensed body ``c`` (``cb[c]``), its
    grid (``loc_lo``, ``loc_h`` ``[C, 3]``, ``loc_res``, ``loc_table`` from ``loc_toff``)
    and its centroids ``loc_c[loc_noff[c]:loc_noff[c+1]]`` with global ids ``loc_node``.
    """
    nb = cext.shape[2]
    C = len(cb)
    stride = 13 * nslot
    e = np.empty(6)
    for xi in range(len(rows)):
        x = rows[xi]
        for b in range(1, nb):
            rt = root[b]
            e[:] = 0.0
            c0 = c1 = c2 = 0.0
            for s in range(k):
                for i in range(6):
                    e[i] += cext[xi, s, b, i]
                fx, fy, fz = cext[xi, s, b, 3], cext[xi, s, b, 4], cext[xi, s, b, 5]
                m0, m1, m2 = _moment(sub, xipos, x, s, rt, b, fx, fy, fz)
                c0 += m0
                c1 += m1
                c2 += m2
            wrench[x, b - 1, 0] = (e[0] + c0) / k
            wrench[x, b - 1, 1] = (e[1] + c1) / k
            wrench[x, b - 1, 2] = (e[2] + c2) / k
            for i in range(3, 6):
                wrench[x, b - 1, i] = e[i] / k
        n_used = 0.0
        n_over = 0
        for s in range(k):
            for c in range(C):
                at = slot0 + c * stride
                found = int(sdc[xi, s, at])
                if found <= 0:
                    continue
                m = min(found, nslot)
                n_used += m
                body = cb[c]
                qw, qx, qy, qz = xquat[x, s, body, 0], xquat[x, s, body, 1], xquat[x, s, body, 2], xquat[x, s, body, 3]  # fmt: skip
                ox, oy, oz = xpos[x, s, body, 0], xpos[x, s, body, 1], xpos[x, s, body, 2]
                sx = sy = sz = 0.0  # reported force, summed
                mx = my = mz = 0.0  # reported points, summed
                for si in range(m + (1 if found > nslot else 0)):
                    if si < m:
                        a = at + 13 * si
                        f0, f1, f2 = sdc[xi, s, a + 1], sdc[xi, s, a + 2], sdc[xi, s, a + 3]
                        nx, ny, nz = sdc[xi, s, a + 7], sdc[xi, s, a + 8], sdc[xi, s, a + 9]
                        tx, ty, tz = sdc[xi, s, a + 10], sdc[xi, s, a + 11], sdc[xi, s, a + 12]
                        ux, uy, uz = ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx
                        fbx = -(f0 * nx + f1 * tx + f2 * ux)
                        fby = -(f0 * ny + f1 * ty + f2 * uy)
                        fbz = -(f0 * nz + f1 * tz + f2 * uz)
                        px, py, pz = sdc[xi, s, a + 4], sdc[xi, s, a + 5], sdc[xi, s, a + 6]
                        sx += fbx
                        sy += fby
                        sz += fbz
                        mx += px
                        my += py
                        mz += pz
                    else:  # the body's contact force beyond its reported contacts
                        n_over += 1
                        fbx = cext[xi, s, body, 3] - sx
                        fby = cext[xi, s, body, 4] - sy
                        fbz = cext[xi, s, body, 5] - sz
                        px, py, pz = mx / m, my / m, mz / m
                    # the point in the body frame: q^-1 (p - xpos), as v + w t + u x t
                    vx, vy, vz = px - ox, py - oy, pz - oz
                    ux, uy, uz = -qx, -qy, -qz
                    tx = 2 * (uy * vz - uz * vy)
                    ty = 2 * (uz * vx - ux * vz)
                    tz = 2 * (ux * vy - uy * vx)
                    lx = vx + qw * tx + (uy * tz - uz * ty)
                    ly = vy + qw * ty + (uz * tx - ux * tz)
                    lz = vz + qw * tz + (ux * ty - uy * tx)
                    n = _nearest(lx, ly, lz, loc_c, loc_lo[c], loc_h[c], loc_res[c], loc_table, loc_toff[c], loc_noff[c], loc_noff[c + 1])  # fmt: skip
                    node = loc_node[n]
                    node_cf[x, node, 0] += fbx / k
                    node_cf[x, node, 1] += fby / k
                    node_cf[x, node, 2] += fbz / k
        count[x] = n_used / k
        overflow[x] = n_over


@njit(**_JIT)
def node_kinematics(xpos, xquat, xipos, cvel, sub, root, node_body, node_c, body_v, node_pos, node_vel):  # pragma: no cover  # fmt: skip
    """Frame-start kinematics ``[X, nb, ...]`` -> body and node velocities and node positions.

    ``body_v [X, nb, 3]``: each body's centre-of-mass velocity, from ``cvel`` (about the
    tree's reference point ``sub[root]``) as ``v + w x (com - c)``; ``node_pos [X, N, 3]``:
    ``xpos + q node_c`` (rotation as ``v + w t + u x t``, ``t = 2 u x v``); ``node_vel``:
    ``v_com + w x (p - com)``.
    """
    X, nb = xpos.shape[0], xpos.shape[1]
    for x in range(X):
        for b in range(nb):
            rt = root[b]
            w0, w1, w2 = cvel[x, b, 0], cvel[x, b, 1], cvel[x, b, 2]
            r0 = xipos[x, b, 0] - sub[x, rt, 0]
            r1 = xipos[x, b, 1] - sub[x, rt, 1]
            r2 = xipos[x, b, 2] - sub[x, rt, 2]
            body_v[x, b, 0] = cvel[x, b, 3] + (w1 * r2 - w2 * r1)
            body_v[x, b, 1] = cvel[x, b, 4] + (w2 * r0 - w0 * r2)
            body_v[x, b, 2] = cvel[x, b, 5] + (w0 * r1 - w1 * r0)
        for n in range(node_pos.shape[1]):
            b = node_body[n]
            qw, ux, uy, uz = xquat[x, b, 0], xquat[x, b, 1], xquat[x, b, 2], xquat[x, b, 3]
            vx, vy, vz = node_c[n, 0], node_c[n, 1], node_c[n, 2]
            tx = 2 * (uy * vz - uz * vy)
            ty = 2 * (uz * vx - ux * vz)
            tz = 2 * (ux * vy - uy * vx)
            px = xpos[x, b, 0] + (vx + qw * tx + (uy * tz - uz * ty))
            py = xpos[x, b, 1] + (vy + qw * ty + (uz * tx - ux * tz))
            pz = xpos[x, b, 2] + (vz + qw * tz + (ux * ty - uy * tx))
            node_pos[x, n, 0], node_pos[x, n, 1], node_pos[x, n, 2] = px, py, pz
            w0, w1, w2 = cvel[x, b, 0], cvel[x, b, 1], cvel[x, b, 2]
            a0, a1, a2 = px - xipos[x, b, 0], py - xipos[x, b, 1], pz - xipos[x, b, 2]
            node_vel[x, n, 0] = body_v[x, b, 0] + (w1 * a2 - w2 * a1)
            node_vel[x, n, 1] = body_v[x, b, 1] + (w2 * a0 - w0 * a2)
            node_vel[x, n, 2] = body_v[x, b, 2] + (w0 * a1 - w1 * a0)


@njit(**_JIT)
def implicit_damping(
    qvel, qvel0, qacc, cdof, ximat, xipos, sub, root, parent, dof_body, mass, inertia, h, k,
    acc, joint, fint,
):  # pragma: no cover
    """Move frame-mean accelerations and joint loads from MuJoCo's ``qacc`` to the integrated one.

    With implicit joint damping (``eulerdamp``) the Euler step advances
    ``qvel[s+1] = qvel[s] + h qacc'[s]`` with ``(M + h B) qacc' = M qacc``, while MuJoCo's
    wrenches and sensors hold ``qacc``. The difference ``dq = qacc' - qacc`` (from the
    recorded velocities: ``qvel [X, k, nv]`` after each step, ``qvel0 [X, nv]`` before the
    frame) changes each body's spatial acceleration about the tree's reference point by
    ``dc[b] = dc[parent] + sum over b's dofs of cdof dq`` (Featherstone 2008, Eq. 5.14,
    the velocity terms being unchanged), its centre-of-mass acceleration by
    ``da = dc_lin + dc_ang x (com - ref)`` and, by Newton-Euler, the load its joints pass
    to it (its contacts and actuators being unchanged) by ``[I dc_ang; m da]`` about the
    centre of mass (``I = R diag(inertia) R^T``, ``R = ximat``). Updates ``acc``,
    ``joint`` and ``fint`` (the parent's force: the sum over the subtree) in place, adding
    the frame means.
    """
    X, nv, nb = qvel.shape[0], qvel.shape[2], xipos.shape[2]
    dc = np.empty((nb, 6))
    fsub = np.empty((nb, 3))
    for x in range(X):
        for s in range(k):
            for b in range(nb):
                for i in range(6):
                    dc[b, i] = 0.0
            for j in range(nv):
                before = qvel0[x, j] if s == 0 else qvel[x, s - 1, j]
                dq = (qvel[x, s, j] - before) / h - qacc[x, s, j]
                b = dof_body[j]
                for i in range(6):
                    dc[b, i] += cdof[x, s, j, i] * dq
            for b in range(1, nb):  # parents come first in MuJoCo's body order
                p = parent[b]
                for i in range(6):
                    dc[b, i] += dc[p, i]
            for b in range(nb):
                for i in range(3):
                    fsub[b, i] = 0.0
            for b in range(nb - 1, 0, -1):
                rt = root[b]
                rx = xipos[x, s, b, 0] - sub[x, s, rt, 0]
                ry = xipos[x, s, b, 1] - sub[x, s, rt, 1]
                rz = xipos[x, s, b, 2] - sub[x, s, rt, 2]
                wx, wy, wz = dc[b, 0], dc[b, 1], dc[b, 2]
                da0 = dc[b, 3] + wy * rz - wz * ry
                da1 = dc[b, 4] + wz * rx - wx * rz
                da2 = dc[b, 5] + wx * ry - wy * rx
                m = mass[b]
                acc[x, b - 1, 0] += da0 / k
                acc[x, b - 1, 1] += da1 / k
                acc[x, b - 1, 2] += da2 / k
                joint[x, b - 1, 3] += m * da0 / k
                joint[x, b - 1, 4] += m * da1 / k
                joint[x, b - 1, 5] += m * da2 / k
                # I dw in world axes: R diag(inertia) R^T dw
                for i in range(3):
                    t = 0.0
                    for a in range(3):
                        ra = ximat[x, s, b, 3 * i + a]
                        t += ra * inertia[b, a] * (
                            ximat[x, s, b, a] * wx + ximat[x, s, b, 3 + a] * wy
                            + ximat[x, s, b, 6 + a] * wz
                        )
                    joint[x, b - 1, i] += t / k
                fsub[b, 0] += m * da0
                fsub[b, 1] += m * da1
                fsub[b, 2] += m * da2
                for i in range(3):
                    fint[x, b - 1, i] += fsub[b, i] / k
                    if parent[b] > 0:
                        fsub[parent[b], i] += fsub[b, i]

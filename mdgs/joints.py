"""Joint constraint module: put jointed objects back onto their joints after a predicted step.

The structural module (Appendix B.1.3, :mod:`mdgs.structure`) keeps every object rigid but
nothing in MDGS keeps jointed objects together: a flywheel can leave its cube. This module
reads the joints of the scene's MJCF and, after each step, projects the predicted state onto
the set of states the joints allow, parents before children (MuJoCo numbers bodies so that a
parent precedes its children):

pose of each parent ``(R, t)``: Kabsch of its reference shape (element centroids ``p`` in its
body frame, :attr:`mdgs.graphs.SceneGraph.ref_shape`) onto the predicted nodes ``q``, so
``R, t`` are MuJoCo's ``xmat, xpos`` of the body (or its corrected pose, if it is a child). For a child ``c`` of parent ``p`` (world: ``R = I, t = 0``)
with ``Q0`` the child frame in the parent frame at ``qpos0`` (``body_quat``), joint axis ``a``
and anchor ``a_c`` in the child frame and ``a_p = body_pos + Q0 a_c`` in the parent frame:

- hinge: ``R_c' = R_p Q0 Rot(a, theta*)``, the anchor on the parent's anchor ``A``, with
  ``theta*`` the least-squares fit of the child's predicted nodes:
  ``min sum_i |R_p Q0 Rot(a, theta) (p_i - a_c) + A - q_i|^2``, i.e. with
  ``N = (R_p Q0)^T sum_i (q_i - A)(p_i - a_c)^T``, ``theta* = atan2(a . vee(N - N^T), tr N - a^T N a)``
  (maximises ``tr(Rot(a, theta)^T N)``);
- slide: ``R_c' = R_p Q0``, the anchor moved from ``A`` along the world axis ``n`` by the
  least-squares fit of the predicted nodes;
- ball: the predicted rotation kept, the anchor put on the parent's anchor;
- no joint (welded): ``R_c' = R_p Q0``, ``t_c' = R_p body_pos + t_p``.

Velocities, with the parent's (corrected) twist ``(v_p at a point, omega_p)`` and the child's
predicted twist: hinge ``omega_c' = omega_p + ((omega_c - omega_p) . n) n`` (``n = R_c' a``),
points moving as ``v_p(A) + omega_c' x (y - A)`` about the anchor ``A``; slide ``omega_c' =
omega_p`` and ``v_p(y)`` plus the predicted sliding rate along ``n``; ball ``v_p(A) +
omega_c x (y - A)``; welded ``v_p(y)``.

Free joints impose nothing. Joints the projection cannot pose are left alone and listed by
:func:`joints_of` in ``skipped``: a body with several joints, an object with fewer than three
nodes, a parent whose elements do not fix its rotation (fewer than three, or on a line), a
parent body that has no nodes and is not the world. A child's own pose is fitted to its
predicted nodes under the joint (least squares), so a child whose elements lie on a line (a
thin pole) is projected as well.
Everything runs in float64; shapes ``[B, N, 3]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from mdgs.rigid import rotation_matrix, twist
from mdgs.structure import kabsch

__all__ = ["Joint", "JointSet", "joints_of", "project_joints"]

KINDS = ("hinge", "slide", "ball", "weld")


@dataclass(frozen=True)
class Joint:
    """One joint between two objects (object indices of :class:`mdgs.graphs.SceneGraph`).

    parent : object index, or -1 for the world (a fixed frame).
    kind : "hinge", "slide", "ball" or "weld".
    q0 : [3, 3] child frame in the parent frame at qpos0; body_pos : [3] child frame origin
    in the parent frame at qpos0; axis : [3] unit joint axis in the child frame; anchor : [3]
    joint position in the child frame (m).
    """

    child: int
    parent: int
    kind: str
    q0: np.ndarray
    body_pos: np.ndarray
    axis: np.ndarray
    anchor: np.ndarray


@dataclass
class JointSet:
    """The joints the projection enforces (parents first) and the ones it leaves alone, with why."""

    joints: list[Joint] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    _cache: dict = field(default_factory=dict, repr=False)

    def __bool__(self) -> bool:
        return bool(self.joints)

    def tensors(self, seg: torch.Tensor) -> list[tuple]:
        """Per joint ``(q0, axis, anchor, body_pos, anchor in the parent frame, child's node indices)``
        as float64 / int64 tensors on ``seg``'s device, built once per device and node map."""
        key = (str(seg.device), seg.data_ptr(), seg.numel())
        if key not in self._cache:
            f = dict(dtype=torch.float64, device=seg.device)
            out = []
            for j in self.joints:
                q0, a, ac, bp = (torch.as_tensor(v, **f) for v in (j.q0, j.axis, j.anchor, j.body_pos))
                out.append((q0, a, ac, bp, bp + q0 @ ac, torch.nonzero(seg == j.child).flatten()))
            self._cache[key] = out
        return self._cache[key]


def _posable(ref: np.ndarray) -> bool:
    """Whether element centroids ``ref`` [k, 3] fix a rotation: at least 3, not all on a line."""
    if len(ref) < 3:
        return False
    s = np.linalg.svd(ref - ref.mean(0), compute_uv=False)
    return bool(s[0] > 0 and s[1] > 1e-6 * s[0])


def joints_of(mj_model, node_body: np.ndarray, node_centroid: np.ndarray) -> JointSet:
    """The joints between the objects of a scene.

    mj_model : the scene's ``mujoco.MjModel``; node_body : [N] MuJoCo body of each node
    (``static["node_body"]``); node_centroid : [N, 3] element centroids in their body frames;
    objects are the sorted distinct bodies with nodes.
    """
    import mujoco

    m = mj_model
    node_body = np.asarray(node_body, int)
    bodies, counts = np.unique(node_body, return_counts=True)
    obj_of = {int(b): k for k, b in enumerate(bodies)}
    n_nodes = {int(b): int(c) for b, c in zip(bodies, counts, strict=True)}
    out = JointSet()
    kinds = {int(mujoco.mjtJoint.mjJNT_HINGE): "hinge", int(mujoco.mjtJoint.mjJNT_SLIDE): "slide",
             int(mujoco.mjtJoint.mjJNT_BALL): "ball", int(mujoco.mjtJoint.mjJNT_FREE): "free"}
    for b in (int(x) for x in bodies):
        if b == 0:
            continue
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or f"body {b}"
        jnts = [j for j in range(m.njnt) if int(m.jnt_bodyid[j]) == b]
        if len(jnts) > 1:
            out.skipped.append(f"{name}: {len(jnts)} joints")
            continue
        kind = kinds[int(m.jnt_type[jnts[0]])] if jnts else "weld"
        if kind == "free":
            continue
        p = int(m.body_parentid[b])
        if p != 0 and p not in obj_of:
            out.skipped.append(f"{name}: its parent body has no elements")
            continue
        if n_nodes[b] < 2:
            out.skipped.append(f"{name}: fewer than 2 elements")
            continue
        if p != 0 and not _posable(np.asarray(node_centroid)[node_body == p]):
            out.skipped.append(f"{name}: its parent's elements do not fix its rotation (fewer than 3, or on a line)")
            continue
        q0 = np.zeros(9)
        mujoco.mju_quat2Mat(q0, m.body_quat[b])
        axis = np.array(m.jnt_axis[jnts[0]], float) if jnts else np.array([0.0, 0.0, 1.0])
        anchor = np.array(m.jnt_pos[jnts[0]], float) if jnts else np.zeros(3)
        out.joints.append(Joint(obj_of[b], obj_of[p] if p != 0 else -1, kind, q0.reshape(3, 3),
                                np.array(m.body_pos[b], float), axis / np.linalg.norm(axis), anchor))
    return out


def _point_velocity(vc: torch.Tensor, w: torch.Tensor, c: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Velocity at world points ``y`` [B, k, 3] of a rigid body with mass-centre velocity ``vc``, angular
    velocity ``w`` and mass centre ``c`` (each [B, 3]): ``vc + w x (y - c)``."""
    return vc.unsqueeze(1) + torch.linalg.cross(w.unsqueeze(1).expand_as(y), y - c.unsqueeze(1), dim=-1)


def project_joints(x: torch.Tensor, v: torch.Tensor, joints: JointSet, ref: torch.Tensor, seg: torch.Tensor,
                   n_obj: int, mass: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Project ``x, v`` [B, N, 3] onto the joints (module docstring) -> ``x', v'`` in ``x``'s dtype.

    ref : [N, 3] element centroids in their body frames; seg : [N] object of each node;
    mass : [N] element masses (for the predicted twists). Nodes of objects that no enforced joint
    makes a child are returned unchanged.
    """
    if not joints:
        return x, v
    dev, f64 = x.device, torch.float64
    xd, vd = x.to(f64), v.to(f64)
    seg = seg.to(dev)
    R, t = kabsch(ref.to(dev, f64), xd, seg, n_obj)  # [B, S, 3, 3], [B, S, 3]
    tw = twist(xd, vd, seg, n_obj, mass.to(dev))
    R, t = R.clone(), t.clone()
    w = tw.omega.clone()  # corrected angular velocity of each object
    # corrected velocity of each object as (velocity of its mass centre, mass centre)
    vc, c = tw.vc.clone(), tw.c.clone()
    B = x.shape[0]
    xo, vo = xd.clone(), vd.clone()
    refd = ref.to(dev, f64)

    def parent_frame(p):
        if p < 0:
            eye = torch.eye(3, dtype=f64, device=dev).expand(B, 3, 3)
            zero = torch.zeros(B, 3, dtype=f64, device=dev)
            return eye, zero, zero, zero, zero
        return R[:, p], t[:, p], w[:, p], vc[:, p], c[:, p]

    for j, (q0, a, ac, bp, ap, idx) in zip(joints.joints, joints.tensors(seg), strict=True):
        Rp, tp, wp, vcp, cp = parent_frame(j.parent)
        Rc, wc = R[:, j.child], tw.omega[:, j.child]
        p_rel = refd[idx] - ac  # child nodes about the anchor, child frame [k, 3]
        A = (Rp @ ap) + tp  # anchor on the parent, world [B, 3]
        zero_frame = Rp @ q0  # child frame at zero joint angle [B, 3, 3]
        q_rel = xd[:, idx] - A.unsqueeze(1)  # predicted nodes about the anchor [B, k, 3]
        if j.kind == "hinge":  # best fit of the nodes by zero_frame Rot(a, theta) p_rel
            N = zero_frame.transpose(-1, -2) @ torch.einsum("bki,kj->bij", q_rel, p_rel)
            skew = N - N.transpose(-1, -2)
            vee = torch.stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]], -1)
            theta = torch.atan2(vee @ a, N.diagonal(dim1=-2, dim2=-1).sum(-1) - torch.einsum("i,bij,j->b", a, N, a))
            Rn = zero_frame @ rotation_matrix(theta.unsqueeze(-1) * a)
        elif j.kind in ("slide", "weld"):
            Rn = zero_frame
        else:  # ball
            Rn = Rc
        if j.kind == "slide":  # best fit of the nodes by Rn p_rel + A + s n
            n = Rn @ a
            s_fit = ((q_rel - (Rn.unsqueeze(1) @ p_rel.unsqueeze(-1)).squeeze(-1)) * n.unsqueeze(1)).sum(-1).mean(1)
            tn = A + s_fit.unsqueeze(-1) * n - Rn @ ac
        elif j.kind == "weld":
            tn = Rp @ bp + tp
        else:
            tn = A - Rn @ ac
        xn = (Rn.unsqueeze(1) @ refd[idx].unsqueeze(-1)).squeeze(-1) + tn.unsqueeze(1)  # [B, k, 3]
        An = A.unsqueeze(1)
        if j.kind == "hinge":
            n = Rn @ a
            wn = wp + ((wc - wp) * n).sum(-1, keepdim=True) * n
            vn = _point_velocity(vcp, wp, cp, An) + torch.linalg.cross(wn.unsqueeze(1).expand_as(xn), xn - An, dim=-1)
        elif j.kind == "ball":
            wn = wc
            vn = _point_velocity(vcp, wp, cp, An) + torch.linalg.cross(wn.unsqueeze(1).expand_as(xn), xn - An, dim=-1)
        else:
            wn = wp
            vn = _point_velocity(vcp, wp, cp, xn)
            if j.kind == "slide":
                n = Rn @ a
                v_child_A = tw.vc[:, j.child] + torch.linalg.cross(wc, A - tw.c[:, j.child], dim=-1)
                rate = ((v_child_A - _point_velocity(vcp, wp, cp, An).squeeze(1)) * n).sum(-1, keepdim=True)
                vn = vn + (rate * n).unsqueeze(1)
        xo[:, idx], vo[:, idx] = xn, vn
        R[:, j.child], t[:, j.child], w[:, j.child] = Rn, tn, wn
        mc = mass.to(dev, f64)[idx]
        c[:, j.child] = (mc[None, :, None] * xn).sum(1) / mc.sum()
        vc[:, j.child] = (mc[None, :, None] * vn).sum(1) / mc.sum()
    return xo.to(x.dtype), vo.to(v.dtype)

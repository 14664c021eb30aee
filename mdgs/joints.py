"""Joint constraint module: put jointed objects back onto their joints after a predicted step.

The structural module (Appendix B.1.3, :mod:`mdgs.structure`) keeps every object rigid but
nothing in MDGS keeps jointed objects together: a flywheel can leave its cube. This module
reads the joints of the scene's MJCF and, after each step, projects the predicted state onto
the set of states the joints allow, parents before children (MuJoCo numbers bodies so that a
parent precedes its children): level by level down the kinematic tree, the joints of one kind
whose parents are already placed in one batched pass (:meth:`JointSet.tensors`; a Cubli's three
hinged flywheels are one pass):

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
from mdgs.structure import fixes_rotation, kabsch, segment_sum

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


@dataclass(frozen=True)
class _Group:
    """Joints of one kind whose parents are final once the groups before it are done, stacked on one device.

    child, parent : [G] object indices (the world: ``S``, the frame :func:`project_joints` appends);
    q0 : [G, 3, 3]; axis, anchor, body_pos, anchor_parent (``a_p = body_pos + Q0 a_c``) : [G, 3];
    node : [M] the children's nodes, joint after joint; of : [M] the joint (position in the group)
    of each node; ref : [M, 3] their element centroids in the child frame; p_rel : [M, 3] the same
    about the anchor (``p_i - a_c``); mass : [M] element masses (kg); count, total : [G] nodes and
    mass of each child; has_children : whether a later group hangs from one of these children;
    from_world : whether one of these joints hangs from the world.
    """

    kind: str
    child: torch.Tensor
    parent: torch.Tensor
    q0: torch.Tensor
    axis: torch.Tensor
    anchor: torch.Tensor
    body_pos: torch.Tensor
    anchor_parent: torch.Tensor
    node: torch.Tensor
    of: torch.Tensor
    ref: torch.Tensor
    p_rel: torch.Tensor
    mass: torch.Tensor
    count: torch.Tensor
    total: torch.Tensor
    has_children: bool
    from_world: bool


@dataclass
class JointSet:
    """The joints the projection enforces (parents first) and the ones it leaves alone, with why."""

    joints: list[Joint] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    _cache: dict = field(default_factory=dict, repr=False)

    def __bool__(self) -> bool:
        return len(self.joints) > 0  # not bool(list): dynamo (torch 2.11) breaks the graph on it

    def levels(self) -> list[list[int]]:
        """Indices into ``joints`` by depth in the kinematic tree: level 0 hangs from the world or from
        objects no enforced joint moves, level ``d + 1`` from children of level ``d``."""
        depth: dict[int, int] = {}  # object -> depth of the joint that makes it a child
        out: list[list[int]] = []
        for i, j in enumerate(self.joints):  # parents first, so a parent's depth is known
            depth[j.child] = d = depth.get(j.parent, -1) + 1
            out += [[] for _ in range(d + 1 - len(out))]
            out[d].append(i)
        return out

    def tensors(self, seg: torch.Tensor, ref: torch.Tensor, mass: torch.Tensor, n_obj: int,
                device=None) -> list[_Group]:
        """The joints as :class:`_Group` s, level by level and kind by kind (``KINDS``), on ``device``
        (default ``seg``'s): built from the scene's ``seg`` [N], ``ref`` [N, 3] and ``mass`` [N] once
        per device and kept while the same scene tensors are passed."""
        device = seg.device if device is None else torch.device(device)
        hit = self._cache.get(str(device))
        if hit is not None and torch.compiler.is_compiling():
            # a compiled step reads the groups an eager step built (compile_step runs one first, per
            # binding) without the data-pointer comparison, which would split the compiled graph;
            # binding a scene makes a new JointSet
            return hit[1]
        sig = tuple((a.data_ptr(), tuple(a.shape), a.dtype) for a in (seg, ref, mass)) + (n_obj,)
        if hit is not None and hit[0] == sig:
            return hit[1]
        f = dict(dtype=torch.float64, device=device)
        seg, ref, mass = seg.to(device), ref.to(**f), mass.to(**f)
        groups = []
        for level in self.levels():
            for kind in KINDS:
                js = [self.joints[i] for i in level if self.joints[i].kind == kind]
                if not js:
                    continue
                st = {k: torch.as_tensor(np.stack([getattr(j, k) for j in js]), **f)
                      for k in ("q0", "axis", "anchor", "body_pos")}
                nodes = [torch.nonzero(seg == j.child).flatten() for j in js]
                node = torch.cat(nodes)
                of = torch.cat([torch.full_like(n, g) for g, n in enumerate(nodes)])
                m = mass[node]
                groups.append(dict(
                    kind=kind, child=torch.tensor([j.child for j in js], device=device),
                    parent=torch.tensor([j.parent if j.parent >= 0 else n_obj for j in js], device=device),
                    anchor_parent=st["body_pos"] + (st["q0"] @ st["anchor"].unsqueeze(-1)).squeeze(-1),
                    node=node, of=of, ref=ref[node], p_rel=ref[node] - st["anchor"][of], mass=m,
                    count=torch.tensor([len(n) for n in nodes], **f),
                    total=torch.zeros(len(js), **f).index_add_(0, of, m), **st))
        out = []
        for i, g in enumerate(groups):
            later = {int(p) for h in groups[i + 1:] for p in h["parent"]}
            out.append(_Group(**g, has_children=bool(later & {int(c) for c in g["child"]}),
                              from_world=bool((g["parent"] == n_obj).any())))
        self._cache[str(device)] = (sig, out)
        return out


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
        if p != 0 and not fixes_rotation(np.asarray(node_centroid)[node_body == p]):
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
    """Velocity at world points ``y`` of a rigid body with mass-centre velocity ``vc``, angular velocity ``w``
    and mass centre ``c`` (all [..., 3], broadcast): ``vc + w x (y - c)``."""
    r = y - c
    return vc + torch.linalg.cross(w.expand_as(r), r, dim=-1)


def project_joints(x: torch.Tensor, v: torch.Tensor, joints: JointSet, ref: torch.Tensor, seg: torch.Tensor,
                   n_obj: int, mass: torch.Tensor, pose: tuple | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Project ``x, v`` [B, N, 3] onto the joints (module docstring) -> ``x', v'`` in ``x``'s dtype.

    ref : [N, 3] element centroids in their body frames; seg : [N] object of each node;
    mass : [N] element masses (for the predicted twists). Nodes of objects that no enforced joint
    makes a child are returned unchanged. The joints are projected group by group
    (:meth:`JointSet.tensors`: one kind at one depth of the tree), each group in one batched pass.
    pose : every object's placement ``(R [B, S, 3, 3], t [B, S, 3])`` when the caller already has it
        (``x`` placed rigidly by :func:`mdgs.structure.align_with_pose`: the same fit, up to ``x``'s
        rounding); otherwise fitted here (:func:`mdgs.structure.kabsch`). A third entry, when not None, is
        the twists of ``x, v`` (:func:`mdgs.rigid.twist`; :class:`mdgs.actuation.Pose`), else fitted here.
    """
    if not joints:
        return x, v
    dev, f64 = x.device, torch.float64
    groups = joints.tensors(seg, ref, mass, n_obj, dev)
    xd, vd = x.to(f64), v.to(f64)
    seg = seg.to(dev)
    B = x.shape[0]
    R, t = pose[:2] if pose is not None else kabsch(ref.to(dev, f64), xd, seg, n_obj)  # [B, S, 3, 3], [B, S, 3]
    tw = pose[2] if pose is not None and len(pose) > 2 and pose[2] is not None else twist(xd, vd, seg, n_obj,
                                                                                         mass.to(dev))
    # every object's corrected pose and twist (velocity of its mass centre, mass centre), with the
    # world appended as object S (R = I, t = 0, at rest) when a joint hangs from it; tw keeps the predicted twists
    w, vc, c = tw.omega, tw.vc, tw.c
    if any(g.from_world for g in groups):
        R = torch.cat([R, torch.eye(3, dtype=f64, device=dev).expand(B, 1, 3, 3)], 1)
        t, w, vc, c = (torch.cat([a, a.new_zeros(B, 1, 3)], 1) for a in (t, w, vc, c))
    elif any(g.has_children for g in groups):  # corrected in place below
        w, vc, c = w.clone(), vc.clone(), c.clone()
    xo, vo = xd.clone(), vd.clone()
    for g in groups:
        G, k = len(g.child), g.of  # k: the joint of each of the group's nodes
        Rp, tp, wp, vcp, cp = R[:, g.parent], t[:, g.parent], w[:, g.parent], vc[:, g.parent], c[:, g.parent]
        wc = tw.omega[:, g.child]  # predicted angular velocity of each child [B, G, 3]
        A = (Rp @ g.anchor_parent.unsqueeze(-1)).squeeze(-1) + tp  # anchor on the parent, world [B, G, 3]
        zero_frame = Rp @ g.q0  # child frame at zero joint angle [B, G, 3, 3]
        q_rel = xd[:, g.node] - A[:, k]  # predicted nodes about the anchor [B, M, 3]
        if g.kind == "hinge":  # best fit of the nodes by zero_frame Rot(a, theta) p_rel
            N = zero_frame.transpose(-1, -2) @ segment_sum(q_rel.unsqueeze(-1) * g.p_rel.unsqueeze(-2), k, G)
            skew = N - N.transpose(-1, -2)
            vee = torch.stack([skew[..., 2, 1], skew[..., 0, 2], skew[..., 1, 0]], -1)
            aNa = ((N @ g.axis.unsqueeze(-1)).squeeze(-1) * g.axis).sum(-1)  # a^T N a [B, G]
            theta = torch.atan2((vee * g.axis).sum(-1), N.diagonal(dim1=-2, dim2=-1).sum(-1) - aNa)
            Rn = zero_frame @ rotation_matrix(theta.unsqueeze(-1) * g.axis)
        elif g.kind in ("slide", "weld"):
            Rn = zero_frame
        else:  # ball
            Rn = R[:, g.child]
        if g.kind in ("hinge", "slide"):
            n = (Rn @ g.axis.unsqueeze(-1)).squeeze(-1)  # joint axis, world [B, G, 3]
        if g.kind == "slide":  # best fit of the nodes by Rn p_rel + A + s n
            resid = ((q_rel - (Rn[:, k] @ g.p_rel.unsqueeze(-1)).squeeze(-1)) * n[:, k]).sum(-1)  # [B, M]
            s_fit = segment_sum(resid, k, G) / g.count
            tn = A + s_fit.unsqueeze(-1) * n - (Rn @ g.anchor.unsqueeze(-1)).squeeze(-1)
        elif g.kind == "weld":
            tn = (Rp @ g.body_pos.unsqueeze(-1)).squeeze(-1) + tp
        else:
            tn = A - (Rn @ g.anchor.unsqueeze(-1)).squeeze(-1)
        xn = (Rn[:, k] @ g.ref.unsqueeze(-1)).squeeze(-1) + tn[:, k]  # [B, M, 3]
        v_A = _point_velocity(vcp, wp, cp, A)  # the parent's velocity at the anchor [B, G, 3]
        if g.kind in ("hinge", "ball"):
            wn = wp + ((wc - wp) * n).sum(-1, keepdim=True) * n if g.kind == "hinge" else wc
            vn = _point_velocity(v_A[:, k], wn[:, k], A[:, k], xn)
        else:
            wn = wp
            vn = _point_velocity(vcp[:, k], wp[:, k], cp[:, k], xn)
            if g.kind == "slide":
                v_child_A = _point_velocity(tw.vc[:, g.child], wc, tw.c[:, g.child], A)
                rate = ((v_child_A - v_A) * n).sum(-1, keepdim=True)
                vn = vn + (rate * n)[:, k]
        xo[:, g.node], vo[:, g.node] = xn, vn
        if g.has_children:  # later groups hang from these children: their corrected pose and twist
            R[:, g.child], t[:, g.child], w[:, g.child] = Rn, tn, wn
            c[:, g.child] = segment_sum(g.mass[:, None] * xn, k, G) / g.total[:, None]
            vc[:, g.child] = segment_sum(g.mass[:, None] * vn, k, G) / g.total[:, None]
    return xo.to(x.dtype), vo.to(v.dtype)

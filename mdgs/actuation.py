"""The motors' known loads: as node forces on free bodies, as the joint's response with its parent held, and as the whole tree's response.

MDGS's inputs carry a scene's actuator controls as per-node signs (``+ctrl_k`` on the body that
actuator ``k`` drives, ``-ctrl_k`` on its parent; :func:`mdgs.data.split.control_map`): the
network must learn from a handful of examples that a Cubli's brake command of 12 N m stops a
flywheel spinning at 960 rad/s within a frame. For a motor, the load is known exactly from the
MJCF (``actuation`` of :class:`mdgs.models.mdgs.MDGSConfig`, and the "constant twist + motors"
reference of :mod:`mdgs.models.references`).

For actuator ``k`` on the hinge or slide joint of body ``c`` (parent ``p``), with generalised force
``u_k = gear_k * clip(gain_k * clip(ctrl_k, ctrlrange), forcerange)`` (MuJoCo's motor: fixed gain,
no bias, no activation dynamics), the joint axis ``n = R_c a`` and anchor ``A = R_c a_c + t_c`` in
the world (``a``, ``a_c`` the axis and position in the child frame; ``R_c, t_c`` the child's pose
fitted to its nodes by :func:`mdgs.structure.kabsch`, i.e. MuJoCo's ``xmat, xpos``):

**Free-body loads** (:func:`actuation_forces`). Hinge: torque ``T = u_k n`` on ``c`` and ``-T`` on
``p``; slide: force ``f = u_k n`` on ``c`` and ``-f`` on ``p``. Each body ``b`` gets the acceleration
field it would have as a free rigid body under its summed loads, with its MJCF mass ``M_b`` and
inertia ``I_b`` (``body_inertia`` in ``body_iquat``, rotated by ``R_b``), about the mass-weighted
centroid ``c_b`` of its elements (the centre of :func:`mdgs.rigid.twist`)::

    a_i = f_b / M_b + (I_b^-1 T_b) x (x_i - c_b),        node force  F_i = m_i a_i   (N)

so a motor's node forces sum to zero, as internal loads must.

**Joint response, parent held** (:func:`motor_accelerations`). The subtree ``S`` of the driven
body (it and every descendant with elements, moving with it) turns about (slides along) the
joint with MuJoCo's joint-space inertia of that one degree of freedom,
``M_kk = sum_{b in S} (n^T I_b n + M_b |n x (x_b - A)|^2) + armature`` (hinge; ``x_b`` the body's
mass centre, ``R_b body_ipos + t_b``) or ``sum_{b in S} M_b + armature`` (slide)::

    hinge:  a_i = (u_k / M_kk) n x (x_i - A),     slide:  a_i = (u_k / M_kk) n      (i in S)

summed over the motors. It is MuJoCo's ``qacc = M^-1 qfrc_actuator`` when the parent is fixed and
the motor's degree of freedom is the only one (a wheel on a fixed axle, an arm on a fixed
hinge); otherwise an approximation that ignores the parent's recoil and the coupling with other
joints (for a driven tree on a floating base it misses a sizeable part of MuJoCo's node accelerations,
the base's turn against its wheel: tests/test_actuation.py).

**The whole tree's response** (:func:`coupled_motor_accelerations`): MuJoCo's ``M^-1 qfrc_actuator``
exactly, every parent recoiling and every joint passing the load on (Newton-Euler with the joints as
constraints; its docstring). Exact for the motors alone, it is the worse prior where floors and gravity
hold the parents (docs/mdgs-experiments.md, "The whole tree's response").

No form has the velocity terms (gyroscopic, Coriolis), which do not depend on the control.
Actuators that are not motors (position or velocity servos, activation dynamics),
that drive a tendon, a site or a ball or free joint, or whose body's rotation its elements do
not fix, are listed in ``skipped`` and contribute nothing; bodies without elements are left out
of the sums. Everything runs in float64; shapes ``[B, N, 3]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from mdgs.structure import fixes_rotation, kabsch, segment_mean

__all__ = ["Drive", "DriveSet", "Link", "drives_of", "actuation_forces", "motor_accelerations",
           "coupled_motor_accelerations"]


@dataclass(frozen=True)
class Drive:
    """One motor on one hinge or slide joint, between two objects (indices of :class:`mdgs.graphs.SceneGraph`).

    actuator : index of the actuator (column of the controls).
    child : object the joint belongs to; parent : its parent object, or -1 for the world.
    kind : "hinge" (a torque about ``axis``) or "slide" (a force along ``axis``).
    axis : [3] unit joint axis in the child's body frame.
    gain : generalised force per unit actuator force (``gear[0]``).
    force_gain : actuator force per unit control (``gainprm[0]``).
    ctrl_range, force_range : (lo, hi) clamps, or None when the MJCF does not limit.
    anchor : [3] joint position in the child's body frame (m); armature : the joint's armature.
    subtree : the child and its descendant objects (those with elements).
    """

    actuator: int
    child: int
    parent: int
    kind: str
    axis: np.ndarray
    gain: float
    force_gain: float
    ctrl_range: tuple[float, float] | None
    force_range: tuple[float, float] | None
    anchor: np.ndarray = field(default_factory=lambda: np.zeros(3))
    armature: float = 0.0
    subtree: tuple[int, ...] = ()


@dataclass(frozen=True)
class Link:
    """How one object moves against its parent object, for :func:`coupled_motor_accelerations`.

    child, parent : object indices (parent -1: the world, a fixed frame).
    kind : "hinge", "slide", "ball", "weld" (no joint) or "free".
    axis : [3] unit joint axis; perp : [2, 3] two unit vectors completing it to an orthonormal basis;
    anchor : [3] joint position (m); all three in the parent's body frame (the world's for parent -1),
    where a hinge's axis and anchor stay whatever the joint's angle, so they are known even for a
    child whose elements do not fix its rotation (a thin pole); a slide's anchor at ``qpos0`` (moving
    it along the axis changes no row). armature : the joint's armature (hinge, slide; 0 otherwise).
    """

    child: int
    parent: int
    kind: str
    axis: np.ndarray
    perp: np.ndarray
    anchor: np.ndarray
    armature: float = 0.0


@dataclass
class DriveSet:
    """The motors whose loads :func:`actuation_forces` applies, the bodies' inertial data, and what is skipped (why).

    mass : [S] MJCF mass of each object's body; inertia, inv_inertia : [S, 3, 3] its inertia tensor
    about its mass centre in its body frame, and the inverse (zero where singular); com : [S, 3]
    its mass centre in its body frame (``body_ipos``); links : one :class:`Link` per moving object
    whose joint :func:`coupled_motor_accelerations` can write (the others are left free there, and named,
    with the reason, in ``unlinked``); fixed : [S] objects that do not move (the world body's elements).
    """

    drives: list[Drive] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    mass: np.ndarray = field(default_factory=lambda: np.zeros(0))
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    inv_inertia: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    com: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    links: list[Link] = field(default_factory=list)
    unlinked: list[str] = field(default_factory=list)
    fixed: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    _cache: dict = field(default_factory=dict, repr=False)

    def __bool__(self) -> bool:
        return bool(self.drives)

    def tensors(self, dev) -> dict:
        """Stacked float64 / int64 tensors of the drives and bodies on ``dev`` (built once per device)."""
        key = str(dev)
        if key not in self._cache:
            f = dict(dtype=torch.float64, device=dev)
            d = self.drives
            lo = [(dr.ctrl_range or (-np.inf, np.inf))[0] for dr in d]
            hi = [(dr.ctrl_range or (-np.inf, np.inf))[1] for dr in d]
            flo = [(dr.force_range or (-np.inf, np.inf))[0] for dr in d]
            fhi = [(dr.force_range or (-np.inf, np.inf))[1] for dr in d]
            self._cache[key] = {
                "actuator": torch.tensor([dr.actuator for dr in d], dtype=torch.long, device=dev),
                "child": torch.tensor([dr.child for dr in d], dtype=torch.long, device=dev),
                "parent": torch.tensor([dr.parent for dr in d], dtype=torch.long, device=dev),
                "torque": torch.tensor([dr.kind == "hinge" for dr in d], dtype=torch.bool, device=dev),
                "axis": torch.as_tensor(np.array([dr.axis for dr in d]).reshape(-1, 3), **f),
                "gain": torch.tensor([dr.gain for dr in d], **f),
                "force_gain": torch.tensor([dr.force_gain for dr in d], **f),
                "ctrl_lo": torch.tensor(lo, **f), "ctrl_hi": torch.tensor(hi, **f),
                "force_lo": torch.tensor(flo, **f), "force_hi": torch.tensor(fhi, **f),
                "anchor": torch.as_tensor(np.array([dr.anchor for dr in d]).reshape(-1, 3), **f),
                "armature": torch.tensor([dr.armature for dr in d], **f),
                "subtree": torch.tensor(np.array([[o in dr.subtree for o in range(len(self.mass))] for dr in d],
                                                 bool).reshape(len(d), len(self.mass)), device=dev),
                "mass": torch.as_tensor(self.mass, **f),
                "inertia": torch.as_tensor(self.inertia, **f), "com": torch.as_tensor(self.com, **f),
                "inv_inertia": torch.as_tensor(self.inv_inertia, **f),
            }
        return self._cache[key]


def _descends(m, c: int, b: int) -> bool:
    """Whether MuJoCo body ``c`` is ``b`` or one of its descendants."""
    while c > 0:
        if c == b:
            return True
        c = int(m.body_parentid[c])
    return c == b


def drives_of(mj_model, node_body: np.ndarray, node_centroid: np.ndarray) -> DriveSet:
    """The motors of a scene and its objects' inertial data (objects: the sorted distinct bodies with nodes).

    mj_model : the scene's ``mujoco.MjModel``; node_body : [N] MuJoCo body of each node
    (``static["node_body"]``); node_centroid : [N, 3] element centroids in their body frames.
    """
    import mujoco

    m = mj_model
    node_body = np.asarray(node_body, int)
    node_centroid = np.asarray(node_centroid, float)
    bodies = np.unique(node_body)
    obj_of = {int(b): k for k, b in enumerate(bodies)}
    S = len(bodies)
    mass, inertia, inv_inertia, com = np.zeros(S), np.zeros((S, 3, 3)), np.zeros((S, 3, 3)), np.zeros((S, 3))
    posable = np.zeros(S, bool)
    for k, b in enumerate(int(x) for x in bodies):
        q = np.zeros(9)
        mujoco.mju_quat2Mat(q, m.body_iquat[b])
        q = q.reshape(3, 3)
        inertia[k] = q @ np.diag(m.body_inertia[b]) @ q.T
        mass[k], com[k] = float(m.body_mass[b]), m.body_ipos[b]
        if b != 0 and np.linalg.cond(inertia[k]) < 1e12:
            inv_inertia[k] = np.linalg.inv(inertia[k])
        posable[k] = fixes_rotation(node_centroid[node_body == b])
    out = DriveSet(mass=mass, inertia=inertia, inv_inertia=inv_inertia, com=com, fixed=bodies == 0)
    name = lambda kind, i: mujoco.mj_id2name(m, kind, i) or f"#{i}"  # noqa: E731
    kinds = {int(mujoco.mjtJoint.mjJNT_HINGE): "hinge", int(mujoco.mjtJoint.mjJNT_SLIDE): "slide",
             int(mujoco.mjtJoint.mjJNT_BALL): "ball", int(mujoco.mjtJoint.mjJNT_FREE): "free"}
    for k, b in enumerate(int(x) for x in bodies):
        if b == 0:
            continue
        b_name = f"body {name(mujoco.mjtObj.mjOBJ_BODY, b)}"
        p = int(m.body_parentid[b])
        if p != 0 and p not in obj_of:
            out.unlinked.append(f"{b_name}: its parent body has no elements (left free in the coupled response)")
            continue
        nj = int(m.body_jntnum[b])
        if nj > 1:
            out.unlinked.append(f"{b_name}: has {nj} joints (left free in the coupled response)")
            continue
        j = int(m.body_jntadr[b]) if nj else -1
        kind = kinds[int(m.jnt_type[j])] if nj else "weld"
        q0 = np.zeros(9)
        mujoco.mju_quat2Mat(q0, m.body_quat[b])
        q0 = q0.reshape(3, 3)  # the child frame in the parent frame at qpos0
        axis = q0 @ (np.array(m.jnt_axis[j], float) if nj else np.array([0.0, 0.0, 1.0]))
        axis = axis / np.linalg.norm(axis)
        e1 = np.cross(axis, np.eye(3)[int(np.argmin(np.abs(axis)))])
        e1 /= np.linalg.norm(e1)
        anchor = m.body_pos[b] + q0 @ (np.array(m.jnt_pos[j], float) if nj else np.array(m.body_ipos[b], float))
        arm = float(m.dof_armature[m.jnt_dofadr[j]]) if kind in ("hinge", "slide") else 0.0
        out.links.append(Link(k, obj_of[p] if p != 0 else -1, kind, axis, np.stack([e1, np.cross(axis, e1)]),
                              anchor, arm))

    def subtree(b: int) -> tuple[int, ...]:
        return tuple(obj_of[int(c)] for c in range(m.nbody) if int(c) in obj_of and _descends(m, int(c), b))

    for k in range(m.nu):
        a_name = f"actuator {name(mujoco.mjtObj.mjOBJ_ACTUATOR, k)}"
        motor = (int(m.actuator_dyntype[k]) == int(mujoco.mjtDyn.mjDYN_NONE)
                 and int(m.actuator_gaintype[k]) == int(mujoco.mjtGain.mjGAIN_FIXED)
                 and int(m.actuator_biastype[k]) == int(mujoco.mjtBias.mjBIAS_NONE))
        if not motor:
            out.skipped.append(f"{a_name}: not a motor (its force depends on the state or on activation)")
            continue
        if int(m.actuator_trntype[k]) != int(mujoco.mjtTrn.mjTRN_JOINT):
            out.skipped.append(f"{a_name}: drives no single joint (tendon, site or other transmission)")
            continue
        j = int(m.actuator_trnid[k, 0])
        kind = {int(mujoco.mjtJoint.mjJNT_HINGE): "hinge", int(mujoco.mjtJoint.mjJNT_SLIDE): "slide"}.get(
            int(m.jnt_type[j]))
        if kind is None:
            out.skipped.append(f"{a_name}: drives a ball or free joint")
            continue
        b = int(m.jnt_bodyid[j])
        p = int(m.body_parentid[b])
        if b not in obj_of:
            out.skipped.append(f"{a_name}: its body has no elements")
            continue
        if not posable[obj_of[b]]:
            out.skipped.append(f"{a_name}: its body's elements do not fix its rotation (fewer than 3, or on a line)")
            continue
        if p != 0 and p not in obj_of:
            out.skipped.append(f"{a_name}: its parent body has no elements (the reaction would be lost)")
            continue
        axis = np.array(m.jnt_axis[j], float)
        ctrl_range = tuple(float(c) for c in m.actuator_ctrlrange[k]) if bool(m.actuator_ctrllimited[k]) else None
        force_range = tuple(float(c) for c in m.actuator_forcerange[k]) if bool(m.actuator_forcelimited[k]) else None
        out.drives.append(Drive(k, obj_of[b], obj_of[p] if p != 0 else -1, kind, axis / np.linalg.norm(axis),
                                float(m.actuator_gear[k, 0]), float(m.actuator_gainprm[k, 0]),
                                ctrl_range, force_range, np.array(m.jnt_pos[j], float),
                                float(m.dof_armature[m.jnt_dofadr[j]]), subtree(b)))
    return out


def actuation_forces(x: torch.Tensor, ctrl: torch.Tensor, drives: DriveSet, ref: torch.Tensor, seg: torch.Tensor,
                     n_obj: int, mass: torch.Tensor) -> torch.Tensor:
    """Node forces ``F_i = m_i a_i`` [B, N, 3] (N) of the motors' loads on free bodies (module docstring).

    This and :func:`motor_accelerations` share the motors' generalised forces (:func:`_motor_forces`).

    x : [B, N, 3] node positions (m); ctrl : [B, nu] controls (actuator units); ref : [N, 3] element
    centroids in their body frames; seg : [N] object of each node; mass : [N] element masses (kg).
    Returned in ``x``'s dtype; zero when there are no drives.
    """
    if not drives:
        return torch.zeros_like(x)
    dev, f64 = x.device, torch.float64
    T = drives.tensors(dev)
    xd, seg = x.to(f64), seg.to(dev)
    R, _ = kabsch(ref.to(dev, f64), xd, seg, n_obj)  # [B, S, 3, 3]: body rotations
    B = x.shape[0]
    u = _motor_forces(ctrl.to(dev, f64), T)  # [B, D]
    n = (R[:, T["child"]] @ T["axis"].unsqueeze(-1)).squeeze(-1)  # world axes [B, D, 3]
    load = u.unsqueeze(-1) * n
    tq = T["torque"].view(1, -1, 1)
    # summed loads per object; the world (parent -1) takes its reactions in slot n_obj, dropped
    force = xd.new_zeros(B, n_obj + 1, 3)
    torque = xd.new_zeros(B, n_obj + 1, 3)
    parent = torch.where(T["parent"] < 0, n_obj, T["parent"])
    torque.index_add_(1, T["child"], torch.where(tq, load, 0.0)).index_add_(1, parent, torch.where(tq, -load, 0.0))
    force.index_add_(1, T["child"], torch.where(tq, 0.0, load)).index_add_(1, parent, torch.where(tq, 0.0, -load))
    force, torque = force[:, :n_obj], torque[:, :n_obj]
    md = mass.to(dev, f64)
    cen = segment_mean(xd, seg, n_obj, md)  # [B, S, 3] element centroids
    alpha = (R @ T["inv_inertia"] @ R.transpose(-1, -2) @ torque.unsqueeze(-1)).squeeze(-1)  # I_w^-1 T
    lin = force / T["mass"].clamp_min(torch.finfo(f64).tiny).view(1, -1, 1)
    r = xd - cen[:, seg]
    acc = lin[:, seg] + torch.linalg.cross(alpha[:, seg], r, dim=-1)
    return (md.view(1, -1, 1) * acc).to(x.dtype)


def _motor_forces(ctrl: torch.Tensor, T: dict) -> torch.Tensor:
    """Generalised forces ``u_k = gear_k clip(gain_k clip(ctrl_k, ctrlrange), forcerange)`` [B, D]."""
    c = torch.minimum(torch.maximum(ctrl[:, T["actuator"]], T["ctrl_lo"]), T["ctrl_hi"])
    return T["gain"] * torch.minimum(torch.maximum(T["force_gain"] * c, T["force_lo"]), T["force_hi"])


def motor_accelerations(x: torch.Tensor, ctrl: torch.Tensor, drives: DriveSet, ref: torch.Tensor, seg: torch.Tensor,
                        n_obj: int) -> torch.Tensor:
    """Node accelerations [B, N, 3] (m/s^2) of the motors' joints with their parents held (module docstring).

    x : [B, N, 3] node positions (m); ctrl : [B, nu] controls; ref : [N, 3] element centroids in their
    body frames; seg : [N] object of each node. Returned in ``x``'s dtype; zero without drives.
    """
    if not drives:
        return torch.zeros_like(x)
    dev, f64 = x.device, torch.float64
    T = drives.tensors(dev)
    xd, seg = x.to(f64), seg.to(dev)
    R, t = kabsch(ref.to(dev, f64), xd, seg, n_obj)  # [B, S, 3, 3], [B, S, 3]: MuJoCo's xmat, xpos
    u = _motor_forces(ctrl.to(dev, f64), T)  # [B, D]
    Rc, tc = R[:, T["child"]], t[:, T["child"]]  # [B, D, 3, 3], [B, D, 3]
    n = (Rc @ T["axis"].unsqueeze(-1)).squeeze(-1)  # world axes [B, D, 3]
    A = (Rc @ T["anchor"].unsqueeze(-1)).squeeze(-1) + tc  # world anchors [B, D, 3]
    sub = T["subtree"].to(f64)  # [D, S]
    hinge = T["torque"].view(1, -1)
    # hinge: n^T I_b n + M_b |n x (x_b - A)|^2 for every (motor, object); slide: M_b
    xb = (R @ T["com"].unsqueeze(-1)).squeeze(-1) + t  # mass centres [B, S, 3]
    Iw = R @ T["inertia"] @ R.transpose(-1, -2)  # [B, S, 3, 3]
    rot = torch.einsum("bdi,bsij,bdj->bds", n, Iw, n)
    arm = torch.linalg.cross(n.unsqueeze(2).expand(-1, -1, n_obj, -1), xb.unsqueeze(1) - A.unsqueeze(2), dim=-1)
    per = torch.where(hinge.unsqueeze(-1), rot + T["mass"] * (arm ** 2).sum(-1), T["mass"].expand_as(rot))
    m_kk = (per * sub).sum(-1) + T["armature"]  # [B, D]
    qacc = u / m_kk.clamp_min(torch.finfo(f64).tiny)
    on = sub[:, seg]  # [D, N]: node i moves with motor d's subtree
    r = xd.unsqueeze(1) - A.unsqueeze(2)  # [B, D, N, 3]
    turn = torch.linalg.cross(n.unsqueeze(2).expand_as(r), r, dim=-1)
    field_ = torch.where(hinge.view(1, -1, 1, 1), turn, n.unsqueeze(2).expand_as(r))
    acc = (qacc.view(*qacc.shape, 1, 1) * on.view(1, *on.shape, 1) * field_).sum(1)
    return acc.to(x.dtype)


def _rows(S: int, B: int, like: torch.Tensor, c: int, p: int, D: torch.Tensor, arm_c: torch.Tensor | None = None,
          arm_p: torch.Tensor | None = None) -> torch.Tensor:
    """Rows [B, k, 6 S] over the objects' stacked accelerations ``(a_s, alpha_s)`` of the relative acceleration of
    child ``c`` against parent ``p`` (-1: the world) along the directions ``D`` [B, k, 3]: angular when ``arm_c``
    is None, else of the point whose offsets from the mass centres are ``arm_c``, ``arm_p`` [B, 3]
    (``d . (alpha x r) = alpha . (r x d)``)."""
    out = like.new_zeros(B, D.shape[1], S, 6)
    if arm_c is None:
        out[:, :, c, 3:] = D
        if p >= 0:
            out[:, :, p, 3:] = -D
    else:
        out[:, :, c, :3] = D
        out[:, :, c, 3:] = torch.linalg.cross(arm_c.unsqueeze(1).expand_as(D), D, dim=-1)
        if p >= 0:
            out[:, :, p, :3] = -D
            out[:, :, p, 3:] = -torch.linalg.cross(arm_p.unsqueeze(1).expand_as(D), D, dim=-1)
    return out.reshape(B, D.shape[1], 6 * S)


def coupled_motor_accelerations(x: torch.Tensor, ctrl: torch.Tensor, drives: DriveSet, ref: torch.Tensor,
                                seg: torch.Tensor, n_obj: int) -> torch.Tensor:
    """Node accelerations [B, N, 3] (m/s^2) of the motors with every joint coupled: MuJoCo's ``M^-1 qfrc_actuator``.

    Unlike :func:`motor_accelerations` (the driven joint alone, its parent held) the parent recoils and
    the other joints pass the load on: a Cubli's cube turns against its braking flywheel, a cart's
    pole swings as the cart is pushed. Newton-Euler in Cartesian form with the joints as constraints
    (the same equations as MuJoCo's joint-space ``M qacc = qfrc``, as the test against ``mj_solveM``
    shows), for the stacked accelerations ``z = (a_s, alpha_s)`` of every object's mass centre
    ``x_s = R_s body_ipos + t_s`` and rotation::

        [ M   J^T ] [ z ]   [ sum_k u_k g_k ]        M = diag(M_s I_3, I_s^w) + sum_j armature_j g_j g_j^T
        [ J    0  ] [ l ] = [       0       ]

    ``g_j`` the row of joint ``j``'s rate (hinge ``n . (alpha_c - alpha_p)``, slide ``n . (a_c(A) -
    a_p(A))`` at the anchor ``A``), ``J`` the rows a link fixes (hinge: the anchor's relative
    acceleration and the relative angular acceleration across ``n``; slide: the relative angular
    acceleration and the anchor's across ``n``; ball: the anchor's; weld: all six; free: none) and the
    world's elements held still. Velocity terms (gyroscopic, Coriolis, the joints' centripetal terms)
    are left out, as they do not depend on the controls. Node accelerations are
    ``a_s + alpha_s x (x_i - x_s)``. Objects named in ``drives.unlinked`` move freely; every moving
    object needs a positive mass and inertia or a link that fixes it. Shapes as
    :func:`motor_accelerations`; float64 inside, returned in ``x``'s dtype.
    """
    if not drives:
        return torch.zeros_like(x)
    dev, f64 = x.device, torch.float64
    T = drives.tensors(dev)
    xd, seg = x.to(f64), seg.to(dev)
    R, t = kabsch(ref.to(dev, f64), xd, seg, n_obj)  # [B, S, 3, 3], [B, S, 3]
    B, S = x.shape[0], n_obj
    xs = (R @ T["com"].unsqueeze(-1)).squeeze(-1) + t  # mass centres [B, S, 3]
    fixed = torch.as_tensor(drives.fixed, device=dev)
    eye3 = torch.eye(3, dtype=f64, device=dev)
    lin = torch.where(fixed.view(S, 1, 1), eye3, T["mass"].view(S, 1, 1) * eye3)  # [S, 3, 3]
    ang = torch.where(fixed.view(1, S, 1, 1), eye3, R @ T["inertia"] @ R.transpose(-1, -2))  # [B, S, 3, 3]
    blocks = xd.new_zeros(B, S, 6, 6)
    blocks[:, :, :3, :3] = lin
    blocks[:, :, 3:, 3:] = ang
    M = torch.einsum("bsij,st->bsitj", blocks, torch.eye(S, dtype=f64, device=dev)).reshape(B, 6 * S, 6 * S)

    def world_of(s: int, v: np.ndarray, point: bool = False) -> torch.Tensor:
        """Vectors (points) [k, 3] given in object s's frame (-1: the world) in the world [B, k, 3]."""
        vv = torch.as_tensor(np.atleast_2d(v), dtype=f64, device=dev).expand(B, -1, 3)
        if s < 0:
            return vv
        return (R[:, s].unsqueeze(1) @ vv.unsqueeze(-1)).squeeze(-1) + (t[:, s].unsqueeze(1) if point else 0.0)

    def joint_row(c: int, p: int, kind: str, n: torch.Tensor, A: torch.Tensor) -> torch.Tensor:
        """Row [B, 1, 6S] of the joint's rate: hinge ``n . (alpha_c - alpha_p)``, slide ``n . (a_c(A) - a_p(A))``."""
        if kind == "hinge":
            return _rows(S, B, xd, c, p, n)
        return _rows(S, B, xd, c, p, n, A - xs[:, c], A - xs[:, p] if p >= 0 else None)

    J = []
    for s in torch.nonzero(fixed).flatten().tolist():  # the world's elements stay put
        J.append(torch.eye(6 * S, dtype=f64, device=dev)[6 * s: 6 * s + 6].expand(B, 6, 6 * S))
    world = eye3.expand(B, 3, 3)
    rate = {}  # child object -> its joint's rate row
    for lk in drives.links:
        c, p = lk.child, lk.parent
        A = world_of(p, lk.anchor, point=True)[:, 0]
        rc, rp = A - xs[:, c], (A - xs[:, p] if p >= 0 else None)
        if lk.kind in ("hinge", "ball", "weld"):
            J.append(_rows(S, B, xd, c, p, world, rc, rp))
        if lk.kind in ("slide", "weld"):
            J.append(_rows(S, B, xd, c, p, world))
        if lk.kind == "hinge":
            J.append(_rows(S, B, xd, c, p, world_of(p, lk.perp)))
        if lk.kind == "slide":
            J.append(_rows(S, B, xd, c, p, world_of(p, lk.perp), rc, rp))
        if lk.kind in ("hinge", "slide"):
            rate[c] = joint_row(c, p, lk.kind, world_of(p, lk.axis), A)  # [B, 1, 6S]
            if lk.armature > 0:
                M = M + lk.armature * rate[c].transpose(-1, -2) @ rate[c]
    u = _motor_forces(ctrl.to(dev, f64), T)  # [B, D]
    F = xd.new_zeros(B, 6 * S)
    for k, dr in enumerate(drives.drives):
        g = rate.get(dr.child)
        if g is None:  # a child left out of the links: its own frame
            g = joint_row(dr.child, dr.parent, dr.kind, world_of(dr.child, dr.axis),
                          world_of(dr.child, dr.anchor, point=True)[:, 0])
        F = F + u[:, k: k + 1] * g[:, 0]
    Jm = torch.cat(J, 1) if J else xd.new_zeros(B, 0, 6 * S)
    C = Jm.shape[1]
    K = torch.cat([torch.cat([M, Jm.transpose(-1, -2)], -1),
                   torch.cat([Jm, xd.new_zeros(B, C, C)], -1)], 1)
    z = torch.linalg.solve(K, torch.cat([F, xd.new_zeros(B, C)], -1))[:, :6 * S].view(B, S, 6)
    acc = z[:, seg, :3] + torch.linalg.cross(z[:, seg, 3:], xd - xs[:, seg], dim=-1)
    return acc.to(x.dtype)

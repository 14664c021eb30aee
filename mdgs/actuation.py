"""The motors' known loads: as node forces on free bodies, as the joint's response with its parent held, as the whole tree's response; and the whole tree's forward dynamics.

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

**The whole tree's forward dynamics** (the same function given the node velocities): everything
else a rigid tree on a floor feels joins the motors - gravity, the gyroscopic torques, the joints'
velocity terms and the floor's contact with box corners and cylinder rims, sticking or sliding with
Coulomb friction (its docstring).
In free flight it is MuJoCo's ``qacc`` to 1e-9 (tests/test_dynamics.py); on the floor it is a rigid,
inelastic contact model instead of MuJoCo's soft one. Stepped once per frame it is the
"rigid tree" reference (:mod:`mdgs.models.references`) and MDGS's ``actuation = "dynamics"`` prior.

The other forms have no velocity terms (gyroscopic, Coriolis), which do not depend on the control.
Actuators that are not motors (position or velocity servos, activation dynamics),
that drive a tendon, a site or a ball or free joint, or whose body's rotation its elements do
not fix, are listed in ``skipped`` and contribute nothing; bodies without elements are left out
of the sums. Everything runs in float64; shapes ``[B, N, 3]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from mdgs.rigid import twist
from mdgs.structure import fixes_rotation, kabsch, segment_mean

#: Forward dynamics' floor contact (:func:`coupled_motor_accelerations`): a box corner closer to the floor than
#: this (m) holds; MuJoCo's soft contacts rest a few tenths of a millimetre deep.
CONTACT_GAP = 2e-3
#: Compliance of a held corner (m/s^2 per N): small against the bodies' 1/mass, it only makes four
#: corners of a face (twelve rows for six degrees of freedom) share the load.
CONTACT_COMPLIANCE = 1e-6
#: Passes of the active-set search that lets go of corners the floor would pull.
CONTACT_PASSES = 4
#: Points on each rim of a colliding cylinder that stand in for it as corners (a 16-gon's rim is
#: within 2 % of the radius of the circle's).
RIM_POINTS = 16

__all__ = ["Drive", "DriveSet", "Link", "drives_of", "actuation_forces", "motor_accelerations",
           "coupled_motor_accelerations", "floor_corners", "warn_unseen"]


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
    For the forward dynamics (:func:`coupled_motor_accelerations` given velocities): gravity : [3] the
    MJCF's ``opt.gravity``; corners : [K, 3] the corners of every colliding box geom of a moving
    object (and ``RIM_POINTS`` on each rim of a colliding cylinder), in its body frame, corner_obj : [K]
    that object, corner_friction : [K] the sliding friction of the corner's geom against the floor
    (the larger of the two, as MuJoCo pairs them); floor : the height of the world's highest colliding
    plane whose normal is +z (None without one; then no corners); unseen : what the forward dynamics
    leaves out of a scene, one line each (colliding geoms it has no contact for, joint limits, damping,
    springs, friction loss), so that a user of the rigid tree or of MDGS's "dynamics" prior is told.
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
    gravity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    corners: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    corner_obj: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    corner_friction: np.ndarray = field(default_factory=lambda: np.zeros(0))
    unseen: list[str] = field(default_factory=list)
    floor: float | None = None
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
    out = DriveSet(mass=mass, inertia=inertia, inv_inertia=inv_inertia, com=com, fixed=bodies == 0,
                   gravity=np.array(m.opt.gravity, float))
    corners, corner_obj, corner_mu, floors = [], [], [], []
    signs = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float)
    geom_name = lambda g: mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"#{g}"  # noqa: E731
    for g in range(m.ngeom):
        if not (int(m.geom_contype[g]) or int(m.geom_conaffinity[g])):
            continue
        gq = np.zeros(9)
        mujoco.mju_quat2Mat(gq, m.geom_quat[g])
        gq = gq.reshape(3, 3)
        b = int(m.geom_bodyid[g])
        kind = mujoco.mjtGeom(int(m.geom_type[g])).name.removeprefix("mjGEOM_").lower()
        if b == 0 and int(m.geom_type[g]) != int(mujoco.mjtGeom.mjGEOM_PLANE):
            out.unseen.append(f"geom {geom_name(g)} ({kind} of the world): nothing touches it, only +z planes are floors")
        elif b != 0 and b in obj_of and int(m.geom_type[g]) not in (int(mujoco.mjtGeom.mjGEOM_BOX),
                                                                  int(mujoco.mjtGeom.mjGEOM_CYLINDER)):
            out.unseen.append(f"geom {geom_name(g)} ({kind}): no contact points, only boxes and cylinders have them")
        if b == 0 and int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_PLANE) and not np.allclose(gq[:, 2], [0, 0, 1]):
            out.unseen.append(f"geom {geom_name(g)} (plane): not a floor, its normal is not +z")
        if b == 0 and int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_PLANE) and np.allclose(gq[:, 2], [0, 0, 1]):
            floors.append((float(m.geom_pos[g][2]), float(m.geom_friction[g][0])))
        elif b != 0 and b in obj_of and int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_BOX):
            corners.append(m.geom_pos[g] + (signs * m.geom_size[g]) @ gq.T)
            corner_obj += [obj_of[b]] * 8
            corner_mu += [float(m.geom_friction[g][0])] * 8
        elif b != 0 and b in obj_of and int(m.geom_type[g]) == int(mujoco.mjtGeom.mjGEOM_CYLINDER):
            r, h = m.geom_size[g][:2]
            ang = 2 * np.pi * np.arange(RIM_POINTS) / RIM_POINTS
            rim = np.stack([r * np.cos(ang), r * np.sin(ang), np.zeros_like(ang)], -1)
            pts = np.concatenate([rim + [0, 0, h], rim - [0, 0, h]])
            corners.append(m.geom_pos[g] + pts @ gq.T)
            corner_obj += [obj_of[b]] * len(pts)
            corner_mu += [float(m.geom_friction[g][0])] * len(pts)
    if floors:
        out.floor, floor_mu = max(floors)
        if corners:  # MuJoCo's friction of a pair: the larger of the two geoms'
            out.corners, out.corner_obj = np.concatenate(corners), np.array(corner_obj, int)
            out.corner_friction = np.maximum(np.array(corner_mu), floor_mu)
    for j in range(m.njnt):
        jn = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}"
        dofs = slice(int(m.jnt_dofadr[j]), int(m.jnt_dofadr[j]) + {0: 6, 1: 3, 2: 1, 3: 1}[int(m.jnt_type[j])])
        left = [what for what, on in (("its range limit", bool(m.jnt_limited[j])),
                                      ("its spring", float(m.jnt_stiffness[j]) != 0.0),
                                      ("its damping", bool(np.any(m.dof_damping[dofs] != 0))),
                                      ("its friction loss", bool(np.any(m.dof_frictionloss[dofs] != 0)))) if on]
        if left:
            out.unseen.append(f"joint {jn}: {', '.join(left)}")
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


def warn_unseen(drives: DriveSet, who: str) -> None:
    """Warn (``UserWarning``, issued here so that Python shows each scene's list once a process) that
    ``who`` (the rigid tree, MDGS's "dynamics" prior) leaves out what ``drives.unseen`` lists; nothing
    when it lists nothing."""
    if drives.unseen:
        import warnings

        warnings.warn(f"{who} uses the forward dynamics of mdgs.actuation, which leaves out, in this scene: "
                      + "; ".join(drives.unseen), UserWarning, stacklevel=1)


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


def floor_corners(R: torch.Tensor, t: torch.Tensor, tw, drives: DriveSet, dt: float) -> tuple:
    """Where the floor acts, by the rule of :func:`coupled_motor_accelerations`: ``drives.corners`` in the
    world ``P`` [B, K, 3], their velocities ``u`` [B, K, 3] (from the objects' twists ``tw``,
    :func:`mdgs.rigid.twist`), which the floor holds [B, K] (within ``CONTACT_GAP`` of it, or reaching it
    within ``dt``), and which move across it faster than friction could stop within ``dt`` [B, K]
    (``|u_xy| > mu |g| dt``: they slide, if held). ``R, t`` [B, S, 3, 3], [B, S, 3]: the objects' poses."""
    f64 = torch.float64
    obj = torch.as_tensor(drives.corner_obj, device=R.device)
    P = (R[:, obj] @ torch.as_tensor(drives.corners, dtype=f64, device=R.device).unsqueeze(-1)).squeeze(-1) + t[:, obj]
    u = tw.vc[:, obj] + torch.linalg.cross(tw.omega[:, obj], P - tw.c[:, obj], dim=-1)
    h = P[..., 2] - drives.floor
    held = (h < CONTACT_GAP) | (h + dt * u[..., 2].clamp_max(0.0) < CONTACT_GAP)
    mu = torch.as_tensor(drives.corner_friction, dtype=f64, device=R.device)
    slide = u[..., :2].norm(dim=-1) > mu * float(np.linalg.norm(drives.gravity)) * dt
    return P, u, held, slide


def coupled_motor_accelerations(x: torch.Tensor, ctrl: torch.Tensor, drives: DriveSet, ref: torch.Tensor,
                                seg: torch.Tensor, n_obj: int, v: torch.Tensor | None = None,
                                mass: torch.Tensor | None = None, dt: float | None = None) -> torch.Tensor:
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
    world's elements held still. Without velocities, velocity terms (gyroscopic, Coriolis, the joints'
    centripetal terms) are left out, as they do not depend on the controls. Node accelerations are
    ``a_s + alpha_s x (x_i - x_s)``. Objects named in ``drives.unlinked`` move freely; every moving
    object needs a positive mass and inertia or a link that fixes it. Shapes as
    :func:`motor_accelerations`; float64 inside, returned in ``x``'s dtype.

    **Forward dynamics** (given the node velocities ``v`` [B, N, 3], the element ``mass`` [N] and the frame
    ``dt``): the same system with everything else a rigid tree on a floor feels, so that the result
    is MuJoCo's ``qacc`` up to its contact model. The right-hand side gains gravity ``M_s g`` on every
    moving object and the gyroscopic torque ``-w_s x (I_s^w w_s)``; each constraint row gains its
    velocity term (a hinge or ball anchor: ``-(w_c x (w_c x r_c) - w_p x (w_p x r_p))``; a hinge's
    two cross-axis rows ``p . (w_p x (w_c - w_p))``, the axis turning with the parent; slides without
    theirs). The twists ``w_s`` are the least-squares fits of :func:`mdgs.rigid.twist`. Floor contact:
    every corner of a colliding box, and each of ``RIM_POINTS`` points on either rim of a colliding
    cylinder (``drives.corners``; spheres, capsules and meshes are not seen), that is within ``CONTACT_GAP`` of the floor, or
    would reach it within ``dt``, is held: while it moves across the floor slower than friction could
    stop it within the frame (``mu |g| dt``, ``mu`` = ``drives.corner_friction``) it sticks, three rows
    holding its acceleration at ``-w x (w x r) - u / dt`` (``u`` its velocity: an inelastic, sticking
    impact over one frame); faster, it slides: only the normal row is held and the floor's push ``f_n``
    comes with Coulomb friction ``mu f_n`` against the slip (the row's column in the upper right of
    the system carries it, so the system is not symmetric). The rows have a compliance of
    ``CONTACT_COMPLIANCE`` so that four corners of a face (twelve rows for six degrees of freedom)
    share the load in the least-squares way (the held corners of a batch are gathered into as many
    slots as its most held). A corner whose floor would have to pull it down is let go and the system
    solved again (``CONTACT_PASSES`` passes, an active-set search). Not modelled: the friction cone of a
    sticking corner (it holds whatever tangential force sticking takes), rolling and torsional
    friction, joint limits, damping and springs, and contact with any other geom (the Cubli's wall and
    block, rotational-center's posts): ``drives.unseen`` names what a scene has of these, and the rigid
    tree and MDGS's "dynamics" prior warn with it when bound (:func:`warn_unseen`).
    """
    dynamic = v is not None
    if not drives and not dynamic:
        return torch.zeros_like(x)
    dev, f64 = x.device, torch.float64
    T = drives.tensors(dev)
    xd, seg = x.to(f64), seg.to(dev)
    R, t = kabsch(ref.to(dev, f64), xd, seg, n_obj)  # [B, S, 3, 3], [B, S, 3]
    if dynamic:
        tw = twist(xd, v, seg, n_obj, mass.to(dev))
        w = tw.omega  # [B, S, 3]
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

    J, rhs = [], []  # constraint rows [B, k, 6S] and their right-hand sides [B, k]
    zero3 = xd.new_zeros(B, 3)
    for s in torch.nonzero(fixed).flatten().tolist():  # the world's elements stay put
        J.append(torch.eye(6 * S, dtype=f64, device=dev)[6 * s: 6 * s + 6].expand(B, 6, 6 * S))
        rhs.append(xd.new_zeros(B, 6))
    world = eye3.expand(B, 3, 3)
    rate = {}  # child object -> its joint's rate row
    for lk in drives.links:
        c, p = lk.child, lk.parent
        A = world_of(p, lk.anchor, point=True)[:, 0]
        rc, rp = A - xs[:, c], (A - xs[:, p] if p >= 0 else None)
        wc = w[:, c] if dynamic else zero3
        wp = w[:, p] if dynamic and p >= 0 else zero3
        if lk.kind in ("hinge", "ball", "weld"):
            J.append(_rows(S, B, xd, c, p, world, rc, rp))
            rp0 = rp if rp is not None else zero3
            rhs.append(-(torch.linalg.cross(wc, torch.linalg.cross(wc, rc, dim=-1), dim=-1)
                         - torch.linalg.cross(wp, torch.linalg.cross(wp, rp0, dim=-1), dim=-1)))
        if lk.kind in ("slide", "weld"):
            J.append(_rows(S, B, xd, c, p, world))
            rhs.append(xd.new_zeros(B, 3))
        if lk.kind == "hinge":
            D = world_of(p, lk.perp)  # [B, 2, 3], turning with the parent
            J.append(_rows(S, B, xd, c, p, D))
            rhs.append((D * torch.linalg.cross(wp, wc - wp, dim=-1).unsqueeze(1)).sum(-1))
        if lk.kind == "slide":
            J.append(_rows(S, B, xd, c, p, world_of(p, lk.perp), rc, rp))
            rhs.append(xd.new_zeros(B, 2))
        if lk.kind in ("hinge", "slide"):
            rate[c] = joint_row(c, p, lk.kind, world_of(p, lk.axis), A)  # [B, 1, 6S]
            if lk.armature > 0:
                M = M + lk.armature * rate[c].transpose(-1, -2) @ rate[c]
    F = xd.new_zeros(B, 6 * S)
    if drives:
        u = _motor_forces(ctrl.to(dev, f64), T)  # [B, D]
        for k, dr in enumerate(drives.drives):
            g = rate.get(dr.child)
            if g is None:  # a child left out of the links: its own frame
                g = joint_row(dr.child, dr.parent, dr.kind, world_of(dr.child, dr.axis),
                              world_of(dr.child, dr.anchor, point=True)[:, 0])
            F = F + u[:, k: k + 1] * g[:, 0]
    if dynamic:  # gravity and the gyroscopic torques; then the floor's corners
        moving = (~fixed).to(f64).view(1, S, 1)
        grav = torch.as_tensor(drives.gravity, dtype=f64, device=dev)
        Iw = ang  # [B, S, 3, 3]
        gyro = -torch.linalg.cross(w, (Iw @ w.unsqueeze(-1)).squeeze(-1), dim=-1)
        F = F + (moving * torch.cat([T["mass"].view(1, S, 1) * grav.expand(B, S, 3), gyro], -1)).reshape(B, 6 * S)
    C0 = sum(j.shape[1] for j in J)
    contact = dynamic and drives.floor is not None and len(drives.corner_obj) > 0
    if contact:
        obj = torch.as_tensor(drives.corner_obj, device=dev)
        P, uP, active, slide = floor_corners(R, t, tw, drives, dt)  # [B, K, 3] x2, [B, K] x2
        arm = P - xs[:, obj]
        rows, crhs = [], []
        for k, o in enumerate(drives.corner_obj.tolist()):
            rows.append(_rows(S, B, xd, o, -1, world, arm[:, k]))
            wk = w[:, o]
            crhs.append(-torch.linalg.cross(wk, torch.linalg.cross(wk, arm[:, k], dim=-1), dim=-1) - uP[:, k] / dt)
        Jc, rc_ = torch.cat(rows, 1).view(B, -1, 3, 6 * S), torch.cat(crhs, -1).view(B, -1, 3)  # per corner
        mu = torch.as_tensor(drives.corner_friction, dtype=f64, device=dev)  # [K]
        ut = uP[..., :2]
        uhat = ut / ut.norm(dim=-1).clamp_min(torch.finfo(f64).tiny).unsqueeze(-1)
        # a sliding corner's z column carries the friction it feels: -mu |f_n| along its slip
        fric = Jc[:, :, 2] - mu.view(1, -1, 1) * (uhat[..., :1] * Jc[:, :, 0] + uhat[..., 1:] * Jc[:, :, 1])
        Cc = torch.cat([Jc[:, :, :2], torch.where(slide.unsqueeze(-1), fric, Jc[:, :, 2]).unsqueeze(2)], 2)
        rows_on = torch.stack([~slide, ~slide, torch.ones_like(slide)], -1)  # [B, K, 3]
    Jm = torch.cat(J, 1) if J else xd.new_zeros(B, 0, 6 * S)
    b0 = torch.cat(rhs, -1) if rhs else xd.new_zeros(B, 0)
    for _ in range(CONTACT_PASSES if contact else 1):
        if contact:  # the held corners first, as many slots as the batch's most held corners
            order = torch.argsort((~active).to(torch.int8), dim=-1, stable=True)
            n_on = max(int(active.sum(-1).max()), 1)
            sel = order[:, :n_on]  # [B, n_on]
            on = (torch.gather(active, 1, sel).unsqueeze(-1)
                  & torch.gather(rows_on, 1, sel.view(B, n_on, 1).expand(-1, -1, 3))).to(f64).view(B, 3 * n_on)
            idx = sel.view(B, n_on, 1, 1).expand(-1, -1, 3, 6 * S)
            Jsel = torch.gather(Jc, 1, idx).reshape(B, 3 * n_on, 6 * S)
            Csel = torch.gather(Cc, 1, idx).reshape(B, 3 * n_on, 6 * S)
            rsel = torch.gather(rc_, 1, sel.view(B, n_on, 1).expand(-1, -1, 3)).reshape(B, 3 * n_on)
            Jall = torch.cat([Jm, Jsel * on.unsqueeze(-1)], 1)
            Call = torch.cat([Jm, Csel * on.unsqueeze(-1)], 1)
            ball = torch.cat([b0, rsel * on], -1)
            diag = torch.cat([xd.new_zeros(B, C0), torch.where(on > 0, -CONTACT_COMPLIANCE, 1.0)], -1)
        else:
            Jall, Call, ball, diag = Jm, Jm, b0, xd.new_zeros(B, C0)
        K = torch.cat([torch.cat([M, Call.transpose(-1, -2)], -1),
                       torch.cat([Jall, torch.diag_embed(diag)], -1)], 1)
        sol = torch.linalg.solve(K, torch.cat([F, ball], -1))
        if not contact:
            break
        lz = sol[:, 6 * S + C0:].view(B, -1, 3)[..., 2]  # the floor's push on each held corner is -lz
        pulls = torch.zeros_like(active).scatter(1, sel, (lz > 0) & (on.view(B, -1, 3)[..., 2] > 0))
        if not bool(pulls.any()):
            break
        active = active & ~pulls
    z = sol[:, :6 * S].view(B, S, 6)
    acc = z[:, seg, :3] + torch.linalg.cross(z[:, seg, 3:], xd - xs[:, seg], dim=-1)
    return acc.to(x.dtype)

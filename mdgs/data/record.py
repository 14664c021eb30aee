"""Ground-truth loads from MuJoCo and their reduction to recorded frames.

Trajectories are stepped with :class:`mujoco.batch.Batch`, whose ``rollout`` records
MjData fields after every integrator step, in C. The recorder reads MuJoCo's own
per-body wrenches, computed by ``mj_rnePostConstraint`` (triggered by one
``framelinacc`` sensor per body, which also gives MuJoCo's centre-of-mass acceleration):

- ``cfrc_int[b]``: the wrench the parent exerts on body ``b`` through its joints;
- ``cfrc_ext[b]``: the external wrench on ``b`` (contacts only: MuJoCo also puts equality
  constraint and spatial tendon forces there, and applied, fluid and gravity compensation
  forces act on bodies outside any joint; models with them are refused, see
  :func:`instrument`);
- ``qfrc_actuator`` along ``xaxis``: actuator torque (force) of each scalar joint;

all as [torque; force] in world axes about the subtree centre of mass of the body's
tree root (``subtree_com``). Individual contacts come from one ``contact`` sensor per
colliding body (the :data:`CONTACT_SLOTS` largest; the sensor reports the force of the
body on the other, so the load is its negative).

Conventions (checked numerically in ``tests/test_data.py``):

- for step ``s`` the batch records the state *after* the step and the derived fields
  computed at the state *before* it, i.e. with the ``qacc`` that moves ``s`` to
  ``s+1``. Frame ``f`` is step ``f * substeps``; its kinematics are that step's fields.
- loads of frame ``f`` are means over its ``substeps`` steps (impulse / frame time):
  with the Euler integrator ``qvel[s+1] = qvel[s] + h qacc[s]`` exactly, so these are
  the loads that move frame ``f`` to ``f+1``.
- joint damping is integrated implicitly, as MuJoCo does by default (``eulerdamp``):
  the step uses ``qacc' = (M + h B)^-1 M qacc`` instead of the ``qacc`` that MuJoCo's
  wrenches and sensors are computed with, i.e. the damping force is ``-B qvel[s+1]``.
  The recorder moves accelerations and joint loads to ``qacc'`` (the loads that really
  move the state, :func:`mdgs.data._kernels.implicit_damping`), so Newton holds against
  the trajectory itself and not only against MuJoCo's pre-step ``qacc``.
- torques are about the body's centre of mass, forces in the world frame.

Newton per body then reads ``m_b a_b = m_b g + F_contact + F_actuator + F_joint`` with
``F_joint + F_actuator = cfrc_int[b] - sum over children c of cfrc_int[c]``, and the
per-node loads sum to the body's loads (contact forces go to the node nearest the
contact point, joint forces to the node nearest the joint's anchor).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from mdgs.data import _kernels
from mdgs.partition import Partition, PartitionParams, partition_model

__all__ = [
    "SceneError",
    "Instrumented",
    "instrument",
    "FrameReducer",
    "RECORD_FIELDS",
    "CONTACT_SLOTS",
]

CONTACT_SLOTS = 4
"""Individual contacts reported per body and step (the largest by force). When a body has
more, the rest of its contact force (``cfrc_ext``) is put on the node nearest the mean of
the reported contact points, so node contact forces always sum to the body's
(``contact_overflow`` counts it)."""

_S = mujoco.mjtSensor
_O = mujoco.mjtObj
_J = mujoco.mjtJoint
# contact sensor data bits: found=1 force=2 torque=4 dist=8 pos=16 normal=32 tangent=64
_SLOT_BITS, _SLOT_DIM = 1 | 2 | 16 | 32 | 64, 13  # found force pos normal tangent
_REDUCE_MAXFORCE = 2


class SceneError(ValueError):
    """A scene that cannot be recorded faithfully; the message names the element and the fix."""


def _name(model, objtype, i) -> str:
    return mujoco.mj_id2name(model, objtype, i) or f"#{i}"


def _spatial_tendon_forces(model: mujoco.MjModel, t: int) -> list[str]:
    """What makes spatial tendon ``t`` pull on bodies (empty: it never exerts a force)."""
    why = []
    if model.tendon_limited[t]:
        why.append("a length limit")
    if np.any(np.asarray(model.tendon_stiffness[t]) != 0) or np.any(
        np.asarray(getattr(model, "tendon_stiffnesspoly", np.zeros((model.ntendon, 1)))[t]) != 0
    ):
        why.append("stiffness")
    if np.any(np.asarray(model.tendon_damping[t]) != 0):
        why.append("damping")
    if model.tendon_frictionloss[t] != 0:
        why.append("friction loss")
    if np.any(np.asarray(getattr(model, "tendon_armature", np.zeros(model.ntendon))[t]) != 0):
        why.append("armature")
    tendon_trn = model.actuator_trntype == int(mujoco.mjtTrn.mjTRN_TENDON)
    if np.any(tendon_trn & (model.actuator_trnid[:, 0] == t)):
        why.append("an actuator")
    return why


def _check_supported(model: mujoco.MjModel) -> None:
    """Refuse models whose loads the recorder cannot attribute to bodies.

    Fixed tendons act in joint space (their limit, spring, damping and actuator forces are
    joint torques or forces, recorded as joint and actuator loads); a spatial tendon pulls
    the bodies at its sites, a load that is neither a joint's nor a contact's.
    """
    moving = (model.body_weldid[1:] != 0) & (model.body_mass[1:] > 0)
    if model.nv == 0 or not moving.any():
        raise SceneError(
            "the model has no moving body (no joint, or only massless bodies); add a joint (e.g. <freejoint/>) to a body with mass so there is motion to record"
        )
    if model.nflex:
        raise SceneError(
            "the model has flexible bodies (flex/skin); only rigid bodies can be partitioned into elements, remove the flex elements"
        )
    if model.nmocap:
        raise SceneError(
            "the model has mocap bodies; their motion is prescribed, not simulated — replace them by bodies with joints or static geoms"
        )
    if model.neq:
        raise SceneError(
            "the model has equality constraints; their forces are not attributed to bodies by the recorder — replace them by joints"
        )
    for t in range(model.ntendon):
        wraps = model.wrap_type[model.tendon_adr[t] : model.tendon_adr[t] + model.tendon_num[t]]
        spatial = np.any(wraps != int(mujoco.mjtWrap.mjWRAP_JOINT))
        why = _spatial_tendon_forces(model, t) if spatial else []
        if why:
            raise SceneError(
                f"spatial tendon '{_name(model, _O.mjOBJ_TENDON, t)}' has {' and '.join(why)}, so it pulls bodies at its sites, a force the recorder cannot attribute to joints or contacts; use a fixed tendon or joint limits, springs and actuators instead"
            )
    if model.opt.density > 0 or model.opt.viscosity > 0:
        raise SceneError("the model has fluid forces (option density/viscosity > 0); set both to 0")
    if np.any(model.body_gravcomp != 0):
        b = int(np.flatnonzero(model.body_gravcomp != 0)[0])
        raise SceneError(
            f"body '{_name(model, _O.mjOBJ_BODY, b)}' has gravity compensation; remove gravcomp"
        )
    for a in range(model.nu):
        trn = int(model.actuator_trntype[a])
        aname = _name(model, _O.mjOBJ_ACTUATOR, a)
        if trn in (int(mujoco.mjtTrn.mjTRN_JOINT), int(mujoco.mjtTrn.mjTRN_JOINTINPARENT)):
            j = int(model.actuator_trnid[a, 0])
            if int(model.jnt_type[j]) in (int(_J.mjJNT_FREE), int(_J.mjJNT_BALL)):
                raise SceneError(
                    f"actuator '{aname}' drives a free or ball joint; drive hinge or slide joints only"
                )
        elif trn != int(mujoco.mjtTrn.mjTRN_TENDON):
            raise SceneError(
                f"actuator '{aname}' applies an external force (site/body transmission); drive joints or tendons instead"
            )


@dataclass(frozen=True)
class Instrumented:
    """An instrumented scene: the model to step and where each quantity sits in sensordata."""

    model: mujoco.MjModel
    partition: Partition
    notes: tuple[str, ...]
    """What was changed to make loads match finite differences (e.g. integrator replaced)."""
    linacc: np.ndarray  # [nbody, 3] sensordata columns of framelinacc (row 0 unused)
    slots: np.ndarray  # [nbody, CONTACT_SLOTS, 13] sensordata columns, or -1
    has_contact_sensor: np.ndarray  # [nbody] bool
    act_joints: np.ndarray  # [J] hinge/slide joints that actuators drive
    anchor_node: np.ndarray  # [nbody] node of b nearest its own joint anchor (-1: none)
    child_anchor_node: np.ndarray  # [nbody] node of parent(b) nearest b's joint anchor (-1: none)
    lean_model: mujoco.MjModel | None = None
    """``model`` without the contact sensors (None if it has none): the same dynamics, bit for
    bit (sensors only read the state), and ``model``'s sensordata up to the contact sensors.
    Contact-free steps are stepped with it, skipping the contact sensors' cost (see
    :func:`mdgs.data.engine.simulate`)."""
    implicit_damping: bool = False
    """Joint damping integrated implicitly (MuJoCo's default ``eulerdamp``): the recorder
    moves accelerations and joint loads from MuJoCo's ``qacc`` to the integrated one."""

    @property
    def nbody(self) -> int:
        return int(self.model.nbody)


def _compile(spec: mujoco.MjSpec) -> mujoco.MjModel:
    try:
        return spec.compile()
    except Exception as e:  # mujoco raises ValueError with the compiler's message
        raise SceneError(f"MuJoCo cannot compile the scene: {e}") from None


def _load_spec(mjcf: str, path: str | None, assets: dict[str, bytes] | None) -> mujoco.MjSpec:
    try:
        if path is not None:
            return mujoco.MjSpec.from_file(path)
        if assets:  # include files and asset files, by the name the MJCF reads them
            return mujoco.MjSpec.from_string(mjcf, include=assets, assets=assets)
        return mujoco.MjSpec.from_string(mjcf)
    except Exception as e:
        raise SceneError(f"MuJoCo cannot parse the MJCF: {e}") from None


def instrument(
    mjcf: str,
    *,
    path: str | None = None,
    assets: dict[str, bytes] | None = None,
    partition: PartitionParams = PartitionParams(),
    contact_slots: int = CONTACT_SLOTS,
) -> Instrumented:
    """Compile ``mjcf`` (or the file ``path``, which resolves includes and assets) with sensors.

    ``assets``: bytes of the files ``mjcf`` reads, by name (see
    :func:`mdgs.data.engine.self_contained_mjcf`).

    Raises :class:`SceneError` for what cannot be recorded (no moving body, flex, mocap,
    equality constraints, spatial tendons that exert force, fluid forces, gravity
    compensation, external-force actuators) and
    :class:`mdgs.partition.PartitionError` for geoms that cannot be partitioned.
    """
    spec = _load_spec(mjcf, path, assets)
    notes = []
    if spec.option.integrator != mujoco.mjtIntegrator.mjINT_EULER:
        notes.append(
            f"integrator {mujoco.mjtIntegrator(spec.option.integrator).name} replaced by Euler so that loads match finite differences"
        )
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    base = _compile(spec)
    _check_supported(base)
    # MuJoCo integrates joint damping implicitly unless the model disables eulerdamp; the
    # recorder follows it (FrameReducer's implicit-damping correction), never the reverse
    implicit_damping = bool(np.any(base.dof_damping > 0)) and not (
        base.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    )
    part = partition_model(base, partition)

    bodies = list(spec.bodies)
    if len(bodies) != base.nbody or any(
        (b.name or "") != (mujoco.mj_id2name(base, _O.mjOBJ_BODY, i) or "")
        for i, b in enumerate(bodies)
    ):
        raise SceneError("internal: MjSpec body order differs from the compiled model")
    for i, b in enumerate(bodies[1:], start=1):
        if not b.name:
            b.name = f"_mdgs_body{i}"
    collides = np.zeros(base.nbody, bool)
    contacts_on = not (base.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_CONTACT))
    for g in range(base.ngeom):
        if base.geom_contype[g] or base.geom_conaffinity[g]:
            collides[base.geom_bodyid[g]] = True
    collides &= contacts_on
    collides &= base.body_weldid != 0  # bodies welded to the world do not move

    sensors: list[tuple[str, int]] = []  # (key, body)

    def add(key, idx, type_, objtype, objname, intprm=None):
        sen = spec.add_sensor()
        sen.type, sen.objtype, sen.objname = type_, objtype, objname
        sen.name = f"_mdgs_{key}_{idx}"
        if intprm is not None:
            sen.intprm = np.asarray(intprm, dtype=np.int32)
        sensors.append((key, idx))

    for i in range(1, base.nbody):  # MuJoCo's com acceleration; triggers mj_rnePostConstraint
        add("linacc", i, _S.mjSENS_FRAMELINACC, _O.mjOBJ_BODY, bodies[i].name)
    lean = _compile(spec) if collides.any() else None
    for i in np.flatnonzero(collides):
        add(
            "slots",
            int(i),
            _S.mjSENS_CONTACT,
            _O.mjOBJ_BODY,
            bodies[i].name,
            [_SLOT_BITS, _REDUCE_MAXFORCE, contact_slots],
        )
    model = _compile(spec)

    nb = base.nbody
    linacc = -np.ones((nb, 3), int)
    slots = -np.ones((nb, contact_slots, _SLOT_DIM), int)
    for n, (key, i) in enumerate(sensors):
        sid = base.nsensor + n  # the scene's own sensors come first
        adr, dim = int(model.sensor_adr[sid]), int(model.sensor_dim[sid])
        cols = np.arange(adr, adr + dim)
        if key == "linacc":
            linacc[i] = cols
        else:
            slots[i] = cols.reshape(contact_slots, _SLOT_DIM)
    anchor, child_anchor = _anchor_nodes(base, part)
    return Instrumented(
        model=model,
        partition=part,
        notes=tuple(notes),
        linacc=linacc,
        slots=slots,
        has_contact_sensor=collides,
        act_joints=np.array(sorted(_actuated_joints(base)), int),
        anchor_node=anchor,
        child_anchor_node=child_anchor,
        lean_model=lean,
        implicit_damping=implicit_damping,
    )


def _actuated_joints(model: mujoco.MjModel) -> list[int]:
    """Scalar joints that receive actuator force (directly or through a tendon)."""
    out = set()
    for a in range(model.nu):
        trn = int(model.actuator_trntype[a])
        if trn in (int(mujoco.mjtTrn.mjTRN_JOINT), int(mujoco.mjtTrn.mjTRN_JOINTINPARENT)):
            out.add(int(model.actuator_trnid[a, 0]))
        elif trn == int(mujoco.mjtTrn.mjTRN_TENDON):
            t = int(model.actuator_trnid[a, 0])
            for w in range(model.tendon_adr[t], model.tendon_adr[t] + model.tendon_num[t]):
                if int(model.wrap_type[w]) == int(mujoco.mjtWrap.mjWRAP_JOINT):
                    out.add(int(model.wrap_objid[w]))
                else:
                    # spatial tendon: every scalar joint between its sites may feel it
                    for j in range(model.njnt):
                        if int(model.jnt_type[j]) in (int(_J.mjJNT_HINGE), int(_J.mjJNT_SLIDE)):
                            out.add(j)
    for j in list(out):
        if int(model.jnt_type[j]) not in (int(_J.mjJNT_HINGE), int(_J.mjJNT_SLIDE)):
            out.discard(j)
    return sorted(out)


def _anchor_nodes(model: mujoco.MjModel, part: Partition) -> tuple[np.ndarray, np.ndarray]:
    """Nodes where joint loads are attached: nearest to the joint anchor, in the body frames.

    ``anchor[b]``: node of ``b`` nearest to its first joint's anchor (body origin if it
    has no joint); ``child_anchor[b]``: node of ``parent(b)`` nearest to that point.
    """
    nb = model.nbody
    anchor = -np.ones(nb, int)
    child_anchor = -np.ones(nb, int)
    for b in range(1, nb):
        p_local = model.jnt_pos[model.body_jntadr[b]] if model.body_jntnum[b] > 0 else np.zeros(3)
        mine = part.nodes_of(b)
        if len(mine):
            anchor[b] = mine[np.argmin(np.linalg.norm(part.centroid[mine] - p_local, axis=1))]
        par = int(model.body_parentid[b])
        theirs = part.nodes_of(par) if par != 0 else np.zeros(0, int)
        if len(theirs):
            # anchor in the parent's frame at qpos0: body pos/quat relative to the parent
            R = np.zeros(9)
            mujoco.mju_quat2Mat(R, model.body_quat[b])
            q = model.body_pos[b] + R.reshape(3, 3) @ p_local
            child_anchor[b] = theirs[np.argmin(np.linalg.norm(part.centroid[theirs] - q, axis=1))]
    return anchor, child_anchor


class _NearestNode:
    """Nearest node centroid of points in a body frame, exact and fast.

    A lookup grid over the body's cells stores, for every voxel whose 8 corners share
    the same nearest node, that node (then every point of the voxel has it too: Voronoi
    cells are convex). Points in other voxels, or outside the grid, are searched
    directly.
    """

    def __init__(self, centroids: np.ndarray, nodes: np.ndarray, tau: np.ndarray, res: int = 24):
        self.c, self.nodes = centroids, nodes
        lo = (centroids - tau[:, None]).min(0)
        hi = (centroids + tau[:, None]).max(0)
        pad = 0.05 * (hi - lo).max() + 1e-6
        self.lo, self.res = lo - pad, res
        self.h = (hi - lo + 2 * pad) / res
        g = [self.lo[i] + self.h[i] * np.arange(res + 1) for i in range(3)]
        corners = np.stack(np.meshgrid(*g, indexing="ij"), -1).reshape(-1, 3)
        near = self._exact(tuple(corners.T)).reshape(res + 1, res + 1, res + 1)
        same = np.ones((res, res, res), bool)
        base = near[:-1, :-1, :-1]
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    same &= near[dx : res + dx, dy : res + dy, dz : res + dz] == base
        self.table = np.where(same, base, -1).ravel()

    def _exact(self, p) -> np.ndarray:
        d = sum((p[i][:, None] - self.c[None, :, i]) ** 2 for i in range(3))
        return np.argmin(d, 1)


RECORD_FIELDS = (
    "xpos",
    "xquat",
    "xipos",
    "subtree_com",
    "cvel",
    "cfrc_int",
    "cfrc_ext",
    "qfrc_actuator",
    "xaxis",
    "xanchor",
    "sensordata",
    "ncon",
)
"""MjData fields the batch may record after every step (:attr:`FrameReducer.fields` are
those a scene needs: no actuator fields without actuated joints, ``xanchor`` only for
actuated slide joints, ``ncon`` only with contact sensors)."""

KINEMATICS = ("xpos", "xquat", "xipos", "cvel", "subtree_com")
"""Fields read at a frame's first step only (the frame's kinematics)."""


class FrameReducer:
    """Per-step records ``{field: [X, k, ...]}`` (``X`` frames of ``k`` steps) -> frames.

    Loads are means over each frame's ``k`` steps; kinematics are read at the frame's
    first step. MuJoCo's wrenches share one reference point per tree (the root's
    subtree centre of mass ``c``); a wrench moves to the body's centre of mass as
    ``tau + (c - com) x f`` at every step (joint loads: the parent's wrench minus what the
    body passes to its children). The loops are compiled (:mod:`mdgs.data._kernels`) and
    every reduction is per frame, so frames never mix.

    :meth:`loads` reduces the per-step fields, :meth:`kinematics` the first-step ones and
    :meth:`finish` splits actuator loads from joint loads and puts joint forces on nodes;
    :meth:`frames` chains them.
    """

    def __init__(self, inst: Instrumented, substeps: int):
        self.inst = inst
        self.k = int(substeps)
        m = inst.model
        self.nb = nb = m.nbody
        self.B = nb - 1
        self.g = np.array(m.opt.gravity, float)
        self.root = m.body_rootid.astype(np.int64)
        part = inst.partition
        self.node_body = part.body.astype(np.int64)
        self.node_c = np.ascontiguousarray(part.centroid, dtype=float)
        self.N = part.body.shape[0]
        par = m.body_parentid.astype(np.int64)
        self.parent = par
        children = [[c for c in range(1, nb) if par[c] == b] for b in range(nb)]
        self.child_ptr = np.concatenate([[0], np.cumsum([len(c) for c in children])]).astype(
            np.int64
        )
        self.child_idx = np.array([c for cs in children for c in cs], np.int64)
        j = inst.act_joints
        self.act_joint = j
        self.act_dof = m.jnt_dofadr[j].astype(np.int64)
        self.act_jnt = np.asarray(j, np.int64)
        self.act_body = m.jnt_bodyid[j].astype(np.int64)
        self.act_parent = par[self.act_body]
        self.act_slide = m.jnt_type[j] == int(_J.mjJNT_SLIDE)
        self.lin0 = int(inst.linacc[1, 0]) if nb > 1 else 0
        if not np.array_equal(inst.linacc[1:].ravel(), self.lin0 + np.arange(3 * (nb - 1))):
            raise AssertionError("internal: acceleration sensors are not contiguous")
        self.cb = np.flatnonzero(inst.has_contact_sensor).astype(np.int64)  # sensed bodies
        self.C = len(self.cb)
        self.nslot = inst.slots.shape[1]
        self.slot0 = int(inst.slots[self.cb[0], 0, 0]) if self.C else 0
        if self.C and not np.array_equal(
            inst.slots[self.cb, 0, 0], self.slot0 + 13 * self.nslot * np.arange(self.C)
        ):
            raise AssertionError("internal: contact sensors are not contiguous")
        # nearest-node lookup of every sensed body, as flat arrays for the compiled loop
        finders = [
            _NearestNode(
                part.centroid[part.nodes_of(b)], part.nodes_of(b), part.tau[part.nodes_of(b)]
            )
            for b in self.cb
        ]
        self.loc = (
            np.concatenate([f.c for f in finders]) if finders else np.zeros((0, 3)),
            np.concatenate([f.nodes for f in finders]).astype(np.int64)
            if finders
            else np.zeros(0, np.int64),
            np.array([f.lo for f in finders]).reshape(-1, 3),
            np.array([f.h for f in finders]).reshape(-1, 3),
            np.array([f.res for f in finders], np.int64),
            np.concatenate([f.table for f in finders]).astype(np.int64)
            if finders
            else np.zeros(0, np.int64),
            np.concatenate([[0], np.cumsum([len(f.table) for f in finders])]).astype(np.int64),
            np.concatenate([[0], np.cumsum([len(f.nodes) for f in finders])]).astype(np.int64),
        )
        # bodies that may touch but have no contact sensor (welded to the world, or in
        # explicit contact pairs only): their cfrc_ext is still read every step
        has_anchor = inst.anchor_node >= 0
        self.jf_src, self.jf_dst = np.flatnonzero(has_anchor), inst.anchor_node[has_anchor]
        has_child = inst.child_anchor_node >= 0
        self.jr_src, self.jr_dst = np.flatnonzero(has_child), inst.child_anchor_node[has_child]
        fields = ["xpos", "xquat", "xipos", "subtree_com", "cvel", "cfrc_int", "cfrc_ext"]
        if len(j):
            fields += ["qfrc_actuator", "xaxis"] + (["xanchor"] if self.act_slide.any() else [])
        fields += ["sensordata"] + (["ncon"] if self.C else [])
        self.implicit = bool(inst.implicit_damping)
        if self.implicit:  # the integrated acceleration and what maps it to body motion
            fields += ["qvel", "qacc", "cdof", "ximat"]
            self.h = float(m.opt.timestep)
            self.dof_body = m.dof_bodyid.astype(np.int64)
            self.body_mass = np.ascontiguousarray(m.body_mass, dtype=float)
            self.body_inertia = np.ascontiguousarray(m.body_inertia, dtype=float)
        self.fields = tuple(fields)
        """The MjData fields :meth:`loads` and :meth:`kinematics` read, to record every step."""
        self.lean_fields = tuple(f for f in fields if f != "cfrc_ext")
        """:attr:`fields` but the contact ones (the lean model, see :meth:`loads`)."""
        self.contact_fields = ("sensordata", "cfrc_ext")

    # -- per-step fields -------------------------------------------------------------
    def loads(
        self,
        rec: dict[str, np.ndarray],
        contact: dict[str, np.ndarray] | None = None,
        rows: np.ndarray | None = None,
        qvel0: np.ndarray | None = None,
    ) -> dict[str, np.ndarray]:
        """Per-step records ``[X, k, ...]`` -> per-frame loads ``[X, ...]``.

        The contact fields (:attr:`contact_fields`, the model's full sensordata) come from
        ``rec``, or from ``contact`` (``[len(rows), k, ...]``) for frames ``rows`` only,
        the others having had no contact. ``qvel0 [X, nv]``: each frame's initial joint
        velocities, needed with implicit joint damping (:attr:`implicit`).
        """
        k, B = self.k, self.B
        cint = rec["cfrc_int"]
        X = cint.shape[0]
        if rows is None:
            contact, rows = rec, np.arange(X)
        rows = np.asarray(rows, np.int64)
        xipos, sub = rec["xipos"], rec["subtree_com"]
        joint, fint = np.empty((X, B, 6)), np.empty((X, B, 3))
        _kernels.joint_loads(cint, xipos, sub, self.root, self.child_ptr, self.child_idx, k, joint, fint)  # fmt: skip
        acc = np.empty((X, B, 3))
        _kernels.step_means(rec["sensordata"], self.lin0, B, self.g, k, acc)
        if self.implicit:
            if qvel0 is None:
                raise ValueError("internal: implicit joint damping needs each frame's qvel0")
            _kernels.implicit_damping(
                rec["qvel"], np.ascontiguousarray(qvel0, dtype=float), rec["qacc"], rec["cdof"],
                rec["ximat"], xipos, sub, self.root, self.parent, self.dof_body, self.body_mass,
                self.body_inertia, self.h, k, acc, joint, fint,
            )  # fmt: skip
        out = {"joint": joint, "fint": fint, "acc": acc}
        J = len(self.act_joint)
        if J:
            gen, arm_b, arm_p = np.empty((X, J, 3)), np.empty((X, J, 3)), np.empty((X, J, 3))
            anchor = rec["xanchor"] if self.act_slide.any() else np.zeros((X, k, 0, 3))
            _kernels.actuator_loads(
                rec["qfrc_actuator"], rec["xaxis"], anchor, xipos, self.act_dof, self.act_jnt,
                self.act_body, self.act_parent, self.act_slide, k, gen, arm_b, arm_p,
            )  # fmt: skip
            out.update(gen=gen, arm_b=arm_b, arm_p=arm_p)
        wrench = np.zeros((X, B, 6))
        count, overflow = np.zeros(X), np.zeros(X, np.int64)
        node_cf = None
        if len(rows) and "cfrc_ext" in contact:
            node_cf = np.zeros((X, self.N, 3)) if self.C else None
            sdc = contact["sensordata"]
            if not self.C:  # no contact sensor: nothing is read from sensordata
                sdc = np.zeros((len(rows), k, 0))
            _kernels.contact_loads(
                rows, sdc, contact["cfrc_ext"], rec["xpos"], rec["xquat"], xipos, sub,
                self.root, self.cb, self.slot0, self.nslot, k, *self.loc,
                wrench, count, overflow, np.zeros((X, 0, 3)) if node_cf is None else node_cf,
            )  # fmt: skip
        out.update(contact=wrench, contact_count=count, contact_overflow=overflow, node_cf=node_cf)
        return out

    # -- first-step fields -----------------------------------------------------------
    def kinematics(
        self,
        xpos: np.ndarray,
        xquat: np.ndarray,
        xipos: np.ndarray,
        cvel: np.ndarray,
        sub: np.ndarray,
    ) -> dict[str, np.ndarray]:
        """Frame-start fields ``[X, nbody, ...]`` -> body and node kinematics ``[X, ...]``.

        Velocities come from ``cvel`` at the tree's reference point ``sub`` (subtree_com).
        """
        X = xpos.shape[0]
        v = np.empty((X, self.nb, 3))
        pos, vel = np.empty((X, self.N, 3)), np.empty((X, self.N, 3))
        _kernels.node_kinematics(
            *(np.ascontiguousarray(a) for a in (xpos, xquat, xipos, cvel, sub)),
            self.root, self.node_body, self.node_c, v, pos, vel,
        )  # fmt: skip
        return {
            "body_pos": xpos[:, 1:],
            "body_quat": xquat[:, 1:],
            "body_com": xipos[:, 1:],
            "body_linvel": v[:, 1:],
            "body_angvel": cvel[:, 1:, 0:3],
            "node_pos": pos,
            "node_vel": vel,
        }

    # -- loads of whole frames ---------------------------------------------------------
    def finish(self, lo: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """:meth:`loads` of ``X`` frames -> the recorded load arrays ``[X, ...]``."""
        X, B = lo["joint"].shape[:2]
        Fa = np.zeros((X, B + 1, 3))  # row 0: the world
        Ta = np.zeros((X, B + 1, 3))
        for j in range(len(self.act_joint)):
            b, pb = self.act_body[j], self.act_parent[j]
            gm = lo["gen"][:, j]
            if self.act_slide[j]:
                Fa[:, b] += gm
                Ta[:, b] += lo["arm_b"][:, j]
                Fa[:, pb] -= gm
                Ta[:, pb] -= lo["arm_p"][:, j]
            else:
                Ta[:, b] += gm
                Ta[:, pb] -= gm
        node_jf = np.zeros((X, self.N, 3))
        fint = lo["fint"]
        for src, dst in zip(self.jf_src, self.jf_dst, strict=True):
            node_jf[:, dst] += fint[:, src - 1]
        for src, dst in zip(self.jr_src, self.jr_dst, strict=True):
            node_jf[:, dst] -= fint[:, src - 1]
        joint = lo["joint"]
        return {
            "body_acc": lo["acc"],
            "body_contact_force": lo["contact"][..., 3:],
            "body_contact_torque": lo["contact"][..., :3],
            "body_actuator_force": Fa[:, 1:],
            "body_actuator_torque": Ta[:, 1:],
            "body_joint_force": joint[..., 3:] - Fa[:, 1:],
            "body_joint_torque": joint[..., :3] - Ta[:, 1:],
            "node_joint_force": node_jf,
            "contact_count": lo["contact_count"],
            "contact_overflow": lo["contact_overflow"],
        }

    def frames(
        self, rec: dict[str, np.ndarray], qvel0: np.ndarray | None = None
    ) -> dict[str, np.ndarray]:
        """Records ``[X, k, ...]`` (X frames of k steps each, full sensordata) -> frames ``[X, ...]``."""
        kin = self.kinematics(*(rec[f][:, 0] for f in KINEMATICS))
        lo = self.loads(rec, qvel0=qvel0)
        X = len(lo["joint"])
        cf = lo.pop("node_cf")
        out = {**kin, **self.finish(lo)}
        out["node_contact_force"] = np.zeros((X, self.N, 3)) if cf is None else cf
        return {key: np.ascontiguousarray(v) for key, v in out.items()}

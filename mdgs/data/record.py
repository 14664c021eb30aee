"""Ground-truth loads from MuJoCo and their reduction to recorded frames.

Trajectories are stepped with :class:`mujoco.batch.Batch`, whose ``rollout`` records
MjData fields after every integrator step, in C. The recorder reads MuJoCo's own
per-body wrenches, computed by ``mj_rnePostConstraint`` (triggered by one
``framelinacc`` sensor per body, which also gives MuJoCo's centre-of-mass acceleration):

- ``cfrc_int[b]``: the wrench the parent exerts on body ``b`` through its joints;
- ``cfrc_ext[b]``: the external wrench on ``b`` (contacts only: applied forces,
  equality constraints and fluid forces are refused, see :func:`instrument`);
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


def _check_supported(model: mujoco.MjModel) -> None:
    """Refuse models whose loads the recorder cannot attribute to bodies."""
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

    @property
    def nbody(self) -> int:
        return int(self.model.nbody)


def _compile(spec: mujoco.MjSpec) -> mujoco.MjModel:
    try:
        return spec.compile()
    except Exception as e:  # mujoco raises ValueError with the compiler's message
        raise SceneError(f"MuJoCo cannot compile the scene: {e}") from None


def _load_spec(mjcf: str, path: str | None) -> mujoco.MjSpec:
    try:
        if path is not None:
            return mujoco.MjSpec.from_file(path)
        return mujoco.MjSpec.from_string(mjcf)
    except Exception as e:
        raise SceneError(f"MuJoCo cannot parse the MJCF: {e}") from None


def instrument(
    mjcf: str,
    *,
    path: str | None = None,
    partition: PartitionParams = PartitionParams(),
    contact_slots: int = CONTACT_SLOTS,
) -> Instrumented:
    """Compile ``mjcf`` (or the file ``path``, which resolves includes and assets) with sensors.

    Raises :class:`SceneError` for what cannot be recorded (flex, mocap, equality
    constraints, fluid forces, gravity compensation, external-force actuators) and
    :class:`mdgs.partition.PartitionError` for geoms that cannot be partitioned.
    """
    spec = _load_spec(mjcf, path)
    notes = []
    if spec.option.integrator != mujoco.mjtIntegrator.mjINT_EULER:
        notes.append(
            f"integrator {mujoco.mjtIntegrator(spec.option.integrator).name} replaced by Euler so that loads match finite differences"
        )
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    base = _compile(spec)
    _check_supported(base)
    if np.any(base.dof_damping > 0) and not (
        base.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    ):
        notes.append(
            "joint damping integrated explicitly (eulerdamp disabled) so that loads match finite differences"
        )
        spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
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


# Vector algebra on "structure of arrays": a vector is a tuple of 3 arrays (x, y, z) and a
# quaternion a tuple of 4 (w, x, y, z). Elementwise formulas on contiguous component
# arrays are an order of magnitude faster in numpy than np.cross on strided [..., 3] views.


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _qrot(q, v, inverse: bool = False):
    """Rotate v by unit quaternion q: v + 2w (u x v) + 2 u x (u x v) (conjugate if ``inverse``)."""
    w = q[0]
    u = (-q[1], -q[2], -q[3]) if inverse else (q[1], q[2], q[3])
    t = _cross(u, v)
    t = (2 * t[0], 2 * t[1], 2 * t[2])
    c = _cross(u, t)
    return (v[0] + w * t[0] + c[0], v[1] + w * t[1] + c[1], v[2] + w * t[2] + c[2])


def _qmat(q):
    """Rotation matrix (9 components, row major) of unit quaternions (w, x, y, z)."""
    w, x, y, z = q
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    return (
        1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
        2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
        2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy),
    )  # fmt: skip


def _mrot(Rm, v, transpose: bool = False):
    """R v (or R^T v) for R given as 9 components."""
    if transpose:
        return tuple(Rm[i] * v[0] + Rm[3 + i] * v[1] + Rm[6 + i] * v[2] for i in range(3))
    return tuple(Rm[3 * i] * v[0] + Rm[3 * i + 1] * v[1] + Rm[3 * i + 2] * v[2] for i in range(3))


def _mean(v, axis: int = 1):
    return tuple(c.mean(axis) for c in v)


def _aos(v) -> np.ndarray:
    """Tuple of component arrays -> array [..., 3]."""
    return np.stack(v, -1)


def _soa(a: np.ndarray) -> tuple:
    """Array [..., d] -> tuple of d contiguous component arrays."""
    t = np.ascontiguousarray(np.moveaxis(a, -1, 0))
    return tuple(t)


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

    def __call__(self, p) -> np.ndarray:
        """Global node ids of the points ``p`` (3 arrays, body frame)."""
        ijk = [np.floor((p[i] - self.lo[i]) / self.h[i]).astype(np.int64) for i in range(3)]
        inside = (
            (ijk[0] >= 0)
            & (ijk[0] < self.res)
            & (ijk[1] >= 0)
            & (ijk[1] < self.res)
            & (ijk[2] >= 0)
            & (ijk[2] < self.res)
        )
        out = np.full(p[0].shape[0], -1, np.int64)
        flat = (ijk[0] * self.res + ijk[1]) * self.res + ijk[2]
        out[inside] = self.table[flat[inside]]
        miss = out < 0
        if miss.any():
            out[miss] = self._exact(tuple(c[miss] for c in p))
        return self.nodes[out]


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
)
"""MjData fields the batch records after every step (besides the physics state)."""


class FrameReducer:
    """Turns per-step records ``{field: [R, F * k, ...]}`` into per-frame arrays ``[R, F, ...]``.

    Loads are means over each frame's ``k`` steps; kinematics are read at the frame's
    first step. MuJoCo's wrenches share one reference point per tree (the root's
    subtree centre of mass ``c``), so sums over bodies are linear and done on frame
    means; only the move to each body's centre of mass, ``tau + (c - com) x f``, and
    the contact rows are computed per step, where ``c - com`` changes.
    """

    def __init__(self, inst: Instrumented, substeps: int):
        self.inst = inst
        self.k = int(substeps)
        m = inst.model
        self.nb = nb = m.nbody
        self.g = np.array(m.opt.gravity, float)
        self.root = m.body_rootid.copy()
        part = inst.partition
        self.node_body = part.body
        self.node_c = tuple(np.ascontiguousarray(part.centroid.T))
        self.N = part.body.shape[0]
        par = m.body_parentid.copy()
        self.parent = par
        self.children = np.array([b for b in range(1, nb) if par[b] != 0], int)
        j = inst.act_joints
        self.act_joint = j
        self.act_dof = m.jnt_dofadr[j].astype(int)
        self.act_body = m.jnt_bodyid[j].astype(int)
        self.act_parent = par[self.act_body]
        self.act_slide = m.jnt_type[j] == int(_J.mjJNT_SLIDE)
        self.lin0 = int(inst.linacc[1, 0])
        if not np.array_equal(inst.linacc[1:].ravel(), self.lin0 + np.arange(3 * (nb - 1))):
            raise AssertionError("internal: acceleration sensors are not contiguous")
        self.cb = np.flatnonzero(inst.has_contact_sensor)  # bodies with contact sensors
        if len(self.cb):
            self.slot0 = int(inst.slots[self.cb[0], 0, 0])
            self.nslot = inst.slots.shape[1]
            if not np.array_equal(
                inst.slots[self.cb, 0, 0], self.slot0 + 13 * self.nslot * np.arange(len(self.cb))
            ):
                raise AssertionError("internal: contact sensors are not contiguous")
        self.locators = {
            int(b): _NearestNode(
                part.centroid[part.nodes_of(b)], part.nodes_of(b), part.tau[part.nodes_of(b)]
            )
            for b in self.cb
        }
        has_anchor = inst.anchor_node >= 0
        self.jf_src, self.jf_dst = np.flatnonzero(has_anchor), inst.anchor_node[has_anchor]
        has_child = inst.child_anchor_node >= 0
        self.jr_src, self.jr_dst = np.flatnonzero(has_child), inst.child_anchor_node[has_child]

    def __call__(self, rec: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Records ``[R, F * k, ...]`` -> frames ``[R, F, ...]``."""
        R_, n = rec["xpos"].shape[:2]
        out = self.frames(
            {key: v.reshape((R_ * (n // self.k), self.k) + v.shape[2:]) for key, v in rec.items()}
        )
        return {key: v.reshape((R_, n // self.k) + v.shape[1:]) for key, v in out.items()}

    def frames(self, rec: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Records ``[X, k, ...]`` (X frames of k steps each) -> frames ``[X, ...]``."""
        k, nb, N = self.k, self.nb, self.N
        X = rec["xpos"].shape[0]

        def steps(name):  # [X, k, ...]
            return rec[name]

        def comp(a, i):  # component i of the last axis: [X, k, nb]
            return a[..., i]

        xipos, sub = steps("xipos"), steps("subtree_com")
        cint, cext = steps("cfrc_int"), steps("cfrc_ext")
        # r = c - com: from each body's centre of mass to its tree's reference point
        r = tuple(np.ascontiguousarray(sub[:, :, self.root, i] - xipos[..., i]) for i in range(3))
        f_int = tuple(np.ascontiguousarray(cint[..., 3 + i]) for i in range(3))
        f_ext = tuple(np.ascontiguousarray(cext[..., 3 + i]) for i in range(3))

        # joints: the parent's wrench minus what b passes to its children (about c), per step
        Jf = [a.copy() for a in f_int]
        Jt = [np.ascontiguousarray(cint[..., i]) for i in range(3)]
        for c in self.children:
            p = self.parent[c]
            for i in range(3):
                Jf[i][:, :, p] -= f_int[i][:, :, c]
                Jt[i][:, :, p] -= cint[:, :, c, i]
        # about the body's centre of mass: tau + (c - com) x f, then frame means
        mean = lambda v: _aos(_mean(v))  # noqa: E731  [X, nb, 3]
        joint_f, joint_t = mean(Jf), mean(_add(Jt, _cross(r, Jf)))
        if np.any(cext):
            ext_t = _add(tuple(comp(cext, i) for i in range(3)), _cross(r, f_ext))
            contact_f, contact_t = mean(f_ext), mean(ext_t)
        else:  # nothing touched anything in this block
            contact_f = contact_t = np.zeros((X, nb, 3))

        # actuators on scalar joints: + on the joint's body, - on its parent
        Fa = np.zeros((X, nb, 3))
        Ta = np.zeros((X, nb, 3))
        if len(self.act_joint):
            tau = steps("qfrc_actuator")[:, :, self.act_dof]  # [X, k, J]
            axis = steps("xaxis")[:, :, self.act_joint]  # [X, k, J, 3] world
            gen = tuple(tau * axis[..., i] for i in range(3))
            gm = mean(gen)
            if self.act_slide.any():
                anchor = steps("xanchor")[:, :, self.act_joint]
                arm_b = mean(
                    _cross(
                        tuple(anchor[..., i] - xipos[:, :, self.act_body, i] for i in range(3)), gen
                    )
                )
                arm_p = mean(
                    _cross(
                        tuple(anchor[..., i] - xipos[:, :, self.act_parent, i] for i in range(3)),
                        gen,
                    )
                )
            for j in range(len(self.act_joint)):
                b, pb = self.act_body[j], self.act_parent[j]
                if self.act_slide[j]:
                    Fa[:, b] += gm[:, j]
                    Ta[:, b] += arm_b[:, j]
                    Fa[:, pb] -= gm[:, j]
                    Ta[:, pb] -= arm_p[:, j]
                else:
                    Ta[:, b] += gm[:, j]
                    Ta[:, pb] -= gm[:, j]

        # contact forces per node, from the individual contacts
        sd = steps("sensordata")
        node_cf = np.zeros((X * N, 3))
        overflow = np.zeros(X, np.int64)
        ncontact = np.zeros(X)
        touched = (
            np.flatnonzero(np.abs(contact_f[:, self.cb]).sum((0, 2)) > 0)
            if len(self.cb)
            else np.zeros(0, int)
        )
        if len(touched):
            C = len(self.cb)
            sl = sd[:, :, self.slot0 : self.slot0 + 13 * self.nslot * C].reshape(
                X, k, C, self.nslot, 13
            )[:, :, touched]
            cb = self.cb[touched]
            found = sl[..., 0, 0]  # [X, k, C'] matched contacts per body
            overflow = (found > self.nslot).sum((1, 2))
            ncontact = np.minimum(found, self.nslot).sum((1, 2)) / k
            xi, ki, ci, si = np.nonzero(sl[..., 0] > 0)
            row = _soa(sl[xi, ki, ci, si])  # 13 x [n]
            nrm, t1 = row[7:10], row[10:13]
            t2 = _cross(nrm, t1)
            fb = [-(row[1] * nrm[i] + row[2] * t1[i] + row[3] * t2[i]) for i in range(3)]
            pw = [row[4 + i] for i in range(3)]
            over = np.nonzero(found > self.nslot)
            if len(over[0]):
                # more contacts than slots: the rest of the body's contact force acts at the
                # mean of its reported contact points (node forces still sum to the body's)
                flat = (xi * k + ki) * len(cb) + ci
                size = X * k * len(cb)
                cnt = np.bincount(flat, minlength=size).reshape(X, k, -1)[over]
                rest = [
                    f_ext[i][:, :, cb][over]
                    - np.bincount(flat, fb[i], size).reshape(X, k, -1)[over]
                    for i in range(3)
                ]
                at = [
                    np.bincount(flat, pw[i], size).reshape(X, k, -1)[over] / cnt for i in range(3)
                ]
                xi, ki, ci = (
                    np.concatenate([a, b]) for a, b in zip((xi, ki, ci), over, strict=True)
                )
                fb = [np.concatenate([fb[i], rest[i]]) for i in range(3)]
                pw = [np.concatenate([pw[i], at[i]]) for i in range(3)]
            if len(xi):
                body = cb[ci]
                xpos, xquat = steps("xpos"), steps("xquat")
                q = tuple(xquat[xi, ki, body, i] for i in range(4))
                local = _qrot(
                    q, tuple(pw[i] - xpos[xi, ki, body, i] for i in range(3)), inverse=True
                )
                near = np.empty(len(xi), np.int64)
                for j, bb in enumerate(cb):
                    sel = np.flatnonzero(ci == j)
                    if len(sel):
                        near[sel] = self.locators[int(bb)](tuple(c[sel] for c in local))
                idx = xi * N + near
                node_cf = np.stack([np.bincount(idx, fb[i], X * N) for i in range(3)], -1) / k
        node_cf = node_cf.reshape(X, N, 3)

        # joint forces per node: from the parent at b's anchor node, reactions at the parent's
        fint_m = mean(f_int)
        node_jf = np.zeros((X, N, 3))
        np.add.at(node_jf, (slice(None), self.jf_dst), fint_m[:, self.jf_src])
        np.add.at(node_jf, (slice(None), self.jr_dst), -fint_m[:, self.jr_src])

        # kinematics at the frame (its first step); velocities from cvel at the reference point
        p0, q0, c0 = steps("xpos")[:, 0], steps("xquat")[:, 0], xipos[:, 0]
        cv = steps("cvel")[:, 0]  # [X, nb, 6] (angular; linear at c)
        w0 = cv[..., 0:3]
        v0 = cv[..., 3:6] + np.cross(w0, c0 - sub[:, 0, self.root])
        nbd = self.node_body
        node_pos = _add(
            tuple(p0[:, nbd, i] for i in range(3)),
            _qrot(tuple(q0[:, nbd, i] for i in range(4)), self.node_c),
        )
        arm = tuple(node_pos[i] - c0[:, nbd, i] for i in range(3))
        node_vel = _aos(
            _add(
                tuple(v0[:, nbd, i] for i in range(3)),
                _cross(tuple(w0[:, nbd, i] for i in range(3)), arm),
            )
        )
        node_pos = _aos(node_pos)
        lin = sd[:, :, self.lin0 : self.lin0 + 3 * (nb - 1)]
        acc = lin.mean(1).reshape(X, nb - 1, 3) + self.g

        out = {
            "body_pos": p0[:, 1:],
            "body_quat": q0[:, 1:],
            "body_com": c0[:, 1:],
            "body_linvel": v0[:, 1:],
            "body_angvel": w0[:, 1:],
            "body_acc": acc,
            "body_contact_force": contact_f[:, 1:],
            "body_contact_torque": contact_t[:, 1:],
            "body_actuator_force": Fa[:, 1:],
            "body_actuator_torque": Ta[:, 1:],
            "body_joint_force": (joint_f - Fa)[:, 1:],
            "body_joint_torque": (joint_t - Ta)[:, 1:],
            "node_pos": node_pos,
            "node_vel": node_vel,
            "node_contact_force": node_cf,
            "node_joint_force": node_jf,
            "contact_count": ncontact,
            "contact_overflow": overflow,
        }
        return {key: np.ascontiguousarray(v) for key, v in out.items()}

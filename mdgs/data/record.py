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
    lean_model: mujoco.MjModel | None = None
    """``model`` without the contact sensors (None if it has none): the same dynamics, bit for
    bit (sensors only read the state), and ``model``'s sensordata up to the contact sensors.
    Contact-free steps are stepped with it, skipping the contact sensors' cost (see
    :func:`mdgs.data.engine.simulate`)."""

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


class _Locator:
    """:class:`_NearestNode` of several bodies at once: points ``p`` of bodies ``which``."""

    def __init__(self, finders: list[_NearestNode]):
        self.finders = finders
        self.lo = np.array([f.lo for f in finders]).T.copy()  # [3, C]
        self.h = np.array([f.h for f in finders]).T.copy()
        self.res = np.array([f.res for f in finders], np.int64)
        sizes = np.array([len(f.table) for f in finders], np.int64)
        self.table_off = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        self.table = (
            np.concatenate([f.table for f in finders]) if finders else np.zeros(0, np.int64)
        )
        counts = np.array([len(f.nodes) for f in finders], np.int64)
        self.node_off = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        self.nodes = (
            np.concatenate([f.nodes for f in finders]) if finders else np.zeros(0, np.int64)
        )

    def __call__(self, p, which: np.ndarray) -> np.ndarray:
        """Global node ids of the points ``p`` (3 arrays, body frames) of bodies ``which``."""
        res = self.res[which]
        ijk = [
            np.floor((p[i] - self.lo[i][which]) / self.h[i][which]).astype(np.int64)
            for i in range(3)
        ]
        inside = (
            (ijk[0] >= 0)
            & (ijk[0] < res)
            & (ijk[1] >= 0)
            & (ijk[1] < res)
            & (ijk[2] >= 0)
            & (ijk[2] < res)
        )
        local = np.full(p[0].shape[0], -1, np.int64)
        flat = (ijk[0] * res + ijk[1]) * res + ijk[2] + self.table_off[which]
        local[inside] = self.table[flat[inside]]
        miss = np.flatnonzero(local < 0)
        if len(miss):
            for j in np.unique(which[miss]):
                sel = miss[which[miss] == j]
                local[sel] = self.finders[j]._exact(tuple(c[sel] for c in p))
        return self.nodes[local + self.node_off[which]]


def _index(a: np.ndarray):
    """``a`` as a slice when it is a run of consecutive integers (a view instead of a copy)."""
    a = np.asarray(a, np.int64)
    if len(a) and np.array_equal(a, np.arange(a[0], a[0] + len(a))):
        return slice(int(a[0]), int(a[0]) + len(a))
    return a


def _rank_groups(targets: np.ndarray, sources: np.ndarray) -> list[tuple]:
    """Split ``x[targets[i]] -= y[sources[i]]`` (in order) into steps with distinct targets.

    Step ``r`` holds each target's ``r``-th operation, so every target sees its operations
    in the original order; each step is cut into runs of consecutive targets and sources,
    which index as slices (views) rather than gathers.
    """
    rank = np.zeros(len(targets), int)
    seen: dict[int, int] = {}
    for i, t in enumerate(targets):
        rank[i] = seen.get(int(t), 0)
        seen[int(t)] = rank[i] + 1
    steps = []
    for r in range(int(rank.max()) + 1 if len(rank) else 0):
        tg, sg = targets[rank == r], sources[rank == r]
        cut = np.flatnonzero((np.diff(tg) != 1) | (np.diff(sg) != 1)) + 1
        steps += [
            (slice(int(t[0]), int(t[-1]) + 1), slice(int(u[0]), int(u[-1]) + 1))
            for t, u in zip(np.split(tg, cut), np.split(sg, cut), strict=True)
        ]
    return steps


def _ksum(a: np.ndarray, axis: int) -> np.ndarray:
    """Sum over the steps axis, adding step after step (the same bits for any batch).

    ``einsum`` runs this reduction several times faster than ``sum`` when the axes after
    ``axis`` are short; with nothing after ``axis`` (``sum`` would switch to pairwise
    summation) the steps are added one by one.
    """
    if int(np.prod(a.shape[axis + 1 :])) <= 1:
        pre = (slice(None),) * axis
        acc = a[pre + (0,)].copy()
        for i in range(1, a.shape[axis]):
            acc += a[pre + (i,)]
        return acc
    sub = "abcdefgh"[: a.ndim]
    return np.einsum(f"{sub}->{sub[:axis]}{sub[axis + 1 :]}", a)


def _cross_sum(r: np.ndarray, f: np.ndarray) -> np.ndarray:
    """``r x f`` summed over the steps, for component-first arrays ``[3, ..., k]``: ``[3, ...]``.

    The steps are the last, contiguous axis, summed pairwise: the same bits for any
    number of frames, since each sum runs over one frame's ``k`` contiguous values.
    """
    out = np.empty_like(f)
    tmp = np.empty_like(f[0])
    for i in range(3):
        j, l = (i + 1) % 3, (i + 2) % 3
        np.multiply(r[j], f[l], out=out[i])
        np.multiply(r[l], f[j], out=tmp)
        out[i] -= tmp
    return out.sum(-1)


def _steps_last(a: np.ndarray) -> np.ndarray:
    """``[X, k, B, 3]`` records -> component-first ``[3, X, B, k]`` view (steps last)."""
    return a.transpose(3, 0, 2, 1)


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
    subtree centre of mass ``c``); the move of a wrench to the body's centre of mass,
    ``tau + (c - com) x f``, is the only per-step product, everything linear is summed
    over the steps first (joint loads: the parent's wrench minus what the body passes
    to its children). Every reduction is per frame, so frames never mix.

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
        self.root = m.body_rootid.copy()
        part = inst.partition
        self.node_body = part.body
        self.node_c = tuple(np.ascontiguousarray(part.centroid.T))
        self.N = part.body.shape[0]
        par = m.body_parentid.copy()
        self.parent = par
        # runs of consecutive bodies of one tree: c - com without gathering c per body
        self.trees = []
        b = 1
        while b < nb:
            e = b + 1
            while e < nb and self.root[e] == self.root[b]:
                e += 1
            self.trees.append((int(self.root[b]), b, e))
            b = e
        children = np.array([b for b in range(1, nb) if par[b] != 0], int)
        self.child_groups = _rank_groups(par[children] - 1, children - 1)  # 0-based bodies 1..
        j = inst.act_joints
        self.act_joint = j
        self.act_dof = _index(m.jnt_dofadr[j])
        self.act_jnt = _index(j)
        self.act_body = m.jnt_bodyid[j].astype(int)
        self.act_parent = par[self.act_body]
        self.act_slide = m.jnt_type[j] == int(_J.mjJNT_SLIDE)
        self.lin0 = int(inst.linacc[1, 0]) if nb > 1 else 0
        if not np.array_equal(inst.linacc[1:].ravel(), self.lin0 + np.arange(3 * (nb - 1))):
            raise AssertionError("internal: acceleration sensors are not contiguous")
        self.cb = np.flatnonzero(inst.has_contact_sensor)  # bodies with contact sensors
        self.C = len(self.cb)
        self.nslot = inst.slots.shape[1]
        self.slot0 = int(inst.slots[self.cb[0], 0, 0]) if self.C else 0
        if self.C and not np.array_equal(
            inst.slots[self.cb, 0, 0], self.slot0 + 13 * self.nslot * np.arange(self.C)
        ):
            raise AssertionError("internal: contact sensors are not contiguous")
        self.locate = _Locator(
            [
                _NearestNode(
                    part.centroid[part.nodes_of(b)], part.nodes_of(b), part.tau[part.nodes_of(b)]
                )
                for b in self.cb
            ]
        )
        # bodies that may touch but have no contact sensor (welded to the world, or in
        # explicit contact pairs only): always checked for a contact force
        can = np.zeros(nb, bool)
        can[m.geom_bodyid[(m.geom_contype != 0) | (m.geom_conaffinity != 0)]] = True
        can[m.geom_bodyid[np.concatenate([m.pair_geom1, m.pair_geom2])]] = True
        can &= not (m.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_CONTACT))
        can[0] = False
        self.unsensed = np.flatnonzero(can & ~inst.has_contact_sensor)
        has_anchor = inst.anchor_node >= 0
        self.jf_src, self.jf_dst = np.flatnonzero(has_anchor), inst.anchor_node[has_anchor]
        has_child = inst.child_anchor_node >= 0
        self.jr_src, self.jr_dst = np.flatnonzero(has_child), inst.child_anchor_node[has_child]
        fields = ["xpos", "xquat", "xipos", "subtree_com", "cvel", "cfrc_int", "cfrc_ext"]
        if len(j):
            fields += ["qfrc_actuator", "xaxis"] + (["xanchor"] if self.act_slide.any() else [])
        fields += ["sensordata"] + (["ncon"] if self.C else [])
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
    ) -> dict[str, np.ndarray]:
        """Per-step records ``[X, k, ...]`` -> per-frame loads ``[X, ...]``.

        The contact fields (:attr:`contact_fields`, the model's full sensordata) come from
        ``rec``, or from ``contact`` (``[len(rows), k, ...]``) for frames ``rows`` only,
        the others having had no contact. Per-step products run on component-first
        copies with the steps last, ``[3, X, B, k]``.
        """
        k, B = self.k, self.B
        cint = rec["cfrc_int"]
        X = cint.shape[0]
        if rows is None:
            contact, rows = rec, np.arange(X)
        xipos, sub = rec["xipos"], rec["subtree_com"]
        # r = c - com: component first, steps last [3, X, B, k]
        r = np.empty((3, X, B, k))
        for root, lo, hi in self.trees:
            np.subtract(
                _steps_last(sub[:, :, root : root + 1]),
                _steps_last(xipos[:, :, lo:hi]),
                out=r[:, :, lo - 1 : hi - 1],
            )
        # joints: the parent's wrench on b minus what b passes to its children
        W = _ksum(cint[:, :, 1:], 1)  # [X, B, 6] sums over the steps (about c)
        fint = W[..., 3:] / k
        Jw = W.copy()
        F0 = np.empty((3, X, B, k))
        np.copyto(F0, _steps_last(cint[:, :, 1:, 3:]))
        Jf = F0.copy() if self.child_groups else F0
        for tg, sg in self.child_groups:
            Jw[:, tg] -= W[:, sg]
            Jf[:, :, tg] -= F0[:, :, sg]
        joint = np.empty((X, B, 6))
        np.divide(Jw[..., :3] + np.moveaxis(_cross_sum(r, Jf), 0, -1), k, out=joint[..., :3])
        np.divide(Jw[..., 3:], k, out=joint[..., 3:])
        # contacts (the only external loads): per step only for bodies in contact
        wrench = np.zeros((X, B, 6))
        found = None
        if self.C and len(rows):  # contacts matched per body and step [len(rows) k, C]
            sdc = np.ascontiguousarray(contact["sensordata"])
            found = sdc.reshape(-1, sdc.shape[-1])[
                :, self.slot0 : self.slot0 + 13 * self.nslot * self.C : 13 * self.nslot
            ]
        cext = contact["cfrc_ext"] if len(rows) else None
        if cext is not None and cext.any():
            E = _ksum(cext[:, :, 1:], 1)
            cw = np.divide(E, k)
            sensed = self.cb[(found > 0).any(0)] if found is not None else self.cb[:0]
            touched = np.union1d(sensed, self.unsensed) - 1
            if len(touched):
                tb = _index(touched)
                fe = np.empty((3, len(rows), len(touched), k))
                np.copyto(fe, _steps_last(cext[:, :, 1:][:, :, tb, 3:]))
                rc = r[:, :, tb] if len(rows) == X else r[:, rows][:, :, tb]
                cr = np.moveaxis(_cross_sum(rc, fe), 0, -1)
                cw[:, tb, :3] = (E[:, tb, :3] + cr) / k
            wrench[rows] = cw
        sd = rec["sensordata"]
        acc = _ksum(sd[:, :, self.lin0 : self.lin0 + 3 * B], 1) / k
        out = {
            "joint": joint,
            "fint": fint,
            "contact": wrench,
            "acc": acc.reshape(X, B, 3) + self.g,
        }
        # actuators on scalar joints: generalized force along the joint axis
        if len(self.act_joint):
            tau = rec["qfrc_actuator"][:, :, self.act_dof].transpose(0, 2, 1)  # [X, J, k]
            gen = np.empty((3, X, len(self.act_joint), k))
            np.copyto(gen, _steps_last(rec["xaxis"][:, :, self.act_jnt]))  # world axes
            gen *= tau
            out["gen"] = np.moveaxis(gen.sum(-1), 0, -1) / k
            if self.act_slide.any():
                anchor = rec["xanchor"][:, :, self.act_jnt]
                for key, bodies in (("arm_b", self.act_body), ("arm_p", self.act_parent)):
                    out[key] = _aos(
                        _mean(
                            _cross(
                                tuple(anchor[..., i] - xipos[:, :, bodies, i] for i in range(3)),
                                tuple(np.swapaxes(g, 1, 2) for g in gen),
                            )
                        )
                    )
        out.update(self._contacts(rec, contact, rows, X))
        return out

    def _contacts(self, rec, contact, rows, X) -> dict[str, np.ndarray]:
        """Contact forces per node from the individual contacts, contact counts."""
        k, N, C, ns = self.k, self.N, self.C, self.nslot
        count = np.zeros(X)
        overflow = np.zeros(X, np.int64)
        out = {"contact_count": count, "contact_overflow": overflow, "node_cf": None}
        if not C or not len(rows):
            return out
        sd = np.ascontiguousarray(contact["sensordata"])
        flat, stride, base = sd.reshape(-1), sd.shape[-1], self.slot0
        Xs = len(rows)
        found = flat.reshape(Xs * k, stride)[:, base : base + 13 * ns * C : 13 * ns]  # [Xs k, C]
        nuse = np.minimum(found, ns)
        count[rows] = nuse.reshape(Xs, k * C).sum(1) / k
        overflow[rows] = (found > ns).reshape(Xs, k * C).sum(1)
        # slots s < min(found, ns) hold a contact (MuJoCo fills them in order)
        xk, ci = np.nonzero(found > 0)
        if not len(xk):
            return out
        m = nuse[xk, ci].astype(np.int64)
        first = np.cumsum(m) - m
        xk, ci = np.repeat(xk, m), np.repeat(ci, m)
        si = np.arange(len(xk)) - np.repeat(first, m)
        # found, force (contact frame), pos, normal, tangent: 13 contiguous [n] columns,
        # gathered by flat index (much faster than fancy indexing of the strided view)
        at0 = xk * stride + base + (ci * ns + si) * 13
        col = list(np.take(flat, at0 + np.arange(13)[:, None]))
        nrm, t1 = col[7:10], col[10:13]
        t2 = _cross(nrm, t1)
        fb = [-(col[1] * nrm[i] + col[2] * t1[i] + col[3] * t2[i]) for i in range(3)]  # on the body
        pw = col[4:7]
        xi, ki = np.divmod(xk, k)
        xs = rows[xi]
        over = np.nonzero((found > ns).reshape(Xs, k, C))
        if len(over[0]):
            # more contacts than slots: the rest of the body's contact force acts at the
            # mean of its reported contact points (node forces still sum to the body's)
            fl = xk * C + ci
            size = Xs * k * C
            cnt = np.bincount(fl, minlength=size).reshape(-1, k, C)[over]
            fo = contact["cfrc_ext"][over[0], over[1], self.cb[over[2]], 3:]
            rest = [
                fo[:, i] - np.bincount(fl, fb[i], size).reshape(-1, k, C)[over] for i in range(3)
            ]
            mean_at = [np.bincount(fl, pw[i], size).reshape(-1, k, C)[over] / cnt for i in range(3)]
            xs = np.concatenate([xs, rows[over[0]]])
            ki = np.concatenate([ki, over[1]])
            ci = np.concatenate([ci, over[2]])
            fb = [np.concatenate([fb[i], rest[i]]) for i in range(3)]
            pw = [np.concatenate([pw[i], mean_at[i]]) for i in range(3)]
        at = (xs * k + ki) * self.nb + self.cb[ci]  # (frame, step, body) rows of xpos/xquat
        p = np.take(rec["xpos"].reshape(-1, 3), at, axis=0).T
        q = np.take(rec["xquat"].reshape(-1, 4), at, axis=0).T
        local = _qrot(tuple(q), tuple(pw[i] - p[i] for i in range(3)), inverse=True)
        idx = xs * N + self.locate(local, ci)
        node_cf = np.stack([np.bincount(idx, fb[i], X * N) for i in range(3)], -1) / k
        out["node_cf"] = node_cf.reshape(X, N, 3)
        return out

    # -- first-step fields -----------------------------------------------------------
    def kinematics(
        self,
        xpos: np.ndarray,
        xquat: np.ndarray,
        xipos: np.ndarray,
        cvel: np.ndarray,
        sub: np.ndarray,
        out: dict[str, np.ndarray] | None = None,
    ) -> dict[str, np.ndarray]:
        """Frame-start fields ``[X, nbody, ...]`` -> body and node kinematics ``[X, ...]``.

        Velocities come from ``cvel`` at the tree's reference point ``sub`` (subtree_com).
        Arrays in ``out`` (``[X, ...]``, e.g. views of the outputs) are filled in place.
        """
        out = {} if out is None else out
        w0 = cvel[..., 0:3]
        v0 = cvel[..., 3:6] + np.cross(w0, xipos - sub[:, self.root])
        nbd = self.node_body

        def nodes(a, i):  # component i of a body field at each node: [X, N]
            return np.take(np.ascontiguousarray(a[..., i]), nbd, axis=1)

        node_pos = _add(
            tuple(nodes(xpos, i) for i in range(3)),
            _qrot(tuple(nodes(xquat, i) for i in range(4)), self.node_c),
        )
        arm = tuple(node_pos[i] - nodes(xipos, i) for i in range(3))
        node_vel = _add(
            tuple(nodes(v0, i) for i in range(3)),
            _cross(tuple(nodes(w0, i) for i in range(3)), arm),
        )
        res = {
            "body_pos": xpos[:, 1:],
            "body_quat": xquat[:, 1:],
            "body_com": xipos[:, 1:],
            "body_linvel": v0[:, 1:],
            "body_angvel": w0[:, 1:],
        }
        for key, v in res.items():
            if key in out:
                out[key][...] = v
            else:
                out[key] = v
        for key, v in (("node_pos", node_pos), ("node_vel", node_vel)):
            out[key] = np.stack(v, -1, out=out.get(key))
        return out

    # -- loads of whole frames ---------------------------------------------------------
    def finish(
        self, lo: dict[str, np.ndarray], out: dict[str, np.ndarray] | None = None
    ) -> dict[str, np.ndarray]:
        """:meth:`loads` of ``X`` frames -> the recorded load arrays ``[X, ...]`` (into ``out``)."""
        out = {} if out is None else out
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
        node_jf = out["node_joint_force"] if "node_joint_force" in out else np.empty((X, self.N, 3))
        node_jf[...] = 0
        fint = lo["fint"]
        np.add.at(node_jf, (slice(None), self.jf_dst), fint[:, self.jf_src - 1])
        np.add.at(node_jf, (slice(None), self.jr_dst), -fint[:, self.jr_src - 1])
        joint = lo["joint"]
        res = {
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
        for key, v in res.items():
            if key in out:
                if out[key] is not v:
                    out[key][...] = v
            else:
                out[key] = v
        return out

    def frames(self, rec: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Records ``[X, k, ...]`` (X frames of k steps each, full sensordata) -> frames ``[X, ...]``."""
        kin = self.kinematics(*(rec[f][:, 0] for f in KINEMATICS))
        lo = self.loads(rec)
        X = len(lo["joint"])
        cf = lo.pop("node_cf")
        out = {**kin, **self.finish(lo)}
        out["node_contact_force"] = np.zeros((X, self.N, 3)) if cf is None else cf
        return {key: np.ascontiguousarray(v) for key, v in out.items()}

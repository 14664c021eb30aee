"""Ground-truth loads from MuJoCo: sensors that expose them, and their per-frame reduction.

A scene's MJCF is *instrumented*: every body gets a site at its centre of mass and
sensors for its pose and velocity, for the force and torque its parent transmits
(``force``/``torque`` sensors read ``cfrc_int``), for its contacts (``contact`` sensors,
one net wrench and individual slots) and for the actuator force on each actuated
scalar joint (``jointactuatorfrc``). Sensors add no physics, so the instrumented model
steps exactly like the scene's own model, and ``mujoco.rollout`` evaluates them in C at
every integrator step.

Conventions (checked numerically in ``tests/test_data.py``):

- rollout returns, for step ``s``, the state *after* the step and the sensors computed
  at the state *before* it, i.e. with the ``qacc`` that moves ``s`` to ``s+1``. Frame
  ``f`` is step ``f * substeps``; its kinematics are read from that step's sensors.
- loads of frame ``f`` are means over its ``substeps`` steps (impulse / frame time):
  with the Euler integrator ``qvel[s+1] = qvel[s] + h qacc[s]`` exactly, so these are
  the loads that move frame ``f`` to ``f+1``.
- ``cfrc_int[b]`` (force sensor, site frame rotated to world) is the wrench the parent
  exerts on body ``b`` through its joints; a ``contact`` sensor with ``body1=b`` reports
  the force of ``b`` on the other body, so the load on ``b`` is its negative.
- torques are about the body's centre of mass, forces in the world frame.

Newton per body then reads (``tests/test_data.py`` checks it at every step):
``m_b a_b = m_b g + F_contact + F_actuator + F_joint``, and the per-node loads sum to the
body's loads (contact forces go to the node nearest the contact point, joint forces to
the node nearest the joint's anchor).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from mdgs.partition import Partition, PartitionParams, partition_model
from mdgs.scenes._mjcf import quat_to_mat

__all__ = ["SceneError", "Instrumented", "instrument", "quat_to_mat", "CONTACT_SLOTS"]

CONTACT_SLOTS = 12
"""Individual contacts reported per body and step (overflow is counted, see ``contact_overflow``)."""

_S = mujoco.mjtSensor
_O = mujoco.mjtObj
_J = mujoco.mjtJoint
# contact sensor data bits: found=1 force=2 torque=4 dist=8 pos=16 normal=32 tangent=64
_NET_BITS, _NET_DIM = 1 | 2 | 4 | 16, 10  # found force torque pos
_SLOT_BITS, _SLOT_DIM = 1 | 2 | 16 | 32 | 64, 13  # found force pos normal tangent
_REDUCE_MAXFORCE, _REDUCE_NETFORCE = 2, 3


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
    # sensordata column indices, arrays [nbody, ...] (row 0, the world, unused)
    pos: np.ndarray
    quat: np.ndarray
    com: np.ndarray
    linvel: np.ndarray
    angvel: np.ndarray
    linacc: np.ndarray
    fint: np.ndarray
    tint: np.ndarray
    net: np.ndarray  # [nbody, 10] or -1
    slots: np.ndarray  # [nbody, CONTACT_SLOTS, 13] or -1
    has_contact_sensor: np.ndarray  # [nbody] bool
    act_joints: np.ndarray  # [J] joint ids with actuator force sensors
    act_cols: np.ndarray  # [J] sensordata column
    # node bookkeeping
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

    sensors: list[tuple[str, int]] = []  # (key, body or joint)

    def add(key, idx, type_, objtype, objname, intprm=None):
        s = spec.add_sensor()
        s.type, s.objtype, s.objname = type_, objtype, objname
        s.name = f"_mdgs_{key}_{idx}"
        if intprm is not None:
            s.intprm = np.asarray(intprm, dtype=np.int32)
        sensors.append((key, idx))

    # kinematic and joint-load sensors of every body first (a uniform 25-float block per
    # body, so the reducer reads them as one strided view), then contacts, then actuators
    for i in range(1, base.nbody):
        b, name = bodies[i], bodies[i].name
        site = b.add_site()
        site.name = f"_mdgs_com{i}"
        site.pos = np.asarray(base.body_ipos[i], float)
        site.group = 5
        add("pos", i, _S.mjSENS_FRAMEPOS, _O.mjOBJ_XBODY, name)
        add("quat", i, _S.mjSENS_FRAMEQUAT, _O.mjOBJ_XBODY, name)
        add("com", i, _S.mjSENS_FRAMEPOS, _O.mjOBJ_BODY, name)
        add("linvel", i, _S.mjSENS_FRAMELINVEL, _O.mjOBJ_BODY, name)
        add("angvel", i, _S.mjSENS_FRAMEANGVEL, _O.mjOBJ_BODY, name)
        add("linacc", i, _S.mjSENS_FRAMELINACC, _O.mjOBJ_BODY, name)
        add("fint", i, _S.mjSENS_FORCE, _O.mjOBJ_SITE, site.name)
        add("tint", i, _S.mjSENS_TORQUE, _O.mjOBJ_SITE, site.name)
    for i in np.flatnonzero(collides):
        add(
            "net",
            int(i),
            _S.mjSENS_CONTACT,
            _O.mjOBJ_BODY,
            bodies[i].name,
            [_NET_BITS, _REDUCE_NETFORCE, 1],
        )
    for i in np.flatnonzero(collides):
        add(
            "slots",
            int(i),
            _S.mjSENS_CONTACT,
            _O.mjOBJ_BODY,
            bodies[i].name,
            [_SLOT_BITS, _REDUCE_MAXFORCE, contact_slots],
        )
    act_joints = sorted({int(j) for j in _actuated_joints(base)})
    joints = list(spec.joints)
    for j in act_joints:
        if not joints[j].name:
            joints[j].name = f"_mdgs_joint{j}"
        add("jact", j, _S.mjSENS_JOINTACTFRC, _O.mjOBJ_JOINT, joints[j].name)
    model = _compile(spec)

    nb = base.nbody
    idx = {
        k: -np.ones((nb, 3), int)
        for k in ("pos", "com", "linvel", "angvel", "linacc", "fint", "tint")
    }
    idx["quat"] = -np.ones((nb, 4), int)
    net = -np.ones((nb, _NET_DIM), int)
    slots = -np.ones((nb, contact_slots, _SLOT_DIM), int)
    act_cols = []
    for n, (key, i) in enumerate(sensors):
        sid = base.nsensor + n  # the scene's own sensors come first
        adr, dim = int(model.sensor_adr[sid]), int(model.sensor_dim[sid])
        cols = np.arange(adr, adr + dim)
        if key in idx:
            idx[key][i] = cols
        elif key == "net":
            net[i] = cols
        elif key == "slots":
            slots[i] = cols.reshape(contact_slots, _SLOT_DIM)
        else:
            act_cols.append(adr)
    anchor, child_anchor = _anchor_nodes(base, part)
    return Instrumented(
        model=model,
        partition=part,
        notes=tuple(notes),
        net=net,
        slots=slots,
        has_contact_sensor=collides,
        act_joints=np.array(act_joints, int),
        act_cols=np.array(act_cols, int),
        anchor_node=anchor,
        child_anchor_node=child_anchor,
        **idx,
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


def _mean(v, axis: int = 1):
    return tuple(c.mean(axis) for c in v)


def _aos(v) -> np.ndarray:
    """Tuple of component arrays -> array [..., 3]."""
    return np.stack(v, -1)


def _soa(a: np.ndarray) -> tuple:
    """Array [..., d] -> tuple of d contiguous component arrays."""
    t = np.ascontiguousarray(np.moveaxis(a, -1, 0))
    return tuple(t)


class FrameReducer:
    """Turns rollout sensordata ``[R, F * k, S]`` into per-frame arrays ``[R, F, ...]``.

    Loads are means over each frame's ``k`` substeps; kinematics are read at the
    frame's first substep. Work per substep is limited to what changes within a frame
    (rotating site-frame wrenches and actuator axes, moment arms, contact rows); sums
    over bodies and nodes are done once per frame. See the module docstring.
    """

    _BLOCK = (
        25  # floats per body: pos 3, quat 4, com 3, linvel 3, angvel 3, linacc 3, fint 3, tint 3
    )

    def __init__(self, inst: Instrumented, substeps: int):
        self.inst = inst
        self.k = int(substeps)
        m = inst.model
        self.nb = nb = m.nbody
        self.g = np.array(m.opt.gravity, float)
        part = inst.partition
        self.node_body = part.body
        self.node_c = tuple(np.ascontiguousarray(part.centroid.T))
        self.node_centroid = part.centroid
        self.N = part.body.shape[0]
        # the body block must be one contiguous strided block (see instrument)
        self.b0 = int(inst.pos[1, 0])
        expect = self.b0 + self._BLOCK * np.arange(nb - 1)
        if not (
            np.array_equal(inst.pos[1:, 0], expect)
            and np.array_equal(inst.tint[1:, 2], expect + 24)
        ):
            raise AssertionError("internal: body sensors are not in one strided block")
        par = m.body_parentid.copy()
        self.children = np.array([b for b in range(1, nb) if par[b] != 0], int)
        self.parents = par[self.children]
        jt = m.jnt_type[inst.act_joints] if len(inst.act_joints) else np.zeros(0, int)
        self.act_body = m.jnt_bodyid[inst.act_joints].astype(int)
        self.act_parent = par[self.act_body]
        self.act_axis = m.jnt_axis[inst.act_joints].copy()
        self.act_pos = m.jnt_pos[inst.act_joints].copy()
        self.act_slide = jt == int(_J.mjJNT_SLIDE)
        self.act0 = int(inst.act_cols[0]) if len(inst.act_cols) else 0
        if len(inst.act_cols) and not np.array_equal(
            inst.act_cols, self.act0 + np.arange(len(inst.act_cols))
        ):
            raise AssertionError("internal: actuator sensors are not contiguous")
        self.cb = np.flatnonzero(inst.has_contact_sensor)  # bodies with contact sensors
        if len(self.cb):
            self.net0 = int(inst.net[self.cb[0], 0])
            self.slot0 = int(inst.slots[self.cb[0], 0, 0])
            self.nslot = inst.slots.shape[1]
        self.body_nodes = {int(b): part.nodes_of(b) for b in self.cb}
        # joint-force attachment
        has_anchor = inst.anchor_node >= 0
        self.jf_src, self.jf_dst = np.flatnonzero(has_anchor), inst.anchor_node[has_anchor]
        has_child = inst.child_anchor_node >= 0
        self.jr_src, self.jr_dst = np.flatnonzero(has_child), inst.child_anchor_node[has_child]

    def __call__(self, sd: np.ndarray) -> dict[str, np.ndarray]:
        k, nb, N = self.k, self.nb, self.N
        R_, n, S = sd.shape
        F = n // k
        x = sd.reshape(R_ * F, k, S)
        X = x.shape[0]
        B = nb - 1
        blk = _soa(
            x[:, :, self.b0 : self.b0 + self._BLOCK * B].reshape(X, k, B, self._BLOCK)
        )  # 25 x [X, k, B]
        pos_s, quat_s, com_s = blk[0:3], blk[3:7], blk[7:10]
        fint = _qrot(quat_s, blk[19:22])  # wrench from the parent, world frame
        tint = _qrot(quat_s, blk[22:25])
        zero = np.zeros((X, nb, 3))

        def put(dst: np.ndarray, rows, v):  # dst[:, rows] = v (v: 3 x [X, len(rows)])
            dst[:, rows] = _aos(v)

        fint_m = zero.copy()
        put(fint_m, slice(1, None), _mean(fint))
        tint_m = zero.copy()
        put(tint_m, slice(1, None), _mean(tint))
        # joints: wrench from the parent minus what b passes on to its children (about com_b)
        Jf, Jt = fint_m.copy(), tint_m.copy()
        if len(self.children):
            c, p = self.children - 1, self.parents - 1
            arm = tuple(com_s[i][:, :, c] - com_s[i][:, :, p] for i in range(3))
            moment = _aos(_mean(_cross(arm, tuple(f[:, :, c] for f in fint))))  # [X, nc, 3]
            for j in range(len(c)):  # few children: a loop beats np.add.at
                Jf[:, p[j] + 1] -= fint_m[:, c[j] + 1]
                Jt[:, p[j] + 1] -= tint_m[:, c[j] + 1] + moment[:, j]

        # actuators on scalar joints: equal and opposite between the joint's body and its parent
        Fa, Ta = zero.copy(), zero.copy()
        if len(self.act_body):
            J = len(self.act_body)
            tau = x[:, :, self.act0 : self.act0 + J]  # [X, k, J]
            b, pb = self.act_body, self.act_parent
            qb = tuple(q[:, :, b - 1] for q in quat_s)
            axis = _qrot(qb, tuple(self.act_axis.T))
            gen = tuple(tau * a for a in axis)
            gm = _aos(_mean(gen))  # [X, J, 3]
            if self.act_slide.any():
                anchor = _add(
                    tuple(pp[:, :, b - 1] for pp in pos_s), _qrot(qb, tuple(self.act_pos.T))
                )
                arm_b = _aos(
                    _mean(_cross(_sub(anchor, tuple(cc[:, :, b - 1] for cc in com_s)), gen))
                )
                com_p = tuple(
                    np.where(pb > 0, cc[:, :, np.maximum(pb, 1) - 1], 0.0) for cc in com_s
                )
                arm_p = _aos(_mean(_cross(_sub(anchor, com_p), gen)))
            for j in range(J):
                if self.act_slide[j]:
                    Fa[:, b[j]] += gm[:, j]
                    Ta[:, b[j]] += arm_b[:, j]
                    Fa[:, pb[j]] -= gm[:, j]
                    Ta[:, pb[j]] -= arm_p[:, j]
                else:
                    Ta[:, b[j]] += gm[:, j]
                    Ta[:, pb[j]] -= gm[:, j]

        # contacts: net wrench per body (the load on b is minus the sensor's), and per node
        Fc, Tc = zero.copy(), zero.copy()
        node_cf = np.zeros((X * N, 3))
        overflow = np.zeros(X, np.int64)
        ncontact = np.zeros(X)
        if len(self.cb):
            C = len(self.cb)
            net = _soa(x[:, :, self.net0 : self.net0 + 10 * C].reshape(X, k, C, 10))
            f = (-net[1], -net[2], -net[3])
            cb = self.cb - 1
            arm = tuple(net[7 + i] - com_s[i][:, :, cb] for i in range(3))
            t = _add((-net[4], -net[5], -net[6]), _cross(arm, f))
            Fc[:, self.cb] = _aos(_mean(f))
            Tc[:, self.cb] = _aos(_mean(t))
            sl = x[:, :, self.slot0 : self.slot0 + 13 * self.nslot * C].reshape(
                X, k, C, self.nslot, 13
            )
            found = sl[..., 0, 0]  # [X, k, C] matched contacts per body
            overflow = (found > self.nslot).sum((1, 2))
            ncontact = np.minimum(found, self.nslot).sum((1, 2)) / k
            xi, ki, ci, si = np.nonzero(sl[..., 0] > 0)
            if len(xi):
                row = _soa(sl[xi, ki, ci, si])  # 13 x [n]
                nrm, t1 = row[7:10], row[10:13]
                t2 = _cross(nrm, t1)
                fw = tuple(row[1] * nrm[i] + row[2] * t1[i] + row[3] * t2[i] for i in range(3))
                body = cb[ci]
                q = tuple(qq[xi, ki, body] for qq in quat_s)
                local = _aos(
                    _qrot(
                        q,
                        tuple(row[4 + i] - pos_s[i][xi, ki, body] for i in range(3)),
                        inverse=True,
                    )
                )
                near = np.empty(len(xi), np.int64)
                for j, bb in enumerate(self.cb):
                    sel = np.flatnonzero(ci == j)
                    if len(sel) == 0:
                        continue
                    nodes = self.body_nodes[int(bb)]
                    cn = self.node_centroid[nodes]
                    d = (cn * cn).sum(1)[None, :] - 2 * local[sel] @ cn.T
                    near[sel] = nodes[np.argmin(d, 1)]
                np.add.at(node_cf, xi * N + near, -_aos(fw) / k)
        node_cf = node_cf.reshape(X, N, 3)

        node_jf = np.zeros((X, N, 3))
        np.add.at(node_jf, (slice(None), self.jf_dst), fint_m[:, self.jf_src])
        np.add.at(node_jf, (slice(None), self.jr_dst), -fint_m[:, self.jr_src])

        # kinematics at the frame (first substep), world row prepended
        def first(i, fill=0.0):
            out = np.empty((X, nb))
            out[:, 0] = fill
            out[:, 1:] = blk[i][:, 0]
            return out

        p0 = tuple(first(i) for i in range(0, 3))
        q0 = (first(3, 1.0),) + tuple(first(i) for i in range(4, 7))
        c0 = tuple(first(i) for i in range(7, 10))
        v0 = tuple(first(i) for i in range(10, 13))
        w0 = tuple(first(i) for i in range(13, 16))
        nbd = self.node_body
        node_pos = _add(
            tuple(a[:, nbd] for a in p0), _qrot(tuple(a[:, nbd] for a in q0), self.node_c)
        )
        node_vel = _add(
            tuple(a[:, nbd] for a in v0),
            _cross(tuple(a[:, nbd] for a in w0), _sub(node_pos, tuple(a[:, nbd] for a in c0))),
        )

        def body(group):
            return _aos(tuple(a[:, 1:] for a in group))

        out = {
            "body_pos": body(p0),
            "body_quat": np.stack([a[:, 1:] for a in q0], -1),
            "body_com": body(c0),
            "body_linvel": body(v0),
            "body_angvel": body(w0),
            "body_acc": _aos(_mean(blk[16:19])) + self.g,
            "body_contact_force": Fc[:, 1:],
            "body_contact_torque": Tc[:, 1:],
            "body_actuator_force": Fa[:, 1:],
            "body_actuator_torque": Ta[:, 1:],
            "body_joint_force": (Jf - Fa)[:, 1:],
            "body_joint_torque": (Jt - Ta)[:, 1:],
            "node_pos": _aos(node_pos),
            "node_vel": _aos(node_vel),
            "node_contact_force": node_cf,
            "node_joint_force": node_jf,
            "contact_count": ncontact,
            "contact_overflow": overflow,
        }
        return {
            key: np.ascontiguousarray(v).reshape((R_, F) + v.shape[1:]) for key, v in out.items()
        }

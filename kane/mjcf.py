"""Kane's equations of any MJCF kinematic tree: the compiled MuJoCo model becomes an analytic system, derived twice and checked against MuJoCo and Pinocchio.

:func:`from_mjcf` reads a user's MJCF file with MuJoCo and turns the *compiled* model
(``MjModel``: masses, centres of mass, inertias ``body_inertia`` rotated by
``body_iquat``, body frames ``body_pos``/``body_quat``, joint axes and anchors, ``qpos0``,
damping, stiffness, ``springref``, armature, gear, gravity) into a
:class:`kane.systems.AnalyticSystem` of hinge, slide, ball and free joints, whose
kinematics come from :func:`kane.systems.tree._tree_kinematics` (the same code as the
built-in systems). Masses, centres, inertia entries, body offsets, damping, stiffness and
armature become named parameter symbols (``m_<body>``, ``cx_<body>``, ``Ixx_<body>``,
``px_<body>``, ``d_<joint>``, ``k_<joint>``, ``a_<joint>``, ``g``) whose values are
MuJoCo's numbers; axes, anchors and fixed rotations stay numbers.

Kane's equations are formed two ways (:class:`MjcfModel`), from the same description:

* ``explicit``: Kane & Levinson (1985) written out in body-frame components
  (:func:`kane.systems.bodyframe.bodyframe_kane`): partial velocities ``V``, ``W`` of every
  mass centre and body; generalized active forces ``F_r`` (gravity, joint damping and
  springs, actuator forces as symbols ``tau_<actuator>``); generalized inertia forces
  ``F*_r = -sum (m a . v_r + (I alpha + omega x I omega) . omega_r)``; armature adds
  ``-a_k udot_k``. No sympy mechanics, no symbolic time derivative.
* ``kanes_method``: sympy's own ``KanesMethod`` on sympy frames and points built by
  :func:`kane.systems.tree._tree_kinematics`, an independent second derivation.

Coordinates (MuJoCo <-> sympy, see :mod:`kane.systems`): hinge/slide ``q`` = ``qpos``;
ball and free rotations as body-fixed Z-Y-X angles of the joint's own rotation, with
speeds = MuJoCo's ``qvel`` (local angular velocity; free: world linear velocity), so that
``udot`` = ``qacc`` and the mass matrix and forces compare entry by entry with
``mj_fullM``, ``qfrc_bias``, ``qfrc_passive``.

Whatever the tree derivation does not model is refused with :class:`MjcfUnsupported`
(one sentence naming the feature): equality constraints (closed loops, welds, joint
couplings), tendons, non-joint actuator transmissions, flexes, plugins, mocap bodies,
gravity compensation, fluid forces, horizontal gravity, spring stiffness on ball/free
joints, a ball joint followed by further joints in its body. Contacts, joint limits and
dry friction are constraints, not terms of Kane's equations of the tree; the checks run
with MuJoCo's constraints off.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import sympy as sp

from kane.systems import ActuatorSpec, AnalyticSystem, BodySpec, JointSpec, SymbolicModel, symbol
from kane.systems.bodyframe import bodyframe_kane
from kane.systems.derive import _plain_model_data

__all__ = ["KANES_METHOD_MAX_DEPTH", "KANES_METHOD_MAX_SPEEDS", "MjcfUnsupported", "MjcfModel", "from_mjcf", "load_model", "crosscheck_mjcf", "random_states", "compiled_mjcf"]


#: MuJoCo enum values (mjtJoint, mjtTrn), as plain ints for comparison with MjModel arrays.
_FREE, _BALL, _SLIDE, _HINGE = 0, 1, 2, 3
_TRN_JOINT = 0


#: sympy's KanesMethod builds its expressions on chains of sympy frames and slows down fast
#: with the number of joints on one path and the number of speeds. Measured on 2 shared
#: cores (benchmarks/bench_mjcf.py): 8 s for examples/mjcf/arm.xml (6 speeds, 4 joints deep),
#: 14 s for floating_base.xml (16 speeds, 3 deep), 126 s for a 24-speed humanoid (4 deep),
#: 218 s for the paper's space-single scene (12 speeds, 7 deep). It runs as the second
#: derivation within these limits; larger trees are derived by the body-frame route alone
#: (6 s for a 12-hinge chain, 15 s for the humanoid) and checked against MuJoCo and Pinocchio.
KANES_METHOD_MAX_DEPTH = 4
KANES_METHOD_MAX_SPEEDS = 16


class MjcfUnsupported(ValueError):
    """The MJCF file holds a feature the tree derivation does not model (one sentence)."""


# --------------------------------------------------------------------------------------
# Reading the compiled model
# --------------------------------------------------------------------------------------


def load_model(path: str | Path):
    """MuJoCo's compiled model of ``path``; a file MuJoCo cannot load raises :class:`MjcfUnsupported`."""
    import mujoco

    p = Path(path)
    if not p.is_file():
        raise MjcfUnsupported(f"{path}: " + ("is a folder, not a file" if p.is_dir() else "no such file")
                              + "; pass an MJCF file.")
    try:
        return mujoco.MjModel.from_xml_path(str(p))
    except Exception as exc:  # MuJoCo's own parse/compile error, one line
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise MjcfUnsupported(f"{path}: MuJoCo cannot load it ({msg.rstrip('.')}).") from exc


def _refuse_unsupported(m, path) -> None:
    """Raise :class:`MjcfUnsupported` for the first feature outside a plain joint tree."""

    def no(feature: str) -> None:
        raise MjcfUnsupported(f"{path}: {feature} is not supported by the tree derivation; remove it to derive Kane's equations.")

    if m.neq:
        no(f"equality constraints ({m.neq}: closed loops, welds or joint couplings)")
    if m.ntendon:
        no(f"tendons ({m.ntendon})")
    if getattr(m, "nflex", 0):
        no("flex bodies")
    if getattr(m, "nplugin", 0):
        no("engine plugins")
    if (m.body_mocapid >= 0).any():
        no("mocap bodies")
    if np.any(m.body_gravcomp != 0):
        no("gravity compensation (gravcomp)")
    if m.opt.density != 0 or m.opt.viscosity != 0 or np.any(m.opt.wind != 0):
        no("fluid forces (density, viscosity or wind)")
    if m.opt.gravity[0] != 0 or m.opt.gravity[1] != 0:
        no("gravity with a horizontal component")
    for a in range(m.nu):
        if int(m.actuator_trntype[a]) != _TRN_JOINT:
            no(f"actuator {a} with a non-joint transmission")
        if int(m.jnt_type[m.actuator_trnid[a, 0]]) not in (_HINGE, _SLIDE):
            no(f"actuator {a} on a ball or free joint")
    for j in range(m.njnt):
        jt = int(m.jnt_type[j])
        b = m.jnt_bodyid[j]
        last = j == m.body_jntadr[b] + m.body_jntnum[b] - 1
        if jt == _BALL and not last:
            no(f"ball joint {j} followed by further joints in its body")
        if jt in (_BALL, _FREE) and m.jnt_stiffness[j] != 0:
            no(f"spring stiffness on ball or free joint {j}")
        dofs = slice(m.jnt_dofadr[j], m.jnt_dofadr[j] + {0: 6, 1: 3}.get(int(jt), 1))
        for arr, what in ((m.dof_damping, "damping"), (m.dof_armature, "armature")):
            if np.ptp(arr[dofs]) != 0:
                no(f"{what} that differs between the degrees of freedom of joint {j}")
        if jt == _BALL and np.any(m.qpos0[m.jnt_qposadr[j] : m.jnt_qposadr[j] + 4] != [1, 0, 0, 0]):
            no(f"a reference orientation on ball joint {j}")


def _clean(name: str, fallback: str, taken: set) -> str:
    s = re.sub(r"\W", "_", name) or fallback
    if s[0].isdigit():
        s = "_" + s
    base, k = s, 1
    while s in taken:
        k += 1
        s = f"{base}_{k}"
    taken.add(s)
    return s


def _num(x: float, tol: float = 1e-15) -> float:
    return 0.0 if abs(x) < tol else float(x)


def _exact_axis(v) -> tuple:
    """Unit axis with exact 0/1/-1 components where MuJoCo's are exactly those."""
    return tuple(int(c) if float(c) in (0.0, 1.0, -1.0) else float(c) for c in v)


def _system_from_model(m, name: str, path) -> tuple[AnalyticSystem, list[int]]:
    """The analytic system of a compiled model, and the MuJoCo joint id of each JointSpec."""
    import mujoco

    _refuse_unsupported(m, path)
    params: dict[str, float] = {"g": float(-m.opt.gravity[2])}
    btaken: set = set()
    jtaken: set = set()
    bnames = {0: None}
    bodies, jids = [], []

    def par(prefix: str, owner: str, value: float):
        """Symbol ``<prefix>_<owner>`` holding ``value``, or exact 0."""
        value = _num(value)
        if value == 0:
            return 0
        params[f"{prefix}_{owner}"] = value
        return symbol(f"{prefix}_{owner}")

    kinds = {
        _FREE: "free",
        _BALL: "ball",
        _SLIDE: "slide",
        _HINGE: "hinge",
    }
    for b in range(1, m.nbody):
        bname = _clean(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or "", f"body{b}", btaken)
        bnames[b] = bname
        joints = []
        for j in range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b]):
            jname = _clean(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or "", f"joint{j}", jtaken)
            kind = kinds[int(m.jnt_type[j])]
            dof = m.jnt_dofadr[j]
            ref = float(m.qpos0[m.jnt_qposadr[j]]) if kind in ("hinge", "slide") else 0.0
            joints.append(
                JointSpec(
                    jname,
                    kind,
                    axis=_exact_axis(m.jnt_axis[j]),
                    pos=tuple(_num(c) for c in m.jnt_pos[j]) if kind != "free" else (0, 0, 0),
                    ref=_num(ref),
                    damping=par("d", jname, m.dof_damping[dof]),
                    stiffness=par("k", jname, m.jnt_stiffness[j]),
                    springref=_num(float(m.qpos_spring[m.jnt_qposadr[j]])) if kind in ("hinge", "slide") else 0,
                    armature=par("a", jname, m.dof_armature[dof]),
                )
            )
            jids.append(j)
        free = any(jt.kind == "free" for jt in joints)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, m.body_iquat[b])
        R = R.reshape(3, 3)
        I = R @ np.diag(m.body_inertia[b]) @ R.T  # about the mass centre, body axes
        scale = max(float(np.abs(I).max()), 1e-300)
        entries = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
        inertia = tuple(
            par(n, bname, v if abs(v) > 1e-14 * scale else 0.0)
            for n, v in zip(("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz"), entries, strict=True)
        )
        bodies.append(
            BodySpec(
                bname,
                bnames[int(m.body_parentid[b])],
                pos=(0, 0, 0) if free else tuple(par(f"p{c}", bname, v) for c, v in zip("xyz", m.body_pos[b], strict=True)),
                joints=tuple(joints),
                mass=par("m", bname, m.body_mass[b]),
                com=tuple(par(f"c{c}", bname, v) for c, v in zip("xyz", m.body_ipos[b], strict=True)),
                inertia=inertia,
                quat=(1, 0, 0, 0) if free else tuple(float(c) for c in m.body_quat[b]),
            )
        )
    jname_of = {j: spec.name for j, spec in zip(jids, (js for bd in bodies for js in bd.joints), strict=True)}
    acts = []
    ataken: set = set()
    for a in range(m.nu):
        aname = _clean(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) or "", f"act{a}", ataken)
        lo, hi = (float(x) for x in m.actuator_ctrlrange[a])
        acts.append(ActuatorSpec(aname, jname_of[int(m.actuator_trnid[a, 0])], (lo, hi), gear=float(m.actuator_gear[a, 0])))
    system = AnalyticSystem(
        name,
        params,
        tuple(bodies),
        tuple(acts),
        timestep=float(m.opt.timestep),
        description=f"user MJCF {Path(path).name}",
    )
    return system, jids


# --------------------------------------------------------------------------------------
# The two derivations
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class MjcfModel:
    """A user's MJCF tree as an analytic system, with Kane's equations derived two ways.

    Attributes
    ----------
    path : str
    system : AnalyticSystem
        Description built from MuJoCo's compiled model (see the module docstring).
    joint_ids : tuple of int
        MuJoCo joint id of each joint of ``system.joints``.
    seconds_load : float
        Time to read and convert the compiled model, s.
    """

    path: str
    system: AnalyticSystem
    joint_ids: tuple
    seconds_load: float = 0.0
    _timing: dict = field(default_factory=dict, repr=False)

    @cached_property
    def mj_model(self):
        """MuJoCo's compiled model of :attr:`path`."""
        return load_model(self.path)

    @cached_property
    def _bodyframe(self) -> dict:
        t0 = time.perf_counter()
        data = bodyframe_kane(self.system)
        self._timing["explicit"] = time.perf_counter() - t0
        return data

    @cached_property
    def explicit(self) -> SymbolicModel:
        """Kane's equations from explicit partial velocities in body-frame components
        (:func:`kane.systems.bodyframe.bodyframe_kane`, the primary derivation)."""
        data = {k: v for k, v in self._bodyframe.items() if k != "partials"}
        return SymbolicModel(system=self.system, seconds=self._timing["explicit"], **data)

    @cached_property
    def kanes_method(self) -> SymbolicModel:
        """The same equations from sympy's ``KanesMethod`` (independent second derivation)."""
        t0 = time.perf_counter()
        km, kin = self.system.kanes_method()
        data = _plain_model_data(self.system, km, kin)
        sec = time.perf_counter() - t0
        self._timing["kanes_method"] = sec
        return SymbolicModel(system=self.system, seconds=sec, **data)

    @property
    def partial_velocities(self) -> list[tuple[str, sp.Matrix, sp.Matrix]]:
        """``(body, V, W)`` per massive body: column r of ``V`` (3 x n_u) is the partial
        velocity of its mass centre, of ``W`` its partial angular velocity, both in the
        body's own frame components (plain symbols)."""
        return self._bodyframe["partials"]

    @cached_property
    def joint_depth(self) -> int:
        """Most joints on one path from the world to a body."""
        depth: dict = {None: 0}
        for b in self.system.bodies:
            depth[b.name] = depth[b.parent] + len(b.joints)
        return max(depth.values())

    @property
    def kanes_method_applies(self) -> bool:
        """Whether sympy's ``KanesMethod`` runs as the second derivation (see :data:`KANES_METHOD_MAX_DEPTH`)."""
        n_speeds = sum({"free": 6, "ball": 3}.get(j.kind, 1) for _, j in self.system.joints)
        return self.joint_depth <= KANES_METHOD_MAX_DEPTH and n_speeds <= KANES_METHOD_MAX_SPEEDS

    @property
    def timing(self) -> dict:
        """Seconds per derivation done so far (``explicit``, ``kanes_method``)."""
        return dict(self._timing)


def from_mjcf(path: str | Path, name: str | None = None) -> MjcfModel:
    """Read an MJCF kinematic tree and build its analytic system (derivations on demand).

    Parameters
    ----------
    path : str or Path
        MJCF file (hinge, slide, ball and free joints).
    name : str, optional
        System name; defaults to the file's stem.

    Returns
    -------
    MjcfModel
        The system, with its explicit and ``KanesMethod`` derivations built on first use.

    Raises
    ------
    MjcfUnsupported
        The file cannot be loaded or holds a feature outside a plain joint tree.
    """
    t0 = time.perf_counter()
    m = load_model(path)
    system, jids = _system_from_model(m, _clean(name or Path(path).stem, "model", set()), path)
    return MjcfModel(str(path), system, tuple(jids), time.perf_counter() - t0)


# --------------------------------------------------------------------------------------
# Cross-checks against MuJoCo and Pinocchio on random states
# --------------------------------------------------------------------------------------


def random_states(m, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` random (qpos, qvel, qacc) of a MuJoCo model: hinge angles in [-pi, pi], slides in
    [-0.5, 0.5] m, uniformly random quaternions, speeds and accelerations ~ N(0, 1) (SI)."""

    rng = np.random.default_rng(seed)
    qpos = np.zeros((n, m.nq))
    for k in range(n):
        for j in range(m.njnt):
            a = m.jnt_qposadr[j]
            jt = int(m.jnt_type[j])
            if jt == _FREE:
                qpos[k, a : a + 3] = rng.uniform(-0.5, 0.5, 3)
                qq = rng.normal(size=4)
                qpos[k, a + 3 : a + 7] = qq / np.linalg.norm(qq)
            elif jt == _BALL:
                qq = rng.normal(size=4)
                qpos[k, a : a + 4] = qq / np.linalg.norm(qq)
            elif jt == _HINGE:
                qpos[k, a] = rng.uniform(-np.pi, np.pi)
            else:
                qpos[k, a] = rng.uniform(-0.5, 0.5)
    return qpos, rng.normal(size=(n, m.nv)), rng.normal(size=(n, m.nv))


def _eval(fn, sm: SymbolicModel, arrays, params: dict[str, float] | None = None) -> np.ndarray:
    """Evaluate one of ``sm``'s lambdified functions with parameters overridden by ``params``."""
    vals = dict(sm.system.params)
    vals.update(params or {})
    cols = [a[i] for a in arrays for i in range(len(a))]
    return np.asarray(fn(*cols, *[vals[str(p)] for p in sm.params]), float)


def _f(x) -> str:
    return " ".join(format(float(v), ".17g") for v in np.atleast_1d(x))


def compiled_mjcf(m) -> tuple[str, dict[str, int]]:
    """Full-precision MJCF of a compiled model's tree, with explicit inertials.

    Bodies with their frames (``body_pos``, ``body_quat``), joints (type, axis, anchor,
    ``ref``, armature) and MuJoCo's mass properties (``body_ipos``, ``body_iquat``,
    ``body_inertia``) written with 17 significant digits; geoms, actuators and passive
    loads left out. Returns the XML and ``{joint name in the XML: MuJoCo joint id}``.
    Pinocchio reads this file when its own reading of the user's file gives other mass
    properties than MuJoCo's (it ignores the mass of visual geoms, for instance).
    """
    kids: dict[int, list[int]] = {}
    for b in range(1, m.nbody):
        kids.setdefault(int(m.body_parentid[b]), []).append(b)
    names: dict[str, int] = {}
    lines: list[str] = []
    types = {_HINGE: "hinge", _SLIDE: "slide", _BALL: "ball"}

    def body(b: int, ind: str) -> None:
        lines.append(f'{ind}<body name="b{b}" pos="{_f(m.body_pos[b])}" quat="{_f(m.body_quat[b])}">')
        for j in range(m.body_jntadr[b], m.body_jntadr[b] + m.body_jntnum[b]):
            jn = f"j{j}"
            names[jn] = j
            jt = int(m.jnt_type[j])
            if jt == _FREE:
                lines.append(f'{ind}  <freejoint name="{jn}"/>')
                continue
            ref = f' ref="{_f(m.qpos0[m.jnt_qposadr[j]])}"' if jt != _BALL else ""
            lines.append(f'{ind}  <joint name="{jn}" type="{types[jt]}" axis="{_f(m.jnt_axis[j])}" pos="{_f(m.jnt_pos[j])}"'
                         f'{ref} armature="{_f(m.dof_armature[m.jnt_dofadr[j]])}"/>')
        lines.append(f'{ind}  <inertial pos="{_f(m.body_ipos[b])}" quat="{_f(m.body_iquat[b])}" mass="{_f(m.body_mass[b])}" '
                     f'diaginertia="{_f(m.body_inertia[b])}"/>')
        for c in kids.get(b, []):
            body(c, ind + "  ")
        lines.append(f"{ind}</body>")

    for b in kids.get(0, []):
        body(b, "    ")
    xml = "\n".join(['<mujoco model="compiled">', '  <compiler angle="radian" autolimits="true"/>',
                     f'  <option gravity="{_f(m.opt.gravity)}"/>', "  <worldbody>", *lines, "  </worldbody>", "</mujoco>", ""])
    return xml, names


def _pinocchio_read(m, path: str, names: dict[str, int] | None):
    """Pinocchio model of ``path`` and the MuJoCo (qpos, dof) addresses and joint types it covers."""
    import mujoco
    import pinocchio as pin

    pm = pin.buildModelFromMJCF(path)
    pm.gravity.linear = np.array(m.opt.gravity, float)
    qadr, vadr, kinds = [], [], []
    for name in list(pm.names)[1:]:
        j = names[name] if names is not None else mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
        if j is None or j < 0:
            raise ValueError(f"Pinocchio joint {name!r} has no MuJoCo joint of that name")
        jt = int(m.jnt_type[j])
        qadr += list(range(m.jnt_qposadr[j], m.jnt_qposadr[j] + {_FREE: 7, _BALL: 4}.get(jt, 1)))
        vadr += list(range(m.jnt_dofadr[j], m.jnt_dofadr[j] + {_FREE: 6, _BALL: 3}.get(jt, 1)))
        kinds.append(jt)
    if len(qadr) != pm.nq or len(vadr) != pm.nv:
        raise ValueError("Pinocchio's joints do not match MuJoCo's (composite joints?)")
    return pm, np.array(qadr), np.array(vadr), kinds


def _pinocchio_tree(mm: MjcfModel):
    """Pinocchio model of the file, the MuJoCo dofs it covers, and which file it read.

    Pinocchio's MJCF reader builds one kinematic tree, the first top-level body's; the
    dofs of later trees are left out of the comparison (they are decoupled in the mass
    matrix and bias forces). Pinocchio reads the user's file itself when its mass matrix
    there agrees with MuJoCo's (``mj_fullM``) to 1e-12 at a random configuration; otherwise
    (its MJCF reader computes other mass properties, e.g. ignoring visual geoms' mass) it
    reads :func:`compiled_mjcf`, MuJoCo's compiled tree in full precision.
    """
    import tempfile

    import mujoco
    import pinocchio as pin

    from kane.crosscheck import _full_mass

    m = mm.mj_model
    try:
        pm, qadr, vadr, kinds = _pinocchio_read(m, mm.path, None)
        qpos, _, _ = random_states(m, 1, seed=12345)
        d = mujoco.MjData(m)
        d.qpos[:] = qpos[0]
        mujoco.mj_forward(m, d)
        Mf = _full_mass(m, d, np.zeros((m.nv, m.nv)))[np.ix_(vadr, vadr)]
        pq, _, _, T = _to_pinocchio(kinds, qpos[0, qadr], np.zeros(len(vadr)), np.zeros(len(vadr)))
        Mp = pin.crba(pm, pm.createData(), pq)
        Mp = np.triu(Mp) + np.triu(Mp, 1).T
        gap = float(np.abs(T.T @ Mp @ T - Mf).max() / max(np.abs(Mf).max(), 1e-300))
        if gap <= 1e-12:
            return pm, qadr, vadr, kinds, "the user's file"
        why = f"its reading of the file gives a mass matrix {gap:.1e} off MuJoCo's"
    except Exception as exc:
        why = f"it could not read the file as MuJoCo does ({type(exc).__name__})"
    xml, names = compiled_mjcf(m)
    with tempfile.NamedTemporaryFile("w", suffix=".xml") as fh:
        fh.write(xml)
        fh.flush()
        pm, qadr, vadr, kinds = _pinocchio_read(m, fh.name, names)
    return pm, qadr, vadr, kinds, f"MuJoCo's compiled tree (kane.mjcf.compiled_mjcf), since {why}"


def _to_pinocchio(kinds, qpos, qvel, qacc):
    """MuJoCo (qpos, qvel, qacc) of one tree -> Pinocchio (q, v, a) and T with v = T qvel.

    Ball and free quaternions (w, x, y, z) -> (x, y, z, w); a free joint's linear velocity
    and acceleration go to the local frame: ``v = R^T v_world``, ``a = R^T a_world - w x v``
    (the convention of :func:`kane.crosscheck.mujoco_to_pinocchio`).
    """
    from kane.crosscheck import _quat_to_R

    q, v, a = np.array(qpos, float), np.array(qvel, float), np.array(qacc, float)
    T = np.eye(len(v))
    ip = iv = 0
    for k in kinds:
        if k == 0:  # free
            wxyz = q[ip + 3 : ip + 7].copy()
            q[ip + 3 : ip + 7] = [*wxyz[1:], wxyz[0]]
            R = _quat_to_R(wxyz)
            T[iv : iv + 3, iv : iv + 3] = R.T
            v[iv : iv + 3] = R.T @ qvel[iv : iv + 3]
            a[iv : iv + 3] = R.T @ qacc[iv : iv + 3] - np.cross(qvel[iv + 3 : iv + 6], v[iv : iv + 3])
            ip, iv = ip + 7, iv + 6
        elif k == 1:  # ball: local angular velocity in both engines
            wxyz = q[ip : ip + 4].copy()
            q[ip : ip + 4] = [*wxyz[1:], wxyz[0]]
            ip, iv = ip + 4, iv + 3
        else:
            ip, iv = ip + 1, iv + 1
    return q, v, a, T


def crosscheck_mjcf(mm: MjcfModel, n_states: int = 20, seed: int = 0, model: SymbolicModel | None = None) -> dict:
    """Relative residuals of Kane's terms against MuJoCo and Pinocchio on random states.

    At ``n_states`` random (q, u, udot) (:func:`random_states`) with random actuator
    inputs, and MuJoCo's constraints (contacts, limits, dry friction) off:

    * ``mujoco_mass``: Kane's mass matrix against ``mj_fullM`` (armature included);
    * ``mujoco_bias``: Kane's forcing without inputs against ``qfrc_passive - qfrc_bias``;
    * ``mujoco_actuator``: forcing(inputs) - forcing(0) against ``qfrc_actuator`` with the
      recorded ``actuator_force`` as inputs;
    * ``mujoco_inverse``: ``-(fr + frstar)`` against ``mj_inverse``'s ``qfrc_inverse``;
    * ``pinocchio_crba``, ``pinocchio_rnea``: mass matrix against ``crba`` (upper triangle
      mirrored; Pinocchio reads the armature) and ``-(fr + frstar)`` without passive loads
      against ``rnea`` (Pinocchio has no joint damping/springs in ``rnea``), on the dofs
      of the tree Pinocchio reads (the first top-level body's);
    * ``kanes_method``: the explicit derivation against sympy's ``KanesMethod``, both
      evaluated at the same states (mass matrix and forcing); beyond
      :data:`KANES_METHOD_MAX_DEPTH` joints in a chain or :data:`KANES_METHOD_MAX_SPEEDS`
      speeds ``kanes_method_note`` says it was not run.

    Residuals: max |difference| / max |reference term| over all states (mass:
    max |M|; forces: the largest of |qfrc_bias|, |qfrc_passive|, |M udot|).

    Returns
    -------
    dict
        The residuals above, ``n_states``, ``pinocchio_dofs``, ``pinocchio_source`` (which file
        Pinocchio read), ``pinocchio_note`` (dofs left out, or why the Pinocchio route did not
        run), ``seconds``.
    """
    import mujoco

    t0 = time.perf_counter()
    sm = model or mm.explicit
    system = mm.system
    m = mujoco.MjModel.from_xml_path(mm.path)
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
    d = mujoco.MjData(m)
    qpos, qvel, qacc = random_states(m, n_states, seed)
    rng = np.random.default_rng(seed + 1)
    q, u, ud = system.mujoco_to_kane(qpos, qvel, qacc)
    nu, nv = m.nu, m.nv
    Mfull = np.zeros((nv, nv))
    ref = {k: [] for k in ("M", "bias", "act", "inv", "scale")}
    kM = sm.mass(q)
    kf0 = sm.force(q, u)
    ctrl = rng.uniform(-1, 1, (n_states, nu)) * 2.0
    tau = np.zeros((n_states, nu))
    from kane.crosscheck import _full_mass

    for k in range(n_states):
        d.qpos[:], d.qvel[:], d.ctrl[:] = qpos[k], qvel[k], ctrl[k]
        mujoco.mj_forward(m, d)
        _full_mass(m, d, Mfull)
        ref["M"].append(Mfull.copy())
        ref["bias"].append(d.qfrc_passive - d.qfrc_bias)
        ref["act"].append(d.qfrc_actuator.copy())
        tau[k] = d.actuator_force
        ref["scale"].append(max(np.abs(d.qfrc_bias).max(), np.abs(d.qfrc_passive).max(), np.abs(Mfull @ qacc[k]).max()))
        d.qacc[:] = qacc[k]
        mujoco.mj_inverse(m, d)
        ref["inv"].append(d.qfrc_inverse.copy())
    Mref, bias, act, inv = (np.array(ref[k]) for k in ("M", "bias", "act", "inv"))
    fscale = max(max(ref["scale"]), 1e-300)
    mscale = max(np.abs(Mref).max(), 1e-300)
    out: dict = {"n_states": n_states}
    out["mujoco_mass"] = float(np.abs(kM - Mref).max() / mscale)
    out["mujoco_bias"] = float(np.abs(kf0 - bias).max() / fscale)
    if nu:
        out["mujoco_actuator"] = float(np.abs(sm.force(q, u, tau) - kf0 - act).max() / max(np.abs(act).max(), 1e-300))
    out["mujoco_inverse"] = float(np.abs(sm.inverse_dynamics(q, u, ud) - inv).max() / fscale)
    # Pinocchio: passive loads off (damping, stiffness: parameters d_*, k_* set to 0)
    try:
        import pinocchio as pin

        pm, qadr, vadr, kinds, source = _pinocchio_tree(mm)
        out["pinocchio_source"] = source
        pd = pm.createData()
        off = {k: 0.0 for k in system.params if k.startswith(("d_", "k_"))}
        errM = errR = 0.0
        for k in range(n_states):
            pq, pv, pa, T = _to_pinocchio(kinds, qpos[k, qadr], qvel[k, vadr], qacc[k, vadr])
            Mp = pin.crba(pm, pd, pq)
            Mp = np.triu(Mp) + np.triu(Mp, 1).T  # crba fills the upper triangle only
            errM = max(errM, np.abs(kM[k][np.ix_(vadr, vadr)] - T.T @ Mp @ T).max())
            kin_inv = -_eval(sm._residual_fn, sm, [q[k], u[k], ud[k], np.zeros(len(sm.inputs))], off)
            errR = max(errR, np.abs(kin_inv[vadr] - T.T @ pin.rnea(pm, pd, pq, pv, pa)).max())
        out["pinocchio_crba"] = float(errM / mscale)
        out["pinocchio_rnea"] = float(errR / fscale)
        out["pinocchio_dofs"] = int(len(vadr))
        if len(vadr) < nv:
            out["pinocchio_note"] = f"Pinocchio read the first kinematic tree only ({len(vadr)} of {nv} dofs)"
    except Exception as exc:  # Pinocchio could not read the file: say why, decide nothing
        out["pinocchio_note"] = f"Pinocchio route not run ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})"
    # explicit derivation vs KanesMethod, numerically at the same states
    if model is None and not mm.kanes_method_applies and "kanes_method" not in mm.__dict__:  # not derived yet
        out["kanes_method_note"] = (f"sympy KanesMethod not run: {mm.joint_depth} joints deep, {len(sm.u)} speeds "
                                    f"(limits {KANES_METHOD_MAX_DEPTH}, {KANES_METHOD_MAX_SPEEDS}) take it minutes")
    elif model is None:
        km = mm.kanes_method
        out["kanes_method"] = float(
            max(np.abs(km.mass(q) - kM).max() / mscale, np.abs(km.force(q, u, tau) - sm.force(q, u, tau)).max() / fscale)
        )
    out["seconds"] = time.perf_counter() - t0
    return out

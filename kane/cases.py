"""Cases built for the clauses of the corrected statements (issue 20): systems, recorders, measures.

The corrected statements of :mod:`kane.claims` say *when* each of the paper's claims holds;
every clause needs a case that can show it false. This module builds those cases from
MuJoCo, Pinocchio and :mod:`kane.elements` alone:

* :class:`FreeSystem`: a free body of box cells whose free-joint origin may be offset from its
  centre of mass, optionally carrying a hinged flap or striking a floor; :func:`record` steps
  it with MuJoCo's Euler or RK4 and keeps per element the centroid velocity, the *true*
  centroid acceleration (``mj_objectAcceleration``) and the external loads (gravity, contact).
  :func:`eq11_translational` is the translational Eq. (11) residual (Eq. 11*), with forward
  differences or with true accelerations; :func:`observed_order` fits ``residual ~ delta^p``.
* One-hot partial velocities (Eq. 23*): :func:`mujoco_partials`, :func:`pinocchio_partials`,
  :func:`onehot_deviation`, and the statement's own condition :func:`world_axis_translation`.
* Element inertia ratios ``I_max / (M tau^2)`` (Eq. 36*): uniform solid boxes, spheres and
  tetrahedra from MuJoCo's geom inertia; point-mass box cells from :func:`kane.elements.partition_box`;
  the continuum box ratio by sympy integration, for CasADi.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

__all__ = [
    "FreeSystem",
    "Record",
    "free_system_mjcf",
    "record",
    "eq11_sides",
    "eq11_translational",
    "observed_order",
    "OFFSET",
    "mujoco_partials",
    "pinocchio_partials",
    "nearest_onehot",
    "onehot_deviation",
    "world_axis_translation",
    "joint_zoo_mjcf",
    "random_tree_mjcf",
    "solid_box_ratio",
    "sphere_ratio",
    "tetra_ratio",
    "point_box_ratio",
    "continuum_box_ratio_expr",
    "ONEHOT_TOL",
]

#: offset of the box centre from the free joint's origin in the issue's review, m (body frame)
OFFSET = (0.1, 0.05, -0.07)
#: a partial velocity counts as one-hot when every entry is within this of 0 or 1 (round-off
#: of MuJoCo's/Pinocchio's Jacobians of unit-norm quaternion frames is ~1e-16)
ONEHOT_TOL = 1e-12


# ----------------------------------------------------------------------------- Eq. (11)*


@dataclass(frozen=True)
class FreeSystem:
    """A free box of cells (one element per cell), optionally with a hinged flap, on a floor.

    Attributes
    ----------
    half_extents : (3,) m, of the main box.  divisions : cells per axis (elements).
    offset : (3,) m, position of the box centre relative to the free joint's origin (body
        frame); (0, 0, 0) puts the origin at the box's centre of mass.
    flap : add a box (0.1 x 0.05 x 0.05 m half extents) hinged about y at 0.3 m along x.
    floor : add a plane at z = 0.  height : initial height of the joint origin, m.
    v0, omega0 : initial linear velocity of the origin and angular velocity (world), m/s, rad/s.
    flap_rate : initial hinge rate, rad/s.  integrator : "Euler" or "RK4".  dt : s.
    """

    half_extents: tuple = (0.1, 0.15, 0.25)
    divisions: tuple = (2, 1, 1)
    offset: tuple = (0.0, 0.0, 0.0)
    flap: bool = False
    floor: bool = False
    height: float = 1.0
    v0: tuple = (0.0, 0.0, 0.0)
    omega0: tuple = (1.0, 2.0, 3.0)
    flap_rate: float = 2.0
    integrator: str = "Euler"
    dt: float = 1e-3


def free_system_mjcf(s: FreeSystem) -> str:
    """MJCF of ``s``: a root body with a free joint; each cell (and the flap) is a child body
    whose name starts with ``e`` (the elements)."""
    h = np.asarray(s.half_extents, float)
    nd = np.asarray(s.divisions, int)
    size = h / nd
    off = np.asarray(s.offset, float)
    f = lambda v: " ".join(f"{x:.17g}" for x in v)  # noqa: E731
    parts = [f'<mujoco><option timestep="{s.dt:.17g}" integrator="{s.integrator}"/><worldbody>']
    if s.floor:
        parts.append('<geom name="floor" type="plane" size="5 5 0.1" friction="0.8 0.005 0.0001"/>')
    parts.append(f'<body name="root" pos="0 0 {s.height:.17g}"><freejoint name="root"/>')
    k = 0
    for ix in range(nd[0]):
        for iy in range(nd[1]):
            for iz in range(nd[2]):
                c = -h + size * (2 * np.array([ix, iy, iz]) + 1) + off
                parts.append(f'<body name="e{k}" pos="{f(c)}"><geom type="box" size="{f(size)}" density="1000"/></body>')
                k += 1
    if s.flap:
        parts.append(f'<body name="e{k}" pos="{f(off + np.array([0.3, 0, 0]))}"><joint name="flap" type="hinge" axis="0 1 0"/>'
                     '<geom type="box" size="0.1 0.05 0.05" density="1000"/></body>')
    parts.append("</body></worldbody></mujoco>")
    return "".join(parts)


@dataclass(frozen=True)
class Record:
    """Element ground truth along a trajectory (T frames, n elements, world axes).

    v, a : [T, n, 3] centroid velocity (m/s) and true centroid acceleration (m/s^2).
    force : [T, n, 3] external force on each element (gravity + contact), N.
    mass : [n] kg.  dt : s.  n_contacts : [T].
    Frame t holds the state at t and the loads and accelerations of step t -> t+1.
    """

    v: np.ndarray
    a: np.ndarray
    force: np.ndarray
    mass: np.ndarray
    dt: float
    n_contacts: np.ndarray


@lru_cache(maxsize=64)
def record(s: FreeSystem, duration: float) -> Record:
    """Step ``s`` for ``duration`` seconds (cached: several clauses read the same run)."""
    import mujoco

    m = mujoco.MjModel.from_xml_string(free_system_mjcf(s))
    d = mujoco.MjData(m)
    d.qvel[:3] = s.v0
    d.qvel[3:6] = s.omega0  # root starts unrotated: body frame = world frame
    if s.flap:
        d.qvel[6] = s.flap_rate
    els = [b for b in range(m.nbody) if m.body(b).name.startswith("e")]
    mass = m.body_mass[els].copy()
    geom_el = {int(m.body_geomadr[b]): i for i, b in enumerate(els)}
    g = m.opt.gravity.copy()
    T = int(round(duration / s.dt))
    v, a, F = (np.zeros((T + 1, len(els), 3)) for _ in range(3))
    ncon = np.zeros(T + 1, int)
    v6, a6, f6 = np.zeros(6), np.zeros(6), np.zeros(6)
    for t in range(T + 1):
        mujoco.mj_forward(m, d)
        mujoco.mj_rnePostConstraint(m, d)
        for i, b in enumerate(els):
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, b, v6, 0)
            mujoco.mj_objectAcceleration(m, d, mujoco.mjtObj.mjOBJ_BODY, b, a6, 0)
            v[t, i] = v6[3:]
            a[t, i] = a6[3:] + g  # MuJoCo's cacc carries the gravity bias (world accelerates at -g)
            F[t, i] = mass[i] * g
        ncon[t] = d.ncon
        for c in range(d.ncon):
            con = d.contact[c]
            mujoco.mj_contactForce(m, d, c, f6)
            fw = con.frame.reshape(3, 3).T @ f6[:3]  # force of geom1 on geom2, world
            for geom, sign in ((con.geom1, -1.0), (con.geom2, 1.0)):
                if int(geom) in geom_el:
                    F[t, geom_el[int(geom)]] += sign * fw
        if t < T:  # integrate from the very mj_forward whose forces were recorded
            if s.integrator == "RK4":
                mujoco.mj_RungeKutta(m, d, 4)
            else:
                mujoco.mj_Euler(m, d)
    return Record(v, a, F, mass, s.dt, ncon)


def eq11_sides(rec: Record, true_acc: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Both sides of the translational Eq. (11) per frame and world axis, their difference and
    the force scale.

    Returns ``(F, Ma, S, scale)``: ``F`` [T, 3] is ``sum_i F_i`` (N); ``S`` [T, 3] is
    ``sum_i (F_i - M_i a_i)`` (N), with ``a_i`` the forward difference ``(v^{t+1} - v^t)/delta``
    (T - 1 frames, evaluated by the generated ``eq11_term`` of :mod:`kane.terms`) or, with
    ``true_acc``, MuJoCo's instantaneous centroid acceleration; ``Ma = F - S`` is
    ``sum_i M_i a_i`` (N); ``scale`` is the largest ``sum_i |F_i|`` (summed over axes), N."""
    from kane import terms

    scale = float(np.abs(rec.force).sum((1, 2)).max() + 1e-300)
    if true_acc:
        S = (rec.force - rec.mass[None, :, None] * rec.a).sum(1)
        F = rec.force.sum(1)
    else:
        term = terms.loss_functions("numpy")["eq11_term"][1]
        S = term(rec.force[:-1], rec.mass[None, :, None], rec.v[1:], rec.v[:-1], rec.dt, 1.0).sum(1)
        F = rec.force[:-1].sum(1)
    return F, F - S, S, scale


def eq11_translational(rec: Record, true_acc: bool = False, where: bool = False):
    """Largest translational Eq. (11) residual ``|sum_i F_i - sum_i M_i a_i|`` over frames and
    axes, relative to the largest ``sum_i |F_i|`` (:func:`eq11_sides`); with ``where``, also
    the frame and the axis where it is largest: ``(residual, frame, axis)``."""
    _, _, S, scale = eq11_sides(rec, true_acc)
    r = np.abs(S)
    t, g = np.unravel_index(np.argmax(r), r.shape)
    res = float(r[t, g] / scale)
    return (res, int(t), int(g)) if where else res


def observed_order(s: FreeSystem, duration: float, halvings: int = 2) -> tuple[float, list[float], list[float]]:
    """Fit ``r(delta) ~ C delta^p`` of the forward-difference residual over ``delta, delta/2, ...``.

    Returns (p, deltas, residuals); p is the least-squares slope of log r against log delta.
    """
    dts = [s.dt / 2**k for k in range(halvings + 1)]
    res = [eq11_translational(record(replace(s, dt=dt), duration)) for dt in dts]
    if min(res) <= 0:
        return float("nan"), dts, res
    p = float(np.polyfit(np.log(dts), np.log(res), 1)[0])
    return p, dts, res


# ----------------------------------------------------------------------------- Eq. (23)*


def _ancestors(m, b: int) -> set[int]:
    out = {b}
    while b:
        b = int(m.body_parentid[b])
        out.add(b)
    return out


def mujoco_partials(m, d, element_bodies) -> tuple[np.ndarray, np.ndarray]:
    """Partial velocities of the element centroids w.r.t. every dof: u [nv, n, 3], omega [nv, n, 3]."""
    import mujoco

    u = np.zeros((m.nv, len(element_bodies), 3))
    w = np.zeros_like(u)
    jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
    for i, b in enumerate(element_bodies):
        mujoco.mj_jac(m, d, jp, jr, d.xipos[b], b)
        u[:, i], w[:, i] = jp.T, jr.T
    return u, w


def nearest_onehot(u: np.ndarray) -> int:
    """The axis ``k`` of the one-hot vector ``+-e_k`` nearest to one speed's partial velocities
    ``u`` [n, 3] (the same ``k`` for every element: the axis they move along most)."""
    return int(np.argmax(np.abs(u).sum(0)))


def onehot_deviation(u: np.ndarray, w: np.ndarray, per_element: bool = False):
    """How far one speed's partial velocities are from ``u_{i,gamma} = +-e_k`` (the same k for
    every element, :func:`nearest_onehot`) and ``omega_{i,gamma} = 0``: the largest entry-wise
    distance, u [n, 3], w [n, 3]; with ``per_element``, the distance of each element, [n]."""
    target = np.zeros(3)
    target[nearest_onehot(u)] = 1.0
    dev = np.maximum(np.abs(np.abs(u) - target).max(1), np.abs(w).max(1))
    return dev if per_element else float(dev.max())


def world_axis_translation(m, d, dof: int, element_bodies) -> bool:
    """The condition of Eq. (23)*: ``dof`` is a translation along a world coordinate axis of a
    joint that carries every element (MuJoCo: a free joint's linear dofs, which are world
    axes by MuJoCo's convention, or a slide joint whose current world axis is a coordinate
    axis). Decided from the model's structure, not from the Jacobians."""
    import mujoco

    j = int(m.dof_jntid[dof])
    typ = int(m.jnt_type[j])
    k = dof - int(m.jnt_dofadr[j])
    if typ == mujoco.mjtJoint.mjJNT_FREE and k < 3:
        axis = np.eye(3)[k]
    elif typ == mujoco.mjtJoint.mjJNT_SLIDE:
        axis = np.asarray(d.xaxis[j], float)
    else:
        return False
    carries = all(int(m.jnt_bodyid[j]) in _ancestors(m, b) for b in element_bodies)
    return carries and abs(np.abs(axis).max() - 1.0) < ONEHOT_TOL


def joint_zoo_mjcf() -> str:
    """A chain with every kind of speed: a base on slide joints along x and along (1, 1, 0)/sqrt 2
    and a hinge about z, an arm on a hinge about y, a slider on a slide along x."""
    return ('<mujoco><worldbody><body name="e0" pos="0 0 0.5">'
            '<joint name="sx" type="slide" axis="1 0 0"/><joint name="sd" type="slide" axis="1 1 0"/>'
            '<joint name="hz" type="hinge" axis="0 0 1"/><geom type="box" size="0.1 0.1 0.1" pos="0.02 -0.03 0.01"/>'
            '<body name="e1" pos="0.3 0 0" euler="0 0 30"><joint name="hy" type="hinge" axis="0 1 0"/>'
            '<geom type="box" size="0.1 0.04 0.04" pos="0.1 0 0"/>'
            '<body name="e2" pos="0.25 0 0"><joint name="s2" type="slide" axis="1 0 0"/>'
            '<geom type="sphere" size="0.05"/></body></body></body></worldbody></mujoco>')


def random_tree_mjcf(rng: np.random.Generator, n_bodies: int) -> str:
    """A random tree of ``n_bodies`` bodies: the root has a free joint or 1-3 of slide (axis a
    coordinate axis or random) / hinge / ball joints, unrotated half the time; each other body hangs from a random
    earlier body on 0-2 such joints. Every body carries one off-centre box geom."""
    def axis():
        if rng.random() < 0.5:
            return np.eye(3)[rng.integers(3)] * rng.choice([-1.0, 1.0])
        a = rng.standard_normal(3)
        return a / np.linalg.norm(a)

    def joints(b, root):
        if root and rng.random() < 0.4:
            return [f'<freejoint name="j{b}f"/>']
        out, used = [], []
        for k in range(int(rng.integers(1 if root else 0, 3))):
            kind = rng.choice(["slide", "hinge", "ball"], p=[0.5, 0.35, 0.15])
            if kind == "ball" and out:  # a ball after a hinge would give 4 rotations: a singular mass matrix
                kind = "hinge"
            if kind == "ball":  # MuJoCo: nothing may follow a ball joint in its body
                out.append(f'<joint name="j{b}_{k}" type="ball"/>')
                break
            a = axis()
            if any(abs(abs(a @ u) - 1) < 1e-6 for u in used):  # a repeated axis would make the mass matrix singular
                continue
            used.append(a)
            ax = " ".join(f"{x:.17g}" for x in a)
            out.append(f'<joint name="j{b}_{k}" type="{kind}" axis="{ax}"/>')
        return out

    parent = [-1] + [int(rng.integers(0, b)) for b in range(1, n_bodies)]
    children: dict[int, list[int]] = {b: [] for b in range(n_bodies)}
    for b in range(1, n_bodies):
        children[parent[b]].append(b)

    def body(b):
        pos = " ".join(f"{x:.6g}" for x in (rng.uniform(-0.3, 0.3, 3) if b else (0, 0, 1)))
        q = rng.standard_normal(4) if (b or rng.random() < 0.5) else np.array([1.0, 0, 0, 0])  # axis-aligned root half the time
        quat = " ".join(f"{x:.17g}" for x in q / np.linalg.norm(q))
        gpos = " ".join(f"{x:.6g}" for x in rng.uniform(-0.05, 0.05, 3))
        size = " ".join(f"{x:.6g}" for x in rng.uniform(0.02, 0.1, 3))
        inner = "".join(joints(b, b == 0)) + f'<geom type="box" size="{size}" pos="{gpos}"/>' + "".join(body(c) for c in children[b])
        return f'<body name="e{b}" pos="{pos}" quat="{quat}">{inner}</body>'

    return f"<mujoco><worldbody>{body(0)}</worldbody></mujoco>"


def pinocchio_partials(rotation: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Partial velocities (world axes) of ``points`` (body frame, m) of one body on Pinocchio's
    free-flyer joint at orientation ``rotation``, w.r.t. Pinocchio's 6 speeds (linear and
    angular velocity in the body frame): u [6, n, 3], omega [6, n, 3]."""
    import pinocchio as pin

    model = pin.Model()
    jid = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    model.appendBodyToJoint(jid, pin.Inertia.FromBox(1.0, 0.2, 0.3, 0.4), pin.SE3.Identity())
    fids = [model.addFrame(pin.Frame(f"p{i}", jid, 0, pin.SE3(np.eye(3), np.asarray(p, float)), pin.FrameType.OP_FRAME))
            for i, p in enumerate(points)]
    data = model.createData()
    q = pin.neutral(model)
    q[:3] = (0.1, -0.2, 0.3)
    q[3:7] = pin.Quaternion(np.asarray(rotation, float)).coeffs()
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    u = np.zeros((6, len(points), 3))
    w = np.zeros_like(u)
    for i, f in enumerate(fids):
        J = pin.getFrameJacobian(model, data, f, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        u[:, i], w[:, i] = J[:3].T, J[3:].T
    return u, w


# ----------------------------------------------------------------------------- Eq. (36)*


def _geom_ratio(xml_geom: str, tau: float, extra: str = "") -> float:
    import mujoco

    m = mujoco.MjModel.from_xml_string(f"<mujoco>{extra}<worldbody><body><freejoint/>{xml_geom}</body></worldbody></mujoco>")
    return float(m.body_inertia[1].max() / (m.body_mass[1] * tau**2))


def solid_box_ratio(h) -> float:
    """``I_max / (M tau^2)`` of a uniform solid box of half extents ``h`` (MuJoCo's inertia), tau = |h|."""
    h = np.asarray(h, float)
    return _geom_ratio(f'<geom type="box" size="{h[0]:.17g} {h[1]:.17g} {h[2]:.17g}"/>', float(np.linalg.norm(h)))


def sphere_ratio(radius: float = 0.1) -> float:
    """``I / (M tau^2)`` of a uniform solid sphere (MuJoCo's inertia), tau = radius."""
    return _geom_ratio(f'<geom type="sphere" size="{radius:.17g}"/>', radius)


def tetra_ratio(vertices) -> float:
    """``I_max / (M tau^2)`` of a uniform solid tetrahedron (MuJoCo's mesh inertia about its mass
    centre), tau = largest distance from the mass centre to a vertex."""
    import mujoco

    v = np.asarray(vertices, float).reshape(4, 3)
    verts = " ".join(f"{x:.17g}" for x in v.ravel())
    m = mujoco.MjModel.from_xml_string(
        f'<mujoco><asset><mesh name="t" vertex="{verts}"/></asset><worldbody><body><freejoint/>'
        '<geom type="mesh" mesh="t"/></body></worldbody></mujoco>')
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    # body frame is at the body origin; the mesh is re-centred by MuJoCo: use the vertex
    # positions relative to the volume centroid (mean of the vertices for a tetrahedron)
    tau = float(np.linalg.norm(v - v.mean(0), axis=1).max())
    return float(m.body_inertia[1].max() / (m.body_mass[1] * tau**2))


def point_box_ratio(h, points_per_axis: int = 2, jitter: float = 0.0, seed: int = 0) -> float:
    """``I_max / (M tau^2)`` of one box cell of :func:`kane.elements.partition_box` made of
    ``points_per_axis^3`` point masses (the paper's element model), tau = the element's radius."""
    from kane.elements import partition_box

    (e,) = partition_box(h, (1, 1, 1), mass=1.0, points_per_axis=points_per_axis,
                         rng=np.random.default_rng(seed), jitter=jitter)
    return float(np.linalg.eigvalsh(e.inertia).max() / (e.mass * e.tau**2))


@lru_cache(maxsize=1)
def continuum_box_ratio_expr():
    """(args (a, b, c), sympy expression of I_zz / (M tau^2)) of a uniform solid box of half
    extents a, b, c by integration of rho (x^2 + y^2) over its volume, tau^2 = a^2 + b^2 + c^2."""
    import sympy as sp

    a, b, c, x, y, z = sp.symbols("a b c x y z", positive=True)
    Izz = sp.integrate(x**2 + y**2, (x, -a, a), (y, -b, b), (z, -c, c))  # density 1
    M = 8 * a * b * c
    return (a, b, c), sp.simplify(Izz / (M * (a**2 + b**2 + c**2)))

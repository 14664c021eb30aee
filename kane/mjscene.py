"""MuJoCo scenes of element sets, and element-level ground truth along their trajectories.

A rigid body is a free root body whose welded child bodies are its elements (box cells of
uniform density, so MuJoCo integrates their mass properties itself). Along an Euler
trajectory we record, per element: centroid position and velocity (world), MuJoCo's mass
and inertia, and the external loads (gravity and contact forces from ``mj_contactForce``).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

__all__ = ["BoxBodySpec", "box_body_mjcf", "ElementTrajectory", "simulate_elements", "mat_from_quat"]


@dataclass(frozen=True)
class BoxBodySpec:
    """A box body split into ``divisions`` cells, optionally on a floor.

    Attributes
    ----------
    half_extents : (3,) m.  divisions : (nx, ny, nz).  density : kg/m^3 (or per-cell list).
    gravity : (3,) m/s^2.  floor : add a plane at z = 0.  height : initial centre height, m.
    omega0 : (3,) initial angular velocity, world, rad/s.  v0 : (3,) initial velocity, m/s.
    quat0 : (4,) initial orientation (w, x, y, z).  dt : s.  integrator : "Euler" or "RK4".
    """

    half_extents: tuple = (0.1, 0.1, 0.1)
    divisions: tuple = (2, 2, 2)
    density: object = 1000.0
    gravity: tuple = (0.0, 0.0, -9.81)
    floor: bool = False
    height: float = 1.0
    omega0: tuple = (1.0, 2.0, 3.0)
    v0: tuple = (0.0, 0.0, 0.0)
    quat0: tuple = (1.0, 0.0, 0.0, 0.0)
    dt: float = 1e-3
    integrator: str = "Euler"


def _cells(spec: BoxBodySpec):
    h = np.asarray(spec.half_extents, float)
    nd = np.asarray(spec.divisions, int)
    size = h / nd
    dens = np.broadcast_to(np.asarray(spec.density, float), (int(np.prod(nd)),))
    cells = []
    k = 0
    for ix in range(nd[0]):
        for iy in range(nd[1]):
            for iz in range(nd[2]):
                c = -h + size * (2 * np.array([ix, iy, iz]) + 1)
                cells.append((c, size, float(dens[k])))
                k += 1
    return cells


def box_body_mjcf(spec: BoxBodySpec) -> str:
    """MJCF of the box body; the root body's origin is placed at the mass centre of its cells."""
    cells = _cells(spec)
    masses = np.array([d * 8 * np.prod(s) for _, s, d in cells])
    com = (masses[:, None] * np.array([c for c, _, _ in cells])).sum(0) / masses.sum()
    g = " ".join(f"{x:.17g}" for x in spec.gravity)
    parts = [
        '<mujoco model="element_box">',
        f'  <option timestep="{spec.dt:.17g}" integrator="{spec.integrator}" gravity="{g}"/>',
        "  <worldbody>",
    ]
    if spec.floor:
        parts.append('    <geom name="floor" type="plane" size="5 5 0.1" friction="0.8 0.005 0.0001"/>')
    q = " ".join(f"{x:.17g}" for x in spec.quat0)
    parts.append(f'    <body name="root" pos="0 0 {spec.height:.17g}" quat="{q}">')
    parts.append('      <freejoint name="root"/>')
    for i, (c, s, d) in enumerate(cells):
        p = " ".join(f"{x:.17g}" for x in c - com)
        sz = " ".join(f"{x:.17g}" for x in s)
        parts.append(f'      <body name="e{i}" pos="{p}"><geom name="g{i}" type="box" size="{sz}" density="{d:.17g}"/></body>')
    parts += ["    </body>", "  </worldbody>", "</mujoco>"]
    return "\n".join(parts)


def mat_from_quat(q) -> np.ndarray:
    """3x3 rotation of a MuJoCo quaternion (w, x, y, z)."""
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(q, float))
    return m.reshape(3, 3)


@dataclass(frozen=True)
class ElementTrajectory:
    """Element-level ground truth along a trajectory (T frames, n elements).

    Attributes
    ----------
    x, v : [T, n, 3] element centroid positions (m) and velocities (m/s), world.
    omega, alpha : [T, 3] body angular velocity (rad/s) and acceleration (rad/s^2), world.
    force : [T, n, 3] external force resultant per element (gravity + contact), N.
    moment : [T, n, 3] external moment about each element centroid, N m.
    force_abs : [T, n] sum of magnitudes of the external forces on each element, N.
    mass : [n] kg.  inertia : [T, n, 3, 3] world-frame inertia about each centroid, kg m^2.
    tau : [n] largest radius of each cell (half-diagonal), m.  dt : s.
    n_contacts : [T] number of active contacts.
    internal_force, internal_moment : [T, n, 3]
        Force and moment (about the element centroid) that the rest of the body exerts on each
        element, from MuJoCo's ``cfrc_int`` after ``mj_rnePostConstraint`` (N, N m).
    """

    x: np.ndarray
    v: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray
    force: np.ndarray
    moment: np.ndarray
    force_abs: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    tau: np.ndarray
    dt: float
    n_contacts: np.ndarray
    internal_force: np.ndarray
    internal_moment: np.ndarray


def simulate_elements(spec: BoxBodySpec, n_steps: int = 200) -> ElementTrajectory:
    """Step the body ``n_steps`` times and record element ground truth before each step.

    Frame t holds the state at t and the loads/accelerations acting during step t -> t+1
    (Euler: ``qvel[t+1] = qvel[t] + dt * qacc[t]``).
    """
    model = mujoco.MjModel.from_xml_string(box_body_mjcf(spec))
    data = mujoco.MjData(model)
    data.qvel[:3] = spec.v0
    R0 = mat_from_quat(spec.quat0)
    data.qvel[3:6] = R0.T @ np.asarray(spec.omega0, float)  # free joint: angular velocity in body frame
    bodies = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"e{i}") for i in range(int(np.prod(spec.divisions)))]
    n = len(bodies)
    mass = model.body_mass[bodies].copy()
    g = np.asarray(spec.gravity, float)
    tau = np.array([np.linalg.norm(model.geom_size[model.body_geomadr[b]]) for b in bodies])
    body_of_geom = {int(model.body_geomadr[b]): i for i, b in enumerate(bodies)}
    T = n_steps
    out = {k: np.zeros((T, n, 3)) for k in ("x", "v", "force", "moment", "fint", "mint")}
    force_abs = np.zeros((T, n))
    inertia = np.zeros((T, n, 3, 3))
    omega = np.zeros((T, 3))
    alpha = np.zeros((T, 3))
    ncon = np.zeros(T, int)
    vel6 = np.zeros(6)
    f6 = np.zeros(6)
    for t in range(T):
        mujoco.mj_forward(model, data)
        Rb = data.xmat[1].reshape(3, 3)
        omega[t] = Rb @ data.qvel[3:6]
        alpha[t] = Rb @ data.qacc[3:6]
        for i, b in enumerate(bodies):
            out["x"][t, i] = data.xipos[b]
            mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, b, vel6, 0)
            out["v"][t, i] = vel6[3:]  # [rot; lin] at the body origin (= cell centroid), world axes
            Ri = data.ximat[b].reshape(3, 3)
            inertia[t, i] = Ri @ np.diag(model.body_inertia[b]) @ Ri.T
            out["force"][t, i] = mass[i] * g
            force_abs[t, i] = mass[i] * np.linalg.norm(g)
        ncon[t] = data.ncon
        mujoco.mj_rnePostConstraint(model, data)
        for i, b in enumerate(bodies):
            # cfrc_int: [torque; force] of the parent on body b, about the subtree com of b's root
            c = data.subtree_com[model.body_rootid[b]]
            f = data.cfrc_int[b][3:]
            out["fint"][t, i] = f
            out["mint"][t, i] = data.cfrc_int[b][:3] + np.cross(c - out["x"][t, i], f)
        for c in range(data.ncon):
            con = data.contact[c]
            mujoco.mj_contactForce(model, data, c, f6)
            fw = con.frame.reshape(3, 3).T @ f6[:3]  # force of geom1 on geom2, world
            for geom, sign in ((con.geom1, -1.0), (con.geom2, 1.0)):
                i = body_of_geom.get(int(geom))
                if i is None:
                    continue
                f = sign * fw
                out["force"][t, i] += f
                out["moment"][t, i] += np.cross(con.pos - out["x"][t, i], f)
                force_abs[t, i] += np.linalg.norm(f)
        # integrate from the very mj_forward whose forces were recorded (a second mj_forward
        # inside mj_step would re-solve the contact problem from a new warm start)
        if spec.integrator == "RK4":
            mujoco.mj_RungeKutta(model, data, 4)
        else:
            mujoco.mj_Euler(model, data)
    return ElementTrajectory(out["x"], out["v"], omega, alpha, out["force"], out["moment"], force_abs, mass, inertia,
                             tau, spec.dt, ncon, out["fint"], out["mint"])

"""MuJoCo simulation of an analytic system: trajectories with accelerations, actuator forces and contact wrenches."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from kane.systems.system import AnalyticSystem


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A MuJoCo trajectory; row t holds the state at ``time[t]`` and the quantities that
    MuJoCo computed at that state (before integrating to t + 1).

    Attributes
    ----------
    time : ndarray, shape [T], s
    qpos : ndarray, shape [T, nq]
    qvel : ndarray, shape [T, nv]
    qacc : ndarray, shape [T, nv]
        Forward-dynamics acceleration at (qpos, qvel, ctrl); Euler: qvel[t+1] = qvel[t] + dt qacc[t].
    ctrl : ndarray, shape [T, nu]
    actuator_force : ndarray, shape [T, nu], N m or N
    contact_wrench : ndarray, shape [T, n_wrench_bodies, 6]
        Total contact force (N, world) and torque about the body origin (N m, world) on
        each body of ``system.wrench_bodies``.
    n_contacts : ndarray, shape [T], int
    """

    system: AnalyticSystem
    time: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    qacc: np.ndarray
    ctrl: np.ndarray
    actuator_force: np.ndarray
    contact_wrench: np.ndarray
    n_contacts: np.ndarray

    def kane_inputs(self, actuators: bool = True) -> np.ndarray:
        """Input vector of the sympy model per step, shape [T, n_inputs].

        ``actuators=False`` zeroes the actuator entries (keeps contact wrenches), which is
        what inverse dynamics (``qfrc_inverse``, ``rnea``) leaves to the actuators.
        """
        T = len(self.time)
        act = self.actuator_force if actuators else np.zeros_like(self.actuator_force)
        return np.concatenate([act.reshape(T, -1), self.contact_wrench.reshape(T, -1)], axis=1)


def contact_wrenches(model, data, body_ids: Sequence[int]) -> np.ndarray:
    """Contact wrench on each body, ``[len(body_ids), 6]``: force (world, N) and torque about
    the body origin (world, N m), summed over ``data.contact``.

    ``mj_contactForce`` returns the force of geom1 on geom2 in the contact frame (rows of
    ``contact.frame`` are the frame axes, normal first), so world force on geom2's body is
    ``frame.T @ f[:3]`` and geom1's body receives the opposite.
    """
    import mujoco

    out = np.zeros((len(body_ids), 6))
    index = {b: i for i, b in enumerate(body_ids)}
    f6 = np.zeros(6)
    for i in range(data.ncon):
        con = data.contact[i]
        mujoco.mj_contactForce(model, data, i, f6)
        frame = np.asarray(con.frame).reshape(3, 3)
        f = frame.T @ f6[:3]
        tq = frame.T @ f6[3:] if con.dim > 3 else np.zeros(3)
        for geom, sign in ((con.geom2, 1.0), (con.geom1, -1.0)):
            b = int(model.geom_bodyid[geom])
            if b in index:
                arm = np.asarray(con.pos) - data.xpos[b]
                out[index[b], :3] += sign * f
                out[index[b], 3:] += sign * (np.cross(arm, f) + tq)
    return out


def _initial_state(
    system: AnalyticSystem, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Random initial (qpos, qvel) for ``system``; systems with contact start in contact range."""
    if system.derivation == "rolling_disc":
        lean = rng.uniform(-0.3, 0.3)
        q = np.array([rng.uniform(-np.pi, np.pi), lean, rng.uniform(-np.pi, np.pi), 0.0, 0.0])
        spin = rng.choice([-1.0, 1.0]) * rng.uniform(15.0, 25.0)  # rad/s, above the critical speed
        u = np.array([rng.normal(0, 0.3), spin, rng.normal(0, 0.3)])
        return system.kane_to_mujoco(q, u)
    qpos, qvel = [], []
    for _, j in system.joints:
        if j.kind == "free":
            quat = rng.normal(size=4)
            quat /= np.linalg.norm(quat)
            z = rng.uniform(-0.5, 0.5)
            z = system.params.get("z0", z)  # drop height of contact scenes
            qpos += [np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), z]), quat]
            vel = rng.normal(0, 1.0, 3)
            if system.has_contact:
                vel[2] = -abs(vel[2]) - 1.0  # thrown down: hits the floor within ~0.1 s
            qvel += [vel, rng.normal(0, 3.0, 3)]
        elif j.kind == "hinge":
            qpos.append([rng.uniform(-np.pi, np.pi)])
            qvel.append([rng.normal(0, 2.0)])
        else:
            qpos.append([rng.uniform(-0.5, 0.5)])
            qvel.append([rng.normal(0, 1.0)])
    return np.concatenate(qpos), np.concatenate(qvel)


def simulate(
    system: AnalyticSystem, n_steps: int = 200, seed: int = 0, ctrl: np.ndarray | None = None
) -> Trajectory:
    """Simulate ``system`` in MuJoCo (Euler integrator) from a random initial state.

    Each step: set ``ctrl``, ``mj_forward`` (records qacc, actuator forces, contacts), then
    ``mj_Euler`` (qvel += dt qacc, then qpos integrated with the new qvel). The first
    ``system.settle_steps`` steps (zero control) are not recorded.

    Parameters
    ----------
    system : AnalyticSystem
    n_steps : int
        Number of recorded states T.
    seed : int
        Seeds the initial state and, when ``ctrl`` is None, uniform random controls in each
        actuator's ``ctrlrange`` drawn per step.
    ctrl : ndarray, shape [T, nu], optional

    Returns
    -------
    Trajectory
    """
    import mujoco

    model = mujoco.MjModel.from_xml_string(system.mjcf())
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    qpos0, qvel0 = _initial_state(system, rng)
    data.qpos[:] = qpos0
    data.qvel[:] = qvel0
    nu = model.nu
    if ctrl is None:
        lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
        ctrl = rng.uniform(lo, hi, size=(n_steps, nu)) if nu else np.zeros((n_steps, 0))
    ctrl = np.asarray(ctrl, float)
    if ctrl.shape != (n_steps, nu):
        raise ValueError(
            f"simulate({system.name!r}): ctrl must have shape [n_steps, nu] = [{n_steps}, {nu}], "
            f"got {ctrl.shape}"
        )
    body_ids = [model.body(n).id for n in system.wrench_bodies]
    T = n_steps
    rec = {
        k: np.zeros((T, n))
        for k, n in (
            ("qpos", model.nq),
            ("qvel", model.nv),
            ("qacc", model.nv),
            ("actuator_force", nu),
        )
    }
    wrench = np.zeros((T, len(body_ids), 6))
    ncon = np.zeros(T, dtype=int)
    time_ = np.zeros(T)
    for _ in range(system.settle_steps):
        data.ctrl[:] = 0.0
        mujoco.mj_step(model, data)
    for t in range(T):
        data.ctrl[:] = ctrl[t]
        mujoco.mj_forward(model, data)
        time_[t] = data.time
        rec["qpos"][t], rec["qvel"][t], rec["qacc"][t] = data.qpos, data.qvel, data.qacc
        rec["actuator_force"][t] = data.actuator_force
        wrench[t] = contact_wrenches(model, data, body_ids)
        ncon[t] = data.ncon
        mujoco.mj_Euler(model, data)
    return Trajectory(
        system,
        time_,
        rec["qpos"],
        rec["qvel"],
        rec["qacc"],
        ctrl.copy(),
        rec["actuator_force"],
        wrench,
        ncon,
    )

"""Cubli: a cube that jumps up and balances with reaction wheels (Gajamohan et al. 2012).

A solid cube (side 0.15 m) holds one, two or three flywheels on hinges along its body
axes x, y, z, each driven by a motor that doubles as the brake. Every trajectory is
one of two manoeuvres, chosen by its seed:

- **jump**: the cube lies on a face with one flywheel spinning; at a random frame the
  wheel is braked, its angular momentum tips the cube onto the edge parallel to the
  wheel's axis (short of it, onto it, or over it, depending on the random wheel speed),
  and the balance controller catches it on the edge when it gets there;
- **balance**: the cube starts tilted near its balancing point, on an edge (one wheel)
  or on a corner (two or three wheels), and the controller balances it against random
  motor disturbances; a large disturbance makes it fall and tumble.

The balance controller is a discrete LQR at the frame rate on the linearised
inverted-pendulum-with-reaction-wheel model of each tilt axis (Gajamohan et al. 2012,
eqs. 1-4): state (tilt, tilt rate, wheel speed), motor torque as input; on a corner
each horizontal axis has its own LQR and the wheel torques are the least-norm
solution giving the requested horizontal torque. Its parameters (mass, centre of
mass, inertia about the pivot) are read from the compiled model, so the shape and
density variants of Table 3 are controlled as well as the original.

Contact: the cube with the floor (friction 0.8) and with two static obstacles, a low
wall and a block, that a tumbling cube can hit. The flywheels are inside the cube
and do not collide.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import mujoco
import numpy as np
import scipy.linalg
from numba import njit

from mdgs.scenes._mjcf import STATIC_RGBA, Mjcf, place_free, yaw_quat
from mdgs.scenes._spec import SceneBuilder
from mdgs.scenes.controls import smooth_signal

__all__ = ["Cubli"]

_AXES = {"x": 0, "y": 1, "z": 2}
_WHEEL_EULER = {"x": (0, np.pi / 2, 0), "y": (np.pi / 2, 0, 0), "z": (0, 0, 0)}


@dataclass(frozen=True)
class Cubli(SceneBuilder):
    """Parameters of a Cubli scene (SI units)."""

    wheels: str = "xyz"
    """Which body axes carry a flywheel: 'x' (single), 'xy' (double), 'xyz' (triple)."""
    size: tuple[float, float, float] = (0.15, 0.15, 0.15)
    """Full edge lengths of the cube (m); the 'shape varied' variant changes them."""
    frame_mass: float = 0.8  # kg, the cube without its wheels
    wheel_mass: float = 0.25  # kg each
    wheel_radius: float = 0.045  # m
    wheel_half_thickness: float = 0.005  # m
    wheel_inset: float = 0.02  # m, wheel plane to the cube face
    torque_limit: float = 12.0  # N m, motor/brake limit (the brake needs it)
    balance_torque: float = 0.6  # N m, limit used by the balance controller
    noise_torque: float = 0.04  # N m, amplitude of motor disturbances
    intensity: float = 1.0
    """Scales disturbances, initial tilts/rates and jump strength (Table 3: 'more/less intense')."""
    p_jump: float = 0.5  # probability that a trajectory is a jump (else balance)
    timestep: float = 5e-4  # s
    substeps: int = 20  # 10 ms frames (100 Hz controller)

    # ---- MJCF ---------------------------------------------------------------------
    def mjcf(self) -> str:
        doc = Mjcf(f"cubli-{self.wheels}", timestep=self.timestep)
        w = doc.world
        doc.geom(w, "wall", "box", size=(0.02, 0.4, 0.06), pos=(0.42, 0, 0.06), rgba=STATIC_RGBA)
        doc.geom(
            w, "block", "box", size=(0.05, 0.05, 0.04), pos=(-0.3, 0.28, 0.04), euler=(0, 0, 0.4),
            rgba=STATIC_RGBA,
        )  # fmt: skip
        half = np.asarray(self.size) / 2
        cube = doc.free_object(
            "cube", "box", pos=(0, 0, half[2]), joint="root", size=half, mass=self.frame_mass,
            rgba=(0.75, 0.78, 0.82, 1),
        )  # fmt: skip
        for a in self.wheels:
            k = _AXES[a]
            off = np.zeros(3)
            off[k] = half[k] - self.wheel_inset
            wb = doc.body(cube, f"wheel_{a}", pos=off)
            doc.hinge(wb, f"spin_{a}", np.eye(3)[k])
            doc.geom(
                wb, f"wheel_{a}", "cylinder", size=(self.wheel_radius, self.wheel_half_thickness),
                euler=_WHEEL_EULER[a], mass=self.wheel_mass, contype=0, conaffinity=0,
                rgba=(0.85, 0.45, 0.2, 1),
            )  # fmt: skip
            limit = (-self.torque_limit, self.torque_limit)
            doc.actuate("motor", f"motor_{a}", f"spin_{a}", ctrlrange=limit)
        return doc.xml()

    # ---- geometry helpers ----------------------------------------------------------
    def _corners(self) -> np.ndarray:
        h = np.asarray(self.size) / 2
        return np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h

    def _params(self, model: mujoco.MjModel | None = None) -> dict:
        """System mass, centre of mass (cube frame) and inertia about it (all wheels locked)."""
        return _system_params(self)

    def _compute_params(self) -> dict:
        model = mujoco.MjModel.from_xml_string(self.mjcf())
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        cube = model.body("cube").id
        M = float(model.body_subtreemass[cube])
        com_w = data.subtree_com[cube].copy()
        R0 = data.xmat[cube].reshape(3, 3)
        I = np.zeros((3, 3))
        for b in range(cube, model.nbody):
            Rb = data.ximat[b].reshape(3, 3)
            d = data.xipos[b] - com_w
            I += Rb @ np.diag(model.body_inertia[b]) @ Rb.T + model.body_mass[b] * (
                d @ d * np.eye(3) - np.outer(d, d)
            )
        c = R0.T @ (com_w - data.xpos[cube])
        Iw = {
            a: float(model.body_inertia[model.body(f"wheel_{a}").id][_AXES[a]]) for a in self.wheels
        }
        return {"M": M, "com": c, "I": R0.T @ I @ R0, "Iw": Iw}

    # ---- initial state -------------------------------------------------------------
    def initial_state(
        self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator
    ) -> None:
        p = self._params(model)
        jump = rng.uniform() < self.p_jump
        s = self.intensity
        q = yaw_quat(rng.uniform(-np.pi, np.pi))
        qvel = np.zeros(model.nv)
        wheel_dofs = {a: model.jnt_dofadr[model.joint(f"spin_{a}").id] for a in self.wheels}
        if jump:
            a = self.wheels[rng.integers(len(self.wheels))]
            sign = rng.choice([-1.0, 1.0])
            omega = self._jump_speed(p, a) * rng.uniform(0.85, 1.2) * (1 + 0.3 * (s - 1))
            for b in self.wheels:
                qvel[wheel_dofs[b]] = sign * omega if b == a else rng.uniform(-30, 30) * s
        else:
            if len(self.wheels) == 1:
                # edge along x: rotate about x by +-45 deg plus a small error
                tilt = rng.choice([-1.0, 1.0]) * np.pi / 4 + rng.normal(0, 0.04 * s)
                qt = np.zeros(4)
                mujoco.mju_axisAngle2Quat(qt, np.array([1.0, 0, 0]), tilt)
            else:
                # a corner up: the diagonal (sx, sy, sz) goes to -z, plus a small tilt
                d = self._corner_to_com(p, rng.choice([-1.0, 1.0], 3))
                qt = _quat_between(d, np.array([0, 0, 1.0]))
                qe = np.zeros(4)
                err = rng.normal(0, 0.03 * s, 3)
                err[2] = 0
                mujoco.mju_axisAngle2Quat(
                    qe, err / max(np.linalg.norm(err), 1e-12), np.linalg.norm(err)
                )
                mujoco.mju_mulQuat(qt, qe, qt)
            mujoco.mju_mulQuat(q, q, qt)
            qvel[3:6] = rng.normal(0, 0.15 * s, 3)
            for b in self.wheels:
                qvel[wheel_dofs[b]] = rng.uniform(-40, 40) * s
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, q)
        zmin = (self._corners() @ R.reshape(3, 3).T)[:, 2].min()
        data.qpos[:] = model.qpos0
        x, y = rng.uniform(-0.08, 0.08), rng.uniform(-0.08, 0.08)
        place_free(model, data, "root", [x, y, -zmin], q)
        data.qvel[:] = qvel

    def _corner_to_com(self, p: dict, signs: np.ndarray) -> np.ndarray:
        corner = signs * np.asarray(self.size) / 2
        d = p["com"] - corner
        return d / np.linalg.norm(d)

    def _jump_speed(self, p: dict, a: str) -> float:
        """Wheel speed whose braked momentum lifts the cube from a face onto an edge (rad/s)."""
        k = _AXES[a]
        half = np.asarray(self.size) / 2
        o = [i for i in range(3) if i != k]
        edge = np.zeros(3)
        edge[o[0]], edge[o[1]] = half[o[0]], -half[o[1]]
        r = p["com"] - edge
        l = np.linalg.norm(r[o])
        Ia = _pivot_inertia(p, edge, np.eye(3)[k])
        dE = p["M"] * 9.81 * (l - (p["com"][o[1]] + half[o[1]]))
        return float(np.sqrt(2 * Ia * dE) / p["Iw"][a])

    # ---- controls ------------------------------------------------------------------
    def controller(self, model, rngs, n_frames, qpos0) -> _CubliController:
        """Closed loop: the balance controller (overrides :meth:`SceneBuilder.controller`)."""
        return _CubliController(self, model, rngs, n_frames)


@lru_cache(maxsize=64)
def _system_params(cubli: Cubli) -> dict:
    return cubli._compute_params()


def _quat_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Unit quaternion rotating unit vector a onto b."""
    v = np.cross(a, b)
    c = float(a @ b)
    q = np.r_[1 + c, v]
    if np.linalg.norm(q) < 1e-9:
        q = np.r_[0, np.cross(a, [1, 0, 0]) if abs(a[0]) < 0.9 else np.cross(a, [0, 1, 0])]
    return q / np.linalg.norm(q)


def _pivot_inertia(p: dict, pivot: np.ndarray, axis: np.ndarray) -> float:
    """Inertia of the locked system about ``axis`` through ``pivot`` minus the wheels' spin inertia."""
    d = p["com"] - pivot
    I = p["I"] + p["M"] * (d @ d * np.eye(3) - np.outer(d, d))
    spin = sum(p["Iw"][a] * axis[_AXES[a]] ** 2 for a in p["Iw"])
    return float(axis @ I @ axis - spin)


def _lqr_gain(M: float, l: float, Ia: float, Iw: float, dt: float) -> np.ndarray:
    """Discrete LQR gain for x = (tilt, tilt rate, wheel speed), u = motor torque.

    Ia th'' = M g l th - u;  Iw (th'' + psi'') = u  (Gajamohan et al. 2012, linearised).
    """
    g = 9.81
    A = np.array([[0, 1, 0], [M * g * l / Ia, 0, 0], [-M * g * l / Ia, 0, 0]])
    B = np.array([[0], [-1 / Ia], [1 / Iw + 1 / Ia]])
    n = 3
    E = scipy.linalg.expm(np.block([[A, B], [np.zeros((1, n + 1))]]) * dt)
    Ad, Bd = E[:n, :n], E[:n, n:]
    Q = np.diag([1 / 0.03**2, 1 / 0.5**2, 1 / 300.0**2])
    Rc = np.array([[1 / 0.3**2]])
    P = scipy.linalg.solve_discrete_are(Ad, Bd, Q, Rc)
    return np.linalg.solve(Rc + Bd.T @ P @ Bd, Bd.T @ P @ Ad)[0]


@lru_cache(maxsize=64)
def _gains(cubli: Cubli) -> tuple[np.ndarray, np.ndarray]:
    """LQR gains: edge balance per wheel axis [nw, 3], corner balance (both horizontal axes) [3]."""
    p = _system_params(cubli)
    dt = cubli.frame_dt
    half = np.asarray(cubli.size) / 2
    K_edge = []
    for a in cubli.wheels:
        k = _AXES[a]
        o = [i for i in range(3) if i != k]
        edge = np.zeros(3)
        edge[o[0]], edge[o[1]] = half[o[0]], -half[o[1]]
        l = float(np.linalg.norm((p["com"] - edge)[o]))
        K_edge.append(_lqr_gain(p["M"], l, _pivot_inertia(p, edge, np.eye(3)[k]), p["Iw"][a], dt))
    corner = -half
    l = float(np.linalg.norm(p["com"] - corner))
    d = (p["com"] - corner) / l
    u = np.cross(d, [1.0, 0, 0])
    u /= np.linalg.norm(u)
    Iw = float(np.mean([p["Iw"][a] for a in cubli.wheels]))
    return np.array(K_edge), _lqr_gain(p["M"], l, _pivot_inertia(p, corner, u), Iw, dt)


class _CubliController:
    """Brake (jump trajectories), then LQR balance when the tilt is within capture range."""

    closed_loop = True
    capture = 0.25  # rad, largest tilt the balance controller acts on

    def __init__(
        self,
        cubli: Cubli,
        model: mujoco.MjModel,
        rngs: Sequence[np.random.Generator],
        n_frames: int,
    ):
        self.c = cubli
        p = cubli._params(model)
        self.p = p
        self.dt = cubli.frame_dt
        self.nw = len(cubli.wheels)
        self.k_axis = np.array([_AXES[a] for a in cubli.wheels])
        self.dofs = np.array([model.jnt_dofadr[model.joint(f"spin_{a}").id] for a in cubli.wheels])
        self.qadr = None
        self.Iw = np.array([p["Iw"][a] for a in cubli.wheels])
        R = len(rngs)
        s = cubli.intensity
        # per-trajectory choices (drawn after initial_state used the same generators)
        self.noise = (
            np.stack(
                [smooth_signal(r, n_frames, self.dt, self.nw, fmin=0.5, fmax=4.0) for r in rngs]
            )
            * cubli.noise_torque
            * s
        )
        kicks = np.stack([r.uniform(0, 1) < 0.25 * s for r in rngs])
        kick_frame = np.array([r.integers(30, max(31, n_frames - 20)) for r in rngs])
        kick = np.stack([r.normal(0, 1.2 * s, self.nw) for r in rngs])
        for i in range(R):
            if kicks[i]:
                self.noise[i, kick_frame[i] : kick_frame[i] + 3] += kick[i]
        self.brake_frame = np.array([r.integers(3, max(4, n_frames // 3)) for r in rngs])
        self.K_edge, self.K_corner = _gains(cubli)
        self.corners = cubli._corners()

    def __call__(self, frame: int, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        c = self.c
        tau = np.empty((qpos.shape[0], self.nw))
        _control(
            frame, np.ascontiguousarray(qpos), np.ascontiguousarray(qvel), self.noise,
            self.brake_frame, np.asarray(self.p["com"], float), self.corners, self.k_axis,
            self.dofs, self.Iw, self.K_edge, np.asarray(self.K_corner, float), self.dt,
            float(c.torque_limit), float(c.balance_torque), float(self.capture),
            float(min(c.size)), tau,
        )  # fmt: skip
        return tau


@njit(cache=True, nogil=True)
def _control(frame, qpos, qvel, noise, brake_frame, com_b, corners_b, k_axis, dofs, Iw, K_edge, K_corner, dt, torque_limit, balance_torque, capture, side, tau):  # pragma: no cover  # fmt: skip
    """Wheel torques ``tau [R, nw]`` of :class:`_CubliController` for state ``qpos``, ``qvel``.

    Per trajectory: the frame's disturbance; braking (two frames from ``brake_frame``):
    the torque that stops the wheels, instead; on an edge (two corners lowest, the
    third clearly higher) the LQR of the wheel aligned with the edge on (tilt, tilt
    rate, wheel speed); on a corner (one clearly lowest, two or more wheels) one LQR per
    horizontal world axis, wheel torques the least-norm solution for the requested
    horizontal torque. Balance torques are limited to ``balance_torque`` and act only
    within ``capture`` rad of the balancing point; the total to ``torque_limit``.
    """
    nw = len(k_axis)
    Rm = np.empty((3, 3))
    zc = np.empty(8)
    pc = np.empty((8, 3))
    axes = np.empty((nw, 3))
    for r in range(qpos.shape[0]):
        w, x, y, z = qpos[r, 3], qpos[r, 4], qpos[r, 5], qpos[r, 6]
        Rm[0, 0], Rm[0, 1], Rm[0, 2] = (
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
        )
        Rm[1, 0], Rm[1, 1], Rm[1, 2] = (
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
        )
        Rm[2, 0], Rm[2, 1], Rm[2, 2] = (
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        )
        com = np.empty(3)
        omega = np.empty(3)
        for i in range(3):
            com[i] = qpos[r, i] + (Rm[i, 0] * com_b[0] + Rm[i, 1] * com_b[1] + Rm[i, 2] * com_b[2])
            omega[i] = Rm[i, 0] * qvel[r, 3] + Rm[i, 1] * qvel[r, 4] + Rm[i, 2] * qvel[r, 5]
        for j in range(nw):
            for i in range(3):
                axes[j, i] = Rm[i, k_axis[j]]
        for k in range(8):
            for i in range(3):
                pc[k, i] = qpos[r, i] + (
                    Rm[i, 0] * corners_b[k, 0]
                    + Rm[i, 1] * corners_b[k, 1]
                    + Rm[i, 2] * corners_b[k, 2]
                )
            zc[k] = pc[k, 2]
        order = np.argsort(zc)
        z0, z1, z2 = zc[order[0]], zc[order[1]], zc[order[2]]
        for j in range(nw):
            tau[r, j] = noise[r, frame, j]
        braking = brake_frame[r] <= frame < brake_frame[r] + 2
        if braking:
            for j in range(nw):
                tau[r, j] = min(max(-qvel[r, dofs[j]] * Iw[j] / dt, -torque_limit), torque_limit)
        on_corner = z1 - z0 > 0.25 * side and nw >= 2
        on_edge = z1 - z0 < 0.01 and z2 - z1 > 0.25 * side
        if on_edge and not braking:
            a0, a1 = pc[order[0]], pc[order[1]]
            e = a1 - a0
            e /= np.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
            best, wb = -1.0, 0
            for j in range(nw):
                al = abs(axes[j, 0] * e[0] + axes[j, 1] * e[1] + axes[j, 2] * e[2])
                if al > best:
                    best, wb = al, j
            a = axes[wb]
            rv = com - (a0 + a1) / 2
            ra = rv[0] * a[0] + rv[1] * a[1] + rv[2] * a[2]
            rp = rv - ra * a
            th = np.arctan2(-rp[1] * a[0] + rp[0] * a[1], rp[2])
            thd = omega[0] * a[0] + omega[1] * a[1] + omega[2] * a[2]
            ps = qvel[r, dofs[wb]]
            u = -(K_edge[wb, 0] * th + K_edge[wb, 1] * thd + K_edge[wb, 2] * ps)
            if best > 0.95 and abs(th) < capture:
                tau[r, wb] += min(max(u, -balance_torque), balance_torque)
        if on_corner and not braking:
            rv = com - pc[order[0]]
            nr = np.sqrt(rv[0] * rv[0] + rv[1] * rv[1] + rv[2] * rv[2])
            tx, ty = -rv[1] / nr, rv[0] / nr
            th_mag = np.arcsin(min(max(np.sqrt(tx * tx + ty * ty), 0.0), 1.0))
            if th_mag < capture and rv[2] > 0:
                hx = hy = 0.0
                for j in range(nw):
                    hx += qvel[r, dofs[j]] * axes[j, 0]
                    hy += qvel[r, dofs[j]] * axes[j, 1]
                # per horizontal axis (world x, y): x_k = (tilt, tilt rate, wheel momentum)
                T0 = -(tx * K_corner[0] + omega[0] * K_corner[1] + hx * K_corner[2])
                T1 = -(ty * K_corner[0] + omega[1] * K_corner[1] + hy * K_corner[2])
                # least-norm wheel torques: A^T (A A^T)^-1 T, A = horizontal wheel axes [2, nw]
                m00 = m01 = m11 = 0.0
                for j in range(nw):
                    m00 += axes[j, 0] * axes[j, 0]
                    m01 += axes[j, 0] * axes[j, 1]
                    m11 += axes[j, 1] * axes[j, 1]
                det = m00 * m11 - m01 * m01
                y0 = (m11 * T0 - m01 * T1) / det
                y1 = (m00 * T1 - m01 * T0) / det
                big = 0.0
                for j in range(nw):
                    big = max(big, abs(axes[j, 0] * y0 + axes[j, 1] * y1))
                scale = max(1.0, big / balance_torque)
                for j in range(nw):
                    tau[r, j] += (axes[j, 0] * y0 + axes[j, 1] * y1) / scale
        for j in range(nw):
            tau[r, j] = min(max(tau[r, j], -torque_limit), torque_limit)

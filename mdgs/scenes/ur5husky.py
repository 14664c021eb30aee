"""UR5-Husky: a skid-steered four-wheeled base carrying a 6-DoF arm of UR5 size (Table 2).

The base has Husky dimensions (0.80 x 0.56 m chassis, 50 kg, wheels of radius 0.165 m
driven by velocity servos, left pair and right pair together). The arm has the UR5's
link lengths (shoulder 0.089, upper arm 0.425, forearm 0.392, wrist offsets 0.109 /
0.095 / 0.082 m) and link masses (3.7, 8.39, 2.28, 1.22, 1.22, 0.19 kg); its joints are
position servos with reflected motor inertia (``armature``). The base drives with
smooth random forward speed and yaw rate while the arm tracks smooth random joint
targets.

- **original**: base and arm on a flat floor;
- **interaction**: a table in front of the robot with a box and a cylinder on it; the
  base creeps forward and the arm sweeps over the table top, pushing the objects.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from mdgs.scenes._mjcf import (
    WHEELS,
    Mjcf,
    actuator_names,
    at_rest,
    box_volume,
    capsule_volume,
    cylinder_volume,
    place_free,
    yaw_quat,
)
from mdgs.scenes._spec import SceneBuilder
from mdgs.scenes.controls import smooth_signal, smooth_targets

__all__ = ["UR5Husky"]

# UR5 links: name, joint axis, position in the parent, geom (type, radius, half length,
# position), mass (kg), servo kp (N m/rad), kv (N m s/rad), armature (kg m^2), joint range (rad)
# fmt: off
_UR5 = (
    ("shoulder", (0, 0, 1), (0, 0, 0.089159), ("cylinder", 0.06, 0.06, (0, 0, 0)),
     3.7, 400.0, 40.0, 0.4, (-3.1, 3.1)),
    ("upper_arm", (0, 1, 0), (0, 0.13585, 0), ("capsule", 0.054, 0.2125, (0, 0, 0.2125)),
     8.393, 400.0, 40.0, 0.4, (-1.6, 1.6)),
    ("forearm", (0, 1, 0), (0, -0.1197, 0.425), ("capsule", 0.04, 0.196, (0, 0, 0.196)),
     2.275, 200.0, 20.0, 0.2, (-2.4, 2.4)),
    ("wrist_1", (0, 1, 0), (0, 0, 0.39225), ("cylinder", 0.038, 0.047, (0, 0.047, 0)),
     1.219, 40.0, 4.0, 0.05, (-3.1, 3.1)),
    ("wrist_2", (0, 0, 1), (0, 0.093, 0), ("cylinder", 0.038, 0.047, (0, 0, 0.047)),
     1.219, 40.0, 4.0, 0.05, (-3.1, 3.1)),
    ("wrist_3", (0, 1, 0), (0, 0, 0.09465), ("cylinder", 0.032, 0.041, (0, 0.041, 0)),
     0.1879, 20.0, 2.0, 0.02, (-3.1, 3.1)),
)
# fmt: on


@dataclass(frozen=True)
class UR5Husky(SceneBuilder):
    """Parameters of the UR5-Husky scenes (SI units)."""

    interaction: bool = False
    chassis_half: tuple[float, float, float] = (0.40, 0.28, 0.09)
    chassis_mass: float = 50.0
    wheel_radius: float = 0.165
    wheel_half_width: float = 0.05
    wheel_mass: float = 2.5
    wheelbase_half: float = 0.256
    track_half: float = 0.34
    drive_kv: float = 4.0  # N m s / rad
    drive_torque: float = 40.0  # N m
    timestep: float = 5e-4
    substeps: int = 40  # 20 ms frames

    def mjcf(self) -> str:
        doc = Mjcf(
            "ur5husky-interaction" if self.interaction else "ur5husky", timestep=self.timestep
        )
        w = doc.world
        if self.interaction:
            doc.geom(
                w, "table", "box", size=(0.3, 0.45, 0.225), pos=(1.15, 0, 0.225),
                rgba=(0.55, 0.45, 0.35, 1),
            )  # fmt: skip
            doc.free_object(
                "box", "box", pos=(0.95, 0.18, 0.45 + 0.05), size=(0.05, 0.05, 0.05), mass=1.0,
                rgba=(0.85, 0.3, 0.25, 1),
            )  # fmt: skip
            doc.free_object(
                "can", "cylinder", pos=(0.95, -0.18, 0.45 + 0.06), size=(0.04, 0.06), mass=0.6,
                rgba=(0.3, 0.6, 0.35, 1),
            )  # fmt: skip
        ch = np.asarray(self.chassis_half)
        base = doc.free_body("husky", pos=(0, 0, self.wheel_radius + 0.02), joint="root")
        mount = (0.075, 0.05)  # UR5 base cylinder: radius, half height
        rho = self.chassis_mass / (box_volume(ch) + cylinder_volume(*mount))
        doc.geom(base, "chassis", "box", size=ch, density=rho, rgba=(0.85, 0.7, 0.1, 1))
        doc.geom(
            base, "ur5_base", "cylinder", size=mount, pos=(0.15, 0, ch[2] + mount[1]), density=rho,
            rgba=(0.6, 0.6, 0.65, 1),
        )  # fmt: skip
        drive = (self.drive_kv, 12, self.drive_torque)  # targets within +-12 rad/s
        for tag, x, y in WHEELS:
            doc.wheel(
                base, tag, (x * self.wheelbase_half, y * self.track_half, -0.02), self.wheel_radius,
                self.wheel_half_width, drive=drive, mass=self.wheel_mass,
                friction=(1.0, 0.005, 0.0001), rgba=(0.12, 0.12, 0.12, 1),
            )  # fmt: skip
        parent, pos = base, (0.15, 0, ch[2] + 2 * mount[1])
        for name, axis, offset, (gtype, r, hl, gpos), mass, kp, kv, arm, rng in _UR5:
            body = doc.body(
                parent, name, pos=tuple(np.add(pos, offset)) if parent is base else offset
            )
            doc.hinge(body, name, axis, range=rng, armature=arm)
            vol = capsule_volume(r, hl) if gtype == "capsule" else cylinder_volume(r, hl)
            # cylinders of the wrist lie along their joint axis (y or z), capsules along the link (z)
            euler = (np.pi / 2, 0, 0) if (gtype == "cylinder" and axis == (0, 1, 0)) else (0, 0, 0)
            doc.geom(
                body, name, gtype, size=(r, hl), pos=gpos, euler=euler, density=mass / vol,
                rgba=(0.7, 0.75, 0.8, 1),
            )  # fmt: skip
            doc.actuate("position", name, name, kp=kp, kv=kv, ctrlrange=rng)
            parent, pos = body, (0, 0, 0)
        return doc.xml()

    def _arm_box(self) -> tuple[np.ndarray, np.ndarray]:
        """Target ranges: the arm above the base (original) or reaching over the table."""
        if self.interaction:
            return np.array([-0.6, 0.3, 0.0, -1.5, -1.5, -3.0]), np.array(
                [0.6, 1.3, 1.5, 0.5, 1.5, 3.0]
            )
        return np.array([-3.0, -1.2, -2.0, -2.0, -2.0, -3.0]), np.array(
            [3.0, 1.2, 2.0, 2.0, 2.0, 3.0]
        )

    def initial_state(
        self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator
    ) -> None:
        at_rest(model, data)
        yaw = rng.uniform(-0.25, 0.25) if self.interaction else rng.uniform(-np.pi, np.pi)
        x, y = rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1)
        place_free(model, data, "root", [x, y, self.wheel_radius + 0.02 + 1e-4], yaw_quat(yaw))
        lo, hi = self._arm_box()
        qadr = [model.jnt_qposadr[model.joint(name).id] for name, *_ in _UR5]
        for _ in range(50):  # an arm pose that touches nothing (resampled from the same stream)
            for i, a in enumerate(qadr):
                data.qpos[a] = rng.uniform(0.8 * lo[i] + 0.2 * hi[i], 0.6 * lo[i] + 0.4 * hi[i])
            mujoco.mj_forward(model, data)
            if all(data.contact[i].dist > -1e-3 for i in range(data.ncon)):
                break

    def controls(
        self, model: mujoco.MjModel, rng: np.random.Generator, qpos0: np.ndarray, n_frames: int
    ) -> np.ndarray:
        """Arm: smooth joint targets from the initial pose; base: smooth speed and yaw rate."""
        dt = self.frame_dt
        names = actuator_names(model)
        arm_idx = [names.index(n) for n, *_ in _UR5]
        qadr = np.array([model.jnt_qposadr[model.joint(n).id] for n, *_ in _UR5])
        lo, hi = self._arm_box()
        u = np.zeros((n_frames, model.nu))
        u[:, arm_idx] = smooth_targets(
            rng, n_frames, dt, lo, hi, start=qpos0[qadr], fmin=0.1, fmax=0.6
        )
        s = smooth_signal(rng, n_frames, dt, 2, fmin=0.1, fmax=0.6)
        v = (0.15 + 0.15 * s[:, 0]) if self.interaction else 0.8 * s[:, 0]  # m/s
        yaw_rate = (0.2 if self.interaction else 0.8) * s[:, 1]  # rad/s
        for a, name in enumerate(names):
            if name.startswith("drive"):
                side = 1.0 if name.endswith("l") else -1.0
                u[:, a] = (v - side * yaw_rate * self.track_half) / self.wheel_radius
        return u

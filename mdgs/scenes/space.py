"""Space robot: a free-floating satellite base with 6-DoF arms, no gravity (Wang et al. 2022).

The base is a 0.5 m cube (100 kg) with a free joint; each arm is a 6R chain (yaw,
pitch, pitch, roll, pitch, roll; links 0.12/0.45/0.40/0.10/0.10/0.08 m, 12 kg in all)
ending in a two-finger gripper block. Joint servos (position actuators with velocity
feedback, reflected motor inertia as ``armature``) track smooth random joint targets,
so every motion of an arm makes the base counter-rotate and drift: momentum is
conserved, which is what these datasets test.

- **single**: one arm on the +x face;
- **double**: a second arm on the -x face;
- **strike**: one arm, and a free 4 kg box thrown at the robot (random direction,
  1-3 m/s) that hits the base or the arm and bounces off.

Contacts: links with the base and with each other (not with their parent link), and
the thrown box with everything.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from mdgs.scenes._mjcf import Mjcf, at_rest, box_volume, capsule_volume, place_free
from mdgs.scenes._spec import SceneBuilder
from mdgs.scenes.controls import smooth_targets

__all__ = ["SpaceRobot"]

# (name, joint axis, offset from the parent joint, link vector, radius, mass, ctrl range)
_ARM = (
    ("yaw", (0, 0, 1), (0, 0, 0.0), (0, 0, 0.12), 0.05, 3.0, (-2.5, 2.5)),
    ("shoulder", (0, 1, 0), (0, 0, 0.12), (0, 0, 0.45), 0.045, 3.5, (-1.6, 1.6)),
    ("elbow", (0, 1, 0), (0, 0, 0.45), (0, 0, 0.40), 0.04, 2.5, (-2.2, 2.2)),
    ("wrist_roll", (0, 0, 1), (0, 0, 0.40), (0, 0, 0.10), 0.035, 1.0, (-2.5, 2.5)),
    ("wrist_pitch", (0, 1, 0), (0, 0, 0.10), (0, 0, 0.10), 0.035, 1.0, (-1.8, 1.8)),
    ("flange", (0, 0, 1), (0, 0, 0.10), (0, 0, 0.08), 0.03, 1.0, (-2.5, 2.5)),
)
_GRIPPER = (0.06, 0.02, 0.03)  # half sizes of the gripper block (m)


@dataclass(frozen=True)
class SpaceRobot(SceneBuilder):
    """Parameters of the space-robot scenes (SI units)."""

    arms: int = 1
    """Number of arms (1 on +x, 2 adds one on -x)."""
    strike: bool = False
    """Throw a free box at the robot."""
    base_half: float = 0.25
    base_mass: float = 100.0
    kp: float = 60.0  # N m / rad, servo stiffness
    kv: float = 12.0  # N m s / rad, servo damping
    armature: float = 0.2  # kg m^2, reflected motor inertia per joint
    projectile_mass: float = 4.0
    timestep: float = 5e-4
    substeps: int = 40  # 20 ms frames: 2.2 s per trajectory

    def mjcf(self) -> str:
        doc = Mjcf("space-robot", timestep=self.timestep, gravity=(0, 0, 0), floor=False)
        base = doc.free_object(
            "base", "box", pos=(0, 0, 1.5), joint="root", size=(self.base_half,) * 3,
            mass=self.base_mass, rgba=(0.8, 0.75, 0.45, 1),
        )  # fmt: skip
        for k in range(self.arms):
            s = 1 if k == 0 else -1
            tag = "a" if k == 0 else "b"
            mount = doc.body(
                base, f"{tag}_mount", pos=(s * (self.base_half + 0.05), 0, 0),
                euler=(0, s * np.pi / 2, 0),
            )  # fmt: skip
            doc.geom(
                mount, f"{tag}_mount", "cylinder", size=(0.06, 0.05), mass=2.0,
                rgba=(0.4, 0.4, 0.45, 1),
            )  # fmt: skip
            parent = mount
            offset = (0, 0, 0.05)
            for name, axis, _off, vec, rad, mass, rng in _ARM:
                link = f"{tag}_{name}"
                body = doc.body(parent, link, pos=offset)
                doc.hinge(body, link, axis, range=rng, armature=self.armature)
                # one density per body (the partition's uniform-density elements match MuJoCo exactly)
                length = float(np.linalg.norm(vec))
                volume = capsule_volume(rad, length / 2) + (
                    box_volume(_GRIPPER) if name == "flange" else 0.0
                )
                rho = mass / volume
                doc.geom(
                    body, link, "capsule", fromto=(0, 0, 0) + tuple(vec), size=rad, density=rho,
                    rgba=(0.75, 0.78, 0.82, 1),
                )  # fmt: skip
                if name == "flange":
                    doc.geom(
                        body, f"{tag}_gripper", "box", size=_GRIPPER, pos=(0, 0, 0.11),
                        density=rho, rgba=(0.3, 0.3, 0.35, 1),
                    )  # fmt: skip
                doc.actuate("position", link, link, kp=self.kp, kv=self.kv, ctrlrange=rng)
                parent, offset = body, vec
        if self.strike:
            doc.free_object(
                "projectile", "box", pos=(2.0, 0, 1.5), size=(0.08, 0.08, 0.08),
                mass=self.projectile_mass, rgba=(0.85, 0.3, 0.25, 1),
            )  # fmt: skip
        return doc.xml()

    def initial_state(
        self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator
    ) -> None:
        at_rest(model, data)
        for a in range(model.nu):
            j = model.actuator_trnid[a, 0]
            lo, hi = model.jnt_range[j]
            data.qpos[model.jnt_qposadr[j]] = rng.uniform(0.5 * lo, 0.5 * hi)
        data.qvel[3:6] = rng.normal(0, 0.02, 3)  # slow tumble of the base
        if self.strike:
            dadr = model.jnt_dofadr[model.joint("projectile").id]
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            start = np.array([0, 0, 1.5]) + 1.6 * d
            aim = np.array([0, 0, 1.5]) + rng.normal(0, 0.25, 3)
            v = aim - start
            place_free(model, data, "projectile", start, [1, 0, 0, 0])
            data.qvel[dadr : dadr + 3] = rng.uniform(1.0, 3.0) * v / np.linalg.norm(v)
            data.qvel[dadr + 3 : dadr + 6] = rng.normal(0, 2, 3)
        # start the servos at the current joint angles (no initial jerk)
        for a in range(model.nu):
            data.ctrl[a] = data.qpos[model.jnt_qposadr[model.actuator_trnid[a, 0]]]

    def controls(
        self, model: mujoco.MjModel, rng: np.random.Generator, qpos0: np.ndarray, n_frames: int
    ) -> np.ndarray:
        """Smooth joint targets, starting at the initial joint angles (no initial jerk)."""
        lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
        q0 = qpos0[model.jnt_qposadr[model.actuator_trnid[:, 0]]]
        return smooth_targets(rng, n_frames, self.frame_dt, lo, hi, start=q0, fmin=0.1, fmax=0.8)

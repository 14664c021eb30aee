"""Complex rotational body: a gyroscopic assembly with a bearing, and hinges (Table 1).

A hub (a base disc with a column) is free on the floor. A rotor (disc and boss) turns
in a bearing on top of the column, driven by a motor, so the assembly is a gyroscope
that wobbles, precesses, tips and rolls on the floor and bumps into two static posts.
The three variants differ in their hinges:

- **none**: hub and rotor only (the bearing is the only internal joint);
- **side**: two arms hinged at opposite sides of the base disc (axes tangential, like a
  flyball governor), swung by position servos;
- **center**: the column is cut in the middle by a hinge (axis horizontal) whose motor
  tilts the upper half, with the spinning rotor, relative to the base: large
  gyroscopic torques.

Every trajectory starts with the hub resting on its base, a random spin about the
vertical and a small tilt; rotor torque and hinge targets are smooth random signals.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from mdgs.scenes._mjcf import Mjcf, lift_out_of_contact
from mdgs.scenes.controls import OpenLoop, smooth_signal, smooth_targets

__all__ = ["RotationalBody"]


@dataclass(frozen=True)
class RotationalBody:
    """Parameters of the rotational-body scenes (SI units)."""

    hinges: str = "none"
    """'none', 'side' (two flapping arms) or 'center' (the column folds)."""
    base_radius: float = 0.1
    base_half_height: float = 0.025
    column_radius: float = 0.025
    column_half_length: float = 0.08
    rotor_radius: float = 0.13
    rotor_half_thickness: float = 0.012
    density: float = 2700.0  # kg/m^3, aluminium
    rotor_torque: float = 1.0  # N m, bearing motor limit
    fold_torque: float = 4.0  # N m, centre hinge motor limit
    arm_half_length: float = 0.07
    arm_radius: float = 0.015
    spin_max: float = 8.0  # rad/s, initial spin of the hub about the vertical
    tilt_max: float = 0.9  # rad, initial tilt: the hub starts on its rim, like a spinning coin
    timestep: float = 5e-4
    substeps: int = 20  # 10 ms frames

    def mjcf(self) -> str:
        doc = Mjcf(f"rotational-{self.hinges}", timestep=self.timestep)
        w = doc.world
        for i, (x, y) in enumerate([(0.45, 0.1), (-0.3, -0.4)]):
            doc.el(
                w,
                "geom",
                name=f"post{i}",
                type="cylinder",
                size=(0.05, 0.1),
                pos=(x, y, 0.1),
                rgba=(0.55, 0.5, 0.45, 1),
            )
        hub = doc.body(w, "hub", pos=(0, 0, self.base_half_height))
        doc.el(hub, "freejoint", name="root")
        d = self.density
        doc.el(
            hub,
            "geom",
            name="base",
            type="cylinder",
            size=(self.base_radius, self.base_half_height),
            density=d,
            rgba=(0.6, 0.65, 0.75, 1),
        )
        col_bottom = self.base_half_height
        split = self.hinges == "center"
        L = self.column_half_length
        if split:
            doc.el(
                hub,
                "geom",
                name="column_low",
                type="cylinder",
                size=(self.column_radius, L / 2),
                pos=(0, 0, col_bottom + L / 2),
                density=d,
                rgba=(0.6, 0.65, 0.75, 1),
            )
            upper = doc.body(hub, "upper", pos=(0, 0, col_bottom + L))
            doc.el(upper, "joint", name="fold", type="hinge", axis=(1, 0, 0), range=(-1.0, 1.0))
            doc.el(
                upper,
                "geom",
                name="column_up",
                type="cylinder",
                size=(self.column_radius, L / 2),
                pos=(0, 0, L / 2),
                density=d,
                rgba=(0.5, 0.55, 0.7, 1),
            )
            top, top_z = upper, L
            doc.el(
                doc.actuator,
                "motor",
                name="fold",
                joint="fold",
                ctrlrange=(-self.fold_torque, self.fold_torque),
            )
        else:
            doc.el(
                hub,
                "geom",
                name="column",
                type="cylinder",
                size=(self.column_radius, L),
                pos=(0, 0, col_bottom + L),
                density=d,
                rgba=(0.6, 0.65, 0.75, 1),
            )
            top, top_z = hub, col_bottom + 2 * L
        rotor = doc.body(top, "rotor", pos=(0, 0, top_z + self.rotor_half_thickness + 0.002))
        doc.el(rotor, "joint", name="bearing", type="hinge", axis=(0, 0, 1))
        doc.el(
            rotor,
            "geom",
            name="disc",
            type="cylinder",
            size=(self.rotor_radius, self.rotor_half_thickness),
            density=d,
            rgba=(0.85, 0.45, 0.2, 1),
        )
        doc.el(
            rotor,
            "geom",
            name="boss",
            type="cylinder",
            size=(0.03, 0.02),
            pos=(0, 0, self.rotor_half_thickness + 0.02),
            density=d,
            rgba=(0.85, 0.45, 0.2, 1),
        )
        doc.el(
            doc.actuator,
            "motor",
            name="bearing",
            joint="bearing",
            ctrlrange=(-self.rotor_torque, self.rotor_torque),
        )
        if self.hinges == "side":
            for s, name in ((1, "arm_pos"), (-1, "arm_neg")):
                arm = doc.body(hub, name, pos=(s * self.base_radius, 0, self.base_half_height))
                doc.el(
                    arm,
                    "joint",
                    name=f"{name}_hinge",
                    type="hinge",
                    axis=(0, 1, 0),
                    range=(-1.4, 1.4),
                )
                doc.el(
                    arm,
                    "geom",
                    name=name,
                    type="capsule",
                    fromto=(0, 0, 0, s * 2 * self.arm_half_length, 0, 0),
                    size=self.arm_radius,
                    density=d,
                    rgba=(0.4, 0.6, 0.4, 1),
                )
                doc.el(
                    doc.actuator,
                    "position",
                    name=name,
                    joint=f"{name}_hinge",
                    kp=6.0,
                    kv=0.15,
                    ctrlrange=(-1.2, 1.2),
                )
        return doc.xml()

    def initial_state(
        self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator
    ) -> None:
        data.qpos[:] = model.qpos0
        # on its rim: tilt about a random horizontal axis, spin about the vertical
        tilt = rng.uniform(0.1, self.tilt_max)
        heading = rng.uniform(-np.pi, np.pi)
        q = np.zeros(4)
        mujoco.mju_axisAngle2Quat(q, np.array([np.cos(heading), np.sin(heading), 0.0]), tilt)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, q)
        up = R.reshape(3, 3)[:, 2]
        rim = self.base_radius * np.sqrt(max(0.0, 1 - up[2] ** 2)) + self.base_half_height * up[2]
        data.qpos[0:3] = [rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rim + 1e-4]
        data.qpos[3:7] = q
        data.qvel[:] = 0
        spin_world = (
            np.array([0.0, 0.0, rng.uniform(-1, 1) * self.spin_max])
            + np.r_[rng.normal(0, 0.5, 2), 0]
        )
        data.qvel[3:6] = R.reshape(3, 3).T @ spin_world  # free joint angular velocity is local
        data.qvel[0:2] = rng.normal(0, 0.2, 2)
        data.qvel[model.jnt_dofadr[model.joint("bearing").id]] = rng.uniform(-100, 100)
        lift_out_of_contact(model, data, 2)  # the arms may reach below the rim

    def controller(
        self,
        model: mujoco.MjModel,
        rngs: Sequence[np.random.Generator],
        n_frames: int,
        qpos0: np.ndarray,
    ) -> OpenLoop:
        dt = self.timestep * self.substeps
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in range(model.nu)]
        lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]

        def make(rng):
            u = np.zeros((n_frames, model.nu))
            for a, name in enumerate(names):
                if name in ("bearing", "fold"):
                    u[:, a] = hi[a] * smooth_signal(rng, n_frames, dt, 1, fmin=0.3, fmax=2.5)[:, 0]
                else:
                    u[:, a] = smooth_targets(
                        rng, n_frames, dt, lo[a : a + 1], hi[a : a + 1], fmin=0.5, fmax=3.0
                    )[:, 0]
            return u

        return OpenLoop(np.stack([make(r) for r in rngs]))

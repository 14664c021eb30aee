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

from dataclasses import dataclass

import mujoco
import numpy as np

from mdgs.scenes._mjcf import (
    STATIC_RGBA,
    Mjcf,
    actuator_names,
    at_rest,
    lift_out_of_contact,
    place_free,
)
from mdgs.scenes._spec import SceneBuilder
from mdgs.scenes.controls import smooth_signal, smooth_targets

__all__ = ["RotationalBody"]


@dataclass(frozen=True)
class RotationalBody(SceneBuilder):
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
            doc.geom(w, f"post{i}", "cylinder", size=(0.05, 0.1), pos=(x, y, 0.1), rgba=STATIC_RGBA)
        hub = doc.free_body("hub", pos=(0, 0, self.base_half_height), joint="root")
        d = self.density
        hub_rgba, rotor_rgba = (0.6, 0.65, 0.75, 1), (0.85, 0.45, 0.2, 1)
        base = (self.base_radius, self.base_half_height)
        doc.geom(hub, "base", "cylinder", size=base, density=d, rgba=hub_rgba)
        z0, L, r = self.base_half_height, self.column_half_length, self.column_radius
        if self.hinges == "center":
            doc.geom(
                hub, "column_low", "cylinder", size=(r, L / 2), pos=(0, 0, z0 + L / 2), density=d,
                rgba=hub_rgba,
            )  # fmt: skip
            upper = doc.body(hub, "upper", pos=(0, 0, z0 + L))
            doc.hinge(upper, "fold", (1, 0, 0), range=(-1.0, 1.0))
            doc.geom(
                upper, "column_up", "cylinder", size=(r, L / 2), pos=(0, 0, L / 2), density=d,
                rgba=(0.5, 0.55, 0.7, 1),
            )  # fmt: skip
            top, top_z = upper, L
            doc.actuate("motor", "fold", "fold", ctrlrange=(-self.fold_torque, self.fold_torque))
        else:
            doc.geom(
                hub, "column", "cylinder", size=(r, L), pos=(0, 0, z0 + L), density=d, rgba=hub_rgba
            )
            top, top_z = hub, z0 + 2 * L
        t = self.rotor_half_thickness
        rotor = doc.body(top, "rotor", pos=(0, 0, top_z + t + 0.002))
        doc.hinge(rotor, "bearing", (0, 0, 1))
        doc.geom(rotor, "disc", "cylinder", size=(self.rotor_radius, t), density=d, rgba=rotor_rgba)
        doc.geom(
            rotor, "boss", "cylinder", size=(0.03, 0.02), pos=(0, 0, t + 0.02), density=d,
            rgba=rotor_rgba,
        )  # fmt: skip
        limit = (-self.rotor_torque, self.rotor_torque)
        doc.actuate("motor", "bearing", "bearing", ctrlrange=limit)
        if self.hinges == "side":
            for s, name in ((1, "arm_pos"), (-1, "arm_neg")):
                arm = doc.body(hub, name, pos=(s * self.base_radius, 0, z0))
                doc.hinge(arm, f"{name}_hinge", (0, 1, 0), range=(-1.4, 1.4))
                doc.geom(
                    arm, name, "capsule", fromto=(0, 0, 0, s * 2 * self.arm_half_length, 0, 0),
                    size=self.arm_radius, density=d, rgba=(0.4, 0.6, 0.4, 1),
                )  # fmt: skip
                doc.actuate(
                    "position", name, f"{name}_hinge", kp=6.0, kv=0.15, ctrlrange=(-1.2, 1.2)
                )
        return doc.xml()

    def initial_state(
        self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator
    ) -> None:
        at_rest(model, data)
        # on its rim: tilt about a random horizontal axis, spin about the vertical
        tilt = rng.uniform(0.1, self.tilt_max)
        heading = rng.uniform(-np.pi, np.pi)
        q = np.zeros(4)
        mujoco.mju_axisAngle2Quat(q, np.array([np.cos(heading), np.sin(heading), 0.0]), tilt)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, q)
        up = R.reshape(3, 3)[:, 2]
        rim = self.base_radius * np.sqrt(max(0.0, 1 - up[2] ** 2)) + self.base_half_height * up[2]
        x, y = rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05)
        place_free(model, data, "root", [x, y, rim + 1e-4], q)
        spin_world = (
            np.array([0.0, 0.0, rng.uniform(-1, 1) * self.spin_max])
            + np.r_[rng.normal(0, 0.5, 2), 0]
        )
        data.qvel[3:6] = R.reshape(3, 3).T @ spin_world  # free joint angular velocity is local
        data.qvel[0:2] = rng.normal(0, 0.2, 2)
        data.qvel[model.jnt_dofadr[model.joint("bearing").id]] = rng.uniform(-100, 100)
        lift_out_of_contact(model, data, 2)  # the arms may reach below the rim

    def controls(
        self, model: mujoco.MjModel, rng: np.random.Generator, qpos0: np.ndarray, n_frames: int
    ) -> np.ndarray:
        """Rotor and fold torques: smooth signals; arm servos: smooth targets in range."""
        dt = self.frame_dt
        lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
        u = np.zeros((n_frames, model.nu))
        for a, name in enumerate(actuator_names(model)):
            if name in ("bearing", "fold"):
                u[:, a] = hi[a] * smooth_signal(rng, n_frames, dt, 1, fmin=0.3, fmax=2.5)[:, 0]
            else:
                u[:, a] = smooth_targets(
                    rng, n_frames, dt, lo[a : a + 1], hi[a : a + 1], fmin=0.5, fmax=3.0
                )[:, 0]
        return u

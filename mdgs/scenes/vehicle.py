"""Vehicle: a four-wheeled car driven over a floor with friction (Table 2).

A chassis (a slab with a cabin, 25 kg) rides on four wheels (cylinders, radius
0.12 m). The rear wheels are driven by velocity servos (the motor's torque follows
the error to a target wheel speed), the front wheels steer on knuckles driven by
position servos. Throttle and steering are smooth random signals, so the car
accelerates, brakes, reverses and turns; tyres slip when the torque exceeds friction.

- **original**: a flat floor;
- **fixed obstacle**: a wall and a block on the floor in front of the car;
- **damaged**: the rear-left tyre is flat (radius 0.09 m) and its motor is dead, and
  the front-right axle is bent by 0.2 rad: the car pulls and wobbles;
- **movable obstacle**: a free 8 kg crate in front of the car, which it pushes.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from mdgs.scenes._mjcf import (
    STATIC_RGBA,
    WHEELS,
    Mjcf,
    actuator_names,
    at_rest,
    box_volume,
    lift_out_of_contact,
    place_free,
    yaw_quat,
)
from mdgs.scenes._spec import SceneBuilder
from mdgs.scenes.controls import smooth_signal

__all__ = ["Vehicle"]


@dataclass(frozen=True)
class Vehicle(SceneBuilder):
    """Parameters of the vehicle scenes (SI units)."""

    variant: str = "original"
    """'original', 'fixed_obstacle', 'damaged' or 'movable_obstacle'."""
    chassis_half: tuple[float, float, float] = (0.45, 0.22, 0.05)
    cabin_half: tuple[float, float, float] = (0.18, 0.18, 0.07)
    chassis_mass: float = 25.0
    wheel_radius: float = 0.12
    wheel_half_width: float = 0.04
    wheel_mass: float = 1.5
    wheelbase_half: float = 0.32
    track_half: float = 0.27
    drive_kv: float = 3.0  # N m s / rad, velocity servo gain
    drive_torque: float = 15.0  # N m, motor limit
    max_wheel_speed: float = 25.0  # rad/s (3 m/s)
    steer_limit: float = 0.45  # rad
    tyre_friction: float = 1.0
    timestep: float = 5e-4
    substeps: int = 40  # 20 ms frames: 2.2 s per trajectory

    def _radius(self, wheel: str) -> float:
        return 0.09 if (self.variant == "damaged" and wheel == "rl") else self.wheel_radius

    def mjcf(self) -> str:
        doc = Mjcf(f"vehicle-{self.variant}", timestep=self.timestep)
        w = doc.world
        if self.variant == "fixed_obstacle":
            doc.geom(w, "wall", "box", size=(0.1, 0.9, 0.2), pos=(1.9, 0.2, 0.2), rgba=STATIC_RGBA)
            doc.geom(
                w, "block", "box", size=(0.2, 0.2, 0.15), pos=(1.0, -0.9, 0.15), euler=(0, 0, 0.5),
                rgba=STATIC_RGBA,
            )  # fmt: skip
        if self.variant == "movable_obstacle":
            doc.free_object(
                "crate", "box", pos=(1.3, 0.0, 0.15), size=(0.15, 0.15, 0.15), mass=8.0,
                rgba=(0.7, 0.5, 0.3, 1),
            )  # fmt: skip
        ch, cab = np.asarray(self.chassis_half), np.asarray(self.cabin_half)
        rho = self.chassis_mass / (box_volume(ch) + box_volume(cab))
        car = doc.free_object(
            "chassis", "box", pos=(0, 0, self.wheel_radius), joint="root", size=ch, density=rho,
            rgba=(0.2, 0.45, 0.75, 1),
        )  # fmt: skip
        doc.geom(
            car, "cabin", "box", size=cab, pos=(-0.05, 0, ch[2] + cab[2]), density=rho,
            rgba=(0.25, 0.5, 0.8, 1),
        )  # fmt: skip
        steer = (-self.steer_limit, self.steer_limit)
        for tag, x, y in WHEELS:
            pos = (x * self.wheelbase_half, y * self.track_half, 0)
            parent = car
            if x > 0:  # front: a steering knuckle (kingpin: a short steel capsule, no collisions)
                parent = doc.body(car, f"knuckle_{tag}", pos=pos)
                doc.hinge(parent, f"steer_{tag}", (0, 0, 1), range=steer)
                doc.geom(
                    parent, f"knuckle_{tag}", "capsule", size=(0.015, 0.03), density=7800.0,
                    contype=0, conaffinity=0, rgba=(0.3, 0.3, 0.3, 1),
                )  # fmt: skip
                doc.actuate(
                    "position", f"steer_{tag}", f"steer_{tag}", kp=60.0, kv=3.0, ctrlrange=steer
                )
                pos = (0, 0, 0)
            bent = 0.2 if (self.variant == "damaged" and tag == "fr") else 0.0
            dead = self.variant == "damaged" and tag == "rl"
            driven = x < 0 and not dead
            drive = (self.drive_kv, self.max_wheel_speed, self.drive_torque) if driven else None
            r = self._radius(tag)
            doc.wheel(
                parent, tag, (pos[0], pos[1], pos[2] - (self.wheel_radius - r)), r,
                self.wheel_half_width, euler=(bent, 0, 0), drive=drive, mass=self.wheel_mass,
                friction=(self.tyre_friction, 0.005, 0.0001), rgba=(0.15, 0.15, 0.15, 1),
            )  # fmt: skip
        contact = doc.el(doc.root, "contact")
        for tag, *_ in WHEELS:  # a bent wheel may graze the chassis: not a contact we model
            doc.el(contact, "exclude", body1="chassis", body2=f"wheel_{tag}")
        return doc.xml()

    def initial_state(
        self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator
    ) -> None:
        at_rest(model, data)
        free_heading = self.variant == "original"
        yaw = rng.uniform(-np.pi, np.pi) if free_heading else rng.uniform(-0.35, 0.35)
        x, y = rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2)
        a = place_free(model, data, "root", [x, y, self.wheel_radius + 1e-4], yaw_quat(yaw))
        da = model.jnt_dofadr[model.joint("root").id]
        v = rng.uniform(0.0, 1.5)
        data.qvel[da : da + 2] = v * np.array([np.cos(yaw), np.sin(yaw)])
        for tag, *_ in WHEELS:
            data.qvel[model.jnt_dofadr[model.joint(f"spin_{tag}").id]] = v / self._radius(tag)
        lift_out_of_contact(model, data, a + 2)  # the bent wheel reaches below the others

    def controls(
        self, model: mujoco.MjModel, rng: np.random.Generator, qpos0: np.ndarray, n_frames: int
    ) -> np.ndarray:
        """Throttle (wheel speed targets, mostly forward) and steering: smooth random signals."""
        dt = self.frame_dt
        throttle = smooth_signal(rng, n_frames, dt, 1, fmin=0.1, fmax=0.8)[:, 0]
        speed = self.max_wheel_speed * (0.45 + 0.55 * throttle)  # mostly forward, sometimes reverse
        steer = self.steer_limit * smooth_signal(rng, n_frames, dt, 1, fmin=0.1, fmax=1.0)[:, 0]
        u = np.zeros((n_frames, model.nu))
        for a, name in enumerate(actuator_names(model)):
            u[:, a] = speed if name.startswith("drive") else steer
        return u

"""The MJCF writer shared by the scene builders: the common options and the recurring elements.

Every scene uses the Euler integrator (finite-difference accelerations then match the
recorded loads, see :mod:`mdgs.data.record`) and no joint damping. Numbers are written
with ``repr`` precision so the MJCF text, and its hash, are reproducible. Attributes
are written in the order they are given (``name`` and ``type`` first), so a builder's
text does not depend on which helper wrote an element.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable

import mujoco
import numpy as np

__all__ = [
    "Mjcf",
    "STATIC_RGBA",
    "WHEELS",
    "fmt",
    "actuator_names",
    "yaw_quat",
    "at_rest",
    "place_free",
    "box_volume",
    "capsule_volume",
    "cylinder_volume",
    "lift_out_of_contact",
]


def fmt(v) -> str:
    """Format a number or a vector for an MJCF attribute."""
    if isinstance(v, str):
        return v
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, Iterable):
        return " ".join(fmt(x) for x in v)
    x = float(v)
    if x == 0:
        return "0"
    return (
        repr(round(x, 12)).removesuffix(".0")
        if x == int(x) and abs(x) < 1e15
        else repr(round(x, 12))
    )


class Mjcf:
    """An MJCF document under construction.

    ``Mjcf(model, timestep, gravity)`` opens ``<mujoco>`` with the project's options;
    ``el(parent, tag, **attrs)`` adds elements (``class_`` for ``class``).
    """

    def __init__(
        self,
        model: str,
        *,
        timestep: float,
        gravity=(0, 0, -9.81),
        floor: bool = True,
        friction=(0.8, 0.005, 0.0001),
    ):
        self.root = ET.Element("mujoco", model=model)
        ET.SubElement(self.root, "compiler", angle="radian", autolimits="true")
        ET.SubElement(
            self.root,
            "option",
            integrator="Euler",
            timestep=fmt(timestep),
            gravity=fmt(gravity),
            cone="pyramidal",
        )
        ET.SubElement(self.root, "size", memory="20M")
        vis = ET.SubElement(self.root, "visual")
        ET.SubElement(
            vis, "headlight", ambient="0.3 0.3 0.3", diffuse="0.4 0.4 0.4", specular="0 0 0"
        )
        ET.SubElement(vis, "map", znear="0.01", zfar="30")
        asset = ET.SubElement(self.root, "asset")
        ET.SubElement(
            asset,
            "texture",
            name="grid",
            type="2d",
            builtin="checker",
            rgb1="0.82 0.84 0.86",
            rgb2="0.72 0.74 0.77",
            width="256",
            height="256",
        )
        ET.SubElement(
            asset, "material", name="floor", texture="grid", texrepeat="8 8", reflectance="0"
        )
        self.asset = asset
        default = ET.SubElement(self.root, "default")
        ET.SubElement(
            default, "geom", friction=fmt(friction), solref="0.01 1", solimp="0.95 0.99 0.001"
        )
        self.world = ET.SubElement(self.root, "worldbody")
        ET.SubElement(
            self.world,
            "light",
            pos="1 -1 4",
            dir="-0.2 0.2 -1",
            directional="true",
            diffuse="0.5 0.5 0.5",
        )
        if floor:
            ET.SubElement(
                self.world, "geom", name="floor", type="plane", size="20 20 0.1", material="floor"
            )
        self.actuator = ET.SubElement(self.root, "actuator")

    @staticmethod
    def el(parent: ET.Element, tag: str, **attrs) -> ET.Element:
        clean = {}
        for k, v in attrs.items():
            if v is None:
                continue
            clean["class" if k == "class_" else k] = fmt(v)
        return ET.SubElement(parent, tag, clean)

    def body(self, parent: ET.Element, name: str, pos=(0, 0, 0), **attrs) -> ET.Element:
        return self.el(parent, "body", name=name, pos=pos, **attrs)

    def geom(self, parent: ET.Element, name: str, type: str, **attrs) -> ET.Element:
        """A named geom of shape ``type`` (box, cylinder, capsule, ...) on ``parent``."""
        return self.el(parent, "geom", name=name, type=type, **attrs)

    def hinge(self, body: ET.Element, name: str, axis, **attrs) -> ET.Element:
        """A hinge joint of ``body`` about ``axis`` (body frame)."""
        return self.el(body, "joint", name=name, type="hinge", axis=axis, **attrs)

    def actuate(self, kind: str, name: str, joint: str, **attrs) -> ET.Element:
        """An actuator (``kind``: motor, position, velocity) on ``joint``."""
        return self.el(self.actuator, kind, name=name, joint=joint, **attrs)

    def free_body(self, name: str, pos, joint: str | None = None) -> ET.Element:
        """A body of the world on a free joint (named ``joint``, by default ``name``)."""
        body = self.body(self.world, name, pos=pos)
        self.el(body, "freejoint", name=joint or name)
        return body

    def free_object(self, name: str, type: str, pos, joint: str | None = None, **geom):
        """A free body with one geom, both named ``name``: a thrown box, a crate, a can."""
        body = self.free_body(name, pos, joint)
        self.geom(body, name, type, **geom)
        return body

    def wheel(
        self,
        parent: ET.Element,
        tag: str,
        pos,
        radius: float,
        half_width: float,
        *,
        euler=None,
        drive: tuple[float, float, float] | None = None,
        **geom,
    ) -> ET.Element:
        """Body ``wheel_{tag}`` spinning about its y axis on hinge ``spin_{tag}``.

        The geom is a cylinder of ``radius`` turned onto the y axis, with the attributes
        ``geom`` (mass, friction, rgba); ``drive = (kv, speed, torque)`` adds the velocity
        servo ``drive_{tag}``: gain kv (N m s/rad), targets within +-speed (rad/s), torque
        within +-torque (N m).
        """
        body = self.body(parent, f"wheel_{tag}", pos=pos, euler=euler)
        self.hinge(body, f"spin_{tag}", (0, 1, 0))
        size = (radius, half_width)
        self.geom(body, f"wheel_{tag}", "cylinder", size=size, euler=(np.pi / 2, 0, 0), **geom)
        if drive is not None:
            kv, speed, torque = drive
            ranges = {"ctrlrange": (-speed, speed), "forcerange": (-torque, torque)}
            self.actuate("velocity", f"drive_{tag}", f"spin_{tag}", kv=kv, **ranges)
        return body

    def xml(self) -> str:
        if len(self.actuator) == 0:
            self.root.remove(self.actuator)
        ET.indent(self.root)
        return ET.tostring(self.root, encoding="unicode") + "\n"


STATIC_RGBA = (0.55, 0.5, 0.45, 1)
"""Colour of the static obstacles (walls, blocks, posts)."""

WHEELS = (("fl", 1, 1), ("fr", 1, -1), ("rl", -1, 1), ("rr", -1, -1))
"""The four wheels of a car: tag, side along x (+1 front), side along y (+1 left)."""


def box_volume(half) -> float:
    return 8.0 * float(np.prod(half))


def capsule_volume(r: float, half_length: float) -> float:
    return float(np.pi * r * r * 2 * half_length + 4.0 / 3.0 * np.pi * r**3)


def cylinder_volume(r: float, half_length: float) -> float:
    return float(np.pi * r * r * 2 * half_length)


def actuator_names(model) -> list[str]:
    """Names of the actuators of a compiled ``mujoco.MjModel``, in actuator order."""
    return [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in range(model.nu)]


def yaw_quat(yaw: float) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation by ``yaw`` (rad) about the z axis."""
    q = np.zeros(4)
    mujoco.mju_axisAngle2Quat(q, np.array([0, 0, 1.0]), yaw)
    return q


def at_rest(model, data) -> None:
    """Put every joint at its reference position ``qpos0``, at rest."""
    data.qpos[:] = model.qpos0
    data.qvel[:] = 0


def place_free(model, data, joint: str, pos, quat) -> int:
    """Set position and orientation of the free joint ``joint``; returns its qpos address."""
    adr = model.jnt_qposadr[model.joint(joint).id]
    data.qpos[adr : adr + 3] = pos
    data.qpos[adr + 3 : adr + 7] = quat
    return adr


def lift_out_of_contact(model, data, z_adr: int, clearance: float = 1e-4) -> None:
    """Raise a free body (qpos[z_adr] is its height) until no contact penetrates more than 0."""
    for _ in range(4):
        mujoco.mj_forward(model, data)
        depth = min((data.contact[i].dist for i in range(data.ncon)), default=0.0)
        if depth >= 0:
            return
        data.qpos[z_adr] += -depth + clearance

"""Small MJCF writer shared by the scene builders (one place for the common options).

Every scene uses the Euler integrator (finite-difference accelerations then match the
recorded loads, see :mod:`mdgs.data.record`) and no joint damping. Numbers are written
with ``repr`` precision so the MJCF text, and its hash, are reproducible.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable

import numpy as np

__all__ = [
    "Mjcf",
    "fmt",
    "quat_to_mat",
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

    def xml(self) -> str:
        if len(self.actuator) == 0:
            self.root.remove(self.actuator)
        ET.indent(self.root)
        return ET.tostring(self.root, encoding="unicode") + "\n"


def unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def quat_to_mat(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternions (w, x, y, z): [..., 4] -> [..., 3, 3]."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def box_volume(half) -> float:
    return 8.0 * float(np.prod(half))


def capsule_volume(r: float, half_length: float) -> float:
    return float(np.pi * r * r * 2 * half_length + 4.0 / 3.0 * np.pi * r**3)


def cylinder_volume(r: float, half_length: float) -> float:
    return float(np.pi * r * r * 2 * half_length)


def lift_out_of_contact(model, data, z_adr: int, clearance: float = 1e-4) -> None:
    """Raise a free body (qpos[z_adr] is its height) until no contact penetrates more than 0."""
    import mujoco

    for _ in range(4):
        mujoco.mj_forward(model, data)
        depth = min((data.contact[i].dist for i in range(data.ncon)), default=0.0)
        if depth >= 0:
            return
        data.qpos[z_adr] += -depth + clearance

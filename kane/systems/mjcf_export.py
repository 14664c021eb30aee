"""MJCF export of an analytic system: explicit inertials, Euler integrator, no damping, loadable by MuJoCo and Pinocchio."""

from __future__ import annotations

from typing import Any

from kane.systems.specs import BodySpec, GeomSpec, JointSpec, symbol

#: The system description (:class:`kane.systems.system.AnalyticSystem`), named for annotations only:
#: ``system`` imports this module, so importing it back (even for type checkers) would make a cycle.
AnalyticSystem = Any


def _fmt(x: float) -> str:
    return format(float(x), ".17g")


def _mjcf(system: AnalyticSystem) -> str:
    plain = all(
        tuple(float(c) for c in b.quat) == (1.0, 0.0, 0.0, 0.0)
        and all(
            j.kind != "ball" and j == JointSpec(j.name, j.kind, j.axis) for j in b.joints
        )
        for b in system.bodies
    ) and all(a.gear == 1 for a in system.actuators)
    if not plain:
        raise ValueError(
            f"system {system.name!r}: MJCF export covers hinge, slide and free joints without "
            "anchors, references, passive loads, body rotations or gears; use the original file"
        )
    val = system.value
    v3 = lambda c: " ".join(_fmt(val(x)) for x in c)  # noqa: E731
    children: dict[str | None, list[BodySpec]] = {}
    for b in system.bodies:
        children.setdefault(b.parent, []).append(b)

    def geom(gs: GeomSpec, name: str) -> str:
        attrs = [
            f'name="{name}"',
            f'type="{gs.kind}"',
            f'size="{" ".join(_fmt(val(s)) for s in gs.size)}"',
        ]
        if any(val(p) != 0 for p in gs.pos):
            attrs.append(f'pos="{v3(gs.pos)}"')
        if gs.zaxis is not None:
            attrs.append(f'zaxis="{v3(gs.zaxis)}"')
        if gs.contact:
            attrs.append(
                f'contype="1" conaffinity="1" condim="3" friction="{_fmt(val(gs.friction))} 0 0"'
            )
        else:
            attrs.append('contype="0" conaffinity="0"')
        return "<geom " + " ".join(attrs) + "/>"

    lines: list[str] = []

    def body(b: BodySpec, depth: int) -> None:
        ind = "  " * depth
        lines.append(f'{ind}<body name="{b.name}" pos="{v3(b.pos)}">')
        for j in b.joints:
            if j.kind == "free":
                lines.append(f'{ind}  <freejoint name="{j.name}"/>')
            else:
                lines.append(f'{ind}  <joint name="{j.name}" type="{j.kind}" axis="{v3(j.axis)}"/>')
        m = val(b.mass)
        if m == 0:
            lines.append(f'{ind}  <inertial pos="0 0 0" mass="0" diaginertia="0 0 0"/>')
        else:
            lines.append(
                f'{ind}  <inertial pos="{v3(b.com)}" mass="{_fmt(m)}" fullinertia="{" ".join(_fmt(val(x)) for x in b.inertia)}"/>'
            )
        for k, gs in enumerate(b.geoms):
            lines.append(f"{ind}  " + geom(gs, f"{b.name}_geom{k}"))
        for c in children.get(b.name, []):
            body(c, depth + 1)
        lines.append(f"{ind}</body>")

    for b in children.get(None, []):
        body(b, 2)
    opts = {
        "timestep": _fmt(system.timestep),
        "integrator": "Euler",
        "gravity": f"0 0 {_fmt(-val(symbol('g')))}",
        **dict(system.contact_options),
    }
    opt = " ".join(f'{k}="{v}"' for k, v in opts.items())
    flag = "" if system.has_contact else '<flag contact="disable"/>'
    gdef = (
        ("<geom " + " ".join(f'{k}="{v}"' for k, v in system.geom_defaults.items()) + "/>")
        if system.geom_defaults
        else ""
    )
    world = [f"    {geom(gs, f'world_geom{k}')}" for k, gs in enumerate(system.world_geoms)]
    acts = [
        f'    <motor name="{a.name}" joint="{a.joint}" gear="1" ctrlrange="{_fmt(a.ctrlrange[0])} {_fmt(a.ctrlrange[1])}"/>'
        for a in system.actuators
    ]
    return "\n".join(
        [
            f'<mujoco model="{system.name}">',
            '  <compiler angle="radian" inertiafromgeom="false" autolimits="true"/>',
            f"  <option {opt}>{flag}</option>",
            f'  <default><joint damping="0" armature="0" frictionloss="0" stiffness="0"/>{gdef}</default>',
            "  <worldbody>",
            *world,
            *lines,
            "  </worldbody>",
            *(["  <actuator>", *acts, "  </actuator>"] if acts else []),
            "</mujoco>",
            "",
        ]
    )

"""Description of an analytic system's parts: joints, geoms, bodies and motors, with sympy parameter values.

The numbers in these specs are sympy expressions in named parameter symbols
(:func:`symbol`); :class:`kane.systems.system.AnalyticSystem` gathers them into one
system from which the Kane model and the MJCF scene are produced.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import sympy as sp

Expr = Any  # a sympy expression or a number


def symbol(name: str) -> sp.Symbol:
    """The real sympy symbol used for parameter ``name`` (one symbol per name)."""
    return sp.Symbol(name, real=True)


@dataclass(frozen=True)
class JointSpec:
    """One joint of a body.

    Attributes
    ----------
    name : str
        Joint name (MJCF name; the sympy symbols are ``q_<name>``, ``u_<name>``).
    kind : str
        ``'hinge'`` (rad), ``'slide'`` (m), ``'ball'`` (3 rotations, last joint of its
        body) or ``'free'`` (top-level bodies only).
    axis : tuple of 3 floats
        Joint axis in the body frame (unit vector; ignored for ball and free joints).
    pos : tuple of 3
        Joint anchor in the body frame, m (MJCF ``pos``; hinge and ball rotate about it).
    ref : float
        Coordinate at which the body sits at its MJCF pose (MJCF ``ref``, MuJoCo
        ``qpos0``): hinge angle / slide offset is ``q - ref``.
    damping : expr
        Viscous damping per degree of freedom, N m s/rad or N s/m (load ``-damping u``).
    stiffness : expr
        Spring stiffness, N m/rad or N/m (hinge and slide: load ``-stiffness (q - springref)``).
    springref : expr
        Spring rest coordinate (MJCF ``springref``).
    armature : expr
        Rotor inertia added to the joint's diagonal mass-matrix entries (MJCF ``armature``),
        kg m^2 or kg.
    """

    name: str
    kind: str
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    pos: tuple = (0, 0, 0)
    ref: float = 0.0
    damping: Expr = 0
    stiffness: Expr = 0
    springref: Expr = 0
    armature: Expr = 0


@dataclass(frozen=True)
class GeomSpec:
    """A geom: collision shape (``contact=True``) or drawing only. It carries no mass.

    Attributes
    ----------
    kind : str
        MJCF geom type: ``'box'``, ``'sphere'``, ``'cylinder'``, ``'capsule'``, ``'plane'``.
    size : tuple
        MJCF size (half extents, radius, (radius, half-height), ...), m.
    pos : tuple of 3
        Geom centre in the body frame, m.
    zaxis : tuple of 3 or None
        Direction of the geom's z axis in the body frame (cylinder axis).
    contact : bool
        Collides with other contact geoms (else ``contype = conaffinity = 0``).
    friction : float
        Sliding friction coefficient (contact geoms).
    """

    kind: str
    size: tuple
    pos: tuple = (0, 0, 0)
    zaxis: tuple | None = None
    contact: bool = False
    friction: float = 1.0


@dataclass(frozen=True)
class BodySpec:
    """A rigid body: joints to its parent, mass properties, geoms.

    Attributes
    ----------
    name : str
        Body name.
    parent : str or None
        Parent body name; ``None`` for the world.
    pos : tuple of 3
        Body-frame origin in the parent frame when the joint coordinates are zero, m.
    quat : tuple of 4
        Orientation of the body frame in the parent frame at zero joint coordinates, unit
        quaternion ``(w, x, y, z)`` (MJCF ``quat``); numbers, not parameters.
    joints : tuple of JointSpec
        Joints at the body origin, composed in order; empty: welded to the parent.
    mass : expr
        Mass, kg (0 allowed for a carrier whose mass sits in welded children).
    com : tuple of 3
        Mass centre in the body frame, m.
    inertia : tuple of 6
        Inertia matrix entries about the mass centre in body axes,
        ``(Ixx, Iyy, Izz, Ixy, Ixz, Iyz)`` (MJCF ``fullinertia`` order), kg m^2.
    geoms : tuple of GeomSpec
        Shapes (no mass: the mass properties above are the only ones).
    external_wrench : bool
        Body receives an external force/torque input (contact loads).
    """

    name: str
    parent: str | None
    pos: tuple = (0, 0, 0)
    joints: tuple[JointSpec, ...] = ()
    mass: Expr = 0
    com: tuple = (0, 0, 0)
    inertia: tuple = (0, 0, 0, 0, 0, 0)
    geoms: tuple[GeomSpec, ...] = ()
    external_wrench: bool = False
    quat: tuple = (1, 0, 0, 0)


@dataclass(frozen=True)
class ActuatorSpec:
    """A MuJoCo actuator on a hinge or slide joint (``<motor>`` with gear 1 in the built-in systems).

    Attributes
    ----------
    name : str
        Actuator name; the input symbol is ``tau_<name>``.
    joint : str
        Joint it drives.
    ctrlrange : (float, float)
        Control limits, N m (hinge) or N (slide).
    gear : float
        Transmission ratio: the joint receives ``gear * tau`` (MJCF ``gear``).
    """

    name: str
    joint: str
    ctrlrange: tuple[float, float] = (-1.0, 1.0)
    gear: float = 1.0

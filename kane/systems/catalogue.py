"""The catalogue of built-in analytic systems: one factory per system, the registry SYSTEMS and get_system."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from kane.systems.specs import ActuatorSpec, BodySpec, GeomSpec, JointSpec, symbol
from kane.systems.system import AnalyticSystem


def _box_inertia(m, a, b, c) -> tuple:
    """Uniform box of half extents (a, b, c) about its centre: ``m/3 (b^2 + c^2)``, ..."""
    return (m * (b**2 + c**2) / 3, m * (a**2 + c**2) / 3, m * (a**2 + b**2) / 3, 0, 0, 0)


def _check_params(name: str, defaults: dict, given: dict) -> dict:
    unknown = set(given) - set(defaults)
    if unknown:
        raise ValueError(
            f"system {name!r} has no parameter(s) {sorted(unknown)}; valid: {sorted(defaults)}"
        )
    return {**defaults, **given}


def particle(**params) -> AnalyticSystem:
    """Point mass under gravity on three slide joints (x, y, z).

    Parameters (defaults): ``m`` = 1.5 kg, ``g`` = 9.81 m/s^2, ``I`` = 1e-6 kg m^2 (MuJoCo
    needs a positive inertia; with no rotational freedom it does not enter the equations).
    """
    p = _check_params("particle", {"m": 1.5, "g": 9.81, "I": 1e-6}, params)
    m, inert = symbol("m"), symbol("I")
    joints = tuple(
        JointSpec(f"s{a}", "slide", ax) for a, ax in zip("xyz", np.eye(3).tolist(), strict=True)
    )
    body = BodySpec(
        "particle",
        None,
        joints=joints,
        mass=m,
        inertia=(inert, inert, inert, 0, 0, 0),
        geoms=(GeomSpec("sphere", (0.05,)),),
    )
    return AnalyticSystem(
        "particle", p, (body,), description="point mass on x, y, z slides under gravity"
    )


def pendulum(**params) -> AnalyticSystem:
    """Simple pendulum: mass ``m`` at distance ``l`` below a hinge about y.

    Parameters (defaults): ``m`` = 1.0 kg, ``l`` = 0.8 m, ``g`` = 9.81 m/s^2, ``I`` = 1e-6 kg
    m^2 (inertia of the bob about its centre; the textbook simple pendulum is ``I = 0``,
    which MuJoCo does not accept). With I = 0: ``m l^2 qdd + m g l sin q = 0``.
    """
    p = _check_params("pendulum", {"m": 1.0, "l": 0.8, "g": 9.81, "I": 1e-6}, params)
    m, l, inert = symbol("m"), symbol("l"), symbol("I")
    body = BodySpec(
        "bob",
        None,
        joints=(JointSpec("hinge", "hinge", (0.0, 1.0, 0.0)),),
        mass=m,
        com=(0, 0, -l),
        inertia=(inert, inert, inert, 0, 0, 0),
        geoms=(GeomSpec("sphere", (0.05,), pos=(0, 0, -l)),),
    )
    return AnalyticSystem(
        "pendulum", p, (body,), description="simple pendulum (hinge about y, bob below the pivot)"
    )


def double_pendulum(**params) -> AnalyticSystem:
    """Double pendulum of two uniform rods on hinges about y.

    Parameters (defaults): ``m1`` = 1.0, ``m2`` = 0.7 kg; ``l1`` = 0.6, ``l2`` = 0.5 m;
    ``g`` = 9.81 m/s^2; ``I0`` = 1e-4 kg m^2 (rod inertia about its own axis). Rod k has
    its mass centre at ``-l_k/2`` on its z axis and transverse inertia ``m_k l_k^2 / 12``.
    """
    p = _check_params(
        "double_pendulum",
        {"m1": 1.0, "m2": 0.7, "l1": 0.6, "l2": 0.5, "g": 9.81, "I0": 1e-4},
        params,
    )
    m1, m2, l1, l2, i0 = (symbol(n) for n in ("m1", "m2", "l1", "l2", "I0"))
    y = (0.0, 1.0, 0.0)
    b1 = BodySpec(
        "link1",
        None,
        joints=(JointSpec("hinge1", "hinge", y),),
        mass=m1,
        com=(0, 0, -l1 / 2),
        inertia=(m1 * l1**2 / 12, m1 * l1**2 / 12, i0, 0, 0, 0),
        geoms=(GeomSpec("capsule", (0.02, l1 / 2), pos=(0, 0, -l1 / 2)),),
    )
    b2 = BodySpec(
        "link2",
        "link1",
        pos=(0, 0, -l1),
        joints=(JointSpec("hinge2", "hinge", y),),
        mass=m2,
        com=(0, 0, -l2 / 2),
        inertia=(m2 * l2**2 / 12, m2 * l2**2 / 12, i0, 0, 0, 0),
        geoms=(GeomSpec("capsule", (0.02, l2 / 2), pos=(0, 0, -l2 / 2)),),
    )
    return AnalyticSystem(
        "double_pendulum", p, (b1, b2), description="double pendulum of two uniform rods"
    )


def free_box(gravity: bool = True, **params) -> AnalyticSystem:
    """Free-floating rigid box (free joint), gravity on or off.

    Parameters (defaults): ``m`` = 2.0 kg; half extents ``a, b, c`` = 0.15, 0.10, 0.05 m;
    ``g`` = 9.81 m/s^2 (0 when ``gravity=False``); mass-centre offset from the body-frame
    origin ``cx, cy, cz`` = 0.02, -0.01, 0.03 m (non-zero so that the coupling terms between
    translation and rotation in Kane's equations are exercised).
    """
    p = _check_params(
        "free_box",
        {
            "m": 2.0,
            "a": 0.15,
            "b": 0.10,
            "c": 0.05,
            "g": 9.81 if gravity else 0.0,
            "cx": 0.02,
            "cy": -0.01,
            "cz": 0.03,
        },
        params,
    )
    m, a, b, c = (symbol(n) for n in "mabc")
    com = (symbol("cx"), symbol("cy"), symbol("cz"))
    body = BodySpec(
        "box",
        None,
        joints=(JointSpec("root", "free"),),
        mass=m,
        com=com,
        inertia=_box_inertia(m, a, b, c),
        geoms=(GeomSpec("box", (a, b, c), pos=com),),
    )
    return AnalyticSystem(
        "free_box",
        p,
        (body,),
        description="free rigid box" + ("" if gravity else " without gravity"),
    )


def _element_box(name: str, elements, half_extents, values: dict) -> AnalyticSystem:
    """Box carried by a free body of zero own mass, whose mass sits in welded element bodies.

    Element i is a body without joint at its centroid, with parameters ``m_e<i>`` (kg),
    ``cx_e<i>, cy_e<i>, cz_e<i>`` (m, body frame) and ``Ixx_e<i> ... Iyz_e<i>`` (kg m^2,
    about its centroid); ``values`` adds further parameters (``g``, ...).
    """
    p = dict(values)
    h = tuple(float(x) for x in half_extents)
    bodies = [
        BodySpec(
            "box", None, joints=(JointSpec("root", "free"),), mass=0, geoms=(GeomSpec("box", h),)
        )
    ]
    inertia_names = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
    inertia_index = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
    for i, e in enumerate(elements):
        ms = symbol(f"m_e{i}")
        c = tuple(symbol(f"{a}_e{i}") for a in ("cx", "cy", "cz"))
        inert = tuple(symbol(f"{n}_e{i}") for n in inertia_names)
        p[f"m_e{i}"] = e.mass
        p.update({f"{a}_e{i}": float(e.centroid[k]) for k, a in enumerate(("cx", "cy", "cz"))})
        p.update(
            {
                f"{n}_e{i}": float(e.inertia[ix])
                for n, ix in zip(inertia_names, inertia_index, strict=True)
            }
        )
        bodies.append(BodySpec(f"element{i}", "box", pos=c, mass=ms, inertia=inert))
    return AnalyticSystem(
        name, p, tuple(bodies), description=f"box as the rigid union of {len(elements)} element(s)"
    )


def partitioned_box(k: int = 8, jitter: float = 0.0, seed: int = 0, **params) -> AnalyticSystem:
    """The free box as the rigid union of ``k`` elements (Lemma A.1), ``k`` in {1, 2, 8, 27}.

    Elements come from :func:`kane.elements.partition_box_k` (point-mass cells); each is a
    body welded to a free carrier body of zero own mass (MJCF: child body without joint;
    sympy: a RigidBody fixed in the box frame) with the element's mass, centroid and
    inertia about its centroid as parameters ``m_e<i>``, ``cx_e<i>``..., ``Ixx_e<i>``...

    Parameters (defaults): ``m`` = 2.0 kg, half extents ``a, b, c`` = 0.15, 0.10, 0.05 m,
    ``g`` = 9.81 m/s^2; ``jitter`` > 0 draws a non-uniform mass distribution (seed ``seed``).
    """
    from kane.elements import K_DIVISIONS, partition_box_k

    if k not in K_DIVISIONS:
        raise ValueError(f"partitioned_box: k must be one of {sorted(K_DIVISIONS)}, got {k}")
    p = _check_params(
        "partitioned_box", {"m": 2.0, "a": 0.15, "b": 0.10, "c": 0.05, "g": 9.81}, params
    )
    h = (p["a"], p["b"], p["c"])
    els = partition_box_k(h, k, mass=p["m"], rng=np.random.default_rng(seed), jitter=jitter)
    # a, b, c and m are recorded for reference; the mass properties are the elements'
    return _element_box(f"partitioned_box_k{k}", els, h, p)


def element_union_box(
    elements, name: str = "element_union_box", g: float = 9.81, half_extents=(0.15, 0.10, 0.05)
):
    """Box made of the given :class:`kane.elements.Element` list (see :func:`partitioned_box`)."""
    return _element_box(name, elements, half_extents, {"g": g})


def undivided_box(
    elements, name: str = "undivided_box", g: float = 9.81, half_extents=(0.15, 0.10, 0.05)
):
    """One rigid body with the mass properties of the union of ``elements``.

    Mass, mass centre and inertia from :func:`kane.elements.body_mass_properties`, i.e.
    from all point masses at once, independently of the element grouping.
    """
    from kane.elements import body_mass_properties

    M, com, I3 = body_mass_properties(elements)
    p = {
        "g": g,
        "m": M,
        "cx": com[0],
        "cy": com[1],
        "cz": com[2],
        "Ixx": I3[0, 0],
        "Iyy": I3[1, 1],
        "Izz": I3[2, 2],
        "Ixy": I3[0, 1],
        "Ixz": I3[0, 2],
        "Iyz": I3[1, 2],
    }
    c = (symbol("cx"), symbol("cy"), symbol("cz"))
    inert = tuple(symbol(n) for n in ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz"))
    h = tuple(float(x) for x in half_extents)
    body = BodySpec(
        "box",
        None,
        joints=(JointSpec("root", "free"),),
        mass=symbol("m"),
        com=c,
        inertia=inert,
        geoms=(GeomSpec("box", h),),
    )
    return AnalyticSystem(
        name, p, (body,), description="undivided box with the union's mass properties"
    )


def flywheel_box_planar(**params) -> AnalyticSystem:
    """Planar box (slide x, slide z, hinge y) carrying a motor-driven flywheel (hinge y).

    Parameters (defaults): box ``mb`` = 1.2 kg, half extents ``a, c`` = 0.1, 0.1 m (depth
    ``b`` = 0.05 m); flywheel ``mw`` = 0.3 kg, radius ``rw`` = 0.08 m, mounted at ``(dx, 0,
    dz)`` = (0.02, 0, 0.03) m from the box origin; ``g`` = 9.81 m/s^2; motor torque limit
    ``tau_max`` = 0.5 N m. Flywheel inertia: thin disc, ``mw rw^2 / 2`` about y and
    ``mw rw^2 / 4`` about x, z.
    """
    p = _check_params(
        "flywheel_box_planar",
        {
            "mb": 1.2,
            "a": 0.1,
            "b": 0.05,
            "c": 0.1,
            "mw": 0.3,
            "rw": 0.08,
            "dx": 0.02,
            "dz": 0.03,
            "g": 9.81,
            "tau_max": 0.5,
        },
        params,
    )
    mb, a, b, c, mw, rw, dx, dz = (symbol(n) for n in ("mb", "a", "b", "c", "mw", "rw", "dx", "dz"))
    y = (0.0, 1.0, 0.0)
    base = BodySpec(
        "base",
        None,
        joints=(
            JointSpec("x", "slide", (1.0, 0.0, 0.0)),
            JointSpec("z", "slide", (0.0, 0.0, 1.0)),
            JointSpec("pitch", "hinge", y),
        ),
        mass=mb,
        inertia=_box_inertia(mb, a, b, c),
        geoms=(GeomSpec("box", (a, b, c)),),
    )
    wheel = BodySpec(
        "wheel",
        "base",
        pos=(dx, 0, dz),
        joints=(JointSpec("wheel", "hinge", y),),
        mass=mw,
        inertia=(mw * rw**2 / 4, mw * rw**2 / 2, mw * rw**2 / 4, 0, 0, 0),
        geoms=(GeomSpec("cylinder", (rw, 0.01), zaxis=(0, 1, 0)),),
    )
    tmax = p["tau_max"]
    return AnalyticSystem(
        "flywheel_box_planar",
        p,
        (base, wheel),
        (ActuatorSpec("motor", "wheel", (-tmax, tmax)),),
        description="planar box with a motor-driven reaction wheel",
    )


def cubli(**params) -> AnalyticSystem:
    """Cubli: free cube with three motor-driven flywheels on orthogonal hinges (3-D).

    Parameters (defaults): cube ``mb`` = 0.4 kg, half side ``a`` = 0.075 m; wheels ``mw`` =
    0.15 kg, radius ``rw`` = 0.05 m, wheel k on the k-th body axis at distance ``d`` = 0.03 m
    from the cube origin along the next axis; ``g`` = 9.81 m/s^2; torque limit ``tau_max``
    = 0.2 N m.
    """
    p = _check_params(
        "cubli",
        {"mb": 0.4, "a": 0.075, "mw": 0.15, "rw": 0.05, "d": 0.03, "g": 9.81, "tau_max": 0.2},
        params,
    )
    mb, a, mw, rw, d = (symbol(n) for n in ("mb", "a", "mw", "rw", "d"))
    base = BodySpec(
        "cube",
        None,
        joints=(JointSpec("root", "free"),),
        mass=mb,
        inertia=_box_inertia(mb, a, a, a),
        geoms=(GeomSpec("box", (a, a, a)),),
    )
    bodies = [base]
    acts = []
    tmax = p["tau_max"]
    for k, ax in enumerate(np.eye(3)):
        pos = [0, 0, 0]
        pos[(k + 1) % 3] = d
        diag = [mw * rw**2 / 4] * 3
        diag[k] = mw * rw**2 / 2
        bodies.append(
            BodySpec(
                f"wheel{k}",
                "cube",
                pos=tuple(pos),
                joints=(JointSpec(f"wheel{k}", "hinge", tuple(ax)),),
                mass=mw,
                inertia=(*diag, 0, 0, 0),
                geoms=(GeomSpec("cylinder", (rw, 0.005), zaxis=tuple(ax)),),
            )
        )
        acts.append(ActuatorSpec(f"motor{k}", f"wheel{k}", (-tmax, tmax)))
    return AnalyticSystem(
        "cubli",
        p,
        tuple(bodies),
        tuple(acts),
        description="Cubli: free cube with three reaction wheels",
    )


def rolling_disc(**params) -> AnalyticSystem:
    """Thin disc rolling without slip on the plane z = 0 (Kane & Levinson 1985).

    Symbolic: nonholonomic ``KanesMethod`` (coordinates yaw, lean, spin, contact x, y;
    independent speeds = disc angular velocity in the lean frame; velocity constraints:
    the disc's contact point has zero horizontal velocity). Numeric: a MuJoCo cylinder
    (free joint) with friction on a plane; MuJoCo contact is soft and lets the disc slip
    and sink slightly, so the rolling equations hold only approximately there. Pinocchio
    cannot express rolling contact.

    Parameters (defaults): ``m`` = 0.5 kg, radius ``r`` = 0.1 m, half thickness ``h`` =
    0.0002 m (MuJoCo geom only; the inertia is the thin-disc one, ``m r^2 / 2`` about the
    axis, ``m r^2 / 4`` across; a thicker geom touches the floor off the mid-plane),
    ``g`` = 9.81 m/s^2, friction ``mu`` = 1.0.

    MuJoCo settings (chosen to approximate rolling, not to fit a residual): time step
    0.5 ms, elliptic friction cone, ``impratio`` 10, contact ``solref`` (0.005 s, 1), and
    0.1 s of settling before recording, because the ideal rolling initial state (zero
    penetration) is not an equilibrium of the soft contact.
    """
    p = _check_params(
        "rolling_disc", {"m": 0.5, "r": 0.1, "h": 0.0002, "g": 9.81, "mu": 1.0}, params
    )
    m, r, h, mu = (symbol(n) for n in ("m", "r", "h", "mu"))
    disc = BodySpec(
        "disc",
        None,
        joints=(JointSpec("root", "free"),),
        mass=m,
        inertia=(m * r**2 / 4, m * r**2 / 2, m * r**2 / 4, 0, 0, 0),
        geoms=(GeomSpec("cylinder", (r, h), zaxis=(0, 1, 0), contact=True, friction=mu),),
        external_wrench=True,
    )
    floor = GeomSpec("plane", (0, 0, 1), contact=True, friction=mu)
    return AnalyticSystem(
        "rolling_disc",
        p,
        (disc,),
        world_geoms=(floor,),
        derivation="rolling_disc",
        timestep=5e-4,
        contact_options={
            "cone": "elliptic",
            "impratio": "10",
            "tolerance": "1e-12",
            "iterations": "200",
        },
        geom_defaults={"solref": "0.005 1"},
        settle_steps=200,
        description="thin disc rolling on a plane (nonholonomic)",
    )


def box_on_plane(**params) -> AnalyticSystem:
    """Free box dropped and thrown onto the plane z = 0; contact forces enter as loads.

    Parameters (defaults): ``m`` = 1.0 kg, half extents ``a, b, c`` = 0.1, 0.07, 0.05 m,
    ``g`` = 9.81 m/s^2, friction ``mu`` = 0.6, drop height ``z0`` = 0.16 m of the body origin
    (MuJoCo initial state only; above the half diagonal 0.132 m, so it starts free and,
    thrown down at 1 m/s or more, lands within about 30 ms).
    """
    p = _check_params(
        "box_on_plane",
        {"m": 1.0, "a": 0.1, "b": 0.07, "c": 0.05, "g": 9.81, "mu": 0.6, "z0": 0.16},
        params,
    )
    m, a, b, c, mu = (symbol(n) for n in ("m", "a", "b", "c", "mu"))
    body = BodySpec(
        "box",
        None,
        joints=(JointSpec("root", "free"),),
        mass=m,
        inertia=_box_inertia(m, a, b, c),
        geoms=(GeomSpec("box", (a, b, c), contact=True, friction=mu),),
        external_wrench=True,
    )
    floor = GeomSpec("plane", (0, 0, 1), contact=True, friction=mu)
    return AnalyticSystem(
        "box_on_plane",
        p,
        (body,),
        world_geoms=(floor,),
        contact_options={"tolerance": "1e-12", "iterations": "200"},
        description="free box thrown onto a plane with friction",
    )


#: registry of system factories by name; each factory takes keyword parameters.
SYSTEMS: dict[str, Callable[..., AnalyticSystem]] = {
    "particle": particle,
    "pendulum": pendulum,
    "double_pendulum": double_pendulum,
    "free_box": free_box,
    "partitioned_box": partitioned_box,
    "flywheel_box_planar": flywheel_box_planar,
    "cubli": cubli,
    "rolling_disc": rolling_disc,
    "box_on_plane": box_on_plane,
}


def get_system(name: str, **params) -> AnalyticSystem:
    """The system ``name`` built with the given parameters (others at their defaults).

    Raises
    ------
    ValueError
        If ``name`` is not in :data:`SYSTEMS` (the message lists the valid names) or a
        parameter is unknown.
    """
    if name not in SYSTEMS:
        raise ValueError(f"unknown system {name!r}; valid names: {', '.join(sorted(SYSTEMS))}")
    return SYSTEMS[name](**params)

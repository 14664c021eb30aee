"""The motors' known loads: as node forces on free bodies, as the joint's response with its parent held, as the whole tree's response; and the whole tree's forward dynamics.

MDGS's inputs carry a scene's actuator controls as per-node signs (``+ctrl_k`` on the body that
actuator ``k`` drives, ``-ctrl_k`` on its parent; :func:`mdgs.data.split.control_map`): the
network must learn from a handful of examples that a Cubli's brake command of 12 N m stops a
flywheel spinning at 960 rad/s within a frame. For a motor, the load is known exactly from the
MJCF (``actuation`` of :class:`mdgs.models.mdgs.MDGSConfig`, and the "constant twist + motors"
reference of :mod:`mdgs.models.references`).

For actuator ``k`` on the hinge or slide joint of body ``c`` (parent ``p``), with generalised force
``u_k = gear_k * clip(gain_k * clip(ctrl_k, ctrlrange), forcerange)`` (MuJoCo's motor: fixed gain,
no bias, no activation dynamics), the joint axis ``n = R_c a`` and anchor ``A = R_c a_c + t_c`` in
the world (``a``, ``a_c`` the axis and position in the child frame; ``R_c, t_c`` the child's pose
fitted to its nodes by :func:`mdgs.structure.kabsch`, i.e. MuJoCo's ``xmat, xpos``):

**Free-body loads** (:func:`actuation_forces`). Hinge: torque ``T = u_k n`` on ``c`` and ``-T`` on
``p``; slide: force ``f = u_k n`` on ``c`` and ``-f`` on ``p``. Each body ``b`` gets the acceleration
field it would have as a free rigid body under its summed loads, with its MJCF mass ``M_b`` and
inertia ``I_b`` (``body_inertia`` in ``body_iquat``, rotated by ``R_b``), about the mass-weighted
centroid ``c_b`` of its elements (the centre of :func:`mdgs.rigid.twist`)::

    a_i = f_b / M_b + (I_b^-1 T_b) x (x_i - c_b),        node force  F_i = m_i a_i   (N)

so a motor's node forces sum to zero, as internal loads must.

**Joint response, parent held** (:func:`motor_accelerations`). The subtree ``S`` of the driven
body (it and every descendant with elements, moving with it) turns about (slides along) the
joint with MuJoCo's joint-space inertia of that one degree of freedom,
``M_kk = sum_{b in S} (n^T I_b n + M_b |n x (x_b - A)|^2) + armature`` (hinge; ``x_b`` the body's
mass centre, ``R_b body_ipos + t_b``) or ``sum_{b in S} M_b + armature`` (slide)::

    hinge:  a_i = (u_k / M_kk) n x (x_i - A),     slide:  a_i = (u_k / M_kk) n      (i in S)

summed over the motors. It is MuJoCo's ``qacc = M^-1 qfrc_actuator`` when the parent is fixed and
the motor's degree of freedom is the only one (a wheel on a fixed axle, an arm on a fixed
hinge); otherwise an approximation that ignores the parent's recoil and the coupling with other
joints (for a driven tree on a floating base it misses a sizeable part of MuJoCo's node accelerations,
the base's turn against its wheel: tests/test_actuation.py).

**The whole tree's response** (:func:`coupled_motor_accelerations`): MuJoCo's ``M^-1 qfrc_actuator``
exactly, every parent recoiling and every joint passing the load on (Newton-Euler with the joints as
constraints; its docstring). Exact for the motors alone, it is the worse prior where floors and gravity
hold the parents (docs/mdgs-experiments.md, "The whole tree's response").

**The whole tree's forward dynamics** (the same function given the node velocities): everything
else a rigid tree among static obstacles feels joins the motors - gravity, the gyroscopic torques, the
joints' velocity terms, the joints' range limits (MuJoCo's soft limits) and the contact of box corners
and cylinder rims with the world's planes, boxes, spheres, capsules and cylinders, sticking or sliding
with Coulomb friction (its docstring).
In free flight it is MuJoCo's ``qacc`` to 1e-9, against a limit to 1e-6 (tests/test_dynamics.py); in
contact it is a rigid, inelastic contact model instead of MuJoCo's soft one. Stepped once per frame it is the
"rigid tree" reference (:mod:`mdgs.models.references`) and MDGS's ``actuation = "dynamics"`` prior.

The other forms have no velocity terms (gyroscopic, Coriolis), which do not depend on the control.
Actuators that are not motors (position or velocity servos, activation dynamics),
that drive a tendon, a site or a ball or free joint, or whose body's rotation its elements do
not fix, are listed in ``skipped`` and contribute nothing; bodies without elements are left out
of the sums. Everything runs in float64; shapes ``[B, N, 3]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch

from mdgs.rigid import Twist, _skew_mat, advance, twist
from mdgs.structure import fixes_rotation, kabsch, segment_mean

#: Forward dynamics' contact (:func:`coupled_motor_accelerations`): a box corner closer to a surface than
#: this (m) holds; MuJoCo's soft contacts rest a few tenths of a millimetre deep.
CONTACT_GAP = 2e-3
#: Compliance of a held corner (m/s^2 per N): small against the bodies' 1/mass, it only makes four
#: corners of a face (twelve rows for six degrees of freedom) share the load.
CONTACT_COMPLIANCE = 1e-6
#: Held candidates not yet touching (a gap up to the frame's travel): False, the studies' rule, stops the
#: point's approach over the frame (its end velocity zero); True ("speculative"), lets it arrive on the
#: surface at the frame's end under the trapezoidal step where the gap is more than half the frame's
#: travel (benchmarks/mdgs_probes/speculative_contact.py; not a default: see its output). The rigid rule's only: the
#: soft contact holds no corner before it touches.
CONTACT_SPECULATIVE = False
#: Passes of the active-set search that lets go of corners a surface would pull (and limits that would pull),
#: lets a sticking corner slide where its hold leaves the friction cone and sticks a sliding one whose
#: friction would turn its slip round within the frame.
CONTACT_PASSES = 4
#: Newton iterations at most of the soft contact's solve (:func:`_unilateral_solve`): which of the pyramid's edges
#: and the limits push, decided again from each solve, until the decision repeats (MuJoCo's Newton solver takes two
#: or three on the studies' scenes).
SOFT_CONTACT_PASSES = 8
#: MuJoCo's smallest friction coefficient (``mjMINMU``): a frictionless pair's pyramid is its normal four times over.
MIN_FRICTION = 1e-5
#: Contact models of the forward dynamics (``contact`` of :func:`coupled_motor_accelerations`, of the rigid tree
#: and of MDGS's "dynamics" prior): "rigid", an inelastic impact that stops a held corner's approach and slip over
#: the step (the studies' rule before "soft" existed); "soft", MuJoCo's soft contact (:func:`_soft_contact`).
CONTACT_MODELS = ("rigid", "soft")
#: Points on each rim of a colliding cylinder that stand in for it as corners against curved or bounded
#: surfaces (a 16-gon's rim is within 2 % of the radius of the circle's); against a plane a rim touches
#: at its exact lowest point instead (``RIM_SUPPORT`` points, :func:`contacts`).
RIM_POINTS = 16
#: Points of a rim held against a plane: its lowest and two more at +-120 degrees around the rim, so
#: that a disc lying flat rests on a triangle and a tilted one rolls on its lowest point.
RIM_SUPPORT = 3
#: Batched CPU solves of systems with more unknowns than this go one system at a time: torch 2.13's
#: batched LU on the CPU (oneMKL, more than one thread) returns invalid pivots from about 150 unknowns
#: ("Pivots given to lu_solve must all be greater or equal to 1"), met on rotational-center's rollouts
#: (205 unknowns) and reproduced with random well-conditioned matrices (tests/test_dynamics.py).
BATCHED_SOLVE_MAX = 128
#: Compiled, the soft contact's passes solve their systems of the tree's degrees of freedom by elimination written as
#: tensor operations (:func:`_solve_unpivoted`) up to this many unknowns: AOTInductor (torch 2.13) has no C shim for
#: ``torch.linalg.solve_ex`` and calls it through its proxy executor: the eight passes at 9 unknowns and 96 rows cost
#: 137 us with it and 44 us with 9 fused elimination steps a pass (``benchmarks/mdgs_probes/small_solve.py``). Its
#: steps grow with the unknowns, the library's cost barely, and without pivoting it suits only the passes' systems.
UNPIVOTED_SOLVE_MAX = 16
#: :func:`push_out` leaves a corner this deep (m) where it is and moves a deeper one back to this depth, by
#: this fraction of the way per step: 0 and 1 (all the way out at once) were better on the studies' validation
#: splits than the game engines' slop of about a millimetre and fraction 0.2 (benchmarks/mdgs_probes/push_out.py).
PUSH_OUT_SLOP = 0.0
PUSH_OUT_FRACTION = 1.0
#: World geoms a corner can touch (MuJoCo's type names); others are listed in ``DriveSet.unseen``.
SURFACE_KINDS = ("plane", "box", "sphere", "capsule", "cylinder")
#: Revision of the forward dynamics' results: bump it by one with every change that moves them (a new
#: piece of physics, another contact rule). Study cells that run it (MDGS with ``actuation = "dynamics"``,
#: the rigid-tree references) add it to their revision (:meth:`mdgs.study.runner.Cell.spec`), so a rerun
#: study measures them again and its tables keep only the newest lines. 0: world surfaces, rim support
#: points and soft joint limits (the lines of the dynamics before them were moved aside by hand, into
#: each study folder's ``superseded-before-limits.jsonl``). 1: the friction cone and no reversed slip (a box
#: landing flat on its face with a slight slip was thrown sideways at metres per second once a frame was short
#: enough to call its corners sliding: the friction of the impact's push had no bound on what it did to the slip).
FORWARD_DYNAMICS_REVISION = 1
#: Revision of the soft contact's results (``contact = "soft"``), added on top of ``FORWARD_DYNAMICS_REVISION`` by the
#: study cells that use it. 0: one normal and two tangent rows per corner (MuJoCo's pyramid only while all four of
#: its edges push; friction by the rigid rule's active-set passes), holding ``J z``, the point's acceleration less
#: its centripetal part about its mass centre. 1: the pyramid's four edges as rows of their own that may only push,
#: in MuJoCo's contact frame, holding MuJoCo's ``J qacc`` (less the chain's velocity-product acceleration, not the
#: body's own), so a sliding corner and a contact down a chain of joints feel what MuJoCo's do; range limits held
#: once past them, as MuJoCo's; under semi-implicit Euler each root stepped at its frame's origin, as MuJoCo's free
#: joint. Stepped at MuJoCo's timestep with its integrator, the tree then reproduces the recorded frames of the three
#: study scenes to round-off, but where rotational-center's disc strikes a post (docs/mdgs-experiments.md, "MuJoCo's
#: soft contact").
SOFT_CONTACT_REVISION = 1
#: How a step of the forward dynamics treats the gyroscopic terms (``gyroscopic`` of
#: :func:`coupled_motor_accelerations`, of the rigid tree and of MDGS's "dynamics" prior): the weight of the step's
#: end in them, linearised. "explicit": at the step's start (the studies' rule before it existed); "implicit": at
#: its end (backward Euler, which damps a little); "midpoint": halfway (the linearised trapezoidal rule).
GYROSCOPIC = {"explicit": 0.0, "implicit": 1.0, "midpoint": 0.5}


def check_contact(rule: str, push_out: bool = False) -> None:
    """Raise ``ValueError`` naming the rules when ``rule`` is not one of ``CONTACT_MODELS``, or when the soft contact
    comes with ``push_out``, which would undo the depth its spring pushes back from (the configs of the rigid tree
    and of MDGS check theirs with it)."""
    if rule not in CONTACT_MODELS:
        raise ValueError(f"contact must be one of {', '.join(map(repr, CONTACT_MODELS))}, got {rule!r}")
    if rule == "soft" and push_out:
        raise ValueError("push_out moves every corner back onto its surface, which undoes the soft contact's "
                         "depth (its spring): set push_out = false with contact = \"soft\"")


def gyroscopic_weight(rule: str) -> float:
    """The weight of the step's end in the gyroscopic terms under ``rule`` (``GYROSCOPIC``); a rule it does not
    know raises ``ValueError`` naming the rules (the configs of the rigid tree and of MDGS check theirs with it)."""
    if rule not in GYROSCOPIC:
        raise ValueError(f"gyroscopic must be one of {', '.join(map(repr, GYROSCOPIC))}, got {rule!r}")
    return GYROSCOPIC[rule]

__all__ = ["FORWARD_DYNAMICS_REVISION", "SOFT_CONTACT_REVISION", "GYROSCOPIC", "gyroscopic_weight", "CONTACT_MODELS", "check_contact", "Drive", "DriveSet", "Link", "Surface", "Contacts", "drives_of", "actuation_forces",
           "motor_accelerations", "coupled_motor_accelerations", "contacts", "push_out", "project_velocities", "Pose", "pose_of",
           "warn_unseen"]


@dataclass(frozen=True)
class Drive:
    """One motor on one hinge or slide joint, between two objects (indices of :class:`mdgs.graphs.SceneGraph`).

    actuator : index of the actuator (column of the controls).
    child : object the joint belongs to; parent : its parent object, or -1 for the world.
    kind : "hinge" (a torque about ``axis``) or "slide" (a force along ``axis``).
    axis : [3] unit joint axis in the child's body frame.
    gain : generalised force per unit actuator force (``gear[0]``).
    force_gain : actuator force per unit control (``gainprm[0]``).
    ctrl_range, force_range : (lo, hi) clamps, or None when the MJCF does not limit.
    anchor : [3] joint position in the child's body frame (m); armature : the joint's armature.
    subtree : the child and its descendant objects (those with elements).
    """

    actuator: int
    child: int
    parent: int
    kind: str
    axis: np.ndarray
    gain: float
    force_gain: float
    ctrl_range: tuple[float, float] | None
    force_range: tuple[float, float] | None
    anchor: np.ndarray = field(default_factory=lambda: np.zeros(3))
    armature: float = 0.0
    subtree: tuple[int, ...] = ()


@dataclass(frozen=True)
class Link:
    """How one object moves against its parent object, for :func:`coupled_motor_accelerations`.

    child, parent : object indices (parent -1: the world, a fixed frame).
    kind : "hinge", "slide", "ball", "weld" (no joint) or "free".
    axis : [3] unit joint axis; perp : [2, 3] two unit vectors completing it to an orthonormal basis;
    anchor : [3] joint position (m); all three in the parent's body frame (the world's for parent -1),
    where a hinge's axis and anchor stay whatever the joint's angle, so they are known even for a
    child whose elements do not fix its rotation (a thin pole); a slide's anchor at ``qpos0`` (moving
    it along the axis changes no row). armature : the joint's armature (hinge, slide; 0 otherwise).
    limit : (lo, hi) the joint's range in MuJoCo's ``qpos`` units when the MJCF limits it (hinge, slide),
    else None; qpos0 : the joint's ``qpos0`` (its ``ref``); frame0 : [3, 3] the child's frame in the
    parent's at ``qpos0`` (``body_quat``); origin : [3] the child's origin there (``body_pos``), so that a
    hinge's angle is ``qpos0`` plus the turn of ``R_p^T R_c frame0^T`` about ``axis`` and a slide's
    ``qpos0 + axis . (R_p^T (t_c - t_p) - origin)``. solref, solimp, margin, invweight : the limit's
    softness as MuJoCo's (``jnt_solref``, ``jnt_solimp``, ``jnt_margin``, ``dof_invweight0``).
    """

    child: int
    parent: int
    kind: str
    axis: np.ndarray
    perp: np.ndarray
    anchor: np.ndarray
    armature: float = 0.0
    limit: tuple[float, float] | None = None
    qpos0: float = 0.0
    frame0: np.ndarray = field(default_factory=lambda: np.eye(3))
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    solref: tuple[float, float] = (0.02, 1.0)
    solimp: tuple[float, ...] = (0.9, 0.95, 0.001, 0.5, 2.0)
    margin: float = 0.0
    invweight: float = 1.0


@dataclass(frozen=True)
class Surface:
    """A colliding geom of the world (MuJoCo's body 0) that the corners of moving bodies touch.

    kind : one of ``SURFACE_KINDS`` (a plane is MuJoCo's infinite half-space below its local xy plane);
    pos : [3] its centre, rot : [3, 3] its frame (columns: its axes in the world), size : [3] MuJoCo's
    ``geom_size`` (box: half sides; sphere: radius; capsule and cylinder: radius, half length along
    the local z); friction : its sliding friction; name : the geom's name.
    """

    kind: str
    pos: np.ndarray
    rot: np.ndarray
    size: np.ndarray
    friction: float
    name: str = ""


@dataclass
class DriveSet:
    """The motors whose loads :func:`actuation_forces` applies, the bodies' inertial data, and what is skipped (why).

    mass : [S] MJCF mass of each object's body; inertia, inv_inertia : [S, 3, 3] its inertia tensor
    about its mass centre in its body frame, and the inverse (zero where singular); com : [S, 3]
    its mass centre in its body frame (``body_ipos``); links : one :class:`Link` per moving object
    whose joint :func:`coupled_motor_accelerations` can write (the others are left free there, and named,
    with the reason, in ``unlinked``); fixed : [S] objects that do not move (the world body's elements).
    For the forward dynamics (:func:`coupled_motor_accelerations` given velocities): gravity : [3] the
    MJCF's ``opt.gravity``; surfaces : the world's colliding geoms (:class:`Surface`: planes, boxes,
    spheres, capsules, cylinders); corners : [K, 3] the corners of every colliding box geom of a moving
    object (and ``RIM_POINTS`` on each rim of a colliding cylinder, ``on_rim`` [K] True), in its body frame,
    corner_obj : [K] that object, corner_friction : [K] the sliding friction of the corner's geom (against
    a surface MuJoCo takes the larger of the two); rims : [Q, 7] each colliding cylinder's two rims, centre
    [3] and axis [3] in its body frame and radius, rim_obj : [Q], rim_friction : [Q]; none of these
    without surfaces. contact_soft : for each surface, [C, 7] the ``solref`` and ``solimp`` of each of its
    contact candidates in :func:`contacts`'s order (the corners, and against a plane the rims' support points);
    invweight : [S] each object's translational ``body_invweight0`` (both for ``contact = "soft"``). unseen : what the forward dynamics
    leaves out of a scene, one line each (colliding geoms it has no contact for, joint limits it cannot
    hold, damping, springs, friction loss), so that a user of the rigid tree or of MDGS's "dynamics"
    prior is told.
    """

    drives: list[Drive] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    mass: np.ndarray = field(default_factory=lambda: np.zeros(0))
    inertia: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    inv_inertia: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    com: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    links: list[Link] = field(default_factory=list)
    unlinked: list[str] = field(default_factory=list)
    fixed: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    gravity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    corners: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    corner_obj: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    corner_friction: np.ndarray = field(default_factory=lambda: np.zeros(0))
    on_rim: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    rims: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))
    rim_obj: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    rim_friction: np.ndarray = field(default_factory=lambda: np.zeros(0))
    unseen: list[str] = field(default_factory=list)
    surfaces: list[Surface] = field(default_factory=list)
    contact_soft: list[np.ndarray] = field(default_factory=list)
    invweight: np.ndarray = field(default_factory=lambda: np.zeros(0))
    _cache: dict = field(default_factory=dict, repr=False)

    def __bool__(self) -> bool:
        return len(self.drives) > 0  # not bool(list): dynamo (torch 2.11) breaks the graph on it

    def constants(self) -> dict:
        """Static quantities of the scene as Python numbers, built once: a compiled step reads them as
        constants, where the same computed from the arrays inside the step (numpy there is traced as
        tensors) would give data-dependent shapes or a read back to the host. ``fixed``, ``off_rim``: index
        lists of the objects that do not move and of the corners that are not rim points; ``g``: the norm
        of gravity."""
        if "constants" not in self._cache:
            self._cache["constants"] = {"fixed": [int(i) for i in np.flatnonzero(self.fixed)],
                                        "off_rim": [int(i) for i in np.flatnonzero(~np.asarray(self.on_rim, bool))],
                                        "g": float(np.linalg.norm(self.gravity))}
        return self._cache["constants"]

    def moving_columns(self) -> np.ndarray:
        """The indices [6 S - 6 k] of the moving objects' entries in the stacked accelerations ``(a_s, alpha_s)``
        of :func:`coupled_motor_accelerations` (``k`` objects fixed), built once."""
        key = "moving_columns"
        if key not in self._cache:
            cols = np.flatnonzero(np.repeat(~np.asarray(self.fixed, bool), 6))
            if torch.compiler.is_compiling():  # a dictionary growing under dynamo would compile the step again
                return cols
            self._cache[key] = cols
        return self._cache[key]

    def const(self, a: np.ndarray, dev, dtype: torch.dtype = torch.float64) -> torch.Tensor:
        """``torch.as_tensor(a)`` on ``dev``, built once for each of the scene's arrays (a link's axis, a surface's
        frame): a step of the forward dynamics reads dozens of them. Traced (``torch.compile``), no cache: dynamo
        takes the array for a tensor of the graph, and a dictionary growing under it would compile the step again."""
        if torch.compiler.is_compiling():
            return torch.as_tensor(a, dtype=dtype, device=dev)
        key = ("const", id(a), str(dev), dtype)
        hit = self._cache.get(key)
        if hit is None or hit[0] is not a:  # the array is kept with its tensor, so that its id is not reused
            hit = self._cache[key] = (a, torch.as_tensor(a, dtype=dtype, device=dev))
        return hit[1]

    def tensors(self, dev) -> dict:
        """Stacked float64 / int64 tensors of the drives and bodies on ``dev`` (built once per device)."""
        key = str(dev)
        if key not in self._cache:
            f = dict(dtype=torch.float64, device=dev)
            d = self.drives
            lo = [(dr.ctrl_range or (-np.inf, np.inf))[0] for dr in d]
            hi = [(dr.ctrl_range or (-np.inf, np.inf))[1] for dr in d]
            flo = [(dr.force_range or (-np.inf, np.inf))[0] for dr in d]
            fhi = [(dr.force_range or (-np.inf, np.inf))[1] for dr in d]
            self._cache[key] = {
                "actuator": torch.tensor([dr.actuator for dr in d], dtype=torch.long, device=dev),
                "child": torch.tensor([dr.child for dr in d], dtype=torch.long, device=dev),
                "parent": torch.tensor([dr.parent for dr in d], dtype=torch.long, device=dev),
                "torque": torch.tensor([dr.kind == "hinge" for dr in d], dtype=torch.bool, device=dev),
                "axis": torch.as_tensor(np.array([dr.axis for dr in d]).reshape(-1, 3), **f),
                "gain": torch.tensor([dr.gain for dr in d], **f),
                "force_gain": torch.tensor([dr.force_gain for dr in d], **f),
                "ctrl_lo": torch.tensor(lo, **f), "ctrl_hi": torch.tensor(hi, **f),
                "force_lo": torch.tensor(flo, **f), "force_hi": torch.tensor(fhi, **f),
                "anchor": torch.as_tensor(np.array([dr.anchor for dr in d]).reshape(-1, 3), **f),
                "armature": torch.tensor([dr.armature for dr in d], **f),
                "subtree": torch.tensor(np.array([[o in dr.subtree for o in range(len(self.mass))] for dr in d],
                                                 bool).reshape(len(d), len(self.mass)), device=dev),
                "mass": torch.as_tensor(self.mass, **f),
                "inertia": torch.as_tensor(self.inertia, **f), "com": torch.as_tensor(self.com, **f),
                "inv_inertia": torch.as_tensor(self.inv_inertia, **f),
            }
        return self._cache[key]


def _descends(m, c: int, b: int) -> bool:
    """Whether MuJoCo body ``c`` is ``b`` or one of its descendants."""
    while c > 0:
        if c == b:
            return True
        c = int(m.body_parentid[c])
    return c == b


def _contact_param(m, g1: int, g2: int) -> np.ndarray:
    """MuJoCo's ``solref`` (2) and ``solimp`` (5) of a contact between geoms ``g1`` and ``g2`` [7]
    (``mj_contactParam``): the geom of higher ``priority``'s, else mixed by ``solmix`` (``solref`` taken as the
    elementwise minimum where either is given directly, negative)."""
    p1, p2 = int(m.geom_priority[g1]), int(m.geom_priority[g2])
    if p1 != p2:
        g = g1 if p1 > p2 else g2
        return np.r_[m.geom_solref[g], m.geom_solimp[g]].astype(float)
    s1, s2 = float(m.geom_solmix[g1]), float(m.geom_solmix[g2])
    if s1 < 1e-15 and s2 < 1e-15:
        mix = 0.5
    elif s1 < 1e-15:
        mix = 0.0
    elif s2 < 1e-15:
        mix = 1.0
    else:
        mix = s1 / (s1 + s2)
    r1, r2 = np.asarray(m.geom_solref[g1], float), np.asarray(m.geom_solref[g2], float)
    ref = mix * r1 + (1 - mix) * r2 if r1[0] > 0 and r2[0] > 0 else np.minimum(r1, r2)
    return np.r_[ref, mix * np.asarray(m.geom_solimp[g1], float) + (1 - mix) * np.asarray(m.geom_solimp[g2], float)]


def drives_of(mj_model, node_body: np.ndarray, node_centroid: np.ndarray) -> DriveSet:
    """The motors of a scene and its objects' inertial data (objects: the sorted distinct bodies with nodes).

    mj_model : the scene's ``mujoco.MjModel``; node_body : [N] MuJoCo body of each node
    (``static["node_body"]``); node_centroid : [N, 3] element centroids in their body frames.
    """
    import mujoco

    m = mj_model
    node_body = np.asarray(node_body, int)
    node_centroid = np.asarray(node_centroid, float)
    bodies = np.unique(node_body)
    obj_of = {int(b): k for k, b in enumerate(bodies)}
    S = len(bodies)
    mass, inertia, inv_inertia, com = np.zeros(S), np.zeros((S, 3, 3)), np.zeros((S, 3, 3)), np.zeros((S, 3))
    posable = np.zeros(S, bool)
    for k, b in enumerate(int(x) for x in bodies):
        q = np.zeros(9)
        mujoco.mju_quat2Mat(q, m.body_iquat[b])
        q = q.reshape(3, 3)
        inertia[k] = q @ np.diag(m.body_inertia[b]) @ q.T
        mass[k], com[k] = float(m.body_mass[b]), m.body_ipos[b]
        if b != 0 and np.linalg.cond(inertia[k]) < 1e12:
            inv_inertia[k] = np.linalg.inv(inertia[k])
        posable[k] = fixes_rotation(node_centroid[node_body == b])
    out = DriveSet(mass=mass, inertia=inertia, inv_inertia=inv_inertia, com=com, fixed=bodies == 0,
                   gravity=np.array(m.opt.gravity, float))
    corners, corner_obj, corner_mu, on_rim, rims, rim_obj, rim_mu = [], [], [], [], [], [], []
    corner_geom, rim_geom, surface_geom = [], [], []  # the geom of each corner, rim and surface
    signs = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float)
    geom_name = lambda g: mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"#{g}"  # noqa: E731
    for g in range(m.ngeom):
        if not (int(m.geom_contype[g]) or int(m.geom_conaffinity[g])):
            continue
        gq = np.zeros(9)
        mujoco.mju_quat2Mat(gq, m.geom_quat[g])
        gq = gq.reshape(3, 3)
        b = int(m.geom_bodyid[g])
        kind = mujoco.mjtGeom(int(m.geom_type[g])).name.removeprefix("mjGEOM_").lower()
        if b == 0 and kind in SURFACE_KINDS:
            out.surfaces.append(Surface(kind, np.array(m.geom_pos[g], float), gq, np.array(m.geom_size[g], float),
                                        float(m.geom_friction[g][0]), geom_name(g)))
            surface_geom.append(g)
        elif b == 0:
            out.unseen.append(f"geom {geom_name(g)} ({kind} of the world): nothing touches it, only planes, boxes, "
                              "spheres, capsules and cylinders of the world are touched")
        elif b in obj_of and kind == "box":
            corners.append(m.geom_pos[g] + (signs * m.geom_size[g]) @ gq.T)
            corner_obj += [obj_of[b]] * 8
            corner_mu += [float(m.geom_friction[g][0])] * 8
            corner_geom += [g] * 8
            on_rim += [False] * 8
        elif b in obj_of and kind == "cylinder":
            r, h = m.geom_size[g][:2]
            ang = 2 * np.pi * np.arange(RIM_POINTS) / RIM_POINTS
            rim = np.stack([r * np.cos(ang), r * np.sin(ang), np.zeros_like(ang)], -1)
            pts = np.concatenate([rim + [0, 0, h], rim - [0, 0, h]])
            corners.append(m.geom_pos[g] + pts @ gq.T)
            corner_obj += [obj_of[b]] * len(pts)
            corner_mu += [float(m.geom_friction[g][0])] * len(pts)
            corner_geom += [g] * len(pts)
            on_rim += [True] * len(pts)
            for side in (1.0, -1.0):
                rims.append(np.r_[m.geom_pos[g] + side * h * gq[:, 2], gq[:, 2], r])
                rim_obj.append(obj_of[b])
                rim_mu.append(float(m.geom_friction[g][0]))
                rim_geom.append(g)
        elif b in obj_of:
            out.unseen.append(f"geom {geom_name(g)} ({kind}): no contact points, only boxes and cylinders have them")
    if out.surfaces and corners:
        out.corners, out.corner_obj = np.concatenate(corners), np.array(corner_obj, int)
        out.corner_friction, out.on_rim = np.array(corner_mu), np.array(on_rim, bool)
    if out.surfaces and rims:
        out.rims, out.rim_obj, out.rim_friction = np.array(rims), np.array(rim_obj, int), np.array(rim_mu)
    if out.surfaces and (corners or rims):  # each candidate's solref, solimp against each surface (contacts's order)
        out.invweight = np.array([float(m.body_invweight0[int(b), 0]) for b in bodies])
        off_rim = ~np.asarray(out.on_rim, bool)
        for sf, gs in zip(out.surfaces, surface_geom, strict=True):
            gc = [g for g, keep in zip(corner_geom, off_rim if sf.kind == "plane" else np.ones(len(corner_geom), bool),
                                       strict=True)
                  if keep]
            if sf.kind == "plane":
                gc += [g for g in rim_geom for _ in range(RIM_SUPPORT)]
            out.contact_soft.append(np.array([_contact_param(m, g, gs) for g in gc]).reshape(len(gc), 7))
    name = lambda kind, i: mujoco.mj_id2name(m, kind, i) or f"#{i}"  # noqa: E731
    kinds = {int(mujoco.mjtJoint.mjJNT_HINGE): "hinge", int(mujoco.mjtJoint.mjJNT_SLIDE): "slide",
             int(mujoco.mjtJoint.mjJNT_BALL): "ball", int(mujoco.mjtJoint.mjJNT_FREE): "free"}
    held_limits: set[int] = set()  # joints whose range limit a link holds
    for k, b in enumerate(int(x) for x in bodies):
        if b == 0:
            continue
        b_name = f"body {name(mujoco.mjtObj.mjOBJ_BODY, b)}"
        p = int(m.body_parentid[b])
        if p != 0 and p not in obj_of:
            out.unlinked.append(f"{b_name}: its parent body has no elements (left free in the coupled response)")
            continue
        nj = int(m.body_jntnum[b])
        if nj > 1:
            out.unlinked.append(f"{b_name}: has {nj} joints (left free in the coupled response)")
            continue
        j = int(m.body_jntadr[b]) if nj else -1
        kind = kinds[int(m.jnt_type[j])] if nj else "weld"
        q0 = np.zeros(9)
        mujoco.mju_quat2Mat(q0, m.body_quat[b])
        q0 = q0.reshape(3, 3)  # the child frame in the parent frame at qpos0
        axis = q0 @ (np.array(m.jnt_axis[j], float) if nj else np.array([0.0, 0.0, 1.0]))
        axis = axis / np.linalg.norm(axis)
        e1 = np.cross(axis, np.eye(3)[int(np.argmin(np.abs(axis)))])
        e1 /= np.linalg.norm(e1)
        anchor = m.body_pos[b] + q0 @ (np.array(m.jnt_pos[j], float) if nj else np.array(m.body_ipos[b], float))
        arm = float(m.dof_armature[m.jnt_dofadr[j]]) if kind in ("hinge", "slide") else 0.0
        limit = None
        if kind in ("hinge", "slide") and bool(m.jnt_limited[j]):
            limit = (float(m.jnt_range[j][0]), float(m.jnt_range[j][1]))
            held_limits.add(j)
        soft = {}
        if limit is not None:
            ref = float(m.jnt_solref[j][0])
            soft = dict(solref=(max(ref, 2 * float(m.opt.timestep)) if ref > 0 else ref, float(m.jnt_solref[j][1])),
                        solimp=tuple(float(c) for c in m.jnt_solimp[j]), margin=float(m.jnt_margin[j]),
                        invweight=float(m.dof_invweight0[m.jnt_dofadr[j]]))
        out.links.append(Link(k, obj_of[p] if p != 0 else -1, kind, axis, np.stack([e1, np.cross(axis, e1)]),
                              anchor, arm, limit, float(m.qpos0[m.jnt_qposadr[j]]) if nj else 0.0, q0,
                              np.array(m.body_pos[b], float), **soft))

    for j in range(m.njnt):
        jn = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or f"#{j}"
        dofs = slice(int(m.jnt_dofadr[j]), int(m.jnt_dofadr[j]) + {0: 6, 1: 3, 2: 1, 3: 1}[int(m.jnt_type[j])])
        left = [what for what, on in (("its range limit", bool(m.jnt_limited[j]) and j not in held_limits),
                                      ("its spring", float(m.jnt_stiffness[j]) != 0.0),
                                      ("its damping", bool(np.any(m.dof_damping[dofs] != 0))),
                                      ("its friction loss", bool(np.any(m.dof_frictionloss[dofs] != 0)))) if on]
        if left:
            out.unseen.append(f"joint {jn}: {', '.join(left)}")

    def subtree(b: int) -> tuple[int, ...]:
        return tuple(obj_of[int(c)] for c in range(m.nbody) if int(c) in obj_of and _descends(m, int(c), b))

    for k in range(m.nu):
        a_name = f"actuator {name(mujoco.mjtObj.mjOBJ_ACTUATOR, k)}"
        motor = (int(m.actuator_dyntype[k]) == int(mujoco.mjtDyn.mjDYN_NONE)
                 and int(m.actuator_gaintype[k]) == int(mujoco.mjtGain.mjGAIN_FIXED)
                 and int(m.actuator_biastype[k]) == int(mujoco.mjtBias.mjBIAS_NONE))
        if not motor:
            out.skipped.append(f"{a_name}: not a motor (its force depends on the state or on activation)")
            continue
        if int(m.actuator_trntype[k]) != int(mujoco.mjtTrn.mjTRN_JOINT):
            out.skipped.append(f"{a_name}: drives no single joint (tendon, site or other transmission)")
            continue
        j = int(m.actuator_trnid[k, 0])
        kind = {int(mujoco.mjtJoint.mjJNT_HINGE): "hinge", int(mujoco.mjtJoint.mjJNT_SLIDE): "slide"}.get(
            int(m.jnt_type[j]))
        if kind is None:
            out.skipped.append(f"{a_name}: drives a ball or free joint")
            continue
        b = int(m.jnt_bodyid[j])
        p = int(m.body_parentid[b])
        if b not in obj_of:
            out.skipped.append(f"{a_name}: its body has no elements")
            continue
        if not posable[obj_of[b]]:
            out.skipped.append(f"{a_name}: its body's elements do not fix its rotation (fewer than 3, or on a line)")
            continue
        if p != 0 and p not in obj_of:
            out.skipped.append(f"{a_name}: its parent body has no elements (the reaction would be lost)")
            continue
        axis = np.array(m.jnt_axis[j], float)
        ctrl_range = tuple(float(c) for c in m.actuator_ctrlrange[k]) if bool(m.actuator_ctrllimited[k]) else None
        force_range = tuple(float(c) for c in m.actuator_forcerange[k]) if bool(m.actuator_forcelimited[k]) else None
        out.drives.append(Drive(k, obj_of[b], obj_of[p] if p != 0 else -1, kind, axis / np.linalg.norm(axis),
                                float(m.actuator_gear[k, 0]), float(m.actuator_gainprm[k, 0]),
                                ctrl_range, force_range, np.array(m.jnt_pos[j], float),
                                float(m.dof_armature[m.jnt_dofadr[j]]), subtree(b)))
    return out


def warn_unseen(drives: DriveSet, who: str) -> None:
    """Warn (``UserWarning``, issued here so that Python shows each scene's list once a process) that
    ``who`` (the rigid tree, MDGS's "dynamics" prior) leaves out what ``drives.unseen`` lists; nothing
    when it lists nothing."""
    if drives.unseen:
        import warnings

        warnings.warn(f"{who} uses the forward dynamics of mdgs.actuation, which leaves out, in this scene: "
                      + "; ".join(drives.unseen), UserWarning, stacklevel=1)


def actuation_forces(x: torch.Tensor, ctrl: torch.Tensor, drives: DriveSet, ref: torch.Tensor, seg: torch.Tensor,
                     n_obj: int, mass: torch.Tensor) -> torch.Tensor:
    """Node forces ``F_i = m_i a_i`` [B, N, 3] (N) of the motors' loads on free bodies (module docstring).

    This and :func:`motor_accelerations` share the motors' generalised forces (:func:`_motor_forces`).

    x : [B, N, 3] node positions (m); ctrl : [B, nu] controls (actuator units); ref : [N, 3] element
    centroids in their body frames; seg : [N] object of each node; mass : [N] element masses (kg).
    Returned in ``x``'s dtype; zero when there are no drives.
    """
    if not drives:
        return torch.zeros_like(x)
    dev, f64 = x.device, torch.float64
    T = drives.tensors(dev)
    xd, seg = x.to(f64), seg.to(dev)
    R, _ = kabsch(ref.to(dev, f64), xd, seg, n_obj)  # [B, S, 3, 3]: body rotations
    B = x.shape[0]
    u = _motor_forces(ctrl.to(dev, f64), T)  # [B, D]
    n = (R[:, T["child"]] @ T["axis"].unsqueeze(-1)).squeeze(-1)  # world axes [B, D, 3]
    load = u.unsqueeze(-1) * n
    tq = T["torque"].view(1, -1, 1)
    # summed loads per object; the world (parent -1) takes its reactions in slot n_obj, dropped
    force = xd.new_zeros(B, n_obj + 1, 3)
    torque = xd.new_zeros(B, n_obj + 1, 3)
    parent = torch.where(T["parent"] < 0, n_obj, T["parent"])
    torque.index_add_(1, T["child"], torch.where(tq, load, 0.0)).index_add_(1, parent, torch.where(tq, -load, 0.0))
    force.index_add_(1, T["child"], torch.where(tq, 0.0, load)).index_add_(1, parent, torch.where(tq, 0.0, -load))
    force, torque = force[:, :n_obj], torque[:, :n_obj]
    md = mass.to(dev, f64)
    cen = segment_mean(xd, seg, n_obj, md)  # [B, S, 3] element centroids
    alpha = (R @ T["inv_inertia"] @ R.transpose(-1, -2) @ torque.unsqueeze(-1)).squeeze(-1)  # I_w^-1 T
    lin = force / T["mass"].clamp_min(torch.finfo(f64).tiny).view(1, -1, 1)
    r = xd - cen[:, seg]
    acc = lin[:, seg] + torch.linalg.cross(alpha[:, seg], r, dim=-1)
    return (md.view(1, -1, 1) * acc).to(x.dtype)


def _motor_forces(ctrl: torch.Tensor, T: dict) -> torch.Tensor:
    """Generalised forces ``u_k = gear_k clip(gain_k clip(ctrl_k, ctrlrange), forcerange)`` [B, D]."""
    c = torch.minimum(torch.maximum(ctrl[:, T["actuator"]], T["ctrl_lo"]), T["ctrl_hi"])
    return T["gain"] * torch.minimum(torch.maximum(T["force_gain"] * c, T["force_lo"]), T["force_hi"])


def motor_accelerations(x: torch.Tensor, ctrl: torch.Tensor, drives: DriveSet, ref: torch.Tensor, seg: torch.Tensor,
                        n_obj: int) -> torch.Tensor:
    """Node accelerations [B, N, 3] (m/s^2) of the motors' joints with their parents held (module docstring).

    x : [B, N, 3] node positions (m); ctrl : [B, nu] controls; ref : [N, 3] element centroids in their
    body frames; seg : [N] object of each node. Returned in ``x``'s dtype; zero without drives.
    """
    if not drives:
        return torch.zeros_like(x)
    dev, f64 = x.device, torch.float64
    T = drives.tensors(dev)
    xd, seg = x.to(f64), seg.to(dev)
    R, t = kabsch(ref.to(dev, f64), xd, seg, n_obj)  # [B, S, 3, 3], [B, S, 3]: MuJoCo's xmat, xpos
    u = _motor_forces(ctrl.to(dev, f64), T)  # [B, D]
    Rc, tc = R[:, T["child"]], t[:, T["child"]]  # [B, D, 3, 3], [B, D, 3]
    n = (Rc @ T["axis"].unsqueeze(-1)).squeeze(-1)  # world axes [B, D, 3]
    A = (Rc @ T["anchor"].unsqueeze(-1)).squeeze(-1) + tc  # world anchors [B, D, 3]
    sub = T["subtree"].to(f64)  # [D, S]
    hinge = T["torque"].view(1, -1)
    # hinge: n^T I_b n + M_b |n x (x_b - A)|^2 for every (motor, object); slide: M_b
    xb = (R @ T["com"].unsqueeze(-1)).squeeze(-1) + t  # mass centres [B, S, 3]
    Iw = R @ T["inertia"] @ R.transpose(-1, -2)  # [B, S, 3, 3]
    rot = torch.einsum("bdi,bsij,bdj->bds", n, Iw, n)
    arm = torch.linalg.cross(n.unsqueeze(2).expand(-1, -1, n_obj, -1), xb.unsqueeze(1) - A.unsqueeze(2), dim=-1)
    per = torch.where(hinge.unsqueeze(-1), rot + T["mass"] * (arm ** 2).sum(-1), T["mass"].expand_as(rot))
    m_kk = (per * sub).sum(-1) + T["armature"]  # [B, D]
    qacc = u / m_kk.clamp_min(torch.finfo(f64).tiny)
    on = sub[:, seg]  # [D, N]: node i moves with motor d's subtree
    r = xd.unsqueeze(1) - A.unsqueeze(2)  # [B, D, N, 3]
    turn = torch.linalg.cross(n.unsqueeze(2).expand_as(r), r, dim=-1)
    field_ = torch.where(hinge.view(1, -1, 1, 1), turn, n.unsqueeze(2).expand_as(r))
    acc = (qacc.view(*qacc.shape, 1, 1) * on.view(1, *on.shape, 1) * field_).sum(1)
    return acc.to(x.dtype)


class Pose(NamedTuple):
    """Each object's pose fitted to its nodes, and its twist: what every step of the forward dynamics starts from.

    R : [B, S, 3, 3], t : [B, S, 3] the pose (:func:`mdgs.structure.kabsch`, float64); tw : the twists
    (:func:`mdgs.rigid.twist`), None without node velocities.
    """

    R: torch.Tensor
    t: torch.Tensor
    tw: Twist | None


def pose_of(x: torch.Tensor, v: torch.Tensor | None, ref: torch.Tensor, seg: torch.Tensor, n_obj: int,
            mass: torch.Tensor | None = None) -> Pose:
    """The :class:`Pose` of nodes ``x`` [B, N, 3] with velocities ``v`` (or None) and element ``mass`` [N];
    ``ref`` [N, 3] the nodes in their bodies' frames, ``seg`` [N] their objects."""
    dev, f64 = x.device, torch.float64
    xd, seg = x.to(f64), seg.to(dev)
    R, t = kabsch(ref.to(dev, f64), xd, seg, n_obj)
    return Pose(R, t, twist(xd, v, seg, n_obj, mass.to(dev)) if v is not None else None)


def _slots(mask: torch.Tensor, static: bool) -> torch.Tensor:
    """Indices [B, n] of each batch row's candidates with ``mask`` [B, C] first: as many as the batch's most (at
    least one) eagerly; compiled (``static``), all C, so that no shape follows the state."""
    order = torch.argsort((~mask).to(torch.int8), dim=-1, stable=True)
    return order if static else order[:, :max(int(mask.sum(-1).max()), 1)]


def _contact_rows(frame: torch.Tensor, P: torch.Tensor, obj: torch.Tensor, xs: torch.Tensor, S: int) -> torch.Tensor:
    """Rows [B, n, 3, 6S] over the objects' stacked accelerations ``(a_s, alpha_s)`` (or twists) of the contact
    points ``P`` [B, n, 3] of objects ``obj`` ([n] or [B, n]) along their frames ``frame`` [B, n, 3, 3] (rows: two
    tangents and the normal, :class:`Contacts`): ``d . (a_s + alpha_s x r) = d . a_s + (r x d) . alpha_s`` with
    ``r`` the point's offset from its object's mass centre ``xs`` [B, S, 3]."""
    B = frame.shape[0]
    obj = obj.expand(B, -1)
    arm = P - torch.gather(xs, 1, obj.unsqueeze(-1).expand(-1, -1, 3))  # [B, n, 3]
    loc = torch.cat([frame, torch.linalg.cross(arm.unsqueeze(-2).expand_as(frame), frame, dim=-1)], -1)
    onehot = torch.nn.functional.one_hot(obj, S).to(frame.dtype)  # [B, n, S]
    return torch.einsum("bcrk,bcs->bcrsk", loc, onehot).reshape(B, -1, 3, 6 * S)


def _rows(S: int, B: int, like: torch.Tensor, c: int, p: int, D: torch.Tensor, arm_c: torch.Tensor | None = None,
          arm_p: torch.Tensor | None = None) -> torch.Tensor:
    """Rows [B, k, 6 S] over the objects' stacked accelerations ``(a_s, alpha_s)`` of the relative acceleration of
    child ``c`` against parent ``p`` (-1: the world) along the directions ``D`` [B, k, 3]: angular when ``arm_c``
    is None, else of the point whose offsets from the mass centres are ``arm_c``, ``arm_p`` [B, 3]
    (``d . (alpha x r) = alpha . (r x d)``)."""
    out = like.new_zeros(B, D.shape[1], S, 6)
    if arm_c is None:
        out[:, :, c, 3:] = D
        if p >= 0:
            out[:, :, p, 3:] = -D
    else:
        out[:, :, c, :3] = D
        out[:, :, c, 3:] = torch.linalg.cross(arm_c.unsqueeze(1).expand_as(D), D, dim=-1)
        if p >= 0:
            out[:, :, p, :3] = -D
            out[:, :, p, 3:] = -torch.linalg.cross(arm_p.unsqueeze(1).expand_as(D), D, dim=-1)
    return out.reshape(B, D.shape[1], 6 * S)


class Contacts(NamedTuple):
    """Where the world's surfaces act on the corners (:func:`contacts`); candidates surface after surface.

    P : [B, C, 3] the corner (or rim point) in the world; frame : [B, C, 3, 3] rows two tangents and the surface's
    outward normal there; u : [B, C, 3] the corner's velocity; gap : [B, C] its distance along the
    normal (negative inside); held : [B, C] within ``CONTACT_GAP`` of the surface or reaching it within
    ``dt``; slide : [B, C] moving along the surface faster than friction could stop it within ``dt``
    (``|u_t| > mu |g| dt``); obj : [C] the corner's object; mu : [C] the pair's friction (the larger of
    the two geoms', as MuJoCo's); soft : [C, 7] the pair's ``solref`` and ``solimp`` (:func:`_contact_param`).
    """

    P: torch.Tensor
    frame: torch.Tensor
    u: torch.Tensor
    gap: torch.Tensor
    held: torch.Tensor
    slide: torch.Tensor
    obj: torch.Tensor
    mu: torch.Tensor
    soft: torch.Tensor | None = None


def _surface_distance(q: torch.Tensor, kind: str, size: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """Signed distance [...] (m, negative inside) and outward unit normal [..., 3] of points ``q`` [..., 3]
    given in a surface's own frame (:class:`Surface`); inside a box or cylinder, the nearest face's."""
    tiny = torch.finfo(q.dtype).tiny
    if kind == "plane":
        return q[..., 2], torch.zeros_like(q).index_fill_(-1, torch.tensor([2], device=q.device), 1.0)
    if kind in ("sphere", "capsule"):
        axial = q[..., 2:].clamp(-float(size[1]), float(size[1])) if kind == "capsule" else torch.zeros_like(q[..., 2:])
        r = q - torch.cat([torch.zeros_like(q[..., :2]), axial], -1)
        d = r.norm(dim=-1)
        return d - float(size[0]), r / d.clamp_min(tiny).unsqueeze(-1)
    if kind == "box":
        half = torch.as_tensor(size, dtype=q.dtype, device=q.device)
        out = q - torch.maximum(torch.minimum(q, half), -half)
        d_out = out.norm(dim=-1)
        depth = half - q.abs()  # [..., 3], all positive inside
        i = depth.argmin(-1, keepdim=True)
        sign = torch.where(torch.gather(q, -1, i) < 0, -1.0, 1.0).to(q.dtype)
        n_in = torch.zeros_like(q).scatter_(-1, i, sign)
        outside = d_out > 0
        return (torch.where(outside, d_out, -torch.gather(depth, -1, i).squeeze(-1)),
                torch.where(outside.unsqueeze(-1), out / d_out.clamp_min(tiny).unsqueeze(-1), n_in))
    # cylinder: radius size[0], half length size[1] along z
    rho = q[..., :2].norm(dim=-1)
    radial = torch.where((rho > 0).unsqueeze(-1), q[..., :2] / rho.clamp_min(tiny).unsqueeze(-1),
                         torch.tensor([1.0, 0.0], dtype=q.dtype, device=q.device))
    sz = torch.where(q[..., 2] < 0, -1.0, 1.0).to(q.dtype)
    dr, dz = rho - float(size[0]), q[..., 2].abs() - float(size[1])
    o_r, o_z = dr.clamp_min(0.0), dz.clamp_min(0.0)
    d_out = torch.hypot(o_r, o_z)
    n_out = torch.cat([o_r.unsqueeze(-1) * radial, (o_z * sz).unsqueeze(-1)], -1) / d_out.clamp_min(tiny).unsqueeze(-1)
    side = (dr > dz).unsqueeze(-1)
    n_in = torch.where(side, torch.cat([radial, torch.zeros_like(sz).unsqueeze(-1)], -1),
                       torch.cat([torch.zeros_like(radial), sz.unsqueeze(-1)], -1))
    outside = d_out > 0
    return torch.where(outside, d_out, torch.maximum(dr, dz)), torch.where(outside.unsqueeze(-1), n_out, n_in)


def contacts(R: torch.Tensor, t: torch.Tensor, tw, drives: DriveSet, dt: float) -> Contacts:
    """Where the world's surfaces act, by the rule of :func:`coupled_motor_accelerations` (:class:`Contacts`).

    ``R, t`` [B, S, 3, 3], [B, S, 3]: the objects' poses; ``tw``: their twists (:func:`mdgs.rigid.twist`).
    Candidates, surface by surface: every box corner; a cylinder's ``RIM_POINTS`` rim points against a
    surface that is not a plane, and against a plane each rim's lowest point and two more at +-120
    degrees (``RIM_SUPPORT``; any three when the rim lies flat). A corner wedged between a floor and a
    post is held by both."""
    f64, dev = torch.float64, R.device
    B = R.shape[0]
    obj = drives.const(drives.corner_obj, dev, torch.long)
    P_all = (R[:, obj] @ drives.const(drives.corners, dev).unsqueeze(-1)).squeeze(-1) + t[:, obj]
    corner_mu = drives.const(drives.corner_friction, dev)
    Q = len(drives.rim_obj)
    if Q:  # every rim's centre and axis in the world
        robj = drives.const(drives.rim_obj, dev, torch.long)
        rims = drives.const(drives.rims, dev)
        centre = (R[:, robj] @ rims[:, :3].unsqueeze(-1)).squeeze(-1) + t[:, robj]  # [B, Q, 3]
        axis = (R[:, robj] @ rims[:, 3:6].unsqueeze(-1)).squeeze(-1)
        radius = rims[:, 6].view(1, Q, 1, 1)
        phase = torch.tensor([2 * np.pi * k / RIM_SUPPORT for k in range(RIM_SUPPORT)], dtype=f64, device=dev)
    Ps, objs, mus, gaps, normals = [], [], [], [], []
    for sf in drives.surfaces:
        rot, pos = drives.const(sf.rot, dev), drives.const(sf.pos, dev)
        keep = drives.constants()["off_rim"] if sf.kind == "plane" else slice(None)  # not a mask: static shapes
        P, o, mu = P_all[:, keep], obj[keep], corner_mu[keep]
        if sf.kind == "plane" and Q:
            n = rot[:, 2]
            low = -(n - (axis @ n).unsqueeze(-1) * axis)  # towards the plane, across the axis [B, Q, 3]
            any_ = torch.linalg.cross(axis, torch.eye(3, dtype=f64, device=dev)[axis.abs().argmin(-1)], dim=-1)
            flat = low.norm(dim=-1, keepdim=True) < 1e-9
            d0 = torch.where(flat, any_, low)
            d0 = d0 / d0.norm(dim=-1, keepdim=True)
            d1 = torch.linalg.cross(axis, d0, dim=-1)
            ring = (phase.cos().view(1, 1, -1, 1) * d0.unsqueeze(2) + phase.sin().view(1, 1, -1, 1) * d1.unsqueeze(2))
            support = (centre.unsqueeze(2) + radius * ring).reshape(B, Q * RIM_SUPPORT, 3)
            P = torch.cat([P, support], 1)
            o = torch.cat([o, robj.repeat_interleave(RIM_SUPPORT)])
            mu = torch.cat([mu, drives.const(drives.rim_friction, dev).repeat_interleave(RIM_SUPPORT)])
        d, n = _surface_distance((P - pos) @ rot, sf.kind, sf.size)
        Ps.append(P)
        objs.append(o)
        mus.append(mu.clamp_min(sf.friction))
        gaps.append(d)
        normals.append(n @ rot.T)
    P, o, mu = torch.cat(Ps, 1), torch.cat(objs), torch.cat(mus)
    gap, n = torch.cat(gaps, 1), torch.cat(normals, 1)
    soft = torch.cat([drives.const(a, dev) for a in drives.contact_soft]) if drives.contact_soft else None
    u = tw.vc[:, o] + torch.linalg.cross(tw.omega[:, o], P - tw.c[:, o], dim=-1)
    # tangents: n x e with e the world axis least along n, then n x t1
    e = torch.eye(3, dtype=f64, device=dev)[n.abs().argmin(-1)]
    t1 = torch.linalg.cross(n, e, dim=-1)
    t1 = t1 / t1.norm(dim=-1, keepdim=True)
    frame = torch.stack([t1, torch.linalg.cross(n, t1, dim=-1), n], -2)
    un = (u * n).sum(-1)
    held = (gap < CONTACT_GAP) | (gap + dt * un.clamp_max(0.0) < CONTACT_GAP)
    slide = (u - un.unsqueeze(-1) * n).norm(dim=-1) > mu * drives.constants()["g"] * dt
    return Contacts(P, frame, u, gap, held, slide, o, mu, soft)


def _solve(K: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``torch.linalg.solve(K, b)`` for ``K`` [B, n, n], ``b`` [B, n]; one system at a time on a multi-threaded
    CPU beyond ``BATCHED_SOLVE_MAX`` unknowns (its comment). Compiled, ``torch.linalg.solve_ex`` without
    its error check, which reads a flag on the host (a CUDA graph cannot capture that): a singular system
    then gives non-finite accelerations, which a rollout counts as diverged, instead of raising."""
    if torch.compiler.is_compiling():
        return torch.linalg.solve_ex(K, b)[0]
    if K.device.type == "cpu" and K.shape[0] > 1 and K.shape[-1] > BATCHED_SOLVE_MAX and torch.get_num_threads() > 1:
        return torch.stack([torch.linalg.solve(K[i], b[i]) for i in range(K.shape[0])])
    return torch.linalg.solve(K, b)


def _solve_unpivoted(K: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``x`` [B, n] of ``K x = b`` (``K`` [B, n, n], ``b`` [B, n]) by Gauss-Jordan elimination without pivoting, as
    ``n`` steps of whole-matrix tensor operations that a compiled step fuses (``UNPIVOTED_SOLVE_MAX``). Only for
    systems whose symmetric part is positive definite and dominates (the soft passes' ``G^T M G + (Ju G)^T W (Ju G)``
    with the step's small gyroscopic term, :func:`_unilateral_solve`): their pivots stay positive and elimination
    without pivoting is stable (Golub and Van Loan, Matrix Computations, 4th ed., Sec. 4.2); the library's LU
    (``tests/test_soft_contact.py``) to round-off."""
    n = K.shape[-1]
    Kb = torch.cat([K, b.unsqueeze(-1)], -1)  # [B, n, n + 1]
    row = torch.arange(n, device=K.device).view(1, n, 1)
    for k in range(n):
        pivot = Kb[:, k: k + 1] / Kb[:, k: k + 1, k: k + 1]  # row k, its diagonal entry made one
        Kb = torch.where(row == k, pivot, Kb - Kb[:, :, k: k + 1] * pivot)
    return Kb[..., n]


def _soft_reference(pos: torch.Tensor, vel: torch.Tensor, lk: Link) -> tuple[torch.Tensor, torch.Tensor]:
    """MuJoCo's soft constraint for a limit at distance ``pos`` [B] (negative past it) closing at ``vel``
    [B]: the reference acceleration ``a_ref = -b vel - k d(pos) pos`` and the regularisation
    ``R = (1 - d) / d * invweight`` (``mj_makeImpedance``: ``b = 2 / (d_max tau)``, ``k = 1 / (d_max tau
    zeta)^2`` from ``solref = (tau, zeta)``, the impedance ``d`` from ``solimp``'s sigmoid in
    ``|pos| / width``; ``solref[0] < 0`` gives ``-k, -b`` directly)."""
    dmin, dmax, width, mid, power = lk.solimp
    pos = pos - lk.margin
    if dmin == dmax or width <= 1e-15:
        d = torch.full_like(pos, (dmin + dmax) / 2)
    else:
        x = (pos.abs() / width).clamp(0.0, 1.0)
        y = torch.where(x <= mid, x ** power / mid ** (power - 1), 1 - (1 - x) ** power / (1 - mid) ** (power - 1))
        d = dmin + y * (dmax - dmin)
    d = d.clamp(1e-4, 0.9999)  # mjMINIMP, mjMAXIMP
    if lk.solref[0] > 0:
        b, k = 2 / (dmax * lk.solref[0]), 1 / (dmax * lk.solref[0] * lk.solref[1]) ** 2
    else:
        b, k = -lk.solref[1] / dmax, -lk.solref[0] / dmax ** 2
    return -b * vel - k * d * pos, ((1 - d) / d * lk.invweight).clamp_min(1e-15)


def _soft_contact(gap: torch.Tensor, u: torch.Tensor, soft: torch.Tensor, invweight: torch.Tensor, mu: torch.Tensor,
                  dt: float) -> tuple[torch.Tensor, torch.Tensor]:
    """MuJoCo's soft contact for corners at ``gap`` [B, C] (negative inside) moving at ``u`` [B, C, 3] in their
    contact frames (two tangents, the normal), with the pairs' ``soft`` [C, 7] (``solref``, ``solimp``:
    :func:`_contact_param`), the translational ``invweight`` [C] of the moving body (``body_invweight0``) and friction
    ``mu`` [C]: the reference accelerations [B, C, 4] and the regularisation [B, C, 4] of the four edges of MuJoCo's
    pyramidal friction cone, ``J_n + mu J_t1``, ``J_n - mu J_t1``, ``J_n + mu J_t2``, ``J_n - mu J_t2`` (MuJoCo's
    order). Each edge is a unilateral row of its own that may only push: its reference is ``-b u_e - k d gap`` with
    ``u_e`` the edge's velocity ``u_n +- mu u_t`` (so a corner that slides approaches along one edge faster than along
    the normal, and the pyramid pushes harder than a normal row would), and its regularisation ``R_e = (1 - d) / d
    * 2 mu^2 (1 + mu^2) w`` (``mj_makeImpedance`` and ``mj_diagApprox``: ``b = 2 / (d_max tau)``, ``k = 1 / (d_max
    tau zeta)^2``, ``d`` from ``solimp``'s sigmoid in ``|gap| / width``; ``solref[0] < 0`` gives ``-k, -b``
    directly). The time constant is kept above ``2 dt`` as MuJoCo's ``refsafe`` does for its timestep. Read as the
    pyramid whatever the MJCF's ``cone`` (an elliptic cone's rows differ) and ``condim`` (torsional and rolling
    friction are not modelled, and ``condim = 1``'s single row would be softer for a frictionless pair): the
    studies' scenes are pyramidal with ``condim = 3``."""
    ref = soft[:, :2]
    dmin, dmax, width, mid, power = (soft[:, 2 + i] for i in range(5))
    tau = torch.where(ref[:, 0] > 0, ref[:, 0].clamp_min(2 * dt), ref[:, 0])
    dmin, dmax = dmin.clamp(1e-4, 0.9999), dmax.clamp(1e-4, 0.9999)
    k = torch.where(ref[:, 1] > 0, 1 / (dmax * tau * ref[:, 1]) ** 2, -ref[:, 1] / dmax ** 2)
    b = torch.where(tau > 0, 2 / (dmax * tau), -tau / dmax)
    x = (gap.abs() / width.clamp_min(1e-15)).clamp(0.0, 1.0)
    y = torch.where(x < mid, x ** power / mid ** (power - 1), 1 - (1 - x) ** power / (1 - mid) ** (power - 1))
    d = (dmin + y * (dmax - dmin)).clamp(1e-4, 0.9999)
    mu = mu.clamp_min(MIN_FRICTION)
    mut = mu.unsqueeze(-1) * u[..., :2]  # [B, C, 2]
    u_e = u[..., 2:] + torch.stack([mut[..., 0], -mut[..., 0], mut[..., 1], -mut[..., 1]], -1)  # [B, C, 4]
    a = -b.unsqueeze(-1) * u_e - (k * d * gap).unsqueeze(-1)
    R = (1 - d) / d * invweight * 2 * mu ** 2 * (1 + mu ** 2)
    return a, R.unsqueeze(-1).expand_as(a).clamp_min(1e-15)


def pyramid_frame(n: torch.Tensor) -> torch.Tensor:
    """MuJoCo's contact frame [..., 3, 3] (rows: two tangents, then the normal, as :class:`Contacts`) for unit
    normals ``n`` [..., 3] (``mju_makeFrame``: the first tangent is the world's y axis, or its z axis where ``n`` is
    within 60 degrees of y, made orthogonal to ``n``; the second ``n x t1``). The pyramid's edges lie along these
    tangents, so a sliding corner feels MuJoCo's cone only in MuJoCo's frame."""
    ey = torch.zeros_like(n).index_fill_(-1, torch.tensor([1], device=n.device), 1.0)
    ez = torch.zeros_like(n).index_fill_(-1, torch.tensor([2], device=n.device), 1.0)
    y0 = torch.where(n[..., 1:2].abs() < 0.5, ey, ez)
    t1 = y0 - (n * y0).sum(-1, keepdim=True) * n
    t1 = t1 / t1.norm(dim=-1, keepdim=True)
    return torch.stack([t1, torch.linalg.cross(n, t1, dim=-1), n], -2)


def _unilateral_solve(M: torch.Tensor, F: torch.Tensor, Jm: torch.Tensor, b0: torch.Tensor, D: torch.Tensor,
                      Ju: torch.Tensor, ru: torch.Tensor, Ru: torch.Tensor, held: torch.Tensor, static: bool,
                      keep: torch.Tensor | None = None, start: torch.Tensor | None = None,
                      d: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """The stacked accelerations ``z`` [B, 6S] of ``M z = F + Jm^T l_m + Ju^T l_u`` with the bilateral rows ``Jm z =
    b0`` ([B, C0, 6S], [B, C0]) and the soft unilateral rows ``Ju`` [B, U, 6S] (references ``ru``, regularisation
    ``Ru``, [B, U]) of which those ``held`` [B, U] may push: MuJoCo's soft constraints, each row ``J z - R l = a_ref``
    while it pushes (``J z < a_ref``) and free otherwise, the unique minimum of Gauss's principle plus the rows'
    quadratic penalties that MuJoCo's solvers find. Found by Newton's method on the rows' states (which rows push,
    read from the last solve's ``J z - a_ref``), as MuJoCo's Newton solver does without its line search: it stops
    once the states repeat (``SOFT_CONTACT_PASSES`` at most; compiled for the CPU, in a ``torch.while_loop``
    that stops likewise; compiled for another device, or uncompiled with ``static``, all of them).

    A pushing row's force is ``l = W (a_ref - J z)``, ``W = diag(pushing / R)`` [B, U], so the rows leave the system
    (Schur's complement). The bilateral rows leave it too: with ``D`` [B, n, 6S] rows that complete ``Jm`` to a
    square, invertible ``P = [Jm; D]`` (:func:`_generalised_rows`, ``n = 6S - C0`` the tree's degrees of freedom),
    every ``z`` that keeps ``Jm z = b0`` is ``z = G y + zp`` with ``P [G zp] = [[0, b0]; [I, 0]]`` (one factorisation
    of ``P`` a call), and ``G^T`` times the equations of motion leaves Gauss's principle in the ``n`` coordinates
    ``y``::

        (G^T M G + (Ju G)^T W (Ju G)) y = G^T (F - M zp) + (Ju G)^T W (a_ref - Ju zp)

    (``G^T Jm^T = 0``): each pass solves a system of the tree's degrees of freedom (9 on the Cubli, 8 on
    rotational-center) and multiplies the rows by ``n`` columns instead of ``6S``, whatever the number of rows that
    push or could; the same ``z`` as with the rows' forces and the joints' as unknowns (to round-off,
    ``tests/test_soft_contact.py``). Compiled, every row enters (no shape follows the state) and a system of at most
    ``UNPIVOTED_SOLVE_MAX`` unknowns is solved by fused elimination (:func:`_solve_unpivoted`); eagerly the batch's
    held rows only, by the library's LU. ``keep`` [6S - 6k] (int64): the columns of the objects that move, where
    ``Jm``'s first ``6k`` rows hold the other ``k`` still (the world's elements, :func:`_tree`): those accelerations
    are zero, so their rows and columns leave the system first.

    ``start`` [B, U] (bool): the rows that may start pushing (the first pass's states are ``held & start``; all held
    rows without it), so that a solve starts from the states its predecessor in the step settled on
    (``warm`` of :func:`coupled_motor_accelerations`). Where the states settle, the accelerations are those of the
    settled states whatever the start.

    ``d`` [B, n]: with it, the rows hold ``Ju z = ru + Ju z0`` instead of ``ru``, ``z0`` the bias accelerations of
    :func:`_bias_accelerations` (``Jm z0 = b0``, ``D z0 = d``), which the factorisation of ``P`` gives without a
    solve of their own: ``z0 = zp + G d``, so ``a_ref - Ju zp = ru + (Ju G) d``. Returns ``z`` and the states [B, U]
    the last pass decided (every candidate, held or not)."""
    if keep is not None and keep.shape[0] < M.shape[-1]:
        r0 = M.shape[-1] - keep.shape[0]
        z, pushes = _unilateral_solve(M[:, keep][:, :, keep], F[:, keep], Jm[:, r0:][:, :, keep], b0[:, r0:],
                                      D[:, :, keep], Ju[:, :, keep], ru, Ru, held, static, start=start, d=d)
        return M.new_zeros(M.shape[0], M.shape[-1]).index_copy(1, keep, z), pushes
    B, C0, n = Jm.shape[0], Jm.shape[1], D.shape[1]
    # z = G y + zp keeps the bilateral rows: [Jm; D] [G zp] = [[0, b0]; [I, 0]]
    rhs = torch.cat([torch.cat([M.new_zeros(B, C0, n), b0.unsqueeze(-1)], -1),
                     torch.cat([torch.eye(n, dtype=M.dtype, device=M.device).expand(B, n, n), M.new_zeros(B, n, 1)],
                               -1)], 1)
    X = _solve(torch.cat([Jm, D], 1), rhs)  # [B, 6S, n + 1]
    G, zp = X[..., :n], X[..., n]
    GT = G.transpose(-1, -2)
    Mr = GT @ M @ G  # [B, n, n]
    fr = (GT @ (F - (M @ zp.unsqueeze(-1)).squeeze(-1)).unsqueeze(-1)).squeeze(-1)  # [B, n]
    active = held if start is None else held & start
    every = held
    if not static:  # eagerly, only the rows that may push: as many as the batch's most (many candidates, few held)
        sel = _slots(held, False)  # [B, k]
        Ju = torch.gather(Ju, 1, sel.unsqueeze(-1).expand(-1, -1, Ju.shape[-1]))
        ru, Ru, held = torch.gather(ru, 1, sel), torch.gather(Ru, 1, sel), torch.gather(held, 1, sel)
        active = torch.gather(active, 1, sel)
    JG = Ju @ G  # [B, U, n]
    if d is None:
        gap = ru - (Ju @ zp.unsqueeze(-1)).squeeze(-1)  # a_ref - Ju zp [B, U]
    else:  # a_ref = ru + Ju (zp + G d)
        gap = ru + (JG * d.unsqueeze(1)).sum(-1)
    solve = _solve_unpivoted if torch.compiler.is_compiling() and n <= UNPIVOTED_SOLVE_MAX else _solve

    def newton(active: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # one pass: y and the states it decides
        JGT = JG.transpose(-1, -2)  # taken here: a while_loop refuses captured tensors that alias each other
        W = active.to(M.dtype) / Ru  # [B, U]
        y = solve(Mr + JGT @ (W.unsqueeze(-1) * JG), fr + (JGT @ (W * gap).unsqueeze(-1)).squeeze(-1))
        return y, held & ((JG @ y.unsqueeze(-1)).squeeze(-1) < gap)

    if static and torch.compiler.is_compiling() and M.device.type == "cpu":  # compiled for the CPU: the loop
        # itself compiled, stopping as eagerly (every pass after the states repeat would solve the same system)
        def unsettled(k, y, active, settled):
            return (k < SOFT_CONTACT_PASSES) & ~settled

        def one_pass(k, y, active, settled):
            y, pushes = newton(active)
            return k + 1, y.clone(memory_format=torch.contiguous_format), pushes, (pushes == active).all()

        _, y, pushes, _ = torch.while_loop(unsettled, one_pass, (torch.zeros((), dtype=torch.int64, device=M.device),
                                                                 fr.new_zeros(B, n), active.clone(),
                                                                 torch.zeros((), dtype=torch.bool, device=M.device)))
    else:
        for _ in range(SOFT_CONTACT_PASSES):
            y, pushes = newton(active)
            if not static and bool((pushes == active).all()):
                break
            active = pushes
        if not static:
            pushes = torch.zeros_like(every).scatter(1, sel, pushes)
    return (G @ y.unsqueeze(-1)).squeeze(-1) + zp, pushes


def _joint_angles(R: torch.Tensor, t: torch.Tensor, lk: Link, drives: DriveSet) -> torch.Tensor:
    """MuJoCo's ``qpos`` [B] of link ``lk``'s hinge or slide from the objects' poses (:class:`Link`)."""
    f64, dev = torch.float64, R.device
    c, p = lk.child, lk.parent
    Rp = R[:, p] if p >= 0 else torch.eye(3, dtype=f64, device=dev).expand_as(R[:, c])
    axis = drives.const(lk.axis, dev)
    if lk.kind == "hinge":
        A = Rp.transpose(-1, -2) @ R[:, c] @ drives.const(lk.frame0, dev).T  # Rot(axis, q - q0)
        vee = torch.stack([A[:, 2, 1] - A[:, 1, 2], A[:, 0, 2] - A[:, 2, 0], A[:, 1, 0] - A[:, 0, 1]], -1) / 2
        cos = (A.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2
        return lk.qpos0 + torch.atan2(vee @ axis, cos)
    tp = t[:, p] if p >= 0 else torch.zeros_like(t[:, c])
    rel = (Rp.transpose(-1, -2) @ (t[:, c] - tp).unsqueeze(-1)).squeeze(-1)
    return lk.qpos0 + (rel - drives.const(lk.origin, dev)) @ axis


def push_out(x: torch.Tensor, v: torch.Tensor, drives: DriveSet, ref: torch.Tensor, seg: torch.Tensor, n_obj: int,
             mass: torch.Tensor, pose: Pose | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Move the tree out of the world's surfaces, keeping its twists: a position correction after a step.

    The contact rows of :func:`coupled_motor_accelerations` hold accelerations: a corner that ends a
    frame inside a surface (the trapezoidal step's half-frame of travel after an impact, a rolling rim
    whose linearised path dips) stays there and sinks further with every such frame. Here the
    smallest mass-weighted displacement of the objects, ``d = (a_s, alpha_s)`` (translation of each
    mass centre, rotation vector), that puts every penetrating corner back on its surface with the
    joints and the world's elements kept::

        [ M   J^T ] [ d ]   [  0   ]       J: the joints' and the fixed objects' rows of the tree
        [ J    0  ] [ l ] = [  0   ]       (:func:`coupled_motor_accelerations`), N: the normal rows of the
        [ N    .  ]         [ -gap ]       corners with ``gap < 0`` (:func:`contacts`)

    (the same system with displacements for accelerations; a corner whose surface would have to pull
    is let go, ``CONTACT_PASSES`` passes, and the rows have ``CONTACT_COMPLIANCE``). Each object moves
    rigidly by its ``d`` (:func:`mdgs.rigid.advance` over no time), its twist unchanged: the split
    impulse of game physics (Catto 2006; Tonge et al. 2012), where Baumgarte's correction through the
    velocities would launch the bodies. Linear in ``d``: a correction of a few millimetres leaves an
    error of its square over the lever arm. ``x, v`` [B, N, 3]; returns them moved, in ``x``'s dtype, or
    the very tensors ``x, v`` (eager) where no corner is inside a surface; ``pose``: their :class:`Pose`, when
    the caller has it."""
    if not (len(drives.corner_obj) or len(drives.rim_obj)):
        return x, v
    dev, f64 = x.device, torch.float64
    T = drives.tensors(dev)
    xd, seg, mass = x.to(f64), seg.to(dev), mass.to(dev)
    B, S = x.shape[0], n_obj
    R, t, tw = pose if pose is not None else pose_of(x, v, ref, seg, n_obj, mass)
    still = tw._replace(vc=torch.zeros_like(tw.vc), omega=torch.zeros_like(tw.omega))
    ct = contacts(R, t, still, drives, 1.0)
    active = ct.gap < -PUSH_OUT_SLOP  # [B, C]
    static = torch.compiler.is_compiling()
    if not static and not bool(active.any()):
        return x, v
    # eager, the penetrating corners first, as many slots as the batch's most (a scene with many colliding boxes
    # has hundreds of candidates and a handful inside); compiled, every candidate keeps its slot (static shapes)
    sel = _slots(active, static)
    active, gap = torch.gather(active, 1, sel), torch.gather(ct.gap, 1, sel)  # [B, n]
    xs, M, _, J, _, _ = _tree(xd, R, t, T, drives, S, None)
    Jm = torch.cat(J, 1) if J else xd.new_zeros(B, 0, 6 * S)
    C0 = Jm.shape[1]
    frame = torch.gather(ct.frame, 1, sel.view(*sel.shape, 1, 1).expand(-1, -1, 3, 3))
    P = torch.gather(ct.P, 1, sel.unsqueeze(-1).expand(-1, -1, 3))
    Nc = _contact_rows(frame, P, ct.obj[sel], xs, S)[:, :, 2]  # the normal rows [B, n, 6S]
    for _ in range(CONTACT_PASSES):
        on = active.to(f64)
        Jall = torch.cat([Jm, Nc * on.unsqueeze(-1)], 1)
        diag = torch.cat([xd.new_zeros(B, C0), torch.where(active, -CONTACT_COMPLIANCE, 1.0)], -1)
        K = torch.cat([torch.cat([M, Jall.transpose(-1, -2)], -1), torch.cat([Jall, torch.diag_embed(diag)], -1)], 1)
        b = torch.cat([xd.new_zeros(B, 6 * S + C0), -PUSH_OUT_FRACTION * (gap + PUSH_OUT_SLOP) * on], -1)
        sol = _solve(K, b)
        pulls = active & (sol[:, 6 * S + C0:] > 0)
        if not static and not bool(pulls.any()):
            break
        active = active & ~pulls
    d = sol[:, :6 * S].view(B, S, 6)
    alpha = d[..., 3:]
    dc = d[..., :3] + torch.linalg.cross(alpha, tw.c - xs, dim=-1)  # the node centre's displacement
    xn, vn = advance(xd, tw, tw.vc, tw.omega, 0.0, seg, dc, alpha)
    return xn.to(x.dtype), vn.to(v.dtype)


def project_velocities(x: torch.Tensor, v: torch.Tensor, drives: DriveSet, ref: torch.Tensor, seg: torch.Tensor,
                       n_obj: int, mass: torch.Tensor, x_from: torch.Tensor | None = None,
                       dt: float | None = None) -> torch.Tensor:
    """The objects' twists made to satisfy the joints by the least kinetic energy change: node velocities [B, N, 3].

    The joints' rows ``J`` of the tree at the poses of ``x`` [B, N, 3] (:func:`coupled_motor_accelerations`: a
    hinge's anchor and cross-axis rows, a slide's, the world's elements held) hold the stacked twists
    ``nu = (v_s, w_s)`` (velocity of each mass centre, angular velocity) when ``J nu = 0``; the twists of ``v``
    are moved onto that set by the change of least kinetic energy::

        [ M   J^T ] [ d nu ]   [    0    ]        M: the tree's mass matrix (armature included)
        [ J    0  ] [  l   ] = [ -J nu   ]

    so that the change is a set of equal and opposite impulses at the joints, ``-M^-1 J^T l``: the linear and
    angular momentum of bodies jointed only to one another are kept (a joint to the world, or a body of the
    world, takes what it must), where a projection that hands each child its parent's twist across the joint
    (:func:`mdgs.joints.project_joints`) drops the child's share, and with a heavy rotor on a light carrier
    (rotational-center's) moves the rotor to the carrier instead of both to their common motion.
    ``x_from``: the nodes that ``v`` belongs to, when ``x`` is their projected placement (each body's twist,
    fitted to ``x_from, v``, is carried to ``x`` as a body property: the velocity of its mass centre and its
    angular velocity); default ``x``. ``dt``: the corners the world's surfaces hold over ``dt`` (:func:`contacts`)
    keep their velocities, rows ``J_c d nu = 0`` (three for a sticking corner, the normal for a sliding one, with
    ``CONTACT_COMPLIANCE``; a corner whose surface would have to pull is let go, ``CONTACT_PASSES`` passes), so
    that the joints' impulses do not move a body its contacts hold (a resting cube under its flywheels), as they
    would otherwise. Returns ``v'`` in ``v``'s dtype, velocities of the rigid motions at ``x``; ``v`` unchanged
    without joints."""
    if not drives.links and not drives.constants()["fixed"]:
        return v
    dev, f64 = x.device, torch.float64
    T = drives.tensors(dev)
    xd, seg, mass = x.to(f64), seg.to(dev), mass.to(dev)
    B, S = x.shape[0], n_obj
    R, t, _ = pose_of(x, None, ref, seg, n_obj)
    xs, M, _, J, _, _ = _tree(xd, R, t, T, drives, S, None)
    if not J:
        return v
    src = xd if x_from is None else x_from.to(f64)
    tw = twist(src, v.to(f64), seg, n_obj, mass)
    if x_from is None:
        v_ms = tw.vc + torch.linalg.cross(tw.omega, xs - tw.c, dim=-1)
    else:  # the same body point (its mass centre) before the placement moved it
        R0, t0, _ = pose_of(x_from, None, ref, seg, n_obj)
        xs0 = (R0 @ T["com"].unsqueeze(-1)).squeeze(-1) + t0
        v_ms = tw.vc + torch.linalg.cross(tw.omega, xs0 - tw.c, dim=-1)
    nu = torch.cat([v_ms, tw.omega], -1).reshape(B, 6 * S)
    Jm = torch.cat(J, 1)
    C = Jm.shape[1]
    b_j = -(Jm @ nu.unsqueeze(-1)).squeeze(-1)
    rows, on = xd.new_zeros(B, 0, 6 * S), xd.new_zeros(B, 0)
    if dt is not None and (len(drives.corner_obj) or len(drives.rim_obj)):
        ct = contacts(R, t, Twist(xs, v_ms, tw.omega, tw.J), drives, dt)  # the twists about the mass centres
        held = ct.held  # [B, Q]
        if not bool(held.any()):
            dt = None
        else:
            sel = _slots(held, False)
            held = torch.gather(held, 1, sel)
            frame = torch.gather(ct.frame, 1, sel.view(*sel.shape, 1, 1).expand(-1, -1, 3, 3))
            P = torch.gather(ct.P, 1, sel.unsqueeze(-1).expand(-1, -1, 3))
            rows = _contact_rows(frame, P, ct.obj[sel], xs, S).reshape(B, -1, 6 * S)  # [B, 3n, 6S]
            slide = torch.gather(ct.slide, 1, sel)
            on = (held.unsqueeze(-1) & torch.stack([~slide, ~slide, torch.ones_like(slide)], -1)).to(f64).view(B, -1)
    for _ in range(CONTACT_PASSES if dt is not None else 1):
        Jall = torch.cat([Jm, rows * on.unsqueeze(-1)], 1)
        diag = torch.cat([xd.new_zeros(B, C), torch.where(on > 0, -CONTACT_COMPLIANCE, 1.0)], -1)
        K = torch.cat([torch.cat([M, Jall.transpose(-1, -2)], -1), torch.cat([Jall, torch.diag_embed(diag)], -1)], 1)
        sol = _solve(K, torch.cat([xd.new_zeros(B, 6 * S), b_j, torch.zeros_like(on)], -1))
        if dt is None:
            break
        lz = sol[:, 6 * S + C:].view(B, -1, 3)[..., 2]  # the push of each held corner's surface is -lz
        pulls = (lz > 0) & (on.view(B, -1, 3)[..., 2] > 0)
        if not bool(pulls.any()):
            break
        on = on * (~pulls).to(f64).repeat_interleave(3, -1)
    z = (nu + sol[:, :6 * S]).view(B, S, 6)
    out = z[:, seg, :3] + torch.linalg.cross(z[:, seg, 3:], xd - xs[:, seg], dim=-1)
    return out.to(v.dtype)


def _world_of(R: torch.Tensor, t: torch.Tensor, s: int, v: np.ndarray, drives: DriveSet,
              point: bool = False) -> torch.Tensor:
    """Vectors (points) [k, 3] or [3] given in object s's frame (-1: the world) in the world [B, k, 3], the
    objects' poses ``R, t`` [B, S, 3, 3], [B, S, 3]; ``v`` one of ``drives``' arrays."""
    vv = drives.const(v, R.device).view(-1, 3).expand(R.shape[0], -1, 3)
    if s < 0:
        return vv
    return (R[:, s].unsqueeze(1) @ vv.unsqueeze(-1)).squeeze(-1) + (t[:, s].unsqueeze(1) if point else 0.0)


def _joint_row(S: int, B: int, xd: torch.Tensor, xs: torch.Tensor, c: int, p: int, kind: str, n: torch.Tensor,
               A: torch.Tensor) -> torch.Tensor:
    """Row [B, 1, 6S] of the joint's rate: hinge ``n . (alpha_c - alpha_p)``, slide ``n . (a_c(A) - a_p(A))``."""
    if kind == "hinge":
        return _rows(S, B, xd, c, p, n)
    return _rows(S, B, xd, c, p, n, A - xs[:, c], A - xs[:, p] if p >= 0 else None)


def _tree(xd: torch.Tensor, R: torch.Tensor, t: torch.Tensor, T: dict, drives: DriveSet, S: int,
          w: torch.Tensor | None, h: float | None = None) -> tuple:
    """The tree's mass matrix and joint rows at the poses ``R, t`` (:func:`coupled_motor_accelerations`).

    Returns the mass centres ``xs`` [B, S, 3], ``M`` [B, 6S, 6S] (with the joints' armature), the world
    inertias ``ang`` [B, S, 3, 3], the rows ``J`` (a list of [B, k, 6S]: the world's elements held, each
    link's) with their right-hand sides ``rhs`` (list of [B, k]: the velocity terms of the twists ``w``
    [B, S, 3], zero without them) and ``rate`` (child object -> its hinge's or slide's rate row [B, 1, 6S]).
    With a step ``h`` (``gyroscopic`` of :func:`coupled_motor_accelerations`), each of a hinge's two cross-axis
    rows is less ``h`` times its velocity term's gradient in the twists' angular velocities, the row of
    ``J z = rhs(w + h z)`` linearised, so that the term acts at the step's end."""
    B, dev, f64 = xd.shape[0], xd.device, torch.float64
    xs = (R @ T["com"].unsqueeze(-1)).squeeze(-1) + t  # mass centres [B, S, 3]
    fixed = drives.const(drives.fixed, dev, torch.bool)
    eye3 = torch.eye(3, dtype=f64, device=dev)
    lin = torch.where(fixed.view(S, 1, 1), eye3, T["mass"].view(S, 1, 1) * eye3)  # [S, 3, 3]
    ang = torch.where(fixed.view(1, S, 1, 1), eye3, R @ T["inertia"] @ R.transpose(-1, -2))  # [B, S, 3, 3]
    blocks = xd.new_zeros(B, S, 6, 6)
    blocks[:, :, :3, :3] = lin
    blocks[:, :, 3:, 3:] = ang
    M = torch.einsum("bsij,st->bsitj", blocks, torch.eye(S, dtype=f64, device=dev)).reshape(B, 6 * S, 6 * S)
    J, rhs = [], []
    zero3 = xd.new_zeros(B, 3)
    for s in drives.constants()["fixed"]:  # the world's elements stay put
        J.append(torch.eye(6 * S, dtype=f64, device=dev)[6 * s: 6 * s + 6].expand(B, 6, 6 * S))
        rhs.append(xd.new_zeros(B, 6))
    world = eye3.expand(B, 3, 3)
    rate = {}  # child object -> its joint's rate row
    for lk in drives.links:
        c, p = lk.child, lk.parent
        A = _world_of(R, t, p, lk.anchor, drives, point=True)[:, 0]
        rc, rp = A - xs[:, c], (A - xs[:, p] if p >= 0 else None)
        wc = w[:, c] if w is not None else zero3
        wp = w[:, p] if w is not None and p >= 0 else zero3
        if lk.kind in ("hinge", "ball", "weld"):
            J.append(_rows(S, B, xd, c, p, world, rc, rp))
            rp0 = rp if rp is not None else zero3
            rhs.append(-(torch.linalg.cross(wc, torch.linalg.cross(wc, rc, dim=-1), dim=-1)
                         - torch.linalg.cross(wp, torch.linalg.cross(wp, rp0, dim=-1), dim=-1)))
        if lk.kind in ("slide", "weld"):
            J.append(_rows(S, B, xd, c, p, world))
            rhs.append(xd.new_zeros(B, 3))
        if lk.kind == "hinge":
            D = _world_of(R, t, p, lk.perp, drives)  # [B, 2, 3], turning with the parent
            J.append(_rows(S, B, xd, c, p, D))
            rhs.append((D * torch.linalg.cross(wp, wc - wp, dim=-1).unsqueeze(1)).sum(-1))
            if h is not None:  # d/dw_c of D . (w_p x (w_c - w_p)) is D x w_p, d/dw_p is w_c x D
                blk = J[-1].view(B, 2, S, 6)
                blk[:, :, c, 3:] -= h * torch.linalg.cross(D, wp.unsqueeze(1).expand_as(D), dim=-1)
                if p >= 0:
                    blk[:, :, p, 3:] -= h * torch.linalg.cross(wc.unsqueeze(1).expand_as(D), D, dim=-1)
        if lk.kind == "slide":
            J.append(_rows(S, B, xd, c, p, _world_of(R, t, p, lk.perp, drives), rc, rp))
            rhs.append(xd.new_zeros(B, 2))
        if lk.kind in ("hinge", "slide"):
            rate[c] = _joint_row(S, B, xd, xs, c, p, lk.kind, _world_of(R, t, p, lk.axis, drives), A)  # [B, 1, 6S]
            if lk.armature > 0:
                M = M + lk.armature * rate[c].transpose(-1, -2) @ rate[c]
    return xs, M, ang, J, rhs, rate


def _generalised_rows(xd: torch.Tensor, R: torch.Tensor, t: torch.Tensor, xs: torch.Tensor, w: torch.Tensor,
                      drives: DriveSet, S: int, rate: dict) -> tuple[torch.Tensor, torch.Tensor]:
    """Rows ``D`` [B, n, 6S] and values ``d`` [B, n] with ``D z = d`` exactly where every joint's generalised
    acceleration (MuJoCo's ``qacc``) is zero, ``z`` the objects' stacked accelerations: ``D z - d`` are ``n``
    coordinates of the tree's generalised accelerations. Each root (and each free child, and each object left out of
    the links) gives six, its own accelerations (``d``: its mass centre's acceleration while its origin is
    unaccelerated and its angular velocity constant); each hinge and slide one, its rate row (:func:`_tree`'s
    ``rate``; a hinge's ``qdd = n . (alpha_c - alpha_p) - n . (w_p x (w_c - w_p))``); each ball three, the relative
    angular acceleration; welds and the world's elements none. Stacked under the joints' rows ``J`` of :func:`_tree`
    they make a square system: the joints fix ``6S - n`` accelerations, these the other ``n``."""
    B, dev, f64 = xd.shape[0], xd.device, torch.float64
    rows, vals = [], []
    links = {lk.child: lk for lk in drives.links}
    fixed = set(int(s) for s in drives.constants()["fixed"])
    eye = torch.eye(6 * S, dtype=f64, device=dev)
    zero3 = xd.new_zeros(B, 3)
    for s in range(S):
        lk = links.get(s)
        if s in fixed or (lk is not None and lk.kind == "weld"):
            continue
        if lk is None or lk.kind == "free":  # the origin t unaccelerated, the angular velocity constant
            rows.append(eye[6 * s: 6 * s + 6].expand(B, 6, 6 * S))
            ws = w[:, s]
            vals.append(torch.cat([torch.linalg.cross(ws, torch.linalg.cross(ws, xs[:, s] - t[:, s], dim=-1), dim=-1),
                                   zero3], -1))
            continue
        wc, wp = w[:, s], (w[:, lk.parent] if lk.parent >= 0 else zero3)
        if lk.kind == "hinge":  # qdd = n . (alpha_c - alpha_p) - n . (w_p x (w_c - w_p))
            n = _world_of(R, t, lk.parent, lk.axis, drives)[:, 0]
            rows.append(rate[s])
            vals.append((n * torch.linalg.cross(wp, wc - wp, dim=-1)).sum(-1, keepdim=True))
        elif lk.kind == "slide":  # the slide's rate row carries no velocity term (:func:`_tree`)
            rows.append(rate[s])
            vals.append(xd.new_zeros(B, 1))
        else:  # ball: the relative angular velocity constant in the child's frame
            rows.append(_rows(S, B, xd, s, lk.parent, torch.eye(3, dtype=f64, device=dev).expand(B, 3, 3)))
            vals.append(torch.linalg.cross(wc, wc - wp, dim=-1))
    if not rows:
        return xd.new_zeros(B, 0, 6 * S), xd.new_zeros(B, 0)
    return torch.cat(rows, 1), torch.cat(vals, -1)


def _bias_accelerations(J: list, rhs: list, D: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """The objects' stacked accelerations ``z0`` [B, 6S] while every joint's generalised acceleration is zero
    (MuJoCo's ``qacc = 0``: each root's origin unaccelerated and its local angular velocity constant, each hinge,
    slide and ball turning or sliding at a constant rate): the velocity-product part of the objects' accelerations in
    MuJoCo's coordinates, its ``cdof_dot qvel``, from :func:`_tree`'s joint rows ``J`` and right-hand sides ``rhs``
    (without the step's linearisation) and :func:`_generalised_rows`' ``D z = d``. A soft constraint's row holds
    ``J qacc``, the point's acceleration less that part, which is ``J (z - z0)`` here. Where the frame's origin of a
    root is its mass centre and the contacts are on roots (the Cubli), ``J z0`` is zero; on a chain
    (rotational-center's disc, two hinges down a free base) it is the chain's Coriolis and centripetal
    acceleration."""
    return _solve(torch.cat([*J, D], 1), torch.cat([*rhs, d], -1))


def coupled_motor_accelerations(x: torch.Tensor, ctrl: torch.Tensor, drives: DriveSet, ref: torch.Tensor,
                                seg: torch.Tensor, n_obj: int, v: torch.Tensor | None = None,
                                mass: torch.Tensor | None = None, dt: float | None = None,
                                gyroscopic: str = "explicit", pose: Pose | None = None,
                                contact: str = "rigid", warm: dict | None = None) -> torch.Tensor:
    """Node accelerations [B, N, 3] (m/s^2) of the motors with every joint coupled: MuJoCo's ``M^-1 qfrc_actuator``.

    Unlike :func:`motor_accelerations` (the driven joint alone, its parent held) the parent recoils and
    the other joints pass the load on: a Cubli's cube turns against its braking flywheel, a cart's
    pole swings as the cart is pushed. Newton-Euler in Cartesian form with the joints as constraints
    (the same equations as MuJoCo's joint-space ``M qacc = qfrc``, as the test against ``mj_solveM``
    shows), for the stacked accelerations ``z = (a_s, alpha_s)`` of every object's mass centre
    ``x_s = R_s body_ipos + t_s`` and rotation::

        [ M   J^T ] [ z ]   [ sum_k u_k g_k ]        M = diag(M_s I_3, I_s^w) + sum_j armature_j g_j g_j^T
        [ J    0  ] [ l ] = [       0       ]

    ``g_j`` the row of joint ``j``'s rate (hinge ``n . (alpha_c - alpha_p)``, slide ``n . (a_c(A) -
    a_p(A))`` at the anchor ``A``), ``J`` the rows a link fixes (hinge: the anchor's relative
    acceleration and the relative angular acceleration across ``n``; slide: the relative angular
    acceleration and the anchor's across ``n``; ball: the anchor's; weld: all six; free: none) and the
    world's elements held still. Without velocities, velocity terms (gyroscopic, Coriolis, the joints'
    centripetal terms) are left out, as they do not depend on the controls. Node accelerations are
    ``a_s + alpha_s x (x_i - x_s)``. Objects named in ``drives.unlinked`` move freely; every moving
    object needs a positive mass and inertia or a link that fixes it. Shapes as
    :func:`motor_accelerations`; float64 inside, returned in ``x``'s dtype.

    **Forward dynamics** (given the node velocities ``v`` [B, N, 3], the element ``mass`` [N] and the frame
    ``dt``): the same system with everything else a rigid tree among static obstacles feels, so that the
    result is MuJoCo's ``qacc`` up to its contact model. The right-hand side gains gravity ``M_s g`` on
    every moving object and the gyroscopic torque ``-w_s x (I_s^w w_s)``; each constraint row gains its
    velocity term (a hinge or ball anchor: ``-(w_c x (w_c x r_c) - w_p x (w_p x r_p))``; a hinge's
    two cross-axis rows ``p . (w_p x (w_c - w_p))``, the axis turning with the parent; slides without
    theirs). The twists ``w_s`` are the least-squares fits of :func:`mdgs.rigid.twist`.

    ``gyroscopic`` ("explicit", "implicit", "midpoint": ``GYROSCOPIC``): the gyroscopic terms act at the start
    of the step ``dt``, or, linearised, at its end or halfway (one Newton step of the implicit update; Catto
    2015, Bullet's implicit gyroscopic force): with ``h`` = ``dt`` or ``dt / 2``, each moving object's angular
    block of ``M`` gains ``h (skew(w_s) I_s^w - skew(I_s^w w_s))``, the gradient of its torque
    ``w_s x I_s^w w_s``, and each hinge's cross-axis rows ``p . (a_c - a_p) = p . (w_p x (w_c - w_p))`` gain
    ``-h`` times that term's gradient in the angular velocities, ``p x w_p`` for the child and ``w_c x p``
    for the parent. A rotor spinning fast on a lightly built carrier (rotational-center's
    gimbal: 90 rad/s, a nutation near 175 rad/s) gains energy without it, in 2.5 ms substeps as well
    (``benchmarks/mdgs_probes/gyroscopic.py``); the anchors' centripetal terms stay explicit (made
    implicit too, they cost the user scene's cart and pole 130x at t = 110 on the validation split).
    ``pose``: the objects' :class:`Pose` at ``x, v`` (:func:`pose_of`) when the caller has it, so that a
    stepper that needs the twists itself fits them once (the same numbers as fitted here). ``warm``: a dict that a
    stepper passes to every solve of one step, in order. With soft contact each solve leaves there the rows it
    found held but not pushing, and the next starts them free (:func:`_unilateral_solve`'s ``start``): the same
    accelerations wherever the rows' states settle, found in fewer passes.

    *Contact* with the world's colliding geoms (``drives.surfaces``: planes, boxes, spheres, capsules,
    cylinders; :func:`contacts` lists the candidates): every corner of a colliding box of a moving
    object, and a colliding cylinder's rims (``RIM_POINTS`` points each against curved or bounded
    surfaces, the exact lowest point and two more, ``RIM_SUPPORT``, against a plane; spheres, capsules
    and meshes of moving objects have no points), that is within ``CONTACT_GAP`` of a surface, or would
    reach it within ``dt``, is held: while it moves along the surface slower than friction could stop
    it within the frame (``mu |g| dt``, ``mu`` the larger of the two geoms') it sticks, three rows (two
    tangents and the surface's normal) holding its acceleration at ``-w x (w x r) - u / dt`` (``u`` its
    velocity: an inelastic, sticking impact over one frame); faster, it slides: only the normal row is
    held and the surface's push ``f_n`` comes with Coulomb friction ``mu f_n`` against the slip (the
    row's column in the upper right of the system carries it, so the system is not symmetric). These are
    first guesses that the active-set passes correct (the friction cone): a sticking corner whose hold
    takes more tangential force than ``mu`` times its push slides, with friction ``mu f_n`` along that
    force, and a sliding corner whose friction would turn its slip round within the frame sticks (an
    impact's push is large; its friction may stop a slip, not reverse it). The rows
    have a compliance of ``CONTACT_COMPLIANCE`` so that four corners of a face (twelve rows for six
    degrees of freedom) share the load in the least-squares way (the held candidates of a batch are
    gathered into as many slots as its most held).

    ``contact = "soft"``: MuJoCo's soft contact instead (:func:`_soft_contact`). A corner is held only inside its
    surface (``gap < 0``, MuJoCo's rule with no margin), at MuJoCo's contact point halfway between the corner and the
    surface and in MuJoCo's contact frame (:func:`pyramid_frame`), by the four edges of MuJoCo's pyramidal friction
    cone, ``J_n +- mu J_t``, each a row of its own that may only push: ``J_e z - R_e l_e = a_ref,e + J_e z0`` while
    it pushes, free otherwise (:func:`_unilateral_solve`, Newton's method on which rows push, with the soft limits
    below among them), ``a_ref,e`` the reference acceleration of the pair's ``solref`` and ``solimp`` at the edge's
    velocity and ``R_e`` MuJoCo's regularisation. MuJoCo's rows hold ``J qacc``, the point's acceleration less the
    part the joints' velocities alone give it (:func:`_bias_accelerations`, ``z0``); ``J z`` is the point's
    acceleration less its centripetal part about its mass centre, so the difference, zero for a root whose frame's
    origin is its mass centre, goes to the right-hand side. Friction needs no passes of its own: an edge that would
    pull lets go, which is how the pyramid slides. Checked against MuJoCo's ``qacc`` (tests/test_soft_contact.py);
    stepped at MuJoCo's timestep by semi-implicit Euler, the tree reproduces the recorded frames of the study scenes
    to round-off but where a cylinder strikes a cylinder (``benchmarks/mdgs_probes/one_frame.py``). With the four substeps of the studies'
    trees (2.5 ms) the contact's 10 ms time constant is resolved, where one step per frame rang
    (docs/mdgs-experiments.md, "MuJoCo's soft contact").

    *Range limits* of hinges and slides (``Link.limit``): past a limit, or (with the rigid contact) about to pass it
    within ``dt``, one row holds the joint's acceleration as MuJoCo's soft constraint does, ``J z - R l = a_ref``
    (:func:`_soft_reference`: MuJoCo's reference acceleration and regularisation from the joint's
    ``solref``, ``solimp`` and ``dof_invweight0``), so a joint presses a few hundredths of a radian past
    its range under load as in the data.

    A candidate whose surface or limit would have to pull is let go and the system solved again
    (``CONTACT_PASSES`` passes, an active-set search). Compiled (``torch.compile``, a CUDA graph), every
    candidate has a slot and all passes run, so that no shape follows the state: the same multipliers
    (tests/test_dynamics.py), one graph, dearer in batches (benchmarks/compiled_dynamics.py). The soft contact's rows
    leave the system instead, and so do the joints' (:func:`_unilateral_solve`): compiled, every candidate is a row
    of its products, but each pass solves a system of the tree's degrees of freedom.

    Not modelled: with the rigid rule the cone's exact boundary (a corner sticks or slides, each pass deciding from
    the last pass's forces; ``CONTACT_PASSES`` bounds the search) and the softness of MuJoCo's contacts (``contact
    = "soft"`` models both), rolling and torsional friction, limits of ball joints, damping, springs and friction
    loss, and
    contact between moving bodies or with other geoms: ``drives.unseen`` names what a scene has of these, and the rigid tree and MDGS's
    "dynamics" prior warn with it when bound (:func:`warn_unseen`).
    """
    dynamic = v is not None
    if not drives and not dynamic:
        return torch.zeros_like(x)
    dev, f64 = x.device, torch.float64
    T = drives.tensors(dev)
    xd, seg = x.to(f64), seg.to(dev)
    if pose is None:
        pose = pose_of(x, v, ref, seg, n_obj, mass)
    R, t, tw = pose  # [B, S, 3, 3], [B, S, 3], their twists (dynamic) or None
    if dynamic:
        w = tw.omega  # [B, S, 3]
    B, S = x.shape[0], n_obj
    weight = gyroscopic_weight(gyroscopic)
    h = weight * dt if dynamic and weight else None  # the step to the terms' time
    xs, M, ang, J, rhs, rate = _tree(xd, R, t, T, drives, S, w if dynamic else None, h)
    fixed = drives.const(drives.fixed, dev, torch.bool)
    zero3 = xd.new_zeros(B, 3)

    def world_of(s: int, v: np.ndarray, point: bool = False) -> torch.Tensor:
        return _world_of(R, t, s, v, drives, point)

    def joint_row(c: int, p: int, kind: str, n: torch.Tensor, A: torch.Tensor) -> torch.Tensor:
        return _joint_row(S, B, xd, xs, c, p, kind, n, A)

    F = xd.new_zeros(B, 6 * S)
    if drives:
        u = _motor_forces(ctrl.to(dev, f64), T)  # [B, D]
        for k, dr in enumerate(drives.drives):
            g = rate.get(dr.child)
            if g is None:  # a child left out of the links: its own frame
                g = joint_row(dr.child, dr.parent, dr.kind, world_of(dr.child, dr.axis),
                              world_of(dr.child, dr.anchor, point=True)[:, 0])
            F = F + u[:, k: k + 1] * g[:, 0]
    if dynamic:  # gravity and the gyroscopic torques; then the floor's corners
        moving = (~fixed).to(f64).view(1, S, 1)
        grav = drives.const(drives.gravity, dev)
        Iw = ang  # [B, S, 3, 3]
        L_ = (Iw @ w.unsqueeze(-1)).squeeze(-1)  # angular momenta [B, S, 3]
        gyro = -torch.linalg.cross(w, L_, dim=-1)
        F = F + (moving * torch.cat([T["mass"].view(1, S, 1) * grav.expand(B, S, 3), gyro], -1)).reshape(B, 6 * S)
        if h is not None:  # d(w x I w)/dw = skew(w) I - skew(I w), times the step h, into each angular block
            jac = h * (_skew_mat(w) @ Iw - _skew_mat(L_)) * moving.view(1, S, 1, 1)  # [B, S, 3, 3]
            blk = xd.new_zeros(B, S, 6, 6)
            blk[:, :, 3:, 3:] = jac
            M = M + torch.einsum("bsij,st->bsitj", blk, torch.eye(S, dtype=f64, device=dev)).reshape(B, 6 * S, 6 * S)
    C0 = sum(j.shape[1] for j in J)
    # unilateral candidates: corners against the world's surfaces, joints against their range limits;
    # each with three rows [B, k, 3, 6S] (two tangents, the normal), their right-hand sides [B, k, 3],
    # which rows are on [B, k, 3] and whether it is held [B, k]
    cand_J, cand_C, cand_r, cand_on, cand_held, cand_R, cand_mu, cand_ut = [], [], [], [], [], [], [], []
    soft = dynamic and contact == "soft"
    if soft:  # rows completing the joints' to a square system: the bias accelerations and the soft solve use them
        D, d = _generalised_rows(xd, R, t, xs, w, drives, S, rate)
    uni_J, uni_r, uni_R, uni_held = [], [], [], []  # soft: every row its own unilateral candidate [B, k, ...]
    if dynamic and (len(drives.corner_obj) or len(drives.rim_obj)):
        ct = contacts(R, t, tw, drives, dt)
        if soft:  # MuJoCo's contact point, halfway between the corner and its surface, and MuJoCo's contact frame
            P = ct.P - 0.5 * ct.gap.clamp_max(0.0).unsqueeze(-1) * ct.frame[:, :, 2]
            ct = ct._replace(P=P, u=tw.vc[:, ct.obj] + torch.linalg.cross(w[:, ct.obj], P - tw.c[:, ct.obj], dim=-1),
                             frame=pyramid_frame(ct.frame[:, :, 2]))
        Jc = _contact_rows(ct.frame, ct.P, ct.obj, xs, S)  # [B, C, 3, 6S]
        if soft:  # the pyramid's four edges J_n +- mu J_t, each a row of its own
            a_e, R_e = _soft_contact(ct.gap, (ct.frame @ ct.u.unsqueeze(-1)).squeeze(-1), ct.soft,
                                     drives.const(drives.invweight, dev)[ct.obj], ct.mu, dt)
            mJt = ct.mu.clamp_min(MIN_FRICTION).view(1, -1, 1, 1) * Jc[:, :, :2]
            Je = (Jc[:, :, 2:] + torch.stack([mJt[:, :, 0], -mJt[:, :, 0], mJt[:, :, 1], -mJt[:, :, 1]], 2)).reshape(
                B, -1, 6 * S)
            uni_J.append(Je)
            uni_r.append(a_e.reshape(B, -1))  # MuJoCo's a_ref; the bias is added at the solve
            uni_R.append(R_e.reshape(B, -1))
            uni_held.append((ct.gap < 0).repeat_interleave(4, dim=1))  # MuJoCo: dist < margin - gap (0)
    if dynamic and not soft and (len(drives.corner_obj) or len(drives.rim_obj)):
        arm = ct.P - xs[:, ct.obj]  # [B, C, 3]
        wk = w[:, ct.obj]
        # the point's acceleration less its centripetal part about the mass centre, J z, is held at -c - u / dt
        # (c the centripetal part, the point's velocity u gone by the step's end)
        want = -torch.linalg.cross(wk, torch.linalg.cross(wk, arm, dim=-1), dim=-1) - ct.u / dt
        ut = (ct.frame[:, :, :2] @ ct.u.unsqueeze(-1)).squeeze(-1)  # [B, C, 2] the slip
        uhat = ut / ut.norm(dim=-1).clamp_min(torch.finfo(f64).tiny).unsqueeze(-1)
        # a sliding corner's normal column carries the friction it feels: -mu |f_n| along its slip
        fric = Jc[:, :, 2] - ct.mu.view(1, -1, 1) * (uhat[..., :1] * Jc[:, :, 0] + uhat[..., 1:] * Jc[:, :, 1])
        cand_J.append(Jc)
        cand_C.append(torch.cat([Jc[:, :, :2], torch.where(ct.slide.unsqueeze(-1), fric, Jc[:, :, 2]).unsqueeze(2)], 2))
        r = (ct.frame @ want.unsqueeze(-1)).squeeze(-1)  # [B, C, 3]
        if CONTACT_SPECULATIVE:  # end the frame on the surface under the trapezoidal step: end velocity
            # u_n' = min(0, -2 gap / dt - u_n), so that dt (u_n + u_n') / 2 = -gap where that needs no rebound
            un = (ct.u * ct.frame[:, :, 2]).sum(-1)
            extra = (-2.0 * ct.gap.clamp_min(0.0) / dt - un).clamp_max(0.0) / dt
            r = torch.cat([r[..., :2], (r[..., 2] + extra).unsqueeze(-1)], -1)
        cand_r.append(r)
        cand_on.append(torch.stack([~ct.slide, ~ct.slide, torch.ones_like(ct.slide)], -1))
        cand_held.append(ct.held)
        cand_R.append(torch.full(ct.held.shape + (3,), CONTACT_COMPLIANCE, dtype=f64, device=dev))
        cand_mu.append(ct.mu)
        cand_ut.append(ut)
    for lk in drives.links if dynamic else ():
        if lk.limit is None:
            continue
        c, p = lk.child, lk.parent
        q = _joint_angles(R, t, lk, drives)  # [B]
        n = world_of(p, lk.axis)[:, 0]
        wc, wp = w[:, c], (w[:, p] if p >= 0 else zero3)
        if lk.kind == "hinge":  # qdd = n . (alpha_c - alpha_p) - n . (w_p x (w_c - w_p)), the axis turning with p
            qd = (n * (wc - wp)).sum(-1)
            vel = (n * torch.linalg.cross(wp, wc - wp, dim=-1)).sum(-1)
        else:
            A = world_of(p, lk.anchor, point=True)[:, 0]
            v_c = tw.vc[:, c] + torch.linalg.cross(wc, A - tw.c[:, c], dim=-1)
            v_p = tw.vc[:, p] + torch.linalg.cross(wp, A - tw.c[:, p], dim=-1) if p >= 0 else 0.0
            qd = (n * (v_c - v_p)).sum(-1)
            vel = torch.zeros_like(qd)
        for sign, bound in ((1.0, lk.limit[0]), (-1.0, lk.limit[1])):  # the lower limit pushes q up
            past, hd = sign * (q - bound), sign * qd  # the distance to the limit and its rate
            a_ref, R_lim = _soft_reference(past, hd, lk)
            row = xd.new_zeros(B, 1, 3, 6 * S)
            row[:, 0, 2] = sign * rate[c][:, 0]
            r = xd.new_zeros(B, 1, 3)
            r[:, 0, 2] = a_ref + sign * vel
            cR = xd.new_ones(B, 1, 3)
            cR[:, 0, 2] = R_lim
            cand_J.append(row)
            cand_C.append(row)
            cand_r.append(r)
            cand_R.append(cR)
            cand_on.append(torch.tensor([False, False, True], device=dev).expand(B, 1, 3))
            cand_held.append(((past < lk.margin) | (past + dt * hd.clamp_max(0.0) < lk.margin)).unsqueeze(1))
            cand_mu.append(torch.full((1,), torch.inf, dtype=f64, device=dev))
            cand_ut.append(xd.new_zeros(B, 1, 2))
            uni_J.append(row[:, :, 2])
            uni_r.append(a_ref.unsqueeze(1))  # the bias (sign vel, the row's J z0) is added at the solve
            uni_R.append(cR[:, :, 2])
            uni_held.append((past < lk.margin).unsqueeze(1))  # MuJoCo's rule: a limit acts once within its margin
    if soft and uni_J:  # MuJoCo's soft constraints: the pyramids' edges and the limits, each pushing or free
        Jm = torch.cat(J, 1) if J else xd.new_zeros(B, 0, 6 * S)
        b0 = torch.cat(rhs, -1) if rhs else xd.new_zeros(B, 0)
        held = torch.cat(uni_held, 1)
        released = warm.get("released") if warm is not None else None
        Ju, ru = torch.cat(uni_J, 1), torch.cat(uni_r, 1)
        # MuJoCo's rows hold J qacc = J (z - z0), z0 the accelerations at qacc = 0: J z holds a_ref + J z0, z0 of
        # the factorisation the solve makes anyway (its d), or, where the joints' rows are linearised in the step,
        # of their own rows
        if h is not None:
            _, _, _, J0, rhs0, _ = _tree(xd, R, t, T, drives, S, w, None)
            ru = ru + (Ju @ _bias_accelerations(J0, rhs0, D, d).unsqueeze(-1)).squeeze(-1)
        z, pushes = _unilateral_solve(M, F, Jm, b0, D, Ju, ru, torch.cat(uni_R, 1), held,
                                      torch.compiler.is_compiling(),
                                      drives.const(drives.moving_columns(), dev, torch.int64),
                                      start=None if released is None else ~released, d=None if h is not None else d)
        if warm is not None:  # the rows held that did not push: the next solve starts them free
            warm["released"] = held & ~pushes
        z = z.view(B, S, 6)
        acc = z[:, seg, :3] + torch.linalg.cross(z[:, seg, 3:], xd - xs[:, seg], dim=-1)
        return acc.to(x.dtype)
    contact = len(cand_J) > 0
    if contact:
        Jc, Cc, rc_ = torch.cat(cand_J, 1), torch.cat(cand_C, 1), torch.cat(cand_r, 1)
        rows_on, active, Rc = torch.cat(cand_on, 1), torch.cat(cand_held, 1), torch.cat(cand_R, 1)
        mu_c = torch.cat(cand_mu)  # [C] friction of each candidate (a limit: none, inf)
        ut_c = torch.cat(cand_ut, 1)  # [B, C, 2] each candidate's slip in its frame (a limit: zero)
    Jm = torch.cat(J, 1) if J else xd.new_zeros(B, 0, 6 * S)
    b0 = torch.cat(rhs, -1) if rhs else xd.new_zeros(B, 0)
    # compiled (torch.compile, a CUDA graph), every pass solves with a slot for every candidate and all
    # CONTACT_PASSES passes run: the same multipliers (an empty slot is a row lambda = 0), with shapes that do
    # not depend on the state; eager steps keep the smaller systems and stop early
    static = torch.compiler.is_compiling()
    tangents = torch.tensor([True, True, False], device=dev)  # which of a candidate's rows are its tangents
    for _ in range(CONTACT_PASSES if contact else 1):
        if contact:  # the held corners first, as many slots as the batch's most held corners
            sel = _slots(active, static)  # [B, n_on]
            n_on = sel.shape[-1]
            on = (torch.gather(active, 1, sel).unsqueeze(-1)
                  & torch.gather(rows_on, 1, sel.view(B, n_on, 1).expand(-1, -1, 3))).to(f64).view(B, 3 * n_on)
            idx = sel.view(B, n_on, 1, 1).expand(-1, -1, 3, 6 * S)
            Jsel = torch.gather(Jc, 1, idx).reshape(B, 3 * n_on, 6 * S)
            Csel = torch.gather(Cc, 1, idx).reshape(B, 3 * n_on, 6 * S)
            rsel = torch.gather(rc_, 1, sel.view(B, n_on, 1).expand(-1, -1, 3)).reshape(B, 3 * n_on)
            Rsel = torch.gather(Rc, 1, sel.view(B, n_on, 1).expand(-1, -1, 3)).reshape(B, 3 * n_on)
            Jall = torch.cat([Jm, Jsel * on.unsqueeze(-1)], 1)
            Call = torch.cat([Jm, Csel * on.unsqueeze(-1)], 1)
            ball = torch.cat([b0, rsel * on], -1)
            diag = torch.cat([xd.new_zeros(B, C0), torch.where(on > 0, -Rsel, 1.0)], -1)
        else:
            Jall, Call, ball, diag = Jm, Jm, b0, xd.new_zeros(B, C0)
        K = torch.cat([torch.cat([M, Call.transpose(-1, -2)], -1),
                       torch.cat([Jall, torch.diag_embed(diag)], -1)], 1)
        sol = _solve(K, torch.cat([F, ball], -1))
        if not contact:
            break
        lz = sol[:, 6 * S + C0:].view(B, -1, 3)[..., 2]  # the push of each held candidate's surface is -lz
        pulls = torch.zeros_like(active).scatter(1, sel, (lz > 0) & (on.view(B, -1, 3)[..., 2] > 0))
        # the friction cone: a sticking corner whose hold needs more tangential force than mu times its push
        # slides, with friction mu |f_n| along that force; a sliding corner whose friction would turn its slip
        # round within the frame sticks (limits have mu = inf: neither); only once no surface pulls (the forces of
        # a system that still holds a corner its surface would pull are not the ones to judge friction by)
        settled = ~pulls.any(-1, keepdim=True)  # [B, 1]
        lam = sol[:, 6 * S + C0:].view(B, -1, 3)
        lt = lam[..., :2]
        mu_sel = mu_c[sel]  # [B, n_on]
        on3 = on.view(B, -1, 3)
        excess = settled & (on3[..., 0] > 0) & (lz < 0) & (lt.norm(dim=-1) > mu_sel * (-lz))
        zt = (Jsel.view(B, -1, 3, 6 * S)[:, :, :2] @ sol[:, :6 * S].view(B, 1, 6 * S, 1)).squeeze(-1)  # [B, n_on, 2]
        want_t = torch.gather(rc_, 1, sel.view(B, -1, 1).expand(-1, -1, 3))[..., :2]  # -c_t - u_t / dt
        ut_sel = torch.gather(ut_c, 1, sel.unsqueeze(-1).expand(-1, -1, 2))
        sliding = (on3[..., 2] > 0) & (on3[..., 0] == 0) & torch.isfinite(mu_sel)
        turns = settled & sliding & (((zt - want_t) * ut_sel).sum(-1) < 0)  # dt (zt - want_t): the slip at the frame's end
        slips = torch.zeros_like(active).scatter(1, sel, excess)
        sticks = torch.zeros_like(active).scatter(1, sel, turns)
        d = torch.zeros(B, active.shape[1], 2, dtype=f64, device=dev).scatter(
            1, sel.unsqueeze(-1).expand(-1, -1, 2), lt / lt.norm(dim=-1, keepdim=True).clamp_min(torch.finfo(f64).tiny))
        fric = Jc[:, :, 2] - mu_c.clamp_max(1e9).view(1, -1, 1) * (d[..., :1] * Jc[:, :, 0] + d[..., 1:] * Jc[:, :, 1])
        normal = torch.where(slips.view(B, -1, 1), fric, torch.where(sticks.view(B, -1, 1), Jc[:, :, 2], Cc[:, :, 2]))
        Cc = torch.cat([Cc[:, :, :2], normal.unsqueeze(2)], 2)
        rows_on = (rows_on & ~(slips.unsqueeze(-1) & tangents)) | (sticks.unsqueeze(-1) & tangents)
        if not static and not bool(pulls.any()) and not bool(slips.any()) and not bool(sticks.any()):
            break
        active = active & ~pulls
    z = sol[:, :6 * S].view(B, S, 6)
    acc = z[:, seg, :3] + torch.linalg.cross(z[:, seg, 3:], xd - xs[:, seg], dim=-1)
    return acc.to(x.dtype)

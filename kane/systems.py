"""Analytic mechanical systems: one parameterised description gives a sympy Kane model and an MJCF scene.

Each system (pendulum, free box, Cubli, rolling disc, ...) is written once, as a tuple of
:class:`BodySpec` whose numbers are sympy expressions in named parameter symbols. From that
one description this module produces

* :meth:`AnalyticSystem.symbolic`: Kane's equations ``fr + frstar = 0`` (Kane & Levinson
  1985; sympy ``KanesMethod``), with mass matrix, forcing and a lambdified residual, cached
  on disk;
* :meth:`AnalyticSystem.mjcf`: an MJCF string with explicit ``<inertial>`` elements, the
  Euler integrator and no damping/armature, loadable by MuJoCo and by Pinocchio's
  ``buildModelFromMJCF``, so that both engines see exactly the sympy mass properties;
* :func:`simulate`: a MuJoCo trajectory (state, acceleration, actuator forces, contact
  wrenches) along which the cross-checks in :mod:`kane.crosscheck` evaluate the equations.

Conventions (the mapping between sympy q/u and engine coordinates)
-------------------------------------------------------------------
* World frame N: z up, gravity ``-g N.z``. Units: SI (m, kg, s, rad, N, N m).
* hinge / slide joint: one coordinate ``q`` (rad or m) equal to MuJoCo ``qpos``; the
  generalized speed is ``u = dq/dt`` (equal to MuJoCo ``qvel``), ``udot`` = MuJoCo ``qacc``.
  Joint axes are body-frame vectors; several joints in one body compose in order (each
  axis in the frame left by the previous joints), exactly as MuJoCo composes them.
* free joint (top-level bodies only): coordinates ``(x, y, z, yaw, pitch, roll)``: the
  body-origin position in N (m) and body-fixed Z-Y-X Euler angles, ``R = Rz(yaw) Ry(pitch)
  Rx(roll)`` (rad). The speeds follow MuJoCo's free-joint ``qvel`` exactly:
  ``(vx, vy, vz)`` = velocity of the body origin in **world** components (m/s) and
  ``(wx, wy, wz)`` = angular velocity in **body** components (rad/s), so ``udot`` is
  MuJoCo's ``qacc`` unchanged. MuJoCo stores the orientation as a quaternion ``(w, x, y,
  z)``; Euler angles are recovered with scipy (``as_euler('ZYX')``, intrinsic).
  The Euler angles enter only the kinematic differential equations (singular at
  pitch = +-pi/2); Kane's ``fr`` and ``frstar`` depend on them only through the rotation
  matrix, which stays exact there.
* Pinocchio (used in :mod:`kane.crosscheck`): quaternion ``(x, y, z, w)``, and a free
  joint's linear velocity/acceleration and force are in the **local** (body) frame:
  ``v_pin = R^T v_world``, ``a_pin = R^T a_world - w_body x v_pin``, ``f_world = R f_pin``.
* Generalized inputs: actuator forces ``tau_<actuator>`` (N m for hinges, N for slides;
  MuJoCo ``<motor>`` with gear 1, so equal to ``actuator_force``), then, for each body
  with ``external_wrench=True``, an external force ``F`` (N, world components) applied at
  the body origin and a torque ``T`` (N m, world components). Contact forces from MuJoCo
  enter Kane's equations through these.
* Rolling disc (nonholonomic, see :func:`rolling_disc`): coordinates ``(yaw, lean, spin,
  x, y)`` with ``R = Rz(yaw) Rx(lean) Ry(spin)`` (disc axis = body y) and (x, y) the
  ground contact point; independent speeds ``(u1, u2, u3)`` = disc angular velocity in the
  lean frame L; dependent speeds ``(dx/dt, dy/dt)`` eliminated with the rolling
  constraints.

Symbolic expressions in :class:`SymbolicModel` use plain symbols (``q_<joint>``,
``u_<joint>``, ``ud_<joint>``) for the time-dependent ``q(t)``, ``u(t)``, ``du/dt``, so that
they pickle and lambdify; :meth:`AnalyticSystem.kanes_method` returns a fresh
``KanesMethod`` in sympy's dynamicsymbols.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import sympy as sp
from sympy.physics import mechanics as me

__all__ = [
    "JointSpec",
    "GeomSpec",
    "BodySpec",
    "ActuatorSpec",
    "AnalyticSystem",
    "SymbolicModel",
    "Trajectory",
    "SYSTEMS",
    "get_system",
    "simulate",
    "symbol",
    "cache_dir",
]

#: bump when the derivation code changes, so stale cache files are not reused.
_CACHE_VERSION = 5

Expr = Any  # a sympy expression or a number


def symbol(name: str) -> sp.Symbol:
    """The real sympy symbol used for parameter ``name`` (one symbol per name)."""
    return sp.Symbol(name, real=True)


def cache_dir() -> Path:
    """Directory of cached derivations: ``$MDGS_CACHE_DIR`` or ``~/.cache/mdgs/kane``."""
    root = os.environ.get("MDGS_CACHE_DIR")
    return Path(root) if root else Path.home() / ".cache" / "mdgs" / "kane"


# --------------------------------------------------------------------------------------
# Description
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class JointSpec:
    """One joint of a body.

    Attributes
    ----------
    name : str
        Joint name (MJCF name; the sympy symbols are ``q_<name>``, ``u_<name>``).
    kind : str
        ``'hinge'`` (rad), ``'slide'`` (m) or ``'free'`` (top-level bodies only).
    axis : tuple of 3 floats
        Joint axis in the body frame (unit vector; ignored for free joints).
    """

    name: str
    kind: str
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)


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


@dataclass(frozen=True)
class ActuatorSpec:
    """A MuJoCo ``<motor>`` (gear 1) on a hinge or slide joint.

    Attributes
    ----------
    name : str
        Actuator name; the input symbol is ``tau_<name>``.
    joint : str
        Joint it drives.
    ctrlrange : (float, float)
        Control limits, N m (hinge) or N (slide).
    """

    name: str
    joint: str
    ctrlrange: tuple[float, float] = (-1.0, 1.0)


@dataclass(frozen=True, eq=False)
class AnalyticSystem:
    """A mechanical system described once, from which the sympy model and MJCF are produced.

    Attributes
    ----------
    name : str
        Registry name.
    params : dict[str, float]
        Numeric value of every parameter symbol appearing in the description (SI units).
    bodies : tuple of BodySpec
        Bodies, parents before children (depth-first order = MuJoCo body order).
    actuators : tuple of ActuatorSpec
        Motors.
    world_geoms : tuple of GeomSpec
        Geoms fixed in the world (the floor).
    derivation : str
        ``'tree'`` (holonomic joint tree) or ``'rolling_disc'`` (nonholonomic).
    timestep : float
        MuJoCo time step, s.
    contact_options : dict
        Extra MJCF ``<option>`` attributes for contact systems (``cone``, ``impratio``, ...).
    geom_defaults : dict
        MJCF ``<default><geom .../>`` attributes (contact softness ``solref``, ...).
    settle_steps : int
        MuJoCo steps run before :func:`simulate` starts recording (lets a soft contact
        settle from an ideal initial state).
    description : str
        One sentence on what the system is.
    """

    name: str
    params: Mapping[str, float]
    bodies: tuple[BodySpec, ...]
    actuators: tuple[ActuatorSpec, ...] = ()
    world_geoms: tuple[GeomSpec, ...] = ()
    derivation: str = "tree"
    timestep: float = 1e-3
    contact_options: Mapping[str, str] = field(default_factory=dict)
    geom_defaults: Mapping[str, str] = field(default_factory=dict)
    settle_steps: int = 0
    description: str = ""

    # ---- basic views ------------------------------------------------------------------
    @cached_property
    def symbol_values(self) -> dict[sp.Symbol, float]:
        """``{parameter symbol: value}``."""
        return {symbol(k): float(v) for k, v in self.params.items()}

    def value(self, expr: Expr) -> float:
        """Numeric value of a description expression, with the parameters substituted."""
        v = sp.sympify(expr).xreplace(self.symbol_values)
        try:
            return float(v)
        except TypeError as exc:
            raise ValueError(
                f"system {self.name!r}: expression {expr} has symbols {v.free_symbols} with no value in params"
            ) from exc

    @cached_property
    def joints(self) -> tuple[tuple[str, JointSpec], ...]:
        """``(body name, joint)`` pairs in MuJoCo joint order."""
        return tuple((b.name, j) for b in self.bodies for j in b.joints)

    @cached_property
    def has_contact(self) -> bool:
        """Whether any geom collides (otherwise contact is disabled in the MJCF)."""
        return any(g.contact for b in self.bodies for g in b.geoms) or any(
            g.contact for g in self.world_geoms
        )

    @cached_property
    def wrench_bodies(self) -> tuple[str, ...]:
        """Names of the bodies that take an external wrench input (contact loads)."""
        return tuple(b.name for b in self.bodies if b.external_wrench)

    @cached_property
    def nq_mujoco(self) -> int:
        """Length of MuJoCo ``qpos``."""
        return sum(7 if j.kind == "free" else 1 for _, j in self.joints)

    @cached_property
    def nv_mujoco(self) -> int:
        """Length of MuJoCo ``qvel``."""
        return sum(6 if j.kind == "free" else 1 for _, j in self.joints)

    def cache_key(self) -> str:
        """Hash of the description, parameter values, sympy version and cache version."""
        h = hashlib.sha256()
        h.update(repr((_CACHE_VERSION, sp.__version__, self.name, self.derivation)).encode())
        for b in self.bodies:
            h.update(
                sp.srepr(
                    (b.name, b.parent, b.pos, b.joints, b.mass, b.com, b.inertia, b.external_wrench)
                ).encode()
            )
        h.update(repr(self.actuators).encode())
        h.update(repr(sorted(self.params.items())).encode())
        return h.hexdigest()[:16]

    # ---- products ------------------------------------------------------------------------
    def mjcf(self) -> str:
        """MJCF scene of the system (explicit inertials, Euler integrator, no damping).

        Returns
        -------
        str
            XML loadable by ``mujoco.MjModel.from_xml_string`` and, written to a file, by
            ``pinocchio.buildModelFromMJCF``.
        """
        return _mjcf(self)

    def symbolic(self, use_cache: bool = True) -> SymbolicModel:
        """Kane's equations of the system, derived once and cached on disk.

        Parameters
        ----------
        use_cache : bool
            Read/write ``cache_dir()/<name>-<hash>.pkl`` (key: description, parameter
            values, sympy version). ``False`` always derives afresh (and writes nothing).

        Returns
        -------
        SymbolicModel
        """
        key = self.cache_key()
        if use_cache and key in _MEMO:
            return _MEMO[key]
        path = cache_dir() / f"{self.name}-{key}.pkl"
        t0 = time.perf_counter()
        data = None
        if use_cache and path.exists():
            try:
                with open(path, "rb") as fh:
                    data = pickle.load(fh)
            except Exception:  # a corrupt or foreign cache file: derive again
                data = None
        from_cache = data is not None
        if data is None:
            km, extra = self.kanes_method()
            data = _plain_model_data(self, km, extra)
            if use_cache:
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_suffix(f".tmp{os.getpid()}")
                with open(tmp, "wb") as fh:
                    pickle.dump(data, fh, protocol=pickle.HIGHEST_PROTOCOL)
                os.replace(tmp, path)
        model = SymbolicModel(
            system=self, seconds=time.perf_counter() - t0, from_cache=from_cache, **data
        )
        if use_cache:
            _MEMO[key] = model
        return model

    def kanes_method(self) -> tuple[me.KanesMethod, dict]:
        """A fresh sympy ``KanesMethod`` with ``kanes_equations`` already formed (uncached).

        Returns
        -------
        km : sympy.physics.mechanics.KanesMethod
        extra : dict
            ``q``, ``u`` (independent), ``inputs``, ``frame``, ``bodies``, ``loads``,
            ``names`` (plain-symbol names for q and u), ``fr``, ``frstar``.
        """
        if self.derivation == "tree":
            kin = _tree_kinematics(self, speeds="u")
            km = me.KanesMethod(kin["frame"], q_ind=kin["q"], u_ind=kin["u"], kd_eqs=kin["kd"])
        elif self.derivation == "rolling_disc":
            kin = _rolling_disc_kinematics(self)
            km = me.KanesMethod(
                kin["frame"],
                q_ind=kin["q"],
                u_ind=kin["u"],
                u_dependent=kin["u_dep"],
                kd_eqs=kin["kd"],
                velocity_constraints=kin["vc"],
            )
        else:
            raise ValueError(
                f"system {self.name!r}: unknown derivation {self.derivation!r}; use 'tree' or 'rolling_disc'"
            )
        fr, frstar = km.kanes_equations(kin["bodies"], kin["loads"])
        kin["fr"], kin["frstar"] = fr, frstar
        return km, kin

    def lagranges_method(self) -> tuple[me.LagrangesMethod, dict]:
        """sympy ``LagrangesMethod`` of the same description, speeds = dq/dt (holonomic trees).

        Kinematics are rebuilt with sympy's own angular velocities (``orientnew``) and
        ``u = dq/dt``; gravity and actuator loads enter as forces (Lagrangian = kinetic
        energy). Only for trees without free joints, where Kane's speeds are also dq/dt.

        Returns
        -------
        lm : sympy.physics.mechanics.LagrangesMethod (equations formed)
        extra : dict, as in :meth:`kanes_method`.
        """
        if self.derivation != "tree" or any(j.kind == "free" for _, j in self.joints):
            raise ValueError(
                f"system {self.name!r}: the Lagrange route needs a joint tree without free joints "
                "(Kane's speeds then equal dq/dt)"
            )
        kin = _tree_kinematics(self, speeds="qdot")
        L = sum((b.kinetic_energy(kin["frame"]) for b in kin["bodies"]), sp.S.Zero)
        lm = me.LagrangesMethod(L, kin["q"], forcelist=kin["loads"], frame=kin["frame"])
        lm.form_lagranges_equations()
        return lm, kin

    # ---- coordinate maps -----------------------------------------------------------------
    def mujoco_to_kane(self, qpos: np.ndarray, qvel: np.ndarray, qacc: np.ndarray | None = None):
        """Map MuJoCo state to the sympy coordinates and speeds (see module conventions).

        Parameters
        ----------
        qpos : ndarray, shape [..., nq_mujoco]
        qvel : ndarray, shape [..., nv_mujoco]
        qacc : ndarray, shape [..., nv_mujoco], optional

        Returns
        -------
        q : ndarray, shape [..., n_q]
        u : ndarray, shape [..., n_u]
        udot : ndarray, shape [..., n_u] (None when ``qacc`` is None)
        """
        if self.derivation == "rolling_disc":
            return _rolling_disc_from_mujoco(self, qpos, qvel, qacc)
        qpos, qvel = np.asarray(qpos, float), np.asarray(qvel, float)
        qs, us = [], []
        ip = iv = 0
        for _, j in self.joints:
            if j.kind == "free":
                qs += [qpos[..., ip : ip + 3], _quat_wxyz_to_zyx(qpos[..., ip + 3 : ip + 7])]
                us.append(qvel[..., iv : iv + 6])
                ip, iv = ip + 7, iv + 6
            else:
                qs.append(qpos[..., ip : ip + 1])
                us.append(qvel[..., iv : iv + 1])
                ip, iv = ip + 1, iv + 1
        q = np.concatenate(qs, axis=-1)
        u = np.concatenate(us, axis=-1)
        udot = None if qacc is None else np.asarray(qacc, float).copy()
        return q, u, udot

    def kane_to_mujoco(self, q: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`mujoco_to_kane` for a state: ``(qpos [nq], qvel [nv])``."""
        if self.derivation == "rolling_disc":
            return _rolling_disc_to_mujoco(self, q, u)
        q, u = np.asarray(q, float), np.asarray(u, float)
        qpos, qvel = [], []
        i = 0
        for _, j in self.joints:
            if j.kind == "free":
                qpos += [q[i : i + 3], _zyx_to_quat_wxyz(q[i + 3 : i + 6])]
                qvel.append(u[i : i + 6])
                i += 6
            else:
                qpos.append(q[i : i + 1])
                qvel.append(u[i : i + 1])
                i += 1
        return np.concatenate(qpos), np.concatenate(qvel)


_MEMO: dict[str, SymbolicModel] = {}


# --------------------------------------------------------------------------------------
# Symbolic model
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SymbolicModel:
    """Kane's equations of one system, as plain-symbol sympy matrices and numpy functions.

    Attributes
    ----------
    system : AnalyticSystem
    q, u, udot : tuple of sympy.Symbol
        Generalized coordinates, independent generalized speeds and their time
        derivatives (plain symbols standing for q(t), u(t), du/dt).
    inputs : tuple of sympy.Symbol
        Actuator forces, then external wrench components (see module conventions).
    params : tuple of sympy.Symbol
        Parameter symbols (values in ``system.params``).
    fr, frstar : sympy.Matrix, shape [n_u, 1]
        Generalized active and inertia forces K_gamma, K*_gamma of Eq. (1)-(3):
        ``fr + frstar = 0``.
    mass_matrix : sympy.Matrix, shape [n_u, n_u]
    forcing : sympy.Matrix, shape [n_u, 1]
        ``mass_matrix * udot = forcing`` (equivalently ``fr + frstar = forcing - M udot``).
    qdot : tuple of sympy.Expr
        Kinematic differential equations, dq/dt as functions of (q, u).
    seconds : float
        Time this call took (derivation, or cache load), s.
    from_cache : bool
        Whether the expressions were read from the disk cache.
    """

    system: AnalyticSystem
    q: tuple
    u: tuple
    udot: tuple
    inputs: tuple
    params: tuple
    fr: sp.Matrix
    frstar: sp.Matrix
    mass_matrix: sp.Matrix
    forcing: sp.Matrix
    qdot: tuple
    seconds: float = 0.0
    from_cache: bool = False

    @property
    def param_values(self) -> np.ndarray:
        """Values of :attr:`params`, shape [n_params]."""
        return np.array([self.system.params[str(p)] for p in self.params], dtype=float)

    @cached_property
    def _residual_fn(self) -> Callable:
        return _lambdify(
            [*self.q, *self.u, *self.udot, *self.inputs, *self.params], list(self.fr + self.frstar)
        )

    @cached_property
    def _mass_fn(self) -> Callable:
        return _lambdify([*self.q, *self.params], list(self.mass_matrix))

    @cached_property
    def _forcing_fn(self) -> Callable:
        return _lambdify([*self.q, *self.u, *self.inputs, *self.params], list(self.forcing))

    def _args(self, *arrays_and_sizes):
        cols = []
        batch = ()
        for a, n in arrays_and_sizes:
            a = np.zeros(n) if a is None else np.asarray(a, dtype=float)
            if a.shape[-1] != n:
                raise ValueError(
                    f"{self.system.name}: expected last dimension {n}, got array of shape {a.shape}"
                )
            batch = np.broadcast_shapes(batch, a.shape[:-1])
            cols += [a[..., i] for i in range(n)]
        return cols + list(self.param_values), batch

    def residual(self, q, u, udot, inputs=None) -> np.ndarray:
        """Kane residual ``fr + frstar`` (Eq. 3, K_gamma + K*_gamma), numpy.

        Parameters
        ----------
        q : ndarray, shape [..., n_q]
        u, udot : ndarray, shape [..., n_u]
        inputs : ndarray, shape [..., n_inputs], optional (zeros)

        Returns
        -------
        ndarray, shape [..., n_u]
            N or N m per generalized speed; zero on a true motion.
        """
        args, batch = self._args(
            (q, len(self.q)), (u, len(self.u)), (udot, len(self.u)), (inputs, len(self.inputs))
        )
        return _stack(self._residual_fn(*args), batch)

    def mass(self, q) -> np.ndarray:
        """Mass matrix, shape [..., n_u, n_u] for q of shape [..., n_q]."""
        args, batch = self._args((q, len(self.q)))
        n = len(self.u)
        return _stack(self._mass_fn(*args), batch).reshape(*batch, n, n)

    def force(self, q, u, inputs=None) -> np.ndarray:
        """Forcing vector (right side of ``M udot = forcing``), shape [..., n_u]."""
        args, batch = self._args((q, len(self.q)), (u, len(self.u)), (inputs, len(self.inputs)))
        return _stack(self._forcing_fn(*args), batch)

    def inverse_dynamics(self, q, u, udot, inputs=None) -> np.ndarray:
        """Generalized force the actuators must add: ``-(fr + frstar)``, shape [..., n_u].

        With ``inputs`` holding only contact wrenches (actuator entries zero) this is what
        MuJoCo's ``qfrc_inverse`` and Pinocchio's ``rnea`` return.
        """
        return -self.residual(q, u, udot, inputs)


def _lambdify(args, exprs):
    return sp.lambdify(args, exprs, modules="numpy", cse=True)


def _stack(out, batch) -> np.ndarray:
    return np.stack([np.broadcast_to(np.asarray(o, dtype=float), batch) for o in out], axis=-1)


def _plain_model_data(system: AnalyticSystem, km: me.KanesMethod, kin: dict) -> dict:
    """Replace q(t), u(t), du/dt by plain symbols; eliminate dq/dt and dependent speeds."""
    t = me.dynamicsymbols._t
    q, u, names = kin["q"], kin["u"], kin["names"]
    qsym = tuple(sp.Symbol(f"q_{n}", real=True) for n in names["q"])
    usym = tuple(sp.Symbol(f"u_{n}", real=True) for n in names["u"])
    udsym = tuple(sp.Symbol(f"ud_{n}", real=True) for n in names["u"])
    kdd = km.kindiffdict()
    steps: list[dict] = [kdd]
    u_dep = kin.get("u_dep", [])
    if u_dep:
        # dependent speeds (and their time derivatives) from sympy's own constraint
        # solution u_dep = Ars u_ind
        dep_expr = list(km._Ars * sp.Matrix(u))
        steps.append(
            {d.diff(t): e.diff(t).xreplace(kdd) for d, e in zip(u_dep, dep_expr, strict=True)}
        )
        steps.append(dict(zip(u_dep, dep_expr, strict=True)))
    steps.append({x.diff(t): s for x, s in zip(u, udsym, strict=True)})
    steps.append({**dict(zip(q, qsym, strict=True)), **dict(zip(u, usym, strict=True))})

    def plain(expr):
        e = sp.sympify(expr)
        for rep in steps:
            e = e.xreplace(rep)
        left = {d for d in e.atoms(sp.Derivative)} | {
            f for f in e.atoms(sp.Function) if f.args == (t,)
        }
        if left:
            raise RuntimeError(
                f"{system.name}: time-dependent terms left after substitution: {left}"
            )
        return e

    fr = kin["fr"].applyfunc(plain)
    frstar = kin["frstar"].applyfunc(plain)
    if u_dep:
        # reduced (independent-speed) form of fr + frstar = forcing - M udot; sympy's own
        # mass_matrix/forcing also carry the differentiated velocity constraints
        res = fr + frstar
        mm = -res.jacobian(sp.Matrix(udsym))
        fo = res.xreplace(dict.fromkeys(udsym, sp.S.Zero))
    else:
        mm = km.mass_matrix.applyfunc(plain)
        fo = km.forcing.applyfunc(plain)
    qdot = tuple(plain(kdd[x.diff(t)]) for x in q)
    return {
        "q": qsym,
        "u": usym,
        "udot": udsym,
        "inputs": tuple(kin["inputs"]),
        "params": tuple(sorted((symbol(k) for k in system.params), key=str)),
        "fr": fr,
        "frstar": frstar,
        "mass_matrix": mm,
        "forcing": fo,
        "qdot": qdot,
    }


# --------------------------------------------------------------------------------------
# Tree kinematics (hinge / slide / free joints)
# --------------------------------------------------------------------------------------


def _exact(x) -> sp.Expr:
    """Sympify, turning Python floats into exact rationals (0.0/1.0 axes stay 0/1, no Float noise)."""
    return sp.Rational(x) if isinstance(x, float) else sp.sympify(x)


def _vec(frame: me.ReferenceFrame, c) -> me.Vector:
    return sum(
        (_exact(ci) * e for ci, e in zip(c, (frame.x, frame.y, frame.z), strict=True)), me.Vector(0)
    )


def _tree_kinematics(system: AnalyticSystem, speeds: str = "u") -> dict:
    """Frames, points, bodies and loads of a joint tree.

    ``speeds='u'``: generalized speeds are new dynamicsymbols (Kane); angular velocities
    are set explicitly in them. ``speeds='qdot'``: u = dq/dt and sympy derives every
    angular velocity from the orientations itself (Lagrange route, independent check).
    """
    dyn = me.dynamicsymbols
    t = dyn._t
    N = me.ReferenceFrame("N")
    O = me.Point("O")
    O.set_vel(N, 0)
    g = symbol("g")
    frames: dict[str | None, me.ReferenceFrame] = {None: N}
    origins: dict[str | None, me.Point] = {None: O}
    q, u, kd, bodies, loads, inputs = [], [], [], [], [], []
    names = {"q": [], "u": []}
    joint_frames: dict[
        str, tuple
    ] = {}  # joint -> (frame before, frame after, point before, point after, axis)

    def new(name):
        qq = dyn(f"q_{name}")
        uu = qq.diff(t) if speeds == "qdot" else dyn(f"u_{name}")
        return qq, uu

    seen = {None}
    for b in system.bodies:
        if b.parent not in seen:
            raise ValueError(
                f"system {system.name!r}: body {b.name!r} listed before its parent {b.parent!r}"
            )
        seen.add(b.name)
        P, Op = frames[b.parent], origins[b.parent]
        F = P
        pt = Op.locatenew(f"{b.name}_joint", _vec(P, b.pos))
        pt.v2pt_theory(Op, N, P)
        for j in b.joints:
            if j.kind == "free":
                if b.parent is not None or len(b.joints) != 1:
                    raise ValueError(
                        f"system {system.name!r}: free joint {j.name!r} must be the only joint of a top-level body"
                    )
                comps = ["x", "y", "z", "yaw", "pitch", "roll"]
                qs = [dyn(f"q_{j.name}_{c}") for c in comps]
                us = [dyn(f"u_{j.name}_{c}") for c in ["vx", "vy", "vz", "wx", "wy", "wz"]]
                names["q"] += [f"{j.name}_{c}" for c in comps]
                names["u"] += [f"{j.name}_{c}" for c in ["vx", "vy", "vz", "wx", "wy", "wz"]]
                B = N.orientnew(f"{b.name}_frame", "Body", qs[3:], "ZYX")
                B.set_ang_vel(N, us[3] * B.x + us[4] * B.y + us[5] * B.z)
                newpt = O.locatenew(f"{b.name}_origin", qs[0] * N.x + qs[1] * N.y + qs[2] * N.z)
                newpt.set_vel(N, us[0] * N.x + us[1] * N.y + us[2] * N.z)
                kd += [qs[i].diff(t) - us[i] for i in range(3)]
                # Z-Y-X Euler rates from body rates (p, q, r) = (wx, wy, wz), solved in closed
                # form so that KanesMethod need not invert the 3x3 trigonometric system:
                # yaw' = (q sin(roll) + r cos(roll)) / cos(pitch), pitch' = q cos(roll) - r sin(roll),
                # roll' = p + (q sin(roll) + r cos(roll)) tan(pitch)
                _, pitch, roll = qs[3:]
                s_ = us[4] * sp.sin(roll) + us[5] * sp.cos(roll)
                kd += [
                    qs[3].diff(t) - s_ / sp.cos(pitch),
                    qs[4].diff(t) - (us[4] * sp.cos(roll) - us[5] * sp.sin(roll)),
                    qs[5].diff(t) - (us[3] + s_ * sp.tan(pitch)),
                ]
                q += qs
                u += us
                F, pt = B, newpt
                continue
            qq, uu = new(j.name)
            names["q"].append(j.name)
            names["u"].append(j.name)
            q.append(qq)
            u.append(uu)
            if speeds == "u":
                kd.append(qq.diff(t) - uu)
            a = _vec(F, j.axis)
            if j.kind == "hinge":
                Fn = F.orientnew(f"{b.name}_{j.name}", "Axis", [qq, a])
                if speeds == "u":
                    Fn.set_ang_vel(F, uu * a)
                joint_frames[j.name] = (F, Fn, pt, pt, a)
                F = Fn
            elif j.kind == "slide":
                newpt = pt.locatenew(f"{b.name}_{j.name}", qq * a)
                newpt.set_vel(F, uu * a)
                newpt.v1pt_theory(pt, N, F)
                joint_frames[j.name] = (F, F, pt, newpt, a)
                pt = newpt
            else:
                raise ValueError(
                    f"system {system.name!r}: joint {j.name!r} has unknown kind {j.kind!r}; use hinge, slide or free"
                )
        frames[b.name], origins[b.name] = F, pt
        mass = sp.sympify(b.mass)
        if mass != 0:
            G = pt.locatenew(f"{b.name}_com", _vec(F, b.com))
            G.v2pt_theory(pt, N, F)
            ixx, iyy, izz, ixy, ixz, iyz = (sp.sympify(x) for x in b.inertia)
            Idy = me.inertia(F, ixx, iyy, izz, ixy, iyz, ixz)
            bodies.append(me.RigidBody(b.name, G, F, mass, (Idy, G)))
            loads.append((G, -mass * g * N.z))
    # actuators: equal and opposite torque (force) on the two sides of the joint
    for act in system.actuators:
        if act.joint not in joint_frames:
            raise ValueError(
                f"system {system.name!r}: actuator {act.name!r} drives unknown joint {act.joint!r}"
            )
        Fb, Fa, pb, pa, a = joint_frames[act.joint]
        tau = sp.Symbol(f"tau_{act.name}", real=True)
        inputs.append(tau)
        if Fb is Fa:  # slide
            loads += [(pa, tau * a), (pb, -tau * a)]
        else:
            loads += [(Fa, tau * a), (Fb, -tau * a)]
    for b in system.bodies:
        if b.external_wrench:
            Fx, Fy, Fz, Tx, Ty, Tz = (
                sp.Symbol(f"{b.name}_{c}", real=True) for c in ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
            )
            inputs += [Fx, Fy, Fz, Tx, Ty, Tz]
            loads += [
                (origins[b.name], Fx * N.x + Fy * N.y + Fz * N.z),
                (frames[b.name], Tx * N.x + Ty * N.y + Tz * N.z),
            ]
    return {
        "frame": N,
        "q": q,
        "u": u,
        "kd": kd,
        "bodies": bodies,
        "loads": loads,
        "inputs": inputs,
        "names": names,
    }


# --------------------------------------------------------------------------------------
# Rolling disc (nonholonomic)
# --------------------------------------------------------------------------------------


def _rolling_disc_kinematics(system: AnalyticSystem) -> dict:
    """Rolling disc, Kane & Levinson (1985); contact point coordinates kept, rolling as
    two velocity constraints on the dependent speeds (dx/dt, dy/dt)."""
    dyn = me.dynamicsymbols
    t = dyn._t
    disc = system.bodies[0]
    r, g = symbol("r"), symbol("g")
    m = sp.sympify(disc.mass)
    q1, q2, q3, q4, q5 = dyn("q_yaw q_lean q_spin q_x q_y")
    u1, u2, u3, u4, u5 = dyn("u_1 u_2 u_3 u_x u_y")
    N = me.ReferenceFrame("N")
    Y = N.orientnew("Y", "Axis", [q1, N.z])
    L = Y.orientnew("L", "Axis", [q2, Y.x])
    R = L.orientnew("R", "Axis", [q3, L.y])
    w_qd = R.ang_vel_in(N)
    R.set_ang_vel(N, u1 * L.x + u2 * L.y + u3 * L.z)
    O = me.Point("O")
    O.set_vel(N, 0)
    C = O.locatenew("C", q4 * N.x + q5 * N.y)  # geometric contact point on the ground
    C.set_vel(N, u4 * N.x + u5 * N.y)
    D = C.locatenew("D", r * L.z)  # disc centre
    D.v2pt_theory(C, N, L)
    P = D.locatenew("P", -r * L.z)  # material point of the disc at the contact
    P.v2pt_theory(D, N, R)
    vc = [P.vel(N).dot(N.x), P.vel(N).dot(N.y)]
    kd = [(R.ang_vel_in(N) - w_qd).dot(e) for e in (L.x, L.y, L.z)] + [
        q4.diff(t) - u4,
        q5.diff(t) - u5,
    ]
    ixx, iyy, izz, ixy, ixz, iyz = (sp.sympify(x) for x in disc.inertia)
    Idy = me.inertia(R, ixx, iyy, izz, ixy, iyz, ixz)
    body = me.RigidBody("disc", D, R, m, (Idy, D))
    Fx, Fy, Fz, Tx, Ty, Tz = (
        sp.Symbol(f"disc_{c}", real=True) for c in ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
    )
    loads = [
        (D, -m * g * N.z),
        (D, Fx * N.x + Fy * N.y + Fz * N.z),
        (R, Tx * N.x + Ty * N.y + Tz * N.z),
    ]
    return {
        "frame": N,
        "q": [q1, q2, q3, q4, q5],
        "u": [u1, u2, u3],
        "u_dep": [u4, u5],
        "kd": kd,
        "vc": vc,
        "bodies": [body],
        "loads": loads,
        "inputs": [Fx, Fy, Fz, Tx, Ty, Tz],
        "names": {"q": ["yaw", "lean", "spin", "x", "y"], "u": ["1", "2", "3"]},
    }


def _rot_zxy(q1, q2, q3):
    """World-from-body rotation ``Rz(q1) Rx(q2) Ry(q3)`` and the lean frame ``Rz(q1) Rx(q2)``."""
    from scipy.spatial.transform import Rotation

    L = Rotation.from_euler("ZX", np.stack([q1, q2], -1)).as_matrix()
    Rm = Rotation.from_euler("ZXY", np.stack([q1, q2, q3], -1)).as_matrix()
    return Rm, L


def _rolling_disc_from_mujoco(system, qpos, qvel, qacc):
    from scipy.spatial.transform import Rotation

    qpos, qvel = np.asarray(qpos, float), np.asarray(qvel, float)
    r = system.value(symbol("r"))
    quat = qpos[..., 3:7]
    rot = Rotation.from_quat(quat.reshape(-1, 4), scalar_first=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ang = rot.as_euler("ZXY").reshape(*quat.shape[:-1], 3)
    Rm = rot.as_matrix().reshape(*quat.shape[:-1], 3, 3)
    _, L = _rot_zxy(ang[..., 0], ang[..., 1], ang[..., 2])
    Lz = L[..., :, 2]
    contact = qpos[..., 0:3] - r * Lz
    q = np.concatenate([ang, contact[..., 0:2]], axis=-1)
    w_w = np.einsum("...ij,...j->...i", Rm, qvel[..., 3:6])
    u = np.einsum("...ji,...j->...i", L, w_w)  # components in L
    udot = None
    if qacc is not None:
        qacc = np.asarray(qacc, float)
        a_w = np.einsum("...ij,...j->...i", Rm, qacc[..., 3:6])  # d/dt(R w_b) = R dw_b/dt
        # Euler rates from w_world = yawdot * z + leandot * Lx + spindot * Ly
        ez = np.broadcast_to(np.array([0.0, 0.0, 1.0]), Lz.shape)
        Amat = np.stack([ez, L[..., :, 0], L[..., :, 1]], axis=-1)
        rates = np.linalg.solve(Amat, w_w[..., None])[..., 0]
        w_L = rates[..., 0:1] * ez + rates[..., 1:2] * L[..., :, 0]
        # u = L^T w  =>  du/dt = L^T (a - w_L x w)
        udot = np.einsum("...ji,...j->...i", L, a_w - np.cross(w_L, w_w))
    return q, u, udot


def _rolling_disc_to_mujoco(system, q, u):
    from scipy.spatial.transform import Rotation

    q, u = np.asarray(q, float), np.asarray(u, float)
    r = system.value(symbol("r"))
    Rm, L = _rot_zxy(q[0], q[1], q[2])
    Lz = L[:, 2]
    centre = np.array([q[3], q[4], 0.0]) + r * Lz
    w_w = L @ u
    v = np.cross(w_w, r * Lz)  # rolling: v_P = v_D + w x (-r Lz) = 0
    quat = Rotation.from_matrix(Rm).as_quat(scalar_first=True)
    return np.concatenate([centre, quat]), np.concatenate([v, Rm.T @ w_w])


# --------------------------------------------------------------------------------------
# MJCF
# --------------------------------------------------------------------------------------


def _fmt(x: float) -> str:
    return format(float(x), ".17g")


def _mjcf(system: AnalyticSystem) -> str:
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


# --------------------------------------------------------------------------------------
# Quaternion / Euler helpers
# --------------------------------------------------------------------------------------


def _quat_wxyz_to_zyx(quat: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    quat = np.asarray(quat, float)
    rot = Rotation.from_quat(quat.reshape(-1, 4), scalar_first=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gimbal lock: angles still recompose R
        return rot.as_euler("ZYX").reshape(*quat.shape[:-1], 3)


def _zyx_to_quat_wxyz(ang: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("ZYX", np.asarray(ang, float)).as_quat(scalar_first=True)


# --------------------------------------------------------------------------------------
# Systems
# --------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------
# Simulation
# --------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A MuJoCo trajectory; row t holds the state at ``time[t]`` and the quantities that
    MuJoCo computed at that state (before integrating to t + 1).

    Attributes
    ----------
    time : ndarray, shape [T], s
    qpos : ndarray, shape [T, nq]
    qvel : ndarray, shape [T, nv]
    qacc : ndarray, shape [T, nv]
        Forward-dynamics acceleration at (qpos, qvel, ctrl); Euler: qvel[t+1] = qvel[t] + dt qacc[t].
    ctrl : ndarray, shape [T, nu]
    actuator_force : ndarray, shape [T, nu], N m or N
    contact_wrench : ndarray, shape [T, n_wrench_bodies, 6]
        Total contact force (N, world) and torque about the body origin (N m, world) on
        each body of ``system.wrench_bodies``.
    n_contacts : ndarray, shape [T], int
    """

    system: AnalyticSystem
    time: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    qacc: np.ndarray
    ctrl: np.ndarray
    actuator_force: np.ndarray
    contact_wrench: np.ndarray
    n_contacts: np.ndarray

    def kane_inputs(self, actuators: bool = True) -> np.ndarray:
        """Input vector of the sympy model per step, shape [T, n_inputs].

        ``actuators=False`` zeroes the actuator entries (keeps contact wrenches), which is
        what inverse dynamics (``qfrc_inverse``, ``rnea``) leaves to the actuators.
        """
        T = len(self.time)
        act = self.actuator_force if actuators else np.zeros_like(self.actuator_force)
        return np.concatenate([act.reshape(T, -1), self.contact_wrench.reshape(T, -1)], axis=1)


def contact_wrenches(model, data, body_ids: Sequence[int]) -> np.ndarray:
    """Contact wrench on each body, ``[len(body_ids), 6]``: force (world, N) and torque about
    the body origin (world, N m), summed over ``data.contact``.

    ``mj_contactForce`` returns the force of geom1 on geom2 in the contact frame (rows of
    ``contact.frame`` are the frame axes, normal first), so world force on geom2's body is
    ``frame.T @ f[:3]`` and geom1's body receives the opposite.
    """
    import mujoco

    out = np.zeros((len(body_ids), 6))
    index = {b: i for i, b in enumerate(body_ids)}
    f6 = np.zeros(6)
    for i in range(data.ncon):
        con = data.contact[i]
        mujoco.mj_contactForce(model, data, i, f6)
        frame = np.asarray(con.frame).reshape(3, 3)
        f = frame.T @ f6[:3]
        tq = frame.T @ f6[3:] if con.dim > 3 else np.zeros(3)
        for geom, sign in ((con.geom2, 1.0), (con.geom1, -1.0)):
            b = int(model.geom_bodyid[geom])
            if b in index:
                arm = np.asarray(con.pos) - data.xpos[b]
                out[index[b], :3] += sign * f
                out[index[b], 3:] += sign * (np.cross(arm, f) + tq)
    return out


def _initial_state(
    system: AnalyticSystem, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Random initial (qpos, qvel) for ``system``; systems with contact start in contact range."""
    if system.derivation == "rolling_disc":
        lean = rng.uniform(-0.3, 0.3)
        q = np.array([rng.uniform(-np.pi, np.pi), lean, rng.uniform(-np.pi, np.pi), 0.0, 0.0])
        spin = rng.choice([-1.0, 1.0]) * rng.uniform(15.0, 25.0)  # rad/s, above the critical speed
        u = np.array([rng.normal(0, 0.3), spin, rng.normal(0, 0.3)])
        return system.kane_to_mujoco(q, u)
    qpos, qvel = [], []
    for _, j in system.joints:
        if j.kind == "free":
            quat = rng.normal(size=4)
            quat /= np.linalg.norm(quat)
            z = rng.uniform(-0.5, 0.5)
            z = system.params.get("z0", z)  # drop height of contact scenes
            qpos += [np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), z]), quat]
            vel = rng.normal(0, 1.0, 3)
            if system.has_contact:
                vel[2] = -abs(vel[2]) - 1.0  # thrown down: hits the floor within ~0.1 s
            qvel += [vel, rng.normal(0, 3.0, 3)]
        elif j.kind == "hinge":
            qpos.append([rng.uniform(-np.pi, np.pi)])
            qvel.append([rng.normal(0, 2.0)])
        else:
            qpos.append([rng.uniform(-0.5, 0.5)])
            qvel.append([rng.normal(0, 1.0)])
    return np.concatenate(qpos), np.concatenate(qvel)


def simulate(
    system: AnalyticSystem, n_steps: int = 200, seed: int = 0, ctrl: np.ndarray | None = None
) -> Trajectory:
    """Simulate ``system`` in MuJoCo (Euler integrator) from a random initial state.

    Each step: set ``ctrl``, ``mj_forward`` (records qacc, actuator forces, contacts), then
    ``mj_Euler`` (qvel += dt qacc, then qpos integrated with the new qvel). The first
    ``system.settle_steps`` steps (zero control) are not recorded.

    Parameters
    ----------
    system : AnalyticSystem
    n_steps : int
        Number of recorded states T.
    seed : int
        Seeds the initial state and, when ``ctrl`` is None, uniform random controls in each
        actuator's ``ctrlrange`` drawn per step.
    ctrl : ndarray, shape [T, nu], optional

    Returns
    -------
    Trajectory
    """
    import mujoco

    model = mujoco.MjModel.from_xml_string(system.mjcf())
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    qpos0, qvel0 = _initial_state(system, rng)
    data.qpos[:] = qpos0
    data.qvel[:] = qvel0
    nu = model.nu
    if ctrl is None:
        lo, hi = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
        ctrl = rng.uniform(lo, hi, size=(n_steps, nu)) if nu else np.zeros((n_steps, 0))
    ctrl = np.asarray(ctrl, float)
    if ctrl.shape != (n_steps, nu):
        raise ValueError(
            f"simulate({system.name!r}): ctrl must have shape [n_steps, nu] = [{n_steps}, {nu}], "
            f"got {ctrl.shape}"
        )
    body_ids = [model.body(n).id for n in system.wrench_bodies]
    T = n_steps
    rec = {
        k: np.zeros((T, n))
        for k, n in (
            ("qpos", model.nq),
            ("qvel", model.nv),
            ("qacc", model.nv),
            ("actuator_force", nu),
        )
    }
    wrench = np.zeros((T, len(body_ids), 6))
    ncon = np.zeros(T, dtype=int)
    time_ = np.zeros(T)
    for _ in range(system.settle_steps):
        data.ctrl[:] = 0.0
        mujoco.mj_step(model, data)
    for t in range(T):
        data.ctrl[:] = ctrl[t]
        mujoco.mj_forward(model, data)
        time_[t] = data.time
        rec["qpos"][t], rec["qvel"][t], rec["qacc"][t] = data.qpos, data.qvel, data.qacc
        rec["actuator_force"][t] = data.actuator_force
        wrench[t] = contact_wrenches(model, data, body_ids)
        ncon[t] = data.ncon
        mujoco.mj_Euler(model, data)
    return Trajectory(
        system,
        time_,
        rec["qpos"],
        rec["qvel"],
        rec["qacc"],
        ctrl.copy(),
        rec["actuator_force"],
        wrench,
        ncon,
    )

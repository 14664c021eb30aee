"""The analytic system: one parameterised description from which the sympy Kane model and the MJCF scene are produced.

Conventions (the mapping between sympy q/u and engine coordinates) are listed in
:mod:`kane.systems`; the derivation itself lives in :mod:`kane.systems.derive`, the
kinematics of each system family in :mod:`kane.systems.tree` and
:mod:`kane.systems.rolling_disc`, the MJCF writer in :mod:`kane.systems.mjcf_export`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import sympy as sp
from sympy.physics import mechanics as me

from kane.systems.derive import (
    _CACHE_VERSION,
    SymbolicModel,
    kanes_method,
    lagranges_method,
    symbolic_model,
)
from kane.systems.mjcf_export import _mjcf
from kane.systems.rolling_disc import _rolling_disc_from_mujoco, _rolling_disc_to_mujoco
from kane.systems.specs import ActuatorSpec, BodySpec, Expr, GeomSpec, JointSpec, symbol
from kane.systems.tree import _tree_from_mujoco, _tree_to_mujoco


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
        return sum({"free": 7, "ball": 4}.get(j.kind, 1) for _, j in self.joints)

    @cached_property
    def nv_mujoco(self) -> int:
        """Length of MuJoCo ``qvel``."""
        return sum({"free": 6, "ball": 3}.get(j.kind, 1) for _, j in self.joints)

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
        return symbolic_model(self, use_cache)

    def kanes_method(self) -> tuple[me.KanesMethod, dict]:
        """A fresh sympy ``KanesMethod`` with ``kanes_equations`` already formed (uncached).

        Returns
        -------
        km : sympy.physics.mechanics.KanesMethod
        extra : dict
            ``q``, ``u`` (independent), ``inputs``, ``frame``, ``bodies``, ``loads``,
            ``names`` (plain-symbol names for q and u), ``fr``, ``frstar``.
        """
        return kanes_method(self)

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
        return lagranges_method(self)

    # ---- coordinate maps -----------------------------------------------------------------
    def mujoco_to_kane(self, qpos: np.ndarray, qvel: np.ndarray, qacc: np.ndarray | None = None):
        """Map MuJoCo state to the sympy coordinates and speeds (see the conventions in :mod:`kane.systems`).

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
        return _tree_from_mujoco(self, qpos, qvel, qacc)

    def kane_to_mujoco(self, q: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`mujoco_to_kane` for a state: ``(qpos [nq], qvel [nv])``."""
        if self.derivation == "rolling_disc":
            return _rolling_disc_to_mujoco(self, q, u)
        return _tree_to_mujoco(self, q, u)

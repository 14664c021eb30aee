"""Derivation of an analytic system's Kane equations with sympy, their plain-symbol form, numpy functions and disk cache.

:func:`kanes_method` forms sympy's ``KanesMethod`` from the kinematics of the system's
family (:mod:`kane.systems.tree`, :mod:`kane.systems.rolling_disc`);
:func:`symbolic_model` turns it into a :class:`SymbolicModel` of plain symbols, cached on
disk under :func:`cache_dir`.
"""

from __future__ import annotations

import os
import pickle
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import sympy as sp
from sympy.physics import mechanics as me

from kane.systems.rolling_disc import _rolling_disc_kinematics
from kane.systems.specs import symbol
from kane.systems.tree import _tree_kinematics

#: The system description (:class:`kane.systems.system.AnalyticSystem`), named for annotations only:
#: ``system`` imports this module, so importing it back (even for type checkers) would make a cycle.
AnalyticSystem = Any

#: bump when the derivation code changes, so stale cache files are not reused.
_CACHE_VERSION = 5


def cache_dir() -> Path:
    """Directory of cached derivations: ``$MDGS_CACHE_DIR`` or ``~/.cache/mdgs/kane``."""
    root = os.environ.get("MDGS_CACHE_DIR")
    return Path(root) if root else Path.home() / ".cache" / "mdgs" / "kane"


#: models derived (or loaded) in this process, by :meth:`AnalyticSystem.cache_key`.
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
        Actuator forces, then external wrench components (see the conventions in :mod:`kane.systems`).
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
    if kin.get("armature"):
        frstar, mm = sp.Matrix(frstar), sp.Matrix(mm)
    for k, arm in kin.get("armature", ()):
        # MuJoCo's armature: a rotor inertia on the joint's own speed, M_kk += armature
        frstar[k] = frstar[k] - arm * udsym[k]
        mm[k, k] = mm[k, k] + arm
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
# Forming Kane's (and Lagrange's) equations, with the disk cache
# --------------------------------------------------------------------------------------


def symbolic_model(system: AnalyticSystem, use_cache: bool = True) -> SymbolicModel:
    """Kane's equations of ``system``, derived once and cached on disk.

    Parameters
    ----------
    system : AnalyticSystem
    use_cache : bool
        Read/write ``cache_dir()/<name>-<hash>.pkl`` (key: description, parameter
        values, sympy version). ``False`` always derives afresh (and writes nothing).

    Returns
    -------
    SymbolicModel
    """
    key = system.cache_key()
    if use_cache and key in _MEMO:
        return _MEMO[key]
    path = cache_dir() / f"{system.name}-{key}.pkl"
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
        km, extra = kanes_method(system)
        data = _plain_model_data(system, km, extra)
        if use_cache:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(f".tmp{os.getpid()}")
            with open(tmp, "wb") as fh:
                pickle.dump(data, fh, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(tmp, path)
    model = SymbolicModel(
        system=system, seconds=time.perf_counter() - t0, from_cache=from_cache, **data
    )
    if use_cache:
        _MEMO[key] = model
    return model


def kanes_method(system: AnalyticSystem) -> tuple[me.KanesMethod, dict]:
    """A fresh sympy ``KanesMethod`` of ``system`` with ``kanes_equations`` formed (uncached).

    Returns
    -------
    km : sympy.physics.mechanics.KanesMethod
    extra : dict
        ``q``, ``u`` (independent), ``inputs``, ``frame``, ``bodies``, ``loads``,
        ``names`` (plain-symbol names for q and u), ``fr``, ``frstar``.
    """
    if system.derivation == "tree":
        kin = _tree_kinematics(system, speeds="u")
        km = me.KanesMethod(kin["frame"], q_ind=kin["q"], u_ind=kin["u"], kd_eqs=kin["kd"])
    elif system.derivation == "rolling_disc":
        kin = _rolling_disc_kinematics(system)
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
            f"system {system.name!r}: unknown derivation {system.derivation!r}; use 'tree' or 'rolling_disc'"
        )
    fr, frstar = km.kanes_equations(kin["bodies"], kin["loads"])
    kin["fr"], kin["frstar"] = fr, frstar
    return km, kin


def lagranges_method(system: AnalyticSystem) -> tuple[me.LagrangesMethod, dict]:
    """sympy ``LagrangesMethod`` of the same description, speeds = dq/dt (holonomic trees).

    Kinematics are rebuilt with sympy's own angular velocities (``orientnew``) and
    ``u = dq/dt``; gravity and actuator loads enter as forces (Lagrangian = kinetic
    energy). Only for trees without free or ball joints, where Kane's speeds are also dq/dt.

    Returns
    -------
    lm : sympy.physics.mechanics.LagrangesMethod (equations formed)
    extra : dict, as in :func:`kanes_method`.
    """
    if system.derivation != "tree" or any(j.kind in ("free", "ball") for _, j in system.joints):
        raise ValueError(
            f"system {system.name!r}: the Lagrange route needs a joint tree without free joints "
            "(Kane's speeds then equal dq/dt)"
        )
    kin = _tree_kinematics(system, speeds="qdot")
    L = sum((b.kinetic_energy(kin["frame"]) for b in kin["bodies"]), sp.S.Zero)
    lm = me.LagrangesMethod(L, kin["q"], forcelist=kin["loads"], frame=kin["frame"])
    lm.form_lagranges_equations()
    return lm, kin

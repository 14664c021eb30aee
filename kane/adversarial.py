"""Adversarial routes: hypothesis search and CasADi/ipopt maximisation of claim margins.

Both evaluate the sympy margins of :mod:`kane.element_claims` through generated code
(:func:`kane.codegen.to_numpy`, :func:`kane.codegen.to_casadi`), so they test the very
expression that the docs render. Margins are reported relative to the load/inertia scale
``tau sum|F| + M tau^2 (|alpha| + |omega|^2) + M tau^2`` so that one tolerance fits all
sizes: :data:`REL_TOL` (1e-9: double-precision round-off on sums of ~50 products).
"""

from __future__ import annotations

import random
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from kane import codegen
from kane.element_claims import N_POINTS, element_model, margin_expression

__all__ = ["REL_TOL", "SCALE_TEXT", "Sample", "evaluate_margin", "hypothesis_search", "casadi_search"]

REL_TOL = 1e-9
#: the normalisation of every element margin, as the replay prints it (:meth:`Sample.scale`)
SCALE_TEXT = "tau sum_l |F_l| + M tau^2 (|alpha| + |omega|^2 + 1)"


@dataclass(frozen=True)
class Sample:
    """One element state: masses [L] (kg), offsets [L,3] about the centroid (m), forces [L,3] (N),
    omega [3] (rad/s), alpha [3] (rad/s^2). tau is derived: max |offset|."""

    masses: np.ndarray
    offsets: np.ndarray
    forces: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray

    @property
    def tau(self) -> float:
        return float(np.linalg.norm(self.offsets, axis=1).max())

    def flat(self) -> list[float]:
        return [*self.masses, *self.offsets.ravel(), *self.forces.ravel(), *self.omega, *self.alpha, self.tau]

    def scale(self) -> float:
        M, t = float(self.masses.sum()), self.tau
        f = float(np.linalg.norm(self.forces, axis=1).sum())
        return t * f + M * t**2 * (np.linalg.norm(self.alpha) + np.linalg.norm(self.omega) ** 2 + 1.0)

    def to_dict(self) -> dict:
        return {k: np.asarray(getattr(self, k)).tolist() for k in ("masses", "offsets", "forces", "omega", "alpha")}

    @staticmethod
    def from_dict(d: dict) -> Sample:
        return Sample(*(np.asarray(d[k], float) for k in ("masses", "offsets", "forces", "omega", "alpha")))


def centred(masses, points) -> np.ndarray:
    """Offsets of the points about their mass centre (enforces sum_l m_l r_l = 0)."""
    masses = np.asarray(masses, float)
    points = np.asarray(points, float)
    return points - (masses[:, None] * points).sum(0) / masses.sum()


@lru_cache(maxsize=32)
def _numpy_margin(claim_id: str):
    return codegen.to_numpy(element_model().args, margin_expression(claim_id))


def evaluate_margin(claim_id: str, s: Sample) -> float:
    """Relative margin (lhs - rhs) / scale of ``claim_id`` at sample ``s`` (<= 0 where it holds)."""
    return float(_numpy_margin(claim_id)(*s.flat())) / s.scale()


def _strategy():
    from hypothesis import strategies as st

    fl = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
    vec = st.tuples(fl, fl, fl)
    return st.builds(
        lambda m, p, F, w, a: Sample(np.array(m), centred(m, p), np.array(F), np.array(w), np.array(a)),
        st.lists(st.floats(0.05, 2.0), min_size=N_POINTS, max_size=N_POINTS),
        st.lists(vec, min_size=N_POINTS, max_size=N_POINTS),
        st.lists(vec, min_size=N_POINTS, max_size=N_POINTS),
        vec,
        vec,
    ).filter(lambda s: s.tau > 1e-3)


def hypothesis_search(claim_id: str, seed: int = 0, max_examples: int = 300) -> tuple[float, Sample | None, int]:
    """Search for a sample with relative margin > REL_TOL.

    Returns
    -------
    (largest relative margin seen, shrunk counterexample or None, examples tried)
    """
    from hypothesis import HealthCheck, find, settings
    from hypothesis.errors import NoSuchExample

    seen = {"max": -np.inf, "n": 0}

    def violated(s: Sample) -> bool:
        v = evaluate_margin(claim_id, s)
        seen["n"] += 1
        seen["max"] = max(seen["max"], v)
        return v > REL_TOL

    cfg = settings(max_examples=max_examples, database=None, deadline=None, suppress_health_check=list(HealthCheck))
    try:
        cex = find(_strategy(), violated, settings=cfg, random=random.Random(seed))
    except NoSuchExample:
        return float(seen["max"]), None, seen["n"]
    return max(float(seen["max"]), evaluate_margin(claim_id, cex)), cex, seen["n"]


def casadi_search(claim_id: str, seed: int = 0, n_starts: int = 4) -> tuple[float, Sample]:
    """Maximise the margin with ipopt over offsets |r_l| <= tau = 1 (centroid constraint),
    |F_l| <= 1, |omega| <= 1, |alpha| <= 1, with fixed random masses in [0.2, 2].

    Returns (best relative margin, its sample).
    """
    import casadi as ca

    rng = np.random.default_rng(seed)
    f = codegen.to_casadi(element_model().args, margin_expression(claim_id))
    best = (-np.inf, None)
    L = N_POINTS
    for _ in range(n_starts):
        masses = rng.uniform(0.2, 2.0, L)
        opti = ca.Opti()
        r = opti.variable(L, 3)
        F = opti.variable(L, 3)
        w = opti.variable(3)
        a = opti.variable(3)
        tau = 1.0
        for l in range(L):
            opti.subject_to(ca.sumsqr(r[l, :]) <= tau**2)
            opti.subject_to(ca.sumsqr(F[l, :]) <= 1.0)
        opti.subject_to(ca.sumsqr(w) <= 1.0)
        opti.subject_to(ca.sumsqr(a) <= 1.0)
        for k in range(3):
            opti.subject_to(ca.dot(ca.DM(masses), r[:, k]) == 0)
        args = [*masses, *[r[l, k] for l in range(L) for k in range(3)], *[F[l, k] for l in range(L) for k in range(3)],
                *[w[k] for k in range(3)], *[a[k] for k in range(3)], tau]
        opti.minimize(-f(*args))
        opti.set_initial(r, centred(masses, rng.uniform(-0.6, 0.6, (L, 3))))
        opti.set_initial(F, rng.uniform(-0.5, 0.5, (L, 3)))
        opti.set_initial(w, rng.uniform(-0.5, 0.5, 3))
        opti.set_initial(a, rng.uniform(-0.5, 0.5, 3))
        opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes", "max_iter": 300})
        try:
            sol = opti.solve()
            get = sol.value
        except RuntimeError:
            get = opti.debug.value
        s = Sample(masses, np.asarray(get(r)).reshape(L, 3), np.asarray(get(F)).reshape(L, 3),
                   np.asarray(get(w)).reshape(3), np.asarray(get(a)).reshape(3))
        s = Sample(s.masses, centred(s.masses, s.offsets), s.forces, s.omega, s.alpha)
        if s.tau < 1e-6:
            continue
        v = evaluate_margin(claim_id, s)
        if v > best[0]:
            best = (v, s)
    return best

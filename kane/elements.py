"""Elements: rigid cells made of point masses, and partitions of a box into such cells.

Section 3.2 of the paper divides each rigid body into elements, each element a rigid
cell with its own centroid, mass and point masses (Appendix A.1, Lemma A.1). This module
is the numeric description of one element (body-frame geometry, masses) and the
partition of a box into ``k`` of them; the kinematics and Kane terms live in
:mod:`kane.terms`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

__all__ = ["Element", "partition_box", "partition_box_k", "body_mass_properties", "K_DIVISIONS"]

#: divisions (nx, ny, nz) of the box for the element counts k used by the checks.
K_DIVISIONS: dict[int, tuple[int, int, int]] = {1: (1, 1, 1), 2: (2, 1, 1), 8: (2, 2, 2), 27: (3, 3, 3)}


@dataclass(frozen=True, eq=False)
class Element:
    """A rigid cell of point masses, coordinates in the body frame.

    Attributes
    ----------
    masses : ndarray, shape [L]
        Point masses m_{i,l}, kg (all > 0).
    points : ndarray, shape [L, 3]
        Body-frame positions of the point masses, m.
    """

    masses: np.ndarray
    points: np.ndarray

    def __post_init__(self) -> None:
        m = np.asarray(self.masses, dtype=float).reshape(-1)
        p = np.asarray(self.points, dtype=float).reshape(-1, 3)
        if m.shape[0] != p.shape[0] or m.shape[0] == 0:
            raise ValueError(f"Element needs as many masses as points (got {m.shape[0]} and {p.shape[0]})")
        if not np.all(m > 0) or not np.all(np.isfinite(p)):
            raise ValueError("Element point masses must be positive and positions finite")
        object.__setattr__(self, "masses", m)
        object.__setattr__(self, "points", p)

    @cached_property
    def mass(self) -> float:
        """M_i = sum_l m_{i,l}, kg."""
        return float(self.masses.sum())

    @cached_property
    def centroid(self) -> np.ndarray:
        """Mass centre of the element in the body frame, shape [3], m."""
        return (self.masses[:, None] * self.points).sum(0) / self.mass

    @cached_property
    def offsets(self) -> np.ndarray:
        """r_{i,l}: point positions relative to the element centroid, shape [L, 3], m."""
        return self.points - self.centroid

    @cached_property
    def inertia(self) -> np.ndarray:
        """Inertia tensor about the element centroid (body axes), shape [3, 3], kg m^2."""
        r = self.offsets
        rr = (r * r).sum(1)
        return (self.masses[:, None, None] * (rr[:, None, None] * np.eye(3) - r[:, :, None] * r[:, None, :])).sum(0)

    @cached_property
    def tau(self) -> float:
        """Largest distance from the centroid to a point mass (the element radius), m."""
        return float(np.linalg.norm(self.offsets, axis=1).max())


def _cell_lattice(lo: np.ndarray, hi: np.ndarray, n: int) -> np.ndarray:
    """Points at the centres of an n x n x n sub-grid of the cell [lo, hi], shape [n^3, 3]."""
    axes = [lo[a] + (np.arange(n) + 0.5) * (hi[a] - lo[a]) / n for a in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def partition_box(
    half_extents,
    divisions=(1, 1, 1),
    mass: float = 1.0,
    points_per_axis: int = 2,
    rng: np.random.Generator | None = None,
    jitter: float = 0.0,
) -> list[Element]:
    """Divide the box [-h, h] (body frame, centred on the origin) into cells of point masses.

    Parameters
    ----------
    half_extents : array_like, shape [3]
        Half side lengths h of the box, m.
    divisions : (nx, ny, nz)
        Number of cells along each axis; ``nx * ny * nz`` elements are returned.
    mass : float
        Total mass of the box, kg. With ``jitter == 0`` it is spread uniformly.
    points_per_axis : int
        Each cell carries ``points_per_axis**3`` point masses on a regular sub-grid.
    rng, jitter : numpy Generator, float
        Non-uniform mass distributions: each point mass is multiplied by
        ``exp(jitter * N(0, 1))`` before the total is rescaled to ``mass``.

    Returns
    -------
    list of Element, in C order of the (ix, iy, iz) cell index.
    """
    h = np.asarray(half_extents, dtype=float).reshape(3)
    nd = np.asarray(divisions, dtype=int).reshape(3)
    if np.any(h <= 0) or np.any(nd < 1) or points_per_axis < 1 or mass <= 0:
        raise ValueError("partition_box needs positive half extents, divisions >= 1, points_per_axis >= 1, mass > 0")
    edges = [np.linspace(-h[a], h[a], nd[a] + 1) for a in range(3)]
    cells = []
    for ix in range(nd[0]):
        for iy in range(nd[1]):
            for iz in range(nd[2]):
                lo = np.array([edges[0][ix], edges[1][iy], edges[2][iz]])
                hi = np.array([edges[0][ix + 1], edges[1][iy + 1], edges[2][iz + 1]])
                cells.append(_cell_lattice(lo, hi, points_per_axis))
    n_pts = sum(len(c) for c in cells)
    weights = [np.ones(len(c)) for c in cells]
    if jitter > 0:
        rng = rng if rng is not None else np.random.default_rng(0)
        weights = [np.exp(jitter * rng.standard_normal(len(c))) for c in cells]
    total = sum(w.sum() for w in weights)
    scale = mass / total if jitter > 0 else mass / n_pts
    return [Element(masses=w * scale, points=c) for w, c in zip(weights, cells, strict=True)]


def partition_box_k(half_extents, k: int, mass: float = 1.0, **kwargs) -> list[Element]:
    """The box as ``k`` elements, ``k`` in :data:`K_DIVISIONS` (1, 2, 8, 27)."""
    if k not in K_DIVISIONS:
        raise ValueError(f"k must be one of {sorted(K_DIVISIONS)}, got {k}")
    return partition_box(half_extents, K_DIVISIONS[k], mass=mass, **kwargs)


def body_mass_properties(elements: list[Element]) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, mass centre [3] and inertia about the mass centre [3, 3] of a union of elements.

    Computed from all point masses together, so it is the undivided body's properties
    (independent of how the points are grouped into elements).
    """
    m = np.concatenate([e.masses for e in elements])
    p = np.concatenate([e.points for e in elements])
    whole = Element(masses=m, points=p)
    return whole.mass, whole.centroid, whole.inertia

"""Element partition of a MuJoCo model's rigid bodies (paper section 3.2, Fig. 2).

Each rigid body is divided into finite-element-like cells; each cell becomes a graph
node at its centroid carrying its volume, mass (uniform density), largest radius ``tau``
and inertia about its centroid. Cells of the same body that share a face are adjacent.

Cells per geom type (all in the geom frame, then moved to the body frame):

- box: a regular grid of boxes;
- cylinder: rings x sectors x layers (an O-grid; the inner ring is made of wedges);
- sphere: shells x polar bands x azimuth sectors; ellipsoid: the sphere's cells mapped
  by ``diag(a, b, c)``; capsule: cylinder cells plus two hemispheres whose cells meet
  the cylinder's end faces face to face;
- mesh: the mesh's convex hull cut by a voxel grid (each cell is a convex polyhedron;
  slivers under 1 % of a full voxel are merged into their largest face neighbour).

Mass properties of every cell are exact: curvilinear cells are integrated with
tensor Gauss-Legendre quadrature of the map's Jacobian (polynomial in the radius,
trigonometric in the angles, so 6 x 16 x 16 points reach round-off), polyhedral
cells are split into tetrahedra. Hence, at every resolution, the cells of a body sum
to the body's mass, centre of mass and inertia tensor; ``tests/test_partition.py``
checks them against MuJoCo's own ``body_mass``/``body_ipos``/``body_inertia``: equal
to round-off (1e-15) for primitives and to float32 precision (1e-8) for meshes, whose
vertices MuJoCo stores in float32. (A non-convex mesh's hull differs from the mesh
itself; its report shows by how much.)

Default resolution (:func:`default_level`): a body at level ``n`` uses cells of edge
about ``h = L / n`` where ``L`` is the largest extent of its geoms (boxes: ``round(2a/h)``
cells per axis; round sections: rings of thickness ~``h``, sectors with an outer arc
of ~``h``). The default is the smallest ``n`` for which both tolerances of
:class:`PartitionParams` hold:

- ``inertia_tol`` (0.25): the inertia that the *nodes as point masses* miss,
  ``|sum_i I_i|_F / |I_body|_F`` (``I_i`` is cell ``i``'s inertia about its own centroid).
  This is exactly the part of the dynamics that the paper's disturbance ``Psi`` in
  Eq. (11) stands for (Theorem 3.2 bounds it with the cells' own inertia
  ``(2/5) M_i tau^2``), so the rule keeps ``Psi`` a correction, not the leading term: the
  point masses carry at least 75 % of every body's inertia. A cube at 2 x 2 x 2 cells
  misses exactly 1/4 (and 1/n^2 at n^3 cells), so compact bodies get 8 nodes, not 64.
- ``contact_tol`` (0.75): the largest distance from a point of the body's surface to
  its nearest node, relative to the body's bounding radius about its centre of mass
  (one cell per box gives 1.0, the corner; 2 x 2 x 2 gives 0.5). Contact forces are attached to nodes
  (section 3.2.1), so this bounds the lever-arm error of a contact force at a quarter
  of the body's size; it binds for long or flat geoms whose inertia alone would allow
  a single row of cells.

Mass, centre of mass and the full inertia tensor (nodes plus their own inertia) are
exact at every level, so the tolerances only decide what a graph of point masses can
see. ``PartitionParams.refine`` multiplies the default level (finer graphs),
``PartitionParams.level`` fixes it for every body.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np

__all__ = [
    "PartitionParams",
    "Partition",
    "BodyReport",
    "PartitionError",
    "partition_model",
    "default_level",
    "SUPPORTED_GEOMS",
    "format_report",
]

_G = mujoco.mjtGeom
SUPPORTED_GEOMS = ("box", "sphere", "capsule", "cylinder", "ellipsoid", "mesh")
_SUPPORTED_TYPES = {
    int(_G.mjGEOM_BOX): "box",
    int(_G.mjGEOM_SPHERE): "sphere",
    int(_G.mjGEOM_CAPSULE): "capsule",
    int(_G.mjGEOM_CYLINDER): "cylinder",
    int(_G.mjGEOM_ELLIPSOID): "ellipsoid",
    int(_G.mjGEOM_MESH): "mesh",
}

# Quadrature orders: radial/linear parameters, angular parameters.
_NQ_LIN = 6
_NQ_ANG = 16
# Boundary samples per parameter for tau (largest distance from the centroid).
_NS_LIN = 5
_NS_ANG = 17
_SLIVER = 0.01  # mesh cut cells under this fraction of a full voxel are merged


class PartitionError(ValueError):
    """A model that the partition does not support; the message names the geom and the fix."""


#: Most divisions along a body's length that ``refine`` may ask for (about MAX_LEVEL^3 elements per
#: body): beyond it generation would run for hours and models would not fit in memory.
MAX_LEVEL = 24


@dataclass(frozen=True)
class PartitionParams:
    """How finely bodies are partitioned. Every default is the one documented in the module."""

    inertia_tol: float = 0.25
    """Largest fraction of a body's inertia (Frobenius norm) that node point masses may miss."""
    contact_tol: float = 0.75
    """Largest surface-to-nearest-node distance, relative to the body's bounding radius."""
    refine: int = 1
    """Multiplier on the default level (2 doubles the cells along each dimension)."""
    level: int | None = None
    """Fixed level for every body (overrides the default rule and ``refine``)."""
    max_level: int = 24
    """Search limit of the default rule."""
    static_geoms: bool = True
    """Give non-plane geoms of the world body nodes too (obstacles), flagged ``static``."""

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class BodyReport:
    """How well one body's nodes represent it (all errors are relative)."""

    body: int
    name: str
    level: int
    n_nodes: int
    mass_error: float
    """|sum M_i - body_mass| / body_mass (against MuJoCo)."""
    com_error: float
    """|partition com - body_ipos| / bounding radius (against MuJoCo)."""
    inertia_error: float
    """|I_partition - I_mujoco|_F / |I_mujoco|_F, about the com (against MuJoCo)."""
    point_mass_deficit: float
    """|sum_i I_i|_F / |I_body|_F: inertia the nodes miss as point masses."""
    surface_gap: float
    """Largest surface-to-nearest-node distance / body bounding radius about its com."""


@dataclass(frozen=True)
class Partition:
    """Nodes of a model. Arrays are indexed by node; frames are MuJoCo body frames.

    Shapes: ``N`` nodes, ``E`` undirected edges.
    """

    body: np.ndarray  # [N] int32, MuJoCo body id (0 = world: static obstacle geometry)
    geom: np.ndarray  # [N] int32, MuJoCo geom id the cell was cut from
    centroid: np.ndarray  # [N, 3] m, in the body frame
    volume: np.ndarray  # [N] m^3
    mass: np.ndarray  # [N] kg (0 for static nodes)
    tau: np.ndarray  # [N] m, largest distance from the centroid to a point of the cell
    inertia: np.ndarray  # [N, 3, 3] kg m^2, about the centroid, body-frame axes
    static: np.ndarray  # [N] bool, node of the world or of a body welded to it (does not move)
    adjacency: np.ndarray  # [E, 2] int32, i < j, same body and a shared face
    params: PartitionParams
    reports: tuple[BodyReport, ...] = field(default=())

    @property
    def n_nodes(self) -> int:
        return int(self.body.shape[0])

    def nodes_of(self, body: int) -> np.ndarray:
        return np.flatnonzero(self.body == body)

    def summary(self) -> dict:
        """Node count per body name and in total (what the docs and the report list)."""
        return {
            "n_nodes": self.n_nodes,
            "n_edges": int(self.adjacency.shape[0]),
            "per_body": {r.name: r.n_nodes for r in self.reports},
            "levels": {r.name: r.level for r in self.reports},
        }


# --------------------------------------------------------------------------------------
# Cells of one geom
# --------------------------------------------------------------------------------------


@dataclass
class _Cells:
    """Cells of one geom in the geom frame (before moving them into the body frame)."""

    volume: np.ndarray  # [n]
    first: np.ndarray  # [n, 3] integral of x dV
    second: np.ndarray  # [n, 3, 3] integral of x x^T dV
    tau_points: list[np.ndarray]  # per cell: [p, 3] boundary samples (or vertices)
    edges: np.ndarray  # [e, 2] face adjacency within the geom

    @property
    def centroid(self) -> np.ndarray:
        return self.first / self.volume[:, None]


def _gauss(a: np.ndarray, b: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes/weights on each interval [a_k, b_k]: ([k, n], [k, n])."""
    x, w = np.polynomial.legendre.leggauss(n)
    half = (b - a)[:, None] / 2
    return (a + b)[:, None] / 2 + half * x[None, :], half * w[None, :]


def _curvilinear(
    kind: str, edges: Sequence[np.ndarray], scale=(1.0, 1.0, 1.0), shift=(0.0, 0.0, 0.0)
):
    """Mass properties of the tensor-product cells of one parameter block.

    ``kind``: 'box' x=(u,v,w); 'cyl' x=(u cos v, u sin v, w), J=u;
    'sph' x=(u sin v cos w, u sin v sin w, u cos v), J=u^2 sin v. The result is then
    scaled by ``diag(scale)`` (ellipsoids) and shifted (capsule caps).
    Returns volume [n], first [n,3], second [n,3,3], samples [n,p,3], index grid shape.
    """
    eu, ev, ew = (np.asarray(e, float) for e in edges)
    nu, nv, nw = len(eu) - 1, len(ev) - 1, len(ew) - 1
    ang = (False, kind != "box", kind == "sph")  # which parameters are angles
    qv = _NQ_ANG if ang[1] else _NQ_LIN
    qw = _NQ_ANG if ang[2] else _NQ_LIN
    un, uw = _gauss(eu[:-1], eu[1:], _NQ_LIN)
    vn, vw = _gauss(ev[:-1], ev[1:], qv)
    wn, ww = _gauss(ew[:-1], ew[1:], qw)
    # broadcast to [nu, nv, nw, qu, qv, qw]
    U = un[:, None, None, :, None, None]
    V = vn[None, :, None, None, :, None]
    W = wn[None, None, :, None, None, :]
    WT = (
        uw[:, None, None, :, None, None]
        * vw[None, :, None, None, :, None]
        * ww[None, None, :, None, None, :]
    )
    X, J = _map(kind, U, V, W)
    S = np.asarray(scale, float)
    X = [X[i] * S[i] + shift[i] for i in range(3)]
    detS = S[0] * S[1] * S[2]
    wJ = WT * J * detS
    red = (3, 4, 5)
    vol = wJ.sum(red).reshape(-1)
    first = np.stack([(wJ * X[i]).sum(red).reshape(-1) for i in range(3)], -1)
    second = np.empty((vol.shape[0], 3, 3))
    for i in range(3):
        for j in range(i, 3):
            second[:, i, j] = second[:, j, i] = (wJ * X[i] * X[j]).sum(red).reshape(-1)
    # boundary samples for tau (cell corners, edges and faces included)
    su = np.stack([np.linspace(a, b, _NS_LIN) for a, b in zip(eu[:-1], eu[1:], strict=True)])
    sv = np.stack(
        [
            np.linspace(a, b, _NS_ANG if ang[1] else _NS_LIN)
            for a, b in zip(ev[:-1], ev[1:], strict=True)
        ]
    )
    sw = np.stack(
        [
            np.linspace(a, b, _NS_ANG if ang[2] else _NS_LIN)
            for a, b in zip(ew[:-1], ew[1:], strict=True)
        ]
    )
    Xs, _ = _map(
        kind,
        su[:, None, None, :, None, None],
        sv[None, :, None, None, :, None],
        sw[None, None, :, None, None, :],
    )
    Xs = [
        np.broadcast_to(Xs[i], (nu, nv, nw, su.shape[1], sv.shape[1], sw.shape[1])) * S[i]
        + shift[i]
        for i in range(3)
    ]
    samples = np.stack(Xs, -1).reshape(nu * nv * nw, -1, 3)
    return vol, first, second, samples, (nu, nv, nw)


def _map(kind, U, V, W):
    if kind == "box":
        return [U + 0 * V + 0 * W, V + 0 * U + 0 * W, W + 0 * U + 0 * V], np.ones_like(U * V * W)
    if kind == "cyl":
        return [U * np.cos(V) + 0 * W, U * np.sin(V) + 0 * W, W + 0 * U * V], U + 0 * V * W
    if kind == "sph":
        sv = np.sin(V)
        return [U * sv * np.cos(W), U * sv * np.sin(W), U * np.cos(V) + 0 * W], U * U * sv + 0 * W
    raise AssertionError(kind)


def _grid_edges(
    shape: tuple[int, int, int], periodic: tuple[bool, bool, bool]
) -> list[tuple[int, int]]:
    """Face neighbours in a tensor grid (C order), with optional wrap-around."""
    out = []
    idx = np.arange(int(np.prod(shape))).reshape(shape)
    for ax in range(3):
        n = shape[ax]
        if n < 2:
            continue
        a = np.take(idx, range(n - 1), axis=ax).ravel()
        b = np.take(idx, range(1, n), axis=ax).ravel()
        out += list(zip(a.tolist(), b.tolist(), strict=True))
        if periodic[ax] and n > 2:
            a = np.take(idx, [n - 1], axis=ax).ravel()
            b = np.take(idx, [0], axis=ax).ravel()
            out += list(zip(a.tolist(), b.tolist(), strict=True))
    return out


def _divisions(length: float, h: float) -> int:
    return max(1, int(round(length / h)))


def _round_counts(r: float, h: float) -> tuple[int, int]:
    """Rings (or shells) and sectors for a round section of radius ``r`` and cell size ``h``.

    One cell when the diameter is a single division; otherwise rings of thickness about
    ``h`` and sectors whose outer arc is about ``h`` (at least 3 so cells stay convex).
    """
    if _divisions(2 * r, h) == 1:
        return 1, 1
    return max(1, int(round(r / h))), max(3, int(round(2 * np.pi * r / h)))


def _block_cells(kind: str, edges, periodic: tuple[bool, bool, bool], **kw) -> _Cells:
    """Cells of one parameter block (:func:`_curvilinear`) and their face neighbours.

    ``periodic`` marks the parameters that wrap around (an angle over a full turn).
    """
    vol, first, second, samples, shape = _curvilinear(kind, edges, **kw)
    edge_pairs = np.array(_grid_edges(shape, periodic), int).reshape(-1, 2)
    return _Cells(vol, first, second, list(samples), edge_pairs)


def _box_cells(size, h) -> _Cells:
    a, b, c = size
    n = [_divisions(2 * s, h) for s in (a, b, c)]
    edges = [np.linspace(-s, s, k + 1) for s, k in zip((a, b, c), n, strict=True)]
    return _block_cells("box", edges, (False,) * 3)


def _cylinder_cells(r, hh, h) -> _Cells:
    nr, ns = _round_counts(r, h)
    nz = _divisions(2 * hh, h)
    edges = [
        np.linspace(0, r, nr + 1),
        np.linspace(0, 2 * np.pi, ns + 1),
        np.linspace(-hh, hh, nz + 1),
    ]
    return _block_cells("cyl", edges, (False, True, False))


def _sphere_cells(r, h, scale=(1.0, 1.0, 1.0)) -> _Cells:
    nr, nphi = _round_counts(r, h)
    nth = 1 if nphi == 1 else max(2, int(round(np.pi * r / h)))
    edges = [
        np.linspace(0, r, nr + 1),
        np.linspace(0, np.pi, nth + 1),
        np.linspace(0, 2 * np.pi, nphi + 1),
    ]
    return _block_cells("sph", edges, (False, False, True), scale=scale)


def _capsule_cells(r, hh, h) -> _Cells:
    nr, ns = _round_counts(r, h)
    nz = _divisions(2 * hh, h)
    nth = 1 if ns == 1 else max(1, int(round(np.pi * r / (2 * h))))  # bands over a quarter circle
    cyl = _curvilinear(
        "cyl",
        [
            np.linspace(0, r, nr + 1),
            np.linspace(0, 2 * np.pi, ns + 1),
            np.linspace(-hh, hh, nz + 1),
        ],
    )
    top = _curvilinear(
        "sph",
        [
            np.linspace(0, r, nr + 1),
            np.linspace(0, np.pi / 2, nth + 1),
            np.linspace(0, 2 * np.pi, ns + 1),
        ],
        shift=(0, 0, hh),
    )
    bot = _curvilinear(
        "sph",
        [
            np.linspace(0, r, nr + 1),
            np.linspace(np.pi / 2, np.pi, nth + 1),
            np.linspace(0, 2 * np.pi, ns + 1),
        ],
        shift=(0, 0, -hh),
    )
    blocks = [cyl, top, bot]
    offs = np.cumsum([0] + [b[0].shape[0] for b in blocks])
    edges = []
    for blk, off, per in zip(
        blocks,
        offs,
        [(False, True, False), (False, False, True), (False, False, True)],
        strict=False,
    ):
        edges += [(i + off, j + off) for i, j in _grid_edges(blk[4], per)]
    cshape, tshape, bshape = cyl[4], top[4], bot[4]
    for i in range(nr):
        for k in range(ns):
            # cylinder cell (ring i, sector k, top layer) meets cap cell (shell i, last band, sector k)
            ctop = np.ravel_multi_index((i, k, nz - 1), cshape)
            cbot = np.ravel_multi_index((i, k, 0), cshape)
            t = np.ravel_multi_index((i, nth - 1, k), tshape)
            b = np.ravel_multi_index((i, 0, k), bshape)
            edges += [(int(ctop), int(t + offs[1])), (int(cbot), int(b + offs[2]))]
    return _Cells(
        np.concatenate([b[0] for b in blocks]),
        np.concatenate([b[1] for b in blocks]),
        np.concatenate([b[2] for b in blocks]),
        [s for b in blocks for s in b[3]],
        np.array(edges, int).reshape(-1, 2),
    )


# ---- convex polyhedra (mesh geoms) ----------------------------------------------------


def _tet_moments(verts: np.ndarray, tris: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Volume, first and second moments of a closed convex polyhedron (fan from its mean)."""
    o = verts.mean(0)
    a, b, c = verts[tris[:, 0]] - o, verts[tris[:, 1]] - o, verts[tris[:, 2]] - o
    v6 = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c)))
    vol = v6 / 6
    # tetra (o, A, B, C): integral x = V (sum of 4 vertices)/4; x x^T = V/20 (sum v v^T + s s^T)
    P = np.stack([np.broadcast_to(o, a.shape), a + o, b + o, c + o], 1)  # [t, 4, 3]
    s = P.sum(1)
    first = (vol[:, None] * s / 4).sum(0)
    second = (
        vol[:, None, None] / 20 * (np.einsum("tki,tkj->tij", P, P) + np.einsum("ti,tj->tij", s, s))
    ).sum(0)
    return float(vol.sum()), first, second


def _halfspace_cell(A: np.ndarray, b: np.ndarray, tol: float):
    """Vertices of {x : A x <= b} (bounded), or None when its inradius is below ``tol``."""
    from scipy.optimize import linprog
    from scipy.spatial import ConvexHull, HalfspaceIntersection

    norms = np.linalg.norm(A, axis=1)
    res = linprog(
        np.r_[0, 0, 0, -1.0],
        A_ub=np.c_[A, norms],
        b_ub=b,
        bounds=[(None, None)] * 3 + [(0, None)],
        method="highs",
    )
    if not res.success or res.x[3] <= tol:
        return None
    hs = HalfspaceIntersection(np.c_[A, -b], res.x[:3])
    verts = hs.intersections
    hull = ConvexHull(verts)
    return verts[hull.vertices], ConvexHull(verts[hull.vertices])


def _mesh_cells(verts: np.ndarray, h: float) -> _Cells:
    from scipy.spatial import ConvexHull

    hull = ConvexHull(verts)
    H = hull.equations  # n.x + d <= 0 inside
    lo, hi = verts.min(0), verts.max(0)
    n = [_divisions(hi[i] - lo[i], h) for i in range(3)]
    ticks = [np.linspace(lo[i], hi[i], n[i] + 1) for i in range(3)]
    full = np.prod((hi - lo) / np.array(n))
    tol = 1e-9 * float(np.max(hi - lo))
    cells, index = [], {}
    for ijk in np.ndindex(*n):
        A = np.vstack([H[:, :3], np.eye(3), -np.eye(3)])
        b = np.r_[
            -H[:, 3],
            [ticks[k][ijk[k] + 1] for k in range(3)],
            [-ticks[k][ijk[k]] for k in range(3)],
        ]
        out = _halfspace_cell(A, b, tol)
        if out is None:
            continue
        v, ch = out
        vol, first, second = _tet_moments(ch.points, ch.simplices)
        index[ijk] = len(cells)
        cells.append([vol, first, second, v, {ijk}])
    # face adjacency: grid neighbours whose shared face meets the hull with positive area
    edges = set()
    for ijk, i in index.items():
        for ax in range(3):
            nb = list(ijk)
            nb[ax] += 1
            nb = tuple(nb)
            if nb not in index:
                continue
            if _face_area_positive(H, ticks, ijk, ax, tol):
                edges.add((i, index[nb]))
    # merge slivers into their largest face neighbour
    parent = list(range(len(cells)))

    def root(i):
        while parent[i] != i:
            i = parent[i]
        return i

    for i in sorted(range(len(cells)), key=lambda i: cells[i][0]):
        if cells[i][0] >= _SLIVER * full:
            continue
        nbs = [j if a == i else a for a, j in edges if i in (a, j)]
        nbs = [root(j) for j in nbs if root(j) != root(i)]
        if not nbs:
            continue
        j = max(nbs, key=lambda j: cells[j][0])
        ri = root(i)
        cells[j][0] += cells[ri][0]
        cells[j][1] = cells[j][1] + cells[ri][1]
        cells[j][2] = cells[j][2] + cells[ri][2]
        cells[j][3] = np.vstack([cells[j][3], cells[ri][3]])
        cells[ri][0] = 0.0
        parent[ri] = j
    keep = [i for i in range(len(cells)) if parent[i] == i]
    new = {old: k for k, old in enumerate(keep)}
    merged_edges = {
        tuple(sorted((new[root(a)], new[root(b)]))) for a, b in edges if root(a) != root(b)
    }
    return _Cells(
        np.array([cells[i][0] for i in keep]),
        np.array([cells[i][1] for i in keep]),
        np.array([cells[i][2] for i in keep]),
        [cells[i][3] for i in keep],
        np.array(sorted(merged_edges), int).reshape(-1, 2),
    )


def _face_area_positive(H, ticks, ijk, ax, tol) -> bool:
    """Does the face between voxel ``ijk`` and its +``ax`` neighbour meet the hull in an area?"""
    from scipy.optimize import linprog

    c = ticks[ax][ijk[ax] + 1]
    other = [k for k in range(3) if k != ax]
    # hull restricted to the plane x_ax = c: n_o . y <= -d - n_ax c
    A = np.vstack([H[:, other], np.eye(2), -np.eye(2)])
    b = np.r_[
        -H[:, 3] - H[:, ax] * c,
        [ticks[k][ijk[k] + 1] for k in other],
        [-ticks[k][ijk[k]] for k in other],
    ]
    norms = np.linalg.norm(A, axis=1)
    res = linprog(
        np.r_[0, 0, -1.0],
        A_ub=np.c_[A, norms],
        b_ub=b,
        bounds=[(None, None)] * 2 + [(0, None)],
        method="highs",
    )
    return bool(res.success and res.x[2] > tol)


# --------------------------------------------------------------------------------------
# Geoms, bodies, levels
# --------------------------------------------------------------------------------------


def _geom_kind(model: mujoco.MjModel, g: int) -> str:
    t = int(model.geom_type[g])
    if t in _SUPPORTED_TYPES:
        return _SUPPORTED_TYPES[t]
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"#{g}"
    tname = mujoco.mjtGeom(t).name.removeprefix("mjGEOM_").lower()
    raise PartitionError(
        f"geom '{name}' has type '{tname}', which cannot be partitioned into elements; "
        f"use one of {', '.join(SUPPORTED_GEOMS)} for bodies that move (planes only on the world body)"
    )


def _mesh_vertices(model: mujoco.MjModel, g: int) -> np.ndarray:
    m = int(model.geom_dataid[g])
    a, n = int(model.mesh_vertadr[m]), int(model.mesh_vertnum[m])
    return np.array(model.mesh_vert[a : a + n], float)


def _geom_extent(model: mujoco.MjModel, g: int) -> float:
    """Largest dimension of a geom (m)."""
    kind = _geom_kind(model, g)
    s = model.geom_size[g]
    if kind == "box" or kind == "ellipsoid":
        return 2 * float(s.max())
    if kind == "sphere":
        return 2 * float(s[0])
    if kind == "cylinder":
        return 2 * float(max(s[0], s[1]))
    if kind == "capsule":
        return 2 * float(s[0] + s[1])
    v = _mesh_vertices(model, g)
    return float((v.max(0) - v.min(0)).max())


def _geom_cells(model: mujoco.MjModel, g: int, h: float) -> _Cells:
    kind = _geom_kind(model, g)
    s = model.geom_size[g]
    if kind == "box":
        return _box_cells(s, h)
    if kind == "sphere":
        return _sphere_cells(float(s[0]), h)
    if kind == "ellipsoid":
        r = float(s.max())
        return _sphere_cells(r, h, scale=tuple(float(x) / r for x in s))
    if kind == "cylinder":
        return _cylinder_cells(float(s[0]), float(s[1]), h)
    if kind == "capsule":
        return _capsule_cells(float(s[0]), float(s[1]), h)
    return _mesh_cells(_mesh_vertices(model, g), h)


def _surface_points(model: mujoco.MjModel, g: int, n: int = 24) -> np.ndarray:
    """Points on a geom's surface in the geom frame (grid per face / Fibonacci on spheres)."""
    kind = _geom_kind(model, g)
    s = model.geom_size[g]
    t = np.linspace(-1, 1, n)
    if kind == "box":
        A, B = np.meshgrid(t, t)
        pts = []
        for ax in range(3):
            o = [k for k in range(3) if k != ax]
            for sign in (-1, 1):
                p = np.zeros((A.size, 3))
                p[:, ax] = sign
                p[:, o[0]], p[:, o[1]] = A.ravel(), B.ravel()
                pts.append(p)
        return np.vstack(pts) * s[:3]
    i = np.arange(4 * n * n) + 0.5
    phi = np.arccos(1 - 2 * i / i.size)
    th = np.pi * (1 + 5**0.5) * i
    unit = np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], -1)
    if kind == "sphere":
        return unit * s[0]
    if kind == "ellipsoid":
        return unit * s[:3]
    if kind in ("cylinder", "capsule"):
        r, hh = float(s[0]), float(s[1])
        ang = np.linspace(0, 2 * np.pi, 4 * n, endpoint=False)
        Z, TH = np.meshgrid(np.linspace(-hh, hh, n), ang)
        side = np.stack([r * np.cos(TH.ravel()), r * np.sin(TH.ravel()), Z.ravel()], -1)
        if kind == "capsule":
            caps = unit * r
            caps[:, 2] += np.where(caps[:, 2] >= 0, hh, -hh)
            return np.vstack([side, caps])
        R, TH = np.meshgrid(np.linspace(0, r, n), ang)
        disc = np.stack([R.ravel() * np.cos(TH.ravel()), R.ravel() * np.sin(TH.ravel())], -1)
        return np.vstack(
            [side, np.c_[disc, np.full(len(disc), hh)], np.c_[disc, np.full(len(disc), -hh)]]
        )
    from scipy.spatial import ConvexHull

    v = _mesh_vertices(model, g)
    hull = ConvexHull(v)
    tri = v[hull.simplices]
    w = np.array(
        [
            [1, 0, 0],
            [0, 1, 0],
            [0, 0, 1],
            [1 / 3, 1 / 3, 1 / 3],
            [0.5, 0.5, 0],
            [0, 0.5, 0.5],
            [0.5, 0, 0.5],
        ]
    )
    return np.einsum("kj,tjd->tkd", w, tri).reshape(-1, 3)


def _quat_mat(q: np.ndarray) -> np.ndarray:
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(q, float))
    return m.reshape(3, 3)


@dataclass
class _BodyCells:
    geom: np.ndarray
    volume: np.ndarray
    first: np.ndarray  # body frame
    second: np.ndarray  # body frame
    samples: list[np.ndarray]  # body frame
    edges: np.ndarray
    surface: list[
        tuple[np.ndarray, float]
    ]  # per geom: surface points (body frame), bounding radius


def _body_geoms(model: mujoco.MjModel, body: int, static: bool) -> list[int]:
    out = []
    for g in range(model.ngeom):
        if int(model.geom_bodyid[g]) != body:
            continue
        if static:
            if int(model.geom_type[g]) == int(_G.mjGEOM_PLANE):
                continue
            if int(model.geom_type[g]) == int(_G.mjGEOM_HFIELD):
                continue  # terrain is described by the MJCF, not by nodes
            if model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0:
                continue
        out.append(g)
    return out


def _cells_of_body(model: mujoco.MjModel, geoms: list[int], h: float) -> _BodyCells:
    vols, firsts, seconds, samples, edges, gids, surface = [], [], [], [], [], [], []
    off = 0
    for g in geoms:
        c = _geom_cells(model, g, h)
        R, p = _quat_mat(model.geom_quat[g]), np.asarray(model.geom_pos[g], float)
        # x_b = R x_g + p: moments transform exactly
        f = c.first @ R.T + c.volume[:, None] * p
        S = np.einsum("ij,njk,lk->nil", R, c.second, R)
        S = (
            S
            + np.einsum("ni,j->nij", c.first @ R.T, p)
            + np.einsum("i,nj->nij", p, c.first @ R.T)
            + c.volume[:, None, None] * np.outer(p, p)
        )
        vols.append(c.volume)
        firsts.append(f)
        seconds.append(S)
        samples += [s @ R.T + p for s in c.tau_points]
        edges.append(c.edges + off)
        gids.append(np.full(len(c.volume), g))
        pts = _surface_points(model, g)
        surface.append((pts @ R.T + p, float(np.linalg.norm(pts, axis=1).max())))
        off += len(c.volume)
    return _BodyCells(
        np.concatenate(gids).astype(np.int32),
        np.concatenate(vols),
        np.concatenate(firsts),
        np.concatenate(seconds),
        samples,
        np.concatenate(edges) if edges else np.zeros((0, 2), int),
        surface,
    )


def _inertia_about(
    second: np.ndarray, first: np.ndarray, vol, rho: float, c: np.ndarray
) -> np.ndarray:
    """Inertia tensor about point ``c`` from volume moments (uniform density ``rho``)."""
    Sc = second - np.outer(first, c) - np.outer(c, first) + vol * np.outer(c, c)
    return rho * (np.trace(Sc) * np.eye(3) - Sc)


def _body_metrics(model: mujoco.MjModel, body: int, bc: _BodyCells):
    """(point-mass deficit, surface gap ratio) of one body's cells."""
    V = bc.volume.sum()
    rho = 1.0 / V  # unit mass: the ratio does not depend on it
    com = bc.first.sum(0) / V
    I_body = _inertia_about(bc.second.sum(0), bc.first.sum(0), V, rho, com)
    cen = bc.first / bc.volume[:, None]
    own = sum(
        _inertia_about(bc.second[i], bc.first[i], bc.volume[i], rho, cen[i])
        for i in range(len(bc.volume))
    )
    deficit = float(np.linalg.norm(own) / max(np.linalg.norm(I_body), 1e-300))
    from scipy.spatial import cKDTree

    tree = cKDTree(cen)
    pts = np.vstack([p for p, _ in bc.surface])
    d, _ = tree.query(pts)
    radius = float(np.linalg.norm(pts - com, axis=1).max())  # bounding radius about the com
    return deficit, float(d.max()) / radius


def _body_length(model: mujoco.MjModel, geoms: list[int]) -> float:
    return max(_geom_extent(model, g) for g in geoms)


def default_level(
    model: mujoco.MjModel,
    body: int,
    params: PartitionParams = PartitionParams(),
    geoms: list[int] | None = None,
) -> int:
    """Smallest level meeting ``inertia_tol`` and ``contact_tol`` for ``body`` (see module docs).

    Static geometry (the world's geoms, each on its own) only needs ``contact_tol``.
    """
    if geoms is None:
        geoms = _body_geoms(model, body, static=(body == 0))
    if not geoms:
        return 0
    L = _body_length(model, geoms)
    static = body == 0 or int(model.body_weldid[body]) == 0
    for n in range(1, params.max_level + 1):
        bc = _cells_of_body(model, geoms, L / n)
        deficit, gap = _body_metrics(model, body, bc)
        if (static or deficit <= params.inertia_tol + 1e-9) and gap <= params.contact_tol + 1e-9:
            return n
    return params.max_level


def _check_model(model: mujoco.MjModel) -> None:
    for g in range(model.ngeom):
        b = int(model.geom_bodyid[g])
        if b == 0:
            continue
        if int(model.geom_type[g]) == int(_G.mjGEOM_PLANE):
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"#{g}"
            raise PartitionError(
                f"geom '{name}' is a plane on a moving body; planes are only supported on the world body"
            )
        _geom_kind(model, g)


def partition_model(
    model: mujoco.MjModel, params: PartitionParams = PartitionParams()
) -> Partition:
    """Partition every body of ``model`` that has geoms (see the module docstring).

    Element masses use one uniform density per body, ``body_mass / body volume``, so
    the nodes of a body sum exactly to MuJoCo's body mass. Geoms with zero mass
    contribution (``contype = conaffinity = 0`` and ``group`` visual-only) are still
    cells of their body; give such geoms no volume in the MJCF if they are decoration.
    """
    _check_model(model)
    bodies = list(range(1, model.nbody)) + ([0] if params.static_geoms else [])
    cols = {
        k: [] for k in ("body", "geom", "centroid", "volume", "mass", "tau", "inertia", "static")
    }
    edges, reports = [], []
    n0 = 0
    units = []  # (body, geoms): a moving body is one unit, each static world geom its own
    for b in bodies:
        geoms = _body_geoms(model, b, static=(b == 0))
        if not geoms:
            if b != 0 and model.body_mass[b] > 0:
                name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"#{b}"
                raise PartitionError(
                    f"body '{name}' has mass {model.body_mass[b]:g} kg but no geom to cut into elements; give it a geom that has its shape"
                )
            continue
        units += [(b, [g]) for g in geoms] if b == 0 else [(b, geoms)]
    for b, geoms in units:
        if params.level is not None:
            n = int(params.level)
        else:
            n = default_level(model, b, params, geoms) * max(1, int(params.refine))
            if n > MAX_LEVEL:
                name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or f"#{b}"
                raise PartitionError(
                    f"--refine {params.refine} cuts body '{name}' into {n} divisions along its length (up to "
                    f"{n ** 3} elements); the limit is {MAX_LEVEL} divisions: use --refine "
                    f"{max(1, MAX_LEVEL // default_level(model, b, params, geoms))} or less"
                )
        L = _body_length(model, geoms)
        bc = _cells_of_body(model, geoms, L / n)
        k = len(bc.volume)
        V = bc.volume.sum()
        static = b == 0 or int(model.body_weldid[b]) == 0
        mass_b = float(model.body_mass[b])
        rho = mass_b / V
        cen = bc.first / bc.volume[:, None]
        inert = np.stack(
            [_inertia_about(bc.second[i], bc.first[i], bc.volume[i], rho, cen[i]) for i in range(k)]
        )
        tau = np.array(
            [float(np.linalg.norm(s - cen[i], axis=1).max()) for i, s in enumerate(bc.samples)]
        )
        cols["body"].append(np.full(k, b, np.int32))
        cols["geom"].append(bc.geom)
        cols["centroid"].append(cen)
        cols["volume"].append(bc.volume)
        cols["mass"].append(np.zeros(k) if static else rho * bc.volume)
        cols["tau"].append(tau)
        cols["inertia"].append(inert)
        cols["static"].append(np.full(k, static))
        e = _connect(bc.edges, cen, tau, bc.geom)
        edges.append(e + n0)
        n0 += k
        reports.append(_report(model, b, n, bc, rho, cen, geoms))
    arr = {k: np.concatenate(v) if v else np.zeros((0,)) for k, v in cols.items()}
    adj = np.concatenate(edges) if edges else np.zeros((0, 2), int)
    adj = (
        np.unique(np.sort(adj, axis=1), axis=0).astype(np.int32)
        if len(adj)
        else adj.astype(np.int32).reshape(0, 2)
    )
    return Partition(
        body=arr["body"].astype(np.int32),
        geom=arr["geom"].astype(np.int32),
        centroid=arr["centroid"].reshape(-1, 3),
        volume=arr["volume"],
        mass=arr["mass"],
        tau=arr["tau"],
        inertia=arr["inertia"].reshape(-1, 3, 3),
        static=arr["static"].astype(bool),
        adjacency=adj,
        params=params,
        reports=tuple(reports),
    )


def _connect(edges: np.ndarray, cen: np.ndarray, tau: np.ndarray, geom: np.ndarray) -> np.ndarray:
    """Face edges within geoms, plus edges between cells of different geoms of one body.

    Two cells of different geoms are adjacent when their bounding spheres overlap
    (``|c_i - c_j| < tau_i + tau_j``), i.e. the geoms touch or overlap there; if the
    body's graph is still disconnected, the closest pair of each component is joined.
    """
    out = [tuple(e) for e in edges.tolist()]
    if len(np.unique(geom)) > 1:
        d = np.linalg.norm(cen[:, None] - cen[None], axis=-1)
        close = (d < (tau[:, None] + tau[None]) * (1 - 1e-9)) & (geom[:, None] != geom[None])
        i, j = np.nonzero(np.triu(close, 1))
        out += list(zip(i.tolist(), j.tolist(), strict=True))
        # connectivity guard
        while True:
            comp = _components(len(cen), out)
            if comp.max() == 0:
                break
            a = np.flatnonzero(comp == 0)
            b = np.flatnonzero(comp != 0)
            sub = d[np.ix_(a, b)]
            ia, ib = np.unravel_index(np.argmin(sub), sub.shape)
            out.append((int(a[ia]), int(b[ib])))
    return np.array(out, int).reshape(-1, 2)


def _components(n: int, edges) -> np.ndarray:
    parent = list(range(n))

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in edges:
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([root(i) for i in range(n)])
    _, comp = np.unique(roots, return_inverse=True)
    return comp


def _report(
    model: mujoco.MjModel,
    b: int,
    n: int,
    bc: _BodyCells,
    rho: float,
    cen: np.ndarray,
    geoms: list[int],
) -> BodyReport:
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) or ("world" if b == 0 else f"#{b}")
    if b == 0:
        name = "world/" + (
            mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geoms[0]) or f"geom{geoms[0]}"
        )
    deficit, gap = _body_metrics(model, b, bc)
    if b == 0:
        return BodyReport(b, name, n, len(bc.volume), 0.0, 0.0, 0.0, deficit, gap)
    V = bc.volume.sum()
    m = rho * V
    com = bc.first.sum(0) / V
    I = _inertia_about(bc.second.sum(0), bc.first.sum(0), V, rho, com)
    R = _quat_mat(model.body_iquat[b])
    I_mj = R @ np.diag(model.body_inertia[b]) @ R.T
    rad = max(float(np.linalg.norm(s - com, axis=1).max()) for s in bc.samples)
    return BodyReport(
        body=b,
        name=name,
        level=n,
        n_nodes=len(bc.volume),
        mass_error=abs(m - model.body_mass[b]) / max(model.body_mass[b], 1e-300),
        com_error=float(np.linalg.norm(com - model.body_ipos[b])) / rad,
        inertia_error=float(np.linalg.norm(I - I_mj) / max(np.linalg.norm(I_mj), 1e-300)),
        point_mass_deficit=deficit,
        surface_gap=gap,
    )


def _fmt_ratio(x: float) -> str:
    return f"{x:.2e}" if x and (x < 1e-3 or x >= 1e3) else f"{x:.3f}"


def format_report(part: Partition) -> str:
    """A plain-text table of the per-body reports."""
    lines = [
        f"{'body':<18}{'level':>6}{'nodes':>7}{'mass err':>10}{'com err':>10}{'I err':>10}{'pm deficit':>12}{'gap':>7}"
    ]
    for r in part.reports:
        lines.append(
            f"{r.name:<18}{r.level:>6}{r.n_nodes:>7}{_fmt_ratio(r.mass_error):>10}{_fmt_ratio(r.com_error):>10}"
            f"{_fmt_ratio(r.inertia_error):>10}{_fmt_ratio(r.point_mass_deficit):>12}{r.surface_gap:>7.2f}"
        )
    lines.append(f"total nodes {part.n_nodes}, edges {part.adjacency.shape[0]}")
    return "\n".join(lines)

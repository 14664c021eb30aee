"""Graph construction of Section 3.2: object-oriented graph, contact-oriented graph, batching, GCN normalisation.

Nodes are element centroids. Conventions: a batch holds ``B`` graphs of one scene with
``N`` nodes each; batched node ``b * N + i`` is node ``i`` of graph ``b`` (block-diagonal
batching with node offsets ``b * N``). Edge lists are ``[2, E]`` int64 (source, target),
both directions present.

- object-oriented graph (Eq. 4): edge (i, j) iff elements i and j belong to the same
  object and share a face; it is the scene's static ``adjacency``, so its normalised
  adjacency is built once and cached (:class:`ObjectGraph`).
- contact-oriented graph (Eq. 6, Appendix B.1.1): edge (i, j) iff ``|x_i - x_j| < r`` and
  i, j belong to different objects; rebuilt each step by a blockwise ``torch.cdist`` in
  its exact (non-matmul) mode, since PyG's ``radius_graph`` needs pyg-lib.
- radius graph (GNS, :func:`radius_edges`): every ordered pair of nodes of one graph closer
  than ``r``, self-edges included, whatever their objects; same blockwise exact ``cdist``.
- GCN normalisation (Kipf & Welling 2017): ``A_hat = D^-1/2 (A + I) D^-1/2``, as a sparse
  CSR matrix over the batched nodes, or dense ``[N, N]`` for small static graphs.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import torch

# CSR tensors are used deliberately (block-diagonal batches); their beta notice is noise.
warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")

__all__ = [
    "object_edges",
    "contact_edges",
    "radius_edges",
    "batch_edges",
    "gcn_norm",
    "gcn_norm_dense",
    "ObjectGraph",
    "Propagator",
    "SceneGraph",
]


def object_edges(adjacency, num_nodes: int | None = None) -> torch.Tensor:
    """Object-oriented edges from the face adjacency pairs ``[E, 2]`` (i < j) -> ``[2, 2E]`` both directions."""
    a = torch.as_tensor(adjacency, dtype=torch.long).reshape(-1, 2)
    if num_nodes is not None and a.numel() and int(a.max()) >= num_nodes:
        raise ValueError(f"adjacency refers to node {int(a.max())} but the graph has {num_nodes} nodes")
    return torch.cat([a.T, a.T.flip(0)], dim=1)


def contact_edges(pos: torch.Tensor, obj: torch.Tensor, r: float, static: torch.Tensor | None = None,
                  max_block_elems: int = 1 << 24) -> torch.Tensor:
    """Contact-oriented edges (Section 3.2.1): centroids closer than ``r`` on different objects.

    Parameters
    ----------
    pos : [B, N, 3] or [N, 3]
        Centroid positions, m.
    obj : [N] int
        Object id of each node.
    r : float
        Cut-off radius, m (strict ``<``).
    static : [N] bool, optional
        Nodes that never move (world geometry); pairs of two static nodes get no edge.
    max_block_elems : int
        Largest ``B * rows * N`` distance block held at once (memory bound).

    Returns
    -------
    [2, E] int64 edges over the batched node index ``b * N + i``, both directions, sorted
    by source then target.

    Notes
    -----
    ``torch.cdist`` is called with ``compute_mode="donot_use_mm_for_euclid_dist"``: the
    default matmul mode computes ``|x|^2 + |y|^2 - 2 x.y`` and loses the neighbour sets of
    coordinates far from the origin.
    """
    if pos.dim() == 2:
        pos = pos.unsqueeze(0)
    B, N, _ = pos.shape
    obj = obj.to(pos.device)
    rows = max(1, min(N, max_block_elems // max(1, B * N)))
    out = []
    for i0 in range(0, N, rows):
        i1 = min(N, i0 + rows)
        d = torch.cdist(pos[:, i0:i1], pos, compute_mode="donot_use_mm_for_euclid_dist")  # [B, rows, N]
        keep = obj[i0:i1, None] != obj[None, :]
        if static is not None:
            st = static.to(pos.device)
            keep = keep & ~(st[i0:i1, None] & st[None, :])
        m = (d < r) & keep[None]
        b, i, j = m.nonzero(as_tuple=True)
        out.append(torch.stack([b * N + i + i0, b * N + j]))
    return torch.cat(out, dim=1) if out else torch.zeros(2, 0, dtype=torch.long, device=pos.device)


def radius_edges(pos: torch.Tensor, r: float, max_block_elems: int = 1 << 24) -> tuple[torch.Tensor, torch.Tensor]:
    """Radius graph of each graph of a batch: every ordered pair closer than ``r``, self-edges included.

    Parameters
    ----------
    pos : [B, N, 3] node positions, m.  r : cut-off radius, m (strict ``<``).
    max_block_elems : largest ``B * rows * N`` distance block held at once (memory bound).

    Returns
    -------
    ``(senders, receivers)``, each [E] int64 over the batched node index ``b * N + i``.
    Distances by ``torch.cdist`` in its exact mode (see :func:`contact_edges`).
    """
    B, N, _ = pos.shape
    rows = max(1, min(N, max_block_elems // max(1, B * N)))
    snd, rcv = [], []
    for i0 in range(0, N, rows):
        d = torch.cdist(pos[:, i0:i0 + rows], pos, compute_mode="donot_use_mm_for_euclid_dist")  # [B, rows, N]
        b, i, j = (d < r).nonzero(as_tuple=True)
        rcv.append(b * N + i + i0)
        snd.append(b * N + j)
    if not rcv:
        e = torch.zeros(0, dtype=torch.long, device=pos.device)
        return e, e
    return torch.cat(snd), torch.cat(rcv)


def batch_edges(edge_index: torch.Tensor, num_nodes: int, batch_size: int) -> torch.Tensor:
    """Repeat one graph's edges for ``batch_size`` copies with node offsets ``b * num_nodes`` -> ``[2, B E]``."""
    off = torch.arange(batch_size, device=edge_index.device) * num_nodes
    return (edge_index.unsqueeze(1) + off[None, :, None]).reshape(2, -1)


def gcn_norm(edge_index: torch.Tensor, num_nodes: int, dtype=torch.float32, device=None) -> torch.Tensor:
    """Sparse CSR ``D^-1/2 (A + I) D^-1/2`` of a graph with ``num_nodes`` nodes (Kipf & Welling 2017, Eq. 2).

    Duplicate edges are merged (weight 1); self-loops are added once to every node.
    """
    device = edge_index.device if device is None else device
    ei = edge_index.to(device)
    loops = torch.arange(num_nodes, device=device)
    ei = torch.cat([ei[:, ei[0] != ei[1]], torch.stack([loops, loops])], dim=1)
    key = torch.unique(ei[0] * num_nodes + ei[1])  # sorted by (row, col): CSR order
    row, col = key // num_nodes, key % num_nodes
    deg = torch.zeros(num_nodes, dtype=dtype, device=device).index_add_(0, row, torch.ones_like(row, dtype=dtype))
    dis = deg.rsqrt()
    val = dis[row] * dis[col]
    crow = torch.zeros(num_nodes + 1, dtype=torch.long, device=device)
    crow[1:] = torch.cumsum(torch.bincount(row, minlength=num_nodes), 0)
    return torch.sparse_csr_tensor(crow, col, val, (num_nodes, num_nodes), check_invariants=False)


def contact_candidates(obj: torch.Tensor, static: torch.Tensor | None = None) -> torch.Tensor:
    """``[N, N]`` bool: the node pairs a contact edge may join (different objects, not both static)."""
    keep = obj[:, None] != obj[None, :]
    if static is not None:
        st = static.to(obj.device)
        keep = keep & ~(st[:, None] & st[None, :])
    return keep


def dense_contacts(pos: torch.Tensor, obj: torch.Tensor, r: float, static: torch.Tensor | None = None,
                   candidates: torch.Tensor | None = None) -> torch.Tensor:
    """``[B, N, N]`` bool adjacency of the contact edges: the dense form of :func:`contact_edges`
    (the same pairs; for small scenes, where one ``[B, N, N]`` block is cheaper than edge lists).

    candidates : [N, N] bool, :func:`contact_candidates` of ``obj`` and ``static`` if already built
    (:meth:`SceneGraph.contact_candidates` caches it); otherwise built from them.
    """
    if pos.dim() == 2:
        pos = pos.unsqueeze(0)
    d = torch.cdist(pos, pos, compute_mode="donot_use_mm_for_euclid_dist")
    keep = contact_candidates(obj.to(pos.device), static) if candidates is None else candidates
    return (d < r) & keep


def gcn_norm_adjacency(adj: torch.Tensor, dtype=torch.float32) -> torch.Tensor:
    """``D^-1/2 (A + I) D^-1/2`` of bool adjacencies ``adj`` [..., N, N] (self-loops counted once):
    the dense, batched form of :func:`gcn_norm`."""
    a = adj | torch.eye(adj.shape[-1], dtype=torch.bool, device=adj.device)
    a = a.to(dtype)
    dis = a.sum(-1).rsqrt()
    return dis.unsqueeze(-1) * a * dis.unsqueeze(-2)


def gcn_norm_dense(edge_index: torch.Tensor, num_nodes: int, dtype=torch.float32, device=None) -> torch.Tensor:
    """Dense ``[N, N]`` form of :func:`gcn_norm` (for small graphs shared by a whole batch)."""
    return gcn_norm(edge_index, num_nodes, dtype, device).to_dense()


@dataclass
class Propagator:
    """``A_hat @ H`` for ``H`` of shape ``[B, N, F]``.

    Either ``dense`` ``[N, N]`` shared by every graph of the batch (one GEMM) or ``[B, N, N]``
    one per graph (a batched GEMM), or ``csr``
    ``[B N, B N]`` block-diagonal over the batch.
    """

    dense: torch.Tensor | None = None
    csr: torch.Tensor | None = None

    def __call__(self, h: torch.Tensor) -> torch.Tensor:
        if self.dense is not None:
            return torch.matmul(self.dense, h)
        B, N, F = h.shape
        return torch.sparse.mm(self.csr, h.reshape(B * N, F)).reshape(B, N, F)


@dataclass
class ObjectGraph:
    """The scene's static object-oriented graph with cached normalisations.

    Parameters
    ----------
    edge_index : [2, E] both directions; num_nodes : N.
    dense_max_nodes : graphs up to this size propagate with a dense ``[N, N]`` matrix
        (a single batched GEMM, several times faster than sparse ops for small N here);
        larger ones with a block-diagonal CSR matrix cached per (batch size, device, dtype).
    """

    edge_index: torch.Tensor
    num_nodes: int
    dense_max_nodes: int = 256
    _cache: dict = field(default_factory=dict, repr=False)

    def adjacency(self, device) -> torch.Tensor:
        """``[N, N]`` bool adjacency of the object graph (cached per device)."""
        key = ("adjacency", str(device))
        a = self._cache.get(key)
        if a is None:
            a = torch.zeros(self.num_nodes, self.num_nodes, dtype=torch.bool, device=device)
            ei = self.edge_index.to(device)
            a[ei[0], ei[1]] = True
            self._cache[key] = a
        return a

    def propagator(self, batch_size: int, device, dtype=torch.float32) -> Propagator:
        dense = self.num_nodes <= self.dense_max_nodes
        key = (dense, batch_size if not dense else 0, str(device), dtype)
        p = self._cache.get(key)
        if p is None:
            if dense:
                p = Propagator(dense=gcn_norm_dense(self.edge_index, self.num_nodes, dtype, device))
            else:
                ei = batch_edges(self.edge_index.to(device), self.num_nodes, batch_size)
                p = Propagator(csr=gcn_norm(ei, self.num_nodes * batch_size, dtype, device))
            self._cache[key] = p
        return p

    def union(self, contact: torch.Tensor, batch_size: int, device, dtype=torch.float32) -> Propagator:
        """Propagator of the union of the (batched) object graph and contact edges ``[2, E_c]`` (Eq. 5)."""
        ei = batch_edges(self.edge_index.to(device), self.num_nodes, batch_size)
        return Propagator(csr=gcn_norm(torch.cat([ei, contact.to(device)], 1), self.num_nodes * batch_size, dtype, device))


@dataclass
class SceneGraph:
    """Static description of one scene's graph (what does not change along a trajectory).

    Attributes
    ----------
    obj : [N] int64, object (rigid body) of each node, re-indexed to ``0..S-1``.
    n_obj : S.
    static : [N] bool, node never moves (world geometry, bodies welded to the world).
    mass : [N] element mass, kg.  volume : [N] m^3.  tau : [N] element radius, m.
    ref_shape : [N, 3] element centroid in its body's frame (reference shape of B.1.3), m.
    obj_type : [N, 3] one-hot object type: static, root of a free-floating system, other moving.
    object_graph : the object-oriented graph (face adjacency) with cached normalisation.
    has_contact : whether the scene can have contacts (no contact branch otherwise).
    contact_radius : r of Section 3.2.1, m.
    """

    obj: torch.Tensor
    n_obj: int
    static: torch.Tensor
    mass: torch.Tensor
    volume: torch.Tensor
    tau: torch.Tensor
    ref_shape: torch.Tensor
    obj_type: torch.Tensor
    object_graph: ObjectGraph
    has_contact: bool
    contact_radius: float
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def num_nodes(self) -> int:
        return int(self.obj.shape[0])

    def properties(self) -> torch.Tensor:
        """Static node properties ``k_i`` = [mass, volume, tau, object type (3)] -> [N, 6] (built once)."""
        k = self._cache.get("properties")
        if k is None:
            k = torch.cat([self.mass[:, None], self.volume[:, None], self.tau[:, None], self.obj_type], dim=1)
            self._cache["properties"] = k
        return k

    def moving(self, device) -> torch.Tensor:
        """``[N]`` bool, the nodes that move (``~static``), on ``device`` (cached)."""
        key = ("moving", str(device))
        if key not in self._cache:
            self._cache[key] = ~self.static.to(device)
        return self._cache[key]

    def contact_candidates(self, device) -> torch.Tensor:
        """``[N, N]`` bool :func:`contact_candidates` of the scene on ``device`` (cached)."""
        key = ("contact_candidates", str(device))
        if key not in self._cache:
            self._cache[key] = contact_candidates(self.obj.to(device), self.static.to(device))
        return self._cache[key]

    def to(self, device) -> SceneGraph:
        kw = {k: (v.to(device) if isinstance(v, torch.Tensor) else v) for k, v in self.__dict__.items() if k != "_cache"}
        return SceneGraph(**kw)

    @classmethod
    def from_static(cls, static: dict, has_contact: bool, contact_radius: float | None = None,
                    dense_max_nodes: int = 256) -> SceneGraph:
        """Build from a dataset's ``/static`` arrays (:data:`mdgs.data.schema.STATIC_ARRAYS`).

        ``contact_radius`` defaults to twice the largest element radius ``tau`` (see
        docs/ambiguities.md: the paper's r = 0.001 is in its own, unstated units).
        """
        import numpy as np

        node_body = np.asarray(static["node_body"])
        _, obj = np.unique(node_body, return_inverse=True)
        body_id = np.asarray(static["body_id"])
        free = {int(b) for b, f in zip(body_id, np.asarray(static["body_free"]), strict=True) if f}
        st = np.asarray(static["node_static"], bool)
        typ = np.zeros((len(node_body), 3))
        typ[st, 0] = 1
        is_free = np.array([int(b) in free for b in node_body]) & ~st
        typ[is_free, 1] = 1
        typ[~st & ~is_free, 2] = 1
        tau = np.asarray(static["node_tau"], float)
        n = len(node_body)
        f32 = torch.float32
        return cls(
            obj=torch.as_tensor(obj, dtype=torch.long),
            n_obj=int(obj.max()) + 1 if n else 0,
            static=torch.as_tensor(st),
            mass=torch.as_tensor(static["node_mass"], dtype=f32),
            volume=torch.as_tensor(static["node_volume"], dtype=f32),
            tau=torch.as_tensor(tau, dtype=f32),
            ref_shape=torch.as_tensor(static["node_centroid"], dtype=torch.float64),
            obj_type=torch.as_tensor(typ, dtype=f32),
            object_graph=ObjectGraph(object_edges(static["adjacency"], n), n, dense_max_nodes),
            has_contact=bool(has_contact),
            contact_radius=float(contact_radius if contact_radius is not None else 2.0 * tau.max()),
        )

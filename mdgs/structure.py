"""Structural constraint module (Appendix B.1.3): re-align each rigid object's predicted nodes to its reference shape.

Batched Kabsch (Kabsch 1976; Umeyama 1991 for the reflection correction) over segments:
for every graph ``b`` and object ``s`` with nodes ``i in s``,

    R*, t* = argmin_{R in SO(3), t} sum_i | R p_i + t - q_i |^2

where ``p_i`` are the reference positions (the object's shape, any frame) and ``q_i``
the predicted positions; the aligned output is ``R* p_i + t*``. Shapes follow the
``[B, N, 3]`` convention with one segment-id vector ``[N]`` shared by the batch.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np
import torch

__all__ = ["kabsch", "align_to_reference", "align_with_pose", "segment_mean", "fixes_rotation", "det3", "solve3",
           "rotation_fit", "ROTATION_FITS"]


def fixes_rotation(ref: np.ndarray) -> bool:
    """Whether element centroids ``ref`` [k, 3] fix a rotation (:func:`kabsch` is unique): at least 3,
    not all on a line (second singular value of the centred points above 1e-6 of the first)."""
    if len(ref) < 3:
        return False
    s = np.linalg.svd(ref - ref.mean(0), compute_uv=False)
    return bool(s[0] > 0 and s[1] > 1e-6 * s[0])


def det3(A: torch.Tensor) -> torch.Tensor:
    """Determinant of 3x3 matrices ``A`` [..., 3, 3] -> [...] as the triple product of the rows,
    ``a_0 . (a_1 x a_2)``: elementwise arithmetic, so ``torch.compile`` fuses it (``torch.linalg.det``
    is an LU factorisation and a cascade of small kernels per call)."""
    return (A[..., 0, :] * torch.linalg.cross(A[..., 1, :], A[..., 2, :], dim=-1)).sum(-1)


def solve3(A: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``A^-1 b`` for symmetric positive-definite 3x3 ``A`` [..., 3, 3] and ``b`` [..., 3] -> [..., 3].

    The ``L D L^T`` factorisation written out elementwise (Golub & Van Loan, Alg. 4.1.2), so
    ``torch.compile`` fuses it where ``torch.linalg.solve`` is an LU call and a cascade of small
    kernels. Like Cholesky it is backward stable for SPD matrices without pivoting, and it keeps the
    well-determined directions of a nearly singular ``A`` (a rod's regularised inertia, condition
    ~1e12) accurate where the adjugate formula loses them to cancellation; it agrees with
    ``torch.linalg.solve`` to ``cond(A) * 1e-14`` (tests/test_rigid.py). Only the lower triangle of
    ``A`` is read; a singular ``A`` gives inf/NaN, not an error.
    """
    a11, a21, a22 = A[..., 0, 0], A[..., 1, 0], A[..., 1, 1]
    a31, a32, a33 = A[..., 2, 0], A[..., 2, 1], A[..., 2, 2]
    l21, l31 = a21 / a11, a31 / a11
    d2 = a22 - l21 * a21
    l32 = (a32 - l31 * a21) / d2
    d3 = a33 - l31 * a31 - l32 * l32 * d2
    y1 = b[..., 0]
    y2 = b[..., 1] - l21 * y1
    y3 = b[..., 2] - l31 * y1 - l32 * y2
    x3 = y3 / d3
    x2 = y2 / d2 - l32 * x3
    x1 = y1 / a11 - l21 * x2 - l31 * x3
    return torch.stack([x1, x2, x3], -1)


def segment_sum(a: torch.Tensor, seg: torch.Tensor, n_seg: int, dim: int = 1) -> torch.Tensor:
    """Sum of ``a`` over the nodes of each segment ``seg`` [N] along ``dim`` (of size N) -> ``a``'s shape
    with ``n_seg`` at ``dim`` (``index_add``).

    One segment is a plain sum: inductor's CPU code for an ``index_add`` whose indices are all 0 fails
    to compile on more than one thread (pytorch/pytorch#160391; a scene of one body, or one joint of a
    kind, would not compile there), and a sum is the cheaper kernel anyway.
    """
    if n_seg == 1:
        return a.sum(dim, keepdim=True)
    shape = list(a.shape)
    shape[dim] = n_seg
    return a.new_zeros(shape).index_add(dim, seg, a)


def segment_mean(x: torch.Tensor, seg: torch.Tensor, n_seg: int, weight: torch.Tensor | None = None) -> torch.Tensor:
    """Weighted mean of ``x`` [B, N, D] over the nodes of each segment ``seg`` [N] -> [B, S, D].

    ``weight`` [N] (default 1). Empty segments give 0.
    """
    w = torch.ones(seg.shape[0], dtype=x.dtype, device=x.device) if weight is None else weight.to(x.dtype)
    num = segment_sum(x if weight is None else x * w[None, :, None], seg, n_seg)
    den = segment_sum(w, seg, n_seg, dim=0).clamp_min(torch.finfo(x.dtype).tiny)
    return num / den[None, :, None]


def kabsch(ref: torch.Tensor, pred: torch.Tensor, seg: torch.Tensor, n_seg: int | None = None,
           weight: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Optimal proper rotation and translation per (graph, segment) taking ``ref`` onto ``pred``.

    Parameters
    ----------
    ref : [N, 3] or [B, N, 3]
        Reference shape (positions in any frame), m.
    pred : [B, N, 3]
        Predicted positions, m.
    seg : [N] int64
        Segment (rigid object) id of each node, in ``[0, n_seg)``.
    weight : [N], optional
        Node weights (e.g. element masses); default uniform.

    Returns
    -------
    R : [B, S, 3, 3] rotations with det = +1; t : [B, S, 3] translations, so that
    ``pred_i ~ R[seg_i] @ ref_i + t[seg_i]``.

    Notes
    -----
    Computed in float64. The SVD of the cross-covariance ``H = sum_i w_i p~_i q~_i^T = U S V^T``
    gives ``R = V diag(1, 1, d) U^T`` with ``d = sign(det(V U^T))`` (reflection correction).
    Segments with fewer than three non-collinear nodes have a non-unique rotation; the
    aligned positions are still exact for them. Inside :func:`rotation_fit` the same optimum comes
    from Horn's quaternion (:func:`rotation_horn`, matrix products: ``torch.linalg.svd`` reads its
    error flag on the host, which stops a step from being captured as a CUDA graph) or from Jacobi
    rotations (:func:`rotation_jacobi`, elementwise arithmetic that a compiler fuses into one kernel,
    where the SVD of a compiled step is a library call with copies around it). Eagerly the SVD, one
    library call, is the cheaper: either of the others is hundreds of small operations, each launched
    on its own unless the step is compiled.
    """
    n_seg = int(seg.max()) + 1 if n_seg is None else n_seg
    B = pred.shape[0]
    p = (ref if ref.dim() == 3 else ref.unsqueeze(0)).to(torch.float64).expand(B, -1, -1)
    q = pred.to(torch.float64)
    cp = segment_mean(p, seg, n_seg, weight)  # [B, S, 3]
    cq = segment_mean(q, seg, n_seg, weight)
    pc = p - cp[:, seg]
    qc = q - cq[:, seg]
    if weight is None:
        outer = pc.unsqueeze(-1) * qc.unsqueeze(-2)  # [B, N, 3, 3]
    else:
        outer = weight.to(torch.float64)[None, :, None, None] * pc.unsqueeze(-1) * qc.unsqueeze(-2)
    H = segment_sum(outer, seg, n_seg)
    # a diverged prediction (NaN/Inf) gets a NaN placement instead of an SVD error, so a rollout
    # marks the trajectory as diverged rather than aborting the whole batch
    # (branch-free: no host sync, one graph under torch.compile)
    bad = ~torch.isfinite(H).flatten(-2).all(-1)  # [B, S]
    H = torch.where(bad[..., None, None], torch.eye(3, dtype=H.dtype, device=H.device), H)
    fit = _FIT
    if not torch.compiler.is_dynamo_compiling():  # dynamo would guard on the count, and trace anew each step
        fit.calls += 1
    R = rotation_horn(H) if fit.name == "horn" else rotation_jacobi(H) if fit.name == "jacobi" else _rotation_svd(H)
    t = cq - (R @ cp.unsqueeze(-1)).squeeze(-1)
    R = torch.where(bad[..., None, None], torch.nan, R)
    t = torch.where(bad[..., None], torch.nan, t)
    return R, t


def _rotation_svd(H: torch.Tensor) -> torch.Tensor:
    """The proper rotation ``R`` [..., 3, 3] maximising ``tr(R H)`` (Kabsch: ``H = U S V^T``,
    ``R = V diag(1, 1, det(V U^T)) U^T``) for cross-covariances ``H`` [..., 3, 3]."""
    U, _, Vh = torch.linalg.svd(H)
    V = Vh.transpose(-1, -2)
    d = torch.sign(det3(V) * det3(U))  # det(V U^T)
    d = torch.where(d == 0, torch.ones_like(d), d)
    D = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], -1))
    return V @ D @ U.transpose(-1, -2)


#: The fits :func:`rotation_fit` can choose for :func:`kabsch`.
ROTATION_FITS = ("svd", "horn", "jacobi")


@dataclass
class RotationFit:
    """The fit :func:`kabsch` uses (``name``, one of :data:`ROTATION_FITS`) and how many fits it made with it
    (``calls``: each call, or each call site while a step is exported; not counted while dynamo traces)."""

    name: str
    calls: int = 0


_FIT = RotationFit("svd")  # set by rotation_fit(); read by kabsch (a traced step bakes in its name)


@contextlib.contextmanager
def rotation_fit(name: str):
    """Within this block :func:`kabsch` fits rotations by ``name``: "svd" (the default), "horn"
    (:func:`rotation_horn`, matrix products only: what a step captured as a CUDA graph must use) or
    "jacobi" (:func:`rotation_jacobi`, elementwise only: one fused kernel in a compiled step). Yields the
    block's :class:`RotationFit`, whose ``calls`` count the fits made inside it."""
    global _FIT
    if name not in ROTATION_FITS:
        raise ValueError(f"rotation fit {name!r} is not one of {', '.join(ROTATION_FITS)}")
    before, _FIT = _FIT, RotationFit(name)
    try:
        yield _FIT
    finally:
        _FIT = before


#: Squarings of Horn's shifted 4x4 matrix: the top eigenvector's error shrinks as
#: ``(lambda_2 / lambda_1) ** (2 ** k)``, so 40 resolve eigenvalue gaps down to ~1e-11 relative
#: (a body thinner than that has a non-unique rotation anyway).
HORN_SQUARINGS = 40


def rotation_horn(H: torch.Tensor, squarings: int = HORN_SQUARINGS) -> torch.Tensor:
    """The proper rotation ``R`` [..., 3, 3] maximising ``tr(R H)`` for cross-covariances ``H``
    [..., 3, 3] (``H = sum_i w_i p~_i q~_i^T``, reference ``p`` onto prediction ``q``), by Horn's
    quaternion method (Horn 1987, J. Opt. Soc. Am. A 4(4), Eq. 41-44): the unit quaternion of ``R``
    is the top eigenvector of the symmetric 4x4 ``N(H)``, whose eigenvalues lie in
    ``[-c, c]`` with ``c = sqrt(3) |H|_F``. ``N + c I`` is positive semi-definite, and repeated
    squaring (each normalised by its trace) turns it into the projector onto that eigenvector; its
    largest column, normalised, is the quaternion. Only matrix products and elementwise arithmetic:
    no host synchronisation, so a step using it can be captured as a CUDA graph. The same optimum
    as the SVD's reflection-corrected Kabsch where that is unique (tests/test_structure.py); where
    it is not (collinear nodes, fewer than three nodes), another rotation of the same fit."""
    N = torch.stack([torch.stack(row, -1) for row in _horn_matrix(H)], -2)  # [..., 4, 4]
    c = (3.0 ** 0.5) * H.flatten(-2).norm(dim=-1).clamp_min(torch.finfo(H.dtype).tiny)
    eye = torch.eye(4, dtype=H.dtype, device=H.device)
    M = (N + c[..., None, None] * eye) / (4.0 * c[..., None, None])  # PSD, eigenvalues in [0, 1/2]
    for _ in range(squarings):
        M = M @ M
        M = M / (M.diagonal(dim1=-2, dim2=-1).sum(-1)[..., None, None]
                 .clamp_min(torch.finfo(H.dtype).tiny))
    col = M.norm(dim=-2).argmax(-1)  # [...]: the column of the projector with the most weight
    q = torch.take_along_dim(M, col[..., None, None].expand(*M.shape[:-1], 1), dim=-1)[..., 0]
    return _quaternion_rotation(*(q / q.norm(dim=-1, keepdim=True).clamp_min(torch.finfo(H.dtype).tiny)).unbind(-1))


def _horn_matrix(H: torch.Tensor) -> list[list[torch.Tensor]]:
    """The entries ``[4][4]`` (each ``[...]``) of Horn's symmetric ``N(H)`` (Horn 1987, Eq. 43) of
    cross-covariances ``H`` [..., 3, 3]: its top eigenvector is the unit quaternion of the rotation
    maximising ``tr(R H)``."""
    Sxx, Sxy, Sxz = H[..., 0, 0], H[..., 0, 1], H[..., 0, 2]
    Syx, Syy, Syz = H[..., 1, 0], H[..., 1, 1], H[..., 1, 2]
    Szx, Szy, Szz = H[..., 2, 0], H[..., 2, 1], H[..., 2, 2]
    return [[Sxx + Syy + Szz, Syz - Szy, Szx - Sxz, Sxy - Syx],
            [Syz - Szy, Sxx - Syy - Szz, Sxy + Syx, Szx + Sxz],
            [Szx - Sxz, Sxy + Syx, -Sxx + Syy - Szz, Syz + Szy],
            [Sxy - Syx, Szx + Sxz, Syz + Szy, -Sxx - Syy + Szz]]


def _quaternion_rotation(w: torch.Tensor, x: torch.Tensor, y: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """The rotation matrix [..., 3, 3] (applied as ``R @ p``) of the unit quaternions ``(w, x, y, z)``, each [...]."""
    return torch.stack([
        torch.stack([w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        torch.stack([2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)], -1),
        torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z], -1),
    ], -2)


#: Cyclic Jacobi sweeps of :func:`rotation_jacobi`: the off-diagonal part of Horn's 4x4 matrix
#: falls quadratically, to 1e-18 of its norm (squared) after 4 sweeps and below float64's range
#: after 5 on 20 000 random cross-covariances; with 4 the rotations of tests/test_structure.py match
#: the SVD's to 1e-12 (with 3 they are 2e-5 off), so 5 leave a sweep to spare.
JACOBI_SWEEPS = 5
_JACOBI_PAIRS = ((0, 1), (2, 3), (0, 2), (1, 3), (0, 3), (1, 2))


def rotation_jacobi(H: torch.Tensor, sweeps: int = JACOBI_SWEEPS) -> torch.Tensor:
    """The proper rotation ``R`` [..., 3, 3] maximising ``tr(R H)`` for cross-covariances ``H``
    [..., 3, 3], as :func:`rotation_horn`: the top eigenvector of Horn's symmetric 4x4 ``N(H)``,
    here by cyclic Jacobi rotations (Golub & Van Loan, Matrix Computations, 4th ed., Alg. 8.5.3,
    with the stable tangent of Alg. 8.5.1) written out entry by entry. Only elementwise arithmetic on
    ``[...]``-shaped tensors, with no branch and no reduction until the final choice of column, so a
    compiler fuses the whole fit into one loop: what a compiled step uses instead of the SVD
    (:func:`kabsch`). The same optimum as the SVD's reflection-corrected Kabsch where that is unique
    (tests/test_structure.py); where it is not, another rotation of the same fit."""
    A = [list(row) for row in _horn_matrix(H)]
    one, zero = torch.ones_like(A[0][0]), torch.zeros_like(A[0][0])
    tiny = torch.finfo(H.dtype).tiny
    V = [[one if i == j else zero for j in range(4)] for i in range(4)]  # the eigenvectors, by column
    for _ in range(sweeps):
        for p, q in _JACOBI_PAIRS:
            apq = A[p][q]
            # an exact zero (already diagonal in p, q) rotates by a negligible angle, or by any angle where
            # a_pp = a_qq, which keeps the block diagonal
            theta = (A[q][q] - A[p][p]) / (2 * torch.where(apq == 0, tiny, apq))
            # the smaller root of t^2 + 2 theta t - 1 = 0 (|t| <= 1); theta^2 overflowing gives t = 0
            t = torch.copysign(one, theta) / (theta.abs() + torch.sqrt(theta * theta + 1))
            c = torch.rsqrt(t * t + 1)
            s = t * c
            for k in range(4):
                if k != p and k != q:
                    akp, akq = A[k][p], A[k][q]
                    A[k][p] = A[p][k] = c * akp - s * akq
                    A[k][q] = A[q][k] = s * akp + c * akq
            A[p][p] = A[p][p] - t * apq
            A[q][q] = A[q][q] + t * apq
            A[p][q] = A[q][p] = zero
            for k in range(4):
                vkp, vkq = V[k][p], V[k][q]
                V[k][p] = c * vkp - s * vkq
                V[k][q] = s * vkp + c * vkq
    # the column of the largest eigenvalue (the first of equal ones), chosen entry by entry: a gather
    # of stacked columns would make the compiler evaluate the sweeps once per entry it reads
    lam = [A[i][i] for i in range(4)]
    q = [zero] * 4
    taken = torch.zeros_like(one, dtype=torch.bool)
    for j in range(4):
        pick = ~taken
        for i in range(4):
            if i != j:
                pick = pick & (lam[j] >= lam[i])
        taken = taken | pick
        q = [torch.where(pick, V[k][j], q[k]) for k in range(4)]
    norm = torch.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).clamp_min(torch.finfo(H.dtype).tiny)
    return _quaternion_rotation(*(qk / norm for qk in q))


def align_to_reference(pred: torch.Tensor, ref: torch.Tensor, seg: torch.Tensor, n_seg: int | None = None,
                       weight: torch.Tensor | None = None, mask: torch.Tensor | None = None,
                       straight_through: bool = True) -> torch.Tensor:
    """Replace each object's predicted nodes by its reference shape, optimally placed (B.1.3).

    Parameters
    ----------
    pred : [B, N, 3] predicted positions; ref : [N, 3] or [B, N, 3] reference shape;
    seg : [N] object ids; mask : [N] bool, nodes to align (others are returned unchanged,
    e.g. static world elements).
    straight_through : bool
        If True (default) the alignment is applied as ``pred + (aligned - pred).detach()``:
        the forward value is exactly the aligned shape, the gradient is the identity. The SVD's
        own gradient is unbounded for symmetric shapes (a cube of cells has three equal
        singular values), so it is not back-propagated.

    Returns
    -------
    [B, N, 3] aligned positions, dtype of ``pred``.
    """
    return align_with_pose(pred, ref, seg, n_seg, weight, mask, straight_through)[0]


def align_with_pose(pred: torch.Tensor, ref: torch.Tensor, seg: torch.Tensor, n_seg: int | None = None,
                    weight: torch.Tensor | None = None, mask: torch.Tensor | None = None,
                    straight_through: bool = True) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`align_to_reference` and the placement it used: ``(aligned [B, N, 3], R [B, S, 3, 3], t [B, S, 3])``
    (float64; every segment's Kabsch fit of ``pred``, masked or not), so that a later step needing the
    objects' poses (the joint projection) does not fit them again."""
    with torch.set_grad_enabled(not straight_through and torch.is_grad_enabled()):
        R, t = kabsch(ref, pred.detach() if straight_through else pred, seg, n_seg, weight)
        p = (ref if ref.dim() == 3 else ref.unsqueeze(0)).to(torch.float64)
        aligned = (R[:, seg] @ p.unsqueeze(-1)).squeeze(-1) + t[:, seg]
        aligned = aligned.to(pred.dtype)
    if mask is not None:
        aligned = torch.where(mask[None, :, None], aligned, pred.detach() if straight_through else pred)
    return (pred + (aligned - pred).detach() if straight_through else aligned), R, t

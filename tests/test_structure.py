"""Structural constraint module (Appendix B.1.3): batched Kabsch with the reflection correction.

Reference: Kabsch (1976), Acta Cryst. A32, 922; reflection correction as in Umeyama (1991).
"""

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from mdgs.structure import (
    _rotation_svd,
    align_to_reference,
    kabsch,
    rotation_fit,
    rotation_horn,
    rotation_jacobi,
)


def _rotation(q):
    q = np.asarray(q, float)
    q = q / np.linalg.norm(q)
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


quats = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1)
vecs = st.lists(st.floats(-10, 10), min_size=3, max_size=3)


@given(q=quats, t=vecs, seed=st.integers(0, 2**16), n=st.integers(4, 12))
def test_kabsch_recovers_exact_rigid_transform(q, t, seed, n):
    rng = np.random.default_rng(seed)
    ref = rng.normal(size=(n, 3))
    R = _rotation(q)
    pred = ref @ R.T + np.asarray(t)
    seg = torch.zeros(n, dtype=torch.long)
    Rk, tk = kabsch(torch.tensor(ref), torch.tensor(pred)[None], seg, 1)
    np.testing.assert_allclose(Rk[0, 0].numpy(), R, atol=1e-9)
    np.testing.assert_allclose(tk[0, 0].numpy(), t, atol=1e-9)
    out = align_to_reference(torch.tensor(pred)[None], torch.tensor(ref), seg, 1)
    np.testing.assert_allclose(out[0].numpy(), pred, atol=1e-9)


@given(q=quats, seed=st.integers(0, 2**16))
def test_kabsch_is_invariant_to_node_order(q, seed):
    rng = np.random.default_rng(seed)
    n = 10
    ref = rng.normal(size=(n, 3))
    seg = torch.tensor([0] * 4 + [1] * 6)
    pred = ref @ _rotation(q).T + rng.normal(scale=0.05, size=(n, 3))  # deformed
    perm = rng.permutation(n)
    a = align_to_reference(torch.tensor(pred)[None], torch.tensor(ref), seg, 2)[0].numpy()
    b = align_to_reference(torch.tensor(pred[perm])[None], torch.tensor(ref[perm]), seg[perm], 2)[
        0
    ].numpy()
    np.testing.assert_allclose(b, a[perm], atol=1e-10)


def test_reflection_is_corrected():
    """A mirrored point set is matched by a proper rotation (det +1), never by the reflection."""
    rng = np.random.default_rng(0)
    ref = rng.normal(size=(8, 3))
    pred = ref * np.array([1.0, 1.0, -1.0])  # reflection through z = 0
    R, _ = kabsch(torch.tensor(ref), torch.tensor(pred)[None], torch.zeros(8, dtype=torch.long), 1)
    assert abs(torch.linalg.det(R[0, 0]).item() - 1.0) < 1e-12


def test_alignment_restores_shape_and_batches_segments():
    rng = np.random.default_rng(1)
    ref = rng.normal(size=(6, 3))
    seg = torch.tensor([0, 0, 0, 1, 1, 1])
    B = 5
    pred = np.stack(
        [
            np.concatenate(
                [
                    ref[:3] @ _rotation(rng.normal(size=4)).T + rng.normal(size=3),
                    ref[3:] @ _rotation(rng.normal(size=4)).T + rng.normal(size=3),
                ]
            )
            for _ in range(B)
        ]
    )
    noisy = pred + rng.normal(scale=1e-2, size=pred.shape)
    out = align_to_reference(torch.tensor(noisy), torch.tensor(ref), seg, 2).numpy()
    for b in range(B):
        for s in (
            slice(0, 3),
            slice(3, 6),
        ):  # pairwise distances of each object are restored exactly
            d_out = np.linalg.norm(out[b, s, None] - out[b, None, s], axis=-1)
            d_ref = np.linalg.norm(ref[s, None] - ref[None, s], axis=-1)
            np.testing.assert_allclose(d_out, d_ref, atol=1e-12)
    assert np.abs(out - pred).max() < 0.05


def test_mask_and_straight_through_gradient():
    ref = torch.randn(5, 3, dtype=torch.float64)
    pred = (ref + 0.1 * torch.randn(5, 3, dtype=torch.float64))[None].requires_grad_(True)
    mask = torch.tensor([True, True, True, True, False])
    out = align_to_reference(pred, ref, torch.zeros(5, dtype=torch.long), 1, mask=mask)
    assert torch.equal(out[0, 4], pred[0, 4])
    out.sum().backward()
    assert torch.allclose(pred.grad, torch.ones_like(pred))


def test_kabsch_of_a_diverged_prediction_is_nan_not_an_error():
    """A NaN in one graph's prediction gives NaN for that graph only (the rollout flags it as diverged)."""
    ref = torch.randn(5, 3, dtype=torch.float64)
    seg = torch.zeros(5, dtype=torch.long)
    pred = torch.stack([ref, ref.clone()])
    pred[1, 2, 0] = float("nan")
    R, t = kabsch(ref, pred, seg, 1)
    assert torch.isnan(R[1]).all() and torch.isnan(t[1]).all()
    assert torch.allclose(R[0], torch.eye(3, dtype=torch.float64), atol=1e-10) and torch.allclose(t[0], torch.zeros(3, dtype=torch.float64), atol=1e-10)


def test_one_segment_sums_compile_on_two_threads_and_match_index_add():
    """A scene of one body (or one joint of a kind) sums over a single segment: inductor's CPU code for
    an index_add whose indices are all 0 fails on more than one thread (pytorch/pytorch#160391; MDGS
    on the user scene at refine 2 did not compile), so segment_sum takes a plain sum there. Compiled on
    two threads, twist and Kabsch of one 36-node body equal the eager index_add result to float64
    round-off (1e-12 m: sums of 36 terms of order 1 in another order)."""
    from mdgs.rigid import twist
    from mdgs.structure import segment_sum

    g = torch.Generator().manual_seed(0)
    x, v, ref = torch.randn(2, 36, 3, generator=g), torch.randn(2, 36, 3, generator=g), torch.randn(36, 3, generator=g)
    m, seg = torch.rand(36, generator=g) + 0.1, torch.zeros(36, dtype=torch.long)
    a = torch.randn(2, 36, 3, 3, generator=g, dtype=torch.float64)
    assert torch.allclose(segment_sum(a, seg, 1), a.new_zeros(2, 1, 3, 3).index_add(1, seg, a), rtol=0, atol=1e-12)

    def f(x, v):
        tw = twist(x, v, seg, 1, m)
        R, t = kabsch(ref, x, seg, 1, m)
        return tw.c, tw.vc, tw.omega, R, t

    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        got = torch.compile(f, dynamic=False, fullgraph=True)(x, v)
    finally:
        torch.set_num_threads(threads)
    for a, b in zip(got, f(x, v), strict=True):
        assert torch.allclose(a, b, rtol=0, atol=1e-12)


def _fit(R, P, Q):
    """Sum of squared residuals ``|R p_i - q_i|^2`` [B] of rotations R [B, 3, 3] on centred P [N, 3], Q [B, N, 3]."""
    return ((torch.einsum("bij,nj->bni", R, P) - Q) ** 2).sum((1, 2))


@pytest.mark.parametrize("fit", [rotation_horn, rotation_jacobi], ids=["horn", "jacobi"])
def test_quaternion_rotations_are_the_reflection_corrected_kabsch_optimum(fit):
    """:func:`rotation_horn` (matrix products only: what a CUDA graph can capture) and
    :func:`rotation_jacobi` (elementwise only: what a compiled step fuses) give the SVD's rotation to
    1e-12 where the optimum is unique: random shapes, a cube of cells (three equal singular values), a
    flat plate, noisy and mirrored predictions, rotations by nearly 180 degrees; a proper rotation
    (det +1, orthonormal to 1e-12) every time; and where the optimum is not unique (collinear nodes,
    one node, no spread at all) a finite rotation whose fit is as good as the SVD's."""
    rng = np.random.default_rng(0)
    cube = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    flat = np.c_[rng.normal(size=(9, 2)), np.zeros(9)]
    shapes = {"random": rng.normal(size=(10, 3)), "cube": cube, "flat": flat,
              "mirrored": rng.normal(size=(10, 3)), "half turns": rng.normal(size=(10, 3))}
    for name, P in shapes.items():
        P = torch.tensor(P - P.mean(0))
        quats = rng.normal(size=(64, 4))
        if name == "half turns":  # w near 0: the quaternion's scalar part, where a fit may pick the sign badly
            quats[:, 0] = 1e-6 * rng.normal(size=64)
        Rt = torch.tensor(np.stack([_rotation(q) for q in quats]))
        Q = torch.einsum("bij,nj->bni", Rt, P) + 1e-3 * torch.tensor(rng.normal(size=(64, len(P), 3)))
        if name == "mirrored":  # through a plane: no proper rotation fits, det(H) < 0
            Q = Q * torch.tensor([1.0, 1.0, -1.0], dtype=torch.float64)
        Q = Q - Q.mean(1, keepdim=True)
        H = torch.einsum("ni,bnj->bij", P, Q)
        Rh, Rs = fit(H), _rotation_svd(H)
        np.testing.assert_allclose(Rh.numpy(), Rs.numpy(), atol=1e-12, err_msg=name)
        np.testing.assert_allclose(torch.linalg.det(Rh).numpy(), 1.0, atol=1e-12)
        np.testing.assert_allclose((Rh @ Rh.transpose(1, 2)).numpy(), np.broadcast_to(np.eye(3), Rh.shape), atol=1e-12)
    for P in (np.outer(rng.normal(size=6), [0.3, -0.5, 0.8]), np.zeros((1, 3))):  # a line; a single node
        P = torch.tensor(P - P.mean(0))
        Rt = torch.tensor(np.stack([_rotation(rng.normal(size=4)) for _ in range(16)]))
        Q = torch.einsum("bij,nj->bni", Rt, P)
        H = torch.einsum("ni,bnj->bij", P, Q)
        Rh = fit(H)
        assert torch.isfinite(Rh).all()
        np.testing.assert_allclose(torch.linalg.det(Rh).numpy(), 1.0, atol=1e-12)
        np.testing.assert_allclose(_fit(Rh, P, Q).numpy(), _fit(_rotation_svd(H), P, Q).numpy(), atol=1e-20)


def test_mdgs_rolls_out_the_same_with_horns_rotation_as_with_the_svd(tiny_cubli, monkeypatch):
    """What a step captured as a CUDA graph runs (Horn's rotation in every Kabsch fit: the structural
    constraint, the joint projection, the motor prior) against the SVD, on the same device: an untrained MDGS
    with the motor prior (its network acting) rolls out the tiny Cubli test trajectories to the same
    positions within float32 round-off over its first 40 frames."""
    import mdgs.structure
    from mdgs.data.split import load_split
    from mdgs.evaluate.rollout import rollout
    from mdgs.models import MODELS
    from mdgs.models.mdgs import ModelConfig

    calls = []
    monkeypatch.setattr(mdgs.structure, "rotation_horn", lambda H: calls.append(H.shape) or rotation_horn(H))
    te = load_split(tiny_cubli / "test.h5")
    torch.manual_seed(0)
    model = MODELS["mdgs"].from_data(te, ModelConfig(zero_init=False, actuation="prior"))
    svd = rollout(model, te, "cpu")
    assert not calls  # outside the block: the SVD
    with rotation_fit("horn"):
        horn = rollout(model, te, "cpu")
    assert len(calls) >= 2 * (te.x.shape[1] - 1)  # the structure's fit and the motor prior's, every step
    assert np.abs(svd.x[:, -1] - te.x[:, -1]).max() > 1e-3  # the untrained network does move things
    np.testing.assert_allclose(horn.x[:, :40], svd.x[:, :40], rtol=0, atol=1e-5)

"""Structural constraint module (Appendix B.1.3): batched Kabsch with the reflection correction.

Reference: Kabsch (1976), Acta Cryst. A32, 922; reflection correction as in Umeyama (1991).
"""

import numpy as np
import torch
from hypothesis import given
from hypothesis import strategies as st

from mdgs.structure import align_to_reference, kabsch


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

"""Graph construction (Section 3.2, Appendix B.1.1) on hand-made scenes."""

import numpy as np
import pytest
import torch

from mdgs.graphs import (
    ObjectGraph,
    SceneGraph,
    batch_edges,
    contact_candidates,
    contact_edges,
    dense_contacts,
    gcn_norm,
    object_edges,
)


def _pairs(ei):
    return {(int(a), int(b)) for a, b in ei.T}


def test_object_edges_are_symmetric_face_pairs():
    ei = object_edges(np.array([[0, 1], [1, 2]]), 3)
    assert _pairs(ei) == {(0, 1), (1, 0), (1, 2), (2, 1)}
    with pytest.raises(ValueError, match="node 5"):
        object_edges(np.array([[0, 5]]), 3)


def test_contact_edges_hand_made_scene():
    # objects: 0 = {0, 1}, 1 = {2}, 2 = {3}; node 2 is 0.05 from node 1, node 3 far away
    pos = torch.tensor([[0.0, 0, 0], [0.1, 0, 0], [0.15, 0, 0], [5.0, 0, 0]])
    obj = torch.tensor([0, 0, 1, 2])
    ei = contact_edges(pos, obj, r=0.06)
    assert _pairs(ei) == {(1, 2), (2, 1)}  # 0-1 are closer than r but on one object
    assert _pairs(contact_edges(pos, obj, r=0.2)) == {(0, 2), (2, 0), (1, 2), (2, 1)}
    # two static nodes never form a contact edge
    static = torch.tensor([False, True, True, False])
    assert _pairs(contact_edges(pos, obj, r=0.06, static=static)) == set()


def test_dense_contacts_are_the_contact_edges():
    """The dense [B, N, N] form holds the pairs of the edge list, with candidates built or passed in."""
    pos = torch.tensor([[0.0, 0, 0], [0.1, 0, 0], [0.15, 0, 0], [0.2, 0, 0]])
    obj = torch.tensor([0, 0, 1, 2])
    for static in (None, torch.tensor([False, False, True, True])):
        expected = _pairs(contact_edges(pos, obj, r=0.12, static=static))
        assert expected  # not vacuous
        for cand in (None, contact_candidates(obj, static)):
            _, i, j = dense_contacts(pos, obj, 0.12, static, candidates=cand).nonzero(as_tuple=True)
            assert _pairs(torch.stack([i, j])) == expected
    # nodes 2, 3 (different objects, 0.05 apart) touch unless both are static
    assert (2, 3) in _pairs(contact_edges(pos, obj, r=0.12))
    assert not bool(contact_candidates(obj, torch.tensor([False, False, True, True]))[2, 3])


def test_contact_edges_far_from_origin_and_batched():
    """Exact distances (not the matmul form) keep neighbour sets 1e4 m from the origin."""
    rng = np.random.default_rng(0)
    base = rng.uniform(-1, 1, size=(3, 40, 3)) * 0.05
    obj = torch.tensor(rng.integers(0, 4, size=40))
    r = 0.03
    expected = []
    for b in range(3):
        d = np.linalg.norm(base[b, :, None] - base[b, None], axis=-1)
        i, j = np.nonzero((d < r) & (obj.numpy()[:, None] != obj.numpy()[None]))
        expected += [(b * 40 + a, b * 40 + c) for a, c in zip(i, j, strict=True)]
    far = torch.tensor(base + 1e4)
    assert _pairs(contact_edges(far, obj, r)) == set(expected)
    assert _pairs(contact_edges(far, obj, r, max_block_elems=100)) == set(expected)  # blockwise


def test_batch_edges_offsets():
    ei = torch.tensor([[0, 1], [1, 0]])
    assert _pairs(batch_edges(ei, 3, 2)) == {(0, 1), (1, 0), (3, 4), (4, 3)}


def test_gcn_norm_matches_definition():
    ei = object_edges(np.array([[0, 1], [1, 2]]), 3)
    A = np.zeros((3, 3))
    A[[0, 1, 1, 2], [1, 0, 2, 1]] = 1
    A += np.eye(3)
    d = A.sum(1) ** -0.5
    np.testing.assert_allclose(
        gcn_norm(ei, 3).to_dense().numpy(), d[:, None] * A * d[None], atol=1e-7
    )
    # duplicates merged, existing self-loops not doubled
    ei2 = torch.cat([ei, ei, torch.tensor([[0], [0]])], 1)
    np.testing.assert_allclose(
        gcn_norm(ei2, 3).to_dense().numpy(), d[:, None] * A * d[None], atol=1e-7
    )


@pytest.mark.parametrize("dense_max", [0, 100])
def test_object_graph_propagator_dense_and_csr_agree(dense_max):
    ei = object_edges(np.array([[0, 1], [1, 2], [3, 4]]), 5)
    g = ObjectGraph(ei, 5, dense_max_nodes=dense_max)
    h = torch.randn(4, 5, 7)
    ref = torch.einsum("ij,bjf->bif", gcn_norm(ei, 5).to_dense(), h)
    out = g.propagator(4, h.device)(h)
    torch.testing.assert_close(out, ref)
    assert g.propagator(4, h.device) is g.propagator(4, h.device)  # cached


def test_union_graph_contains_both_edge_sets():
    ei = object_edges(np.array([[0, 1], [2, 3]]), 4)
    g = ObjectGraph(ei, 4)
    contact = torch.tensor([[1, 2, 5, 6], [2, 1, 6, 5]])  # graph 0: 1-2; graph 1: 1-2
    A = g.union(contact, 2, "cpu").csr.to_dense()
    nz = {(int(a), int(b)) for a, b in A.nonzero()}
    for a, b in [(0, 1), (2, 3), (1, 2), (4, 5), (6, 7), (5, 6)]:
        assert (a, b) in nz and (b, a) in nz
    assert (0, 4) not in nz


def test_scene_graph_from_static_arrays():
    static = {
        "node_body": np.array([0, 0, 3, 3, 5]),
        "node_static": np.array([True, True, False, False, False]),
        "node_mass": np.array([0.0, 0.0, 1.0, 1.0, 2.0]),
        "node_volume": np.ones(5),
        "node_tau": np.array([0.1, 0.1, 0.2, 0.2, 0.3]),
        "node_centroid": np.zeros((5, 3)),
        "adjacency": np.array([[0, 1], [2, 3]]),
        "body_id": np.array([3, 5]),
        "body_free": np.array([True, False]),
    }
    sc = SceneGraph.from_static(static, has_contact=True)
    assert sc.obj.tolist() == [0, 0, 1, 1, 2] and sc.n_obj == 3
    assert sc.obj_type.argmax(1).tolist() == [0, 0, 1, 1, 2]
    assert sc.contact_radius == pytest.approx(0.6)
    assert sc.properties().shape == (5, 6)
    assert sc.moving("cpu").tolist() == [False, False, True, True, True]
    # contact candidates: nodes of different objects, never two static ones
    expected = (sc.obj[:, None] != sc.obj[None, :]) & ~(sc.static[:, None] & sc.static[None, :])
    assert torch.equal(sc.contact_candidates("cpu"), expected)
    assert torch.equal(sc.to("cpu").properties(), sc.properties())

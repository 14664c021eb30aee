"""MDGS model (Sections 3.2-3.3): shapes, contact branch, structural module, gradient routing."""

import numpy as np
import pytest
import torch

from mdgs.graphs import SceneGraph
from mdgs.losses import constraint_loss, mse_loss
from mdgs.models.mdgs import MDGS, ModelConfig

SMALL = dict(hidden=32, global_dim=16)


def _cubes(k=2, n_obj=2, size=0.1, gap=0.0, world=False):
    """``n_obj`` cubes of k^3 cells along x (face-adjacent cells share an edge); optional static floor cell."""
    pos, body, cent, adj = [], [], [], []
    for o in range(n_obj):
        base = len(pos)
        ids = {}
        for i in range(k):
            for j in range(k):
                for m in range(k):
                    c = (np.array([i, j, m]) + 0.5) * size - k * size / 2
                    ids[i, j, m] = len(pos)
                    pos.append(c + [o * (k * size + gap), 0, 0])
                    body.append(o + 1)
                    cent.append(c)
        for (i, j, m), a in ids.items():
            for d in ((1, 0, 0), (0, 1, 0), (0, 0, 1)):
                b = ids.get((i + d[0], j + d[1], m + d[2]))
                if b is not None:
                    adj.append((a, b))
        assert len(pos) - base == k**3
    if world:
        pos.append([0, 0, -k * size])
        body.append(0)
        cent.append([0, 0, -k * size])
    n = len(pos)
    static = {
        "node_body": np.array(body),
        "node_static": np.array(body) == 0,
        "node_mass": np.where(np.array(body) == 0, 0, 1.0),
        "node_volume": np.full(n, size**3),
        "node_tau": np.full(n, size * np.sqrt(3) / 2),
        "node_centroid": np.array(cent, float),
        "adjacency": np.array(adj),
        "body_id": np.arange(1, n_obj + 1),
        "body_free": np.ones(n_obj, bool),
    }
    return static, torch.tensor(np.array(pos), dtype=torch.float32)


def test_forward_shapes_and_static_nodes():
    static, pos = _cubes(world=True)
    sc = SceneGraph.from_static(static, has_contact=True)
    model = MDGS(ModelConfig(**SMALL))
    x = pos.expand(3, -1, -1).contiguous()
    v = torch.randn_like(x)
    p = model(sc, x, v)
    for t in (p.x, p.v, p.force, p.force_noncontact, p.force_contact):
        assert t.shape == x.shape
    torch.testing.assert_close(p.force, p.force_contact + p.force_noncontact)  # Eq. (7)
    assert torch.equal(p.x[:, -1], x[:, -1]) and torch.all(p.v[:, -1] == 0)  # world node fixed


def test_no_contact_branch_for_scene_without_contact():
    model = MDGS(ModelConfig(**SMALL, contact=False))
    assert not hasattr(model, "force_contact") and not hasattr(model, "global_gather")
    static, pos = _cubes()
    p = model(
        SceneGraph.from_static(static, has_contact=False), pos[None], torch.zeros_like(pos)[None]
    )
    assert torch.all(p.force_contact == 0) and p.contact_edges.shape[1] == 0
    full = MDGS(ModelConfig(**SMALL, contact=True))
    assert sum(q.numel() for q in model.parameters()) < sum(q.numel() for q in full.parameters())


def test_contact_forces_only_on_contact_nodes():
    # two cubes 1 mm apart: only the facing cells are within r = 0.11 of the other cube
    static, pos = _cubes(gap=0.001)
    sc = SceneGraph.from_static(static, has_contact=True, contact_radius=0.11)
    p = MDGS(ModelConfig(**SMALL))(sc, pos[None], torch.zeros_like(pos)[None])
    touched = set(p.contact_edges[0].tolist())
    assert touched == {
        4,
        5,
        6,
        7,
        8,
        9,
        10,
        11,
    }  # x-faces: cells with i = 1 of cube 0, i = 0 of cube 1
    nz = set(torch.nonzero(p.force_contact[0].abs().sum(-1)).flatten().tolist())
    assert nz <= touched and nz


def _cube_rigidity_error(model) -> float:
    static, pos = _cubes()
    sc = SceneGraph.from_static(static, has_contact=True)
    p = model(sc, pos[None], torch.randn_like(pos)[None])
    x = p.x[0].double()
    ref = torch.tensor(static["node_centroid"])
    return max(
        (torch.cdist(x[s], x[s]) - torch.cdist(ref[s], ref[s])).abs().max().item()
        for s in (slice(0, 8), slice(8, 16))
    )


@pytest.mark.parametrize("structure", [True, False])
def test_structural_module_keeps_objects_rigid(structure):
    """With the per-node Euler integrator only the structural module keeps the cubes rigid."""
    model = MDGS(
        ModelConfig(structure=structure, integrator="euler", dt=0.01, dx_scale=0.05, **SMALL)
    )
    assert (_cube_rigidity_error(model) < 1e-5) == structure


def test_rigid_integrator_keeps_objects_rigid_without_the_structural_module():
    model = MDGS(
        ModelConfig(
            structure=False, integrator="rigid", dt=0.01, dx_scale=0.05, dv_scale=3.0, **SMALL
        )
    )
    assert _cube_rigidity_error(model) < 1e-5  # float32 node positions of 0.1 m cubes


def test_rigid_model_with_zero_state_output_keeps_every_twist():
    """g = 0: the rigid integrator is the constant-twist reference (each cube keeps its velocity)."""
    static, pos = _cubes()
    sc = SceneGraph.from_static(static, has_contact=True)
    model = MDGS(ModelConfig(dt=0.01, **SMALL))
    torch.nn.init.zeros_(model.state.lins[-1].weight)
    torch.nn.init.zeros_(model.state.lins[-1].bias)
    v = torch.zeros_like(pos)
    v[:8] = torch.tensor([0.5, 0.0, 0.0])
    p = model(sc, pos[None], v[None])
    # float32 positions of 0.1 m cubes: 1e-6 m
    assert torch.allclose(p.x[0] - pos, v * 0.01, atol=1e-6) and torch.allclose(
        p.v[0], v, atol=1e-6
    )


def test_constraint_loss_updates_only_force_networks():
    static, pos = _cubes()
    sc = SceneGraph.from_static(static, has_contact=True, contact_radius=0.11)
    # zero_init off: a zero state output is the constant-twist step, on which L_cst's hinge is inactive
    torch.manual_seed(0)
    model = MDGS(ModelConfig(**SMALL, zero_init=False))
    x = pos[None] + 0.001 * torch.randn(2, *pos.shape)
    v = torch.randn_like(x)
    p = model(sc, x, v)
    L = constraint_loss(
        p.force, x, v, p.x, p.v, sc.mass, sc.tau, sc.obj, sc.n_obj, 0.01, moving=~sc.static
    )
    assert L.item() > 0  # the hinge is active here, so the gradients below are not vacuous
    L.backward()
    assert all(q.grad is None for q in model.state.parameters())
    assert all(q.grad is not None for q in model.force_noncontact.parameters())
    assert any(
        q.grad is not None and q.grad.abs().sum() > 0 for q in model.force_contact.parameters()
    )


@pytest.mark.parametrize("integrator", ["rigid", "twist", "euler"])
def test_model_fits_one_step(integrator):
    """A few Adam steps on a fixed batch cut L_mse + L_cst: the whole graph is trainable.

    Each cube translates at its own random velocity and falls under gravity for one 10 ms step."""
    torch.manual_seed(0)
    static, pos = _cubes()
    sc = SceneGraph.from_static(static, has_contact=True)
    model = MDGS(
        ModelConfig(
            structure=False,
            integrator=integrator,
            dt=0.01,
            dx_scale=0.01,
            dv_scale=0.1,
            force_scale=10.0,
            **SMALL,
        )
    )
    x = pos[None] + 0.01 * torch.randn(4, 1, 3)
    v = torch.randn(4, 2, 3)[:, sc.obj]
    vt = v + torch.tensor([0.0, 0.0, -0.098])
    xt = x + 0.01 * vt
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)

    def loss():
        p = model(sc, x, v)
        return mse_loss(p.x, p.v, xt, vt, dx_scale=0.01, dv_scale=0.1) + constraint_loss(
            p.force,
            x,
            v,
            p.x,
            p.v,
            sc.mass,
            sc.tau,
            sc.obj,
            sc.n_obj,
            0.01,
            scale=160.0,
            bound="corrected",
        )

    first = loss().item()
    for _ in range(100):
        opt.zero_grad()
        L = loss()
        L.backward()
        opt.step()
    assert L.item() < 0.85 * first


def test_config_rejects_unknown_variant():
    with pytest.raises(ValueError, match="variant"):
        ModelConfig(variant="mdgs-x")
    with pytest.raises(ValueError, match="bound"):
        ModelConfig(bound="tight")


@pytest.mark.parametrize(("setting", "phrase"), [
    ({"hidden": 0}, "hidden must be a positive integer"),
    ({"layers": -1}, "layers must be a positive integer"),
    ({"global_dim": True}, "global_dim must be a positive integer"),
    ({"dense_max_nodes": -2}, "dense_max_nodes must be an integer of at least 0"),
    ({"cst_weight": -1.0}, "cst_weight must be a number of at least 0"),
    ({"cst_weight": float("nan")}, "cst_weight must be a number of at least 0"),
    ({"dx_scale": 0.0}, "dx_scale must be a positive number"),
    ({"force_scale": float("inf")}, "force_scale must be a positive number"),
    ({"lam": 0.0}, "lam must be a positive number or None"),
    ({"dt": -0.01}, "dt must be a number of at least 0"),
    ({"features": "body"}, "features must be one of paper, local"),
    ({"self_weight": "yes"}, "self_weight must be true or false"),
    ({"loss": "l1"}, "loss must be one of mse, huber, relative"),
])
def test_config_rejects_out_of_range_settings_by_name(setting, phrase):
    with pytest.raises(ValueError, match=phrase):
        ModelConfig(**setting)


def test_dense_contact_path_gives_the_sparse_paths_numbers():
    """dense_max_nodes picks [B, N, N] blocks or edge lists for the contact branch: same edges, same
    normalisation, so the same prediction to float32 round-off (1e-5 relative)."""
    static, pos = _cubes(gap=0.001, world=True)
    sc = SceneGraph.from_static(static, has_contact=True, contact_radius=0.11)
    torch.manual_seed(0)
    dense = MDGS(ModelConfig(**SMALL))
    sparse = MDGS(ModelConfig(**SMALL, dense_max_nodes=0))
    sparse.load_state_dict(dense.state_dict())
    g = torch.Generator().manual_seed(1)
    x = pos.expand(4, -1, -1) + 0.02 * torch.randn(4, *pos.shape, generator=g)  # contacts differ per graph
    v = torch.randn(x.shape, generator=g)
    a, b = dense(sc, x, v), sparse(sc, x, v)
    assert torch.equal(a.contact_edges, b.contact_edges) and a.contact_edges.shape[1] > 0
    for p, q in ((a.force_contact, b.force_contact), (a.x, b.x), (a.v, b.v)):
        torch.testing.assert_close(p, q, rtol=1e-5, atol=1e-6)
    assert a.force_contact.abs().sum() > 0


@pytest.mark.parametrize("layers", [1, 2, 3])
def test_folding_the_global_networks_last_layer_into_the_contact_networks_first_keeps_the_prediction(layers, monkeypatch):
    """What an ahead-of-time compiled step computes (inside ``folded_weights()``: g^Z-'s last layer and
    g^F-'s first multiplied once, Eqs. (5)-(6)) is the unfolded prediction to float32 round-off, with
    one, two and three layers, contacts differing per graph; the products are computed again when a
    weight changes; training (gradients on) and a model with ``self_weight`` keep the unfolded path."""
    from mdgs.models.layers import folded_weights

    static, pos = _cubes(gap=0.001, world=True)
    sc = SceneGraph.from_static(static, has_contact=True, contact_radius=0.11)
    torch.manual_seed(0)
    model = MDGS(ModelConfig(**{**SMALL, "layers": layers}))
    g = torch.Generator().manual_seed(1)
    x = pos.expand(4, -1, -1) + 0.02 * torch.randn(4, *pos.shape, generator=g)
    v = torch.randn(x.shape, generator=g)
    calls, fold = [], MDGS._contact_forces_folded
    monkeypatch.setattr(MDGS, "_contact_forces_folded", lambda self, *a: calls.append(1) or fold(self, *a))
    with torch.no_grad():
        plain = model(sc, x, v)
        assert not calls
        with folded_weights():
            folded = model(sc, x, v)
            assert calls and plain.force_contact.abs().sum() > 0
            for p, q in ((folded.force_contact, plain.force_contact), (folded.x, plain.x), (folded.v, plain.v)):
                torch.testing.assert_close(p, q, rtol=1e-5, atol=1e-6)
            model.global_gather.lins[-1].bias.add_(1.0)  # a changed weight: the cached products are not reused
            again = model(sc, x, v)
    with torch.no_grad():
        changed = model(sc, x, v)
    assert (again.force_contact - folded.force_contact).abs().max() > 1e-3
    torch.testing.assert_close(again.force_contact, changed.force_contact, rtol=1e-5, atol=1e-6)
    calls.clear()
    with folded_weights():
        model(sc, x, v)  # gradients on: training
        with torch.no_grad():
            MDGS(ModelConfig(**{**SMALL, "layers": layers, "self_weight": True}))(sc, x, v)
    assert not calls


def test_self_weighted_gcn_tells_a_node_from_its_neighbourhood():
    """On a complete graph (every node's neighbourhood is the whole graph) the paper's GCN gives every
    node the same output whatever their features; a separate weight on each node's own features
    (``self_weight``) does not. Both zero their output with ``zero_output``."""
    from mdgs.graphs import Propagator
    from mdgs.models.layers import GCN

    torch.manual_seed(0)
    prop = Propagator(dense=torch.full((5, 5), 1 / 5))  # A_hat of K5 with self-loops
    h = torch.randn(2, 5, 4)
    plain, own = GCN(4, 16, 3, 3), GCN(4, 16, 3, 3, self_weight=True)
    out = plain(prop, h)
    assert torch.allclose(out, out[:, :1].expand_as(out), atol=1e-6)
    out = own(prop, h)
    assert float((out - out[:, :1]).abs().max()) > 1e-3
    for g in (plain, own):
        g.zero_output()
        assert float(g(prop, h).abs().max()) == 0.0


@pytest.mark.parametrize("features", ["paper", "local"])
def test_local_features_make_a_step_independent_of_where_the_scene_stands(features):
    """``features="local"``: moving every body horizontally moves the predicted step with it (float32
    round-off, 1e-5 m on 0.2 m cubes shifted by 3 m); the paper's absolute positions do not."""
    torch.manual_seed(0)
    static, pos = _cubes(gap=0.05)
    sc = SceneGraph.from_static(static, has_contact=True)
    model = MDGS(ModelConfig(**SMALL, features=features, zero_init=False, dt=0.01))
    x = pos.expand(2, -1, -1).contiguous()
    v = 0.3 * torch.randn_like(x)
    shift = torch.tensor([3.0, -2.0, 0.0])
    with torch.no_grad():
        a, b = model(sc, x, v), model(sc, x + shift, v)
    moved = float((b.x - shift - a.x).abs().max())
    if features == "local":
        assert moved < 1e-5 and torch.allclose(a.v, b.v, atol=1e-5)
    else:
        assert moved > 1e-4

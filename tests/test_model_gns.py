"""Tests of the GNS peer (mdgs.models.gns): shapes, graph, noise recipe, history in rollouts, overfit, CLI.

Most tests use a narrow, shallow GNS (latent 16, 2 message-passing steps) so the file stays
well under a minute on two shared CPU cores; the full-size model is built once to check its
architecture (10 unshared steps, LayerNorm everywhere but the decoder).
"""

from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from mdgs.cli import app
from mdgs.data.split import load_split
from mdgs.evaluate.rollout import rollout
from mdgs.graphs import radius_edges
from mdgs.models import MODELS, ModelError, batch_of
from mdgs.models.gns import GNS, GNSConfig, element_spacing, random_walk_noise
from mdgs.models.references import ConstantTwistConfig

runner = CliRunner()
SMALL = GNSConfig(latent=16, hidden=16, steps=2, type_embedding=4)


@pytest.fixture(scope="module", autouse=True)
def _one_thread(one_torch_thread):
    """Every test of this module runs on one torch thread (tests/conftest.py)."""


@pytest.fixture(scope="module")
def data(tiny_cubli):
    return tiny_cubli


@pytest.fixture(scope="module")
def train_split(data):
    return load_split(data / "train.h5")


@pytest.fixture(scope="module")
def small(train_split):
    torch.manual_seed(0)
    return GNS.from_data(train_split, SMALL)


def _batch(d, model, n=4, start=0):
    return batch_of(d, d.pairs(model.history)[start:start + n], "cpu", model.history)


def test_registered_and_resolved_from_data(train_split):
    assert MODELS["gns"] is GNS and GNS.default_lr == 1e-4
    cfg = GNS.resolve_config(GNSConfig(), train_split)
    # cubli-triple: cube, 3 wheels and the world's static elements; one floor plane; 3 motors
    assert (cfg.n_types, cfg.n_planes, cfg.control_dim) == (5, 1, 3)
    assert cfg.dt == pytest.approx(train_split.frame_dt)
    assert cfg.radius == pytest.approx(1.5 * element_spacing(train_split))
    # the coarsest spacing is the cube's 2 x 2 x 2 elements: 0.15 m / 2 apart
    assert element_spacing(train_split) == pytest.approx(0.075, rel=1e-5)


def test_full_size_architecture(train_split):
    m = GNS(GNS.resolve_config(GNSConfig(), train_split))
    assert len(m.processor) == 10
    ids = {id(p) for blk in m.processor for p in blk.parameters()}
    assert len(ids) == sum(1 for blk in m.processor for _ in blk.parameters())  # unshared weights
    for mlp in (m.node_encoder, m.edge_encoder, m.processor[3].edge, m.processor[7].node):
        assert isinstance(mlp[-1], torch.nn.LayerNorm) and mlp[-1].normalized_shape == (128,)
        assert sum(isinstance(x, torch.nn.Linear) for x in mlp) == 3  # 2 hidden layers + output
    assert not any(isinstance(x, torch.nn.LayerNorm) for x in m.decoder) and m.decoder[-1].out_features == 3
    assert m.embed.embedding_dim == 16 and m.history == 5
    # node input: 5 velocities x 3 + 1 floor distance + 3 controls + 16 type embedding
    assert m.node_encoder[0].in_features == 15 + 1 + 3 + 16


def test_shapes_of_forward_step_and_losses(train_split, small):
    b = _batch(train_split, small)
    xs = torch.cat([b.x_past, b.x[:, None]], 1)
    assert xs.shape == (4, 6, 36, 3)
    assert small(xs, b.ctrl).shape == (4, 36, 3)
    losses = small.losses(b)
    assert set(losses) == {"mse"} and losses["mse"].dim() == 0
    small.bind(train_split)
    st = small.initial_state(train_split, np.array([0, 1]), 7)
    assert st.extra["x_past"].shape == (2, 5, 36, 3)
    with torch.no_grad():
        nxt = small.step(st, torch.from_numpy(train_split.ctrl[:, 7]))
    assert nxt.x.shape == nxt.v.shape == (2, 36, 3) and nxt.extra["x_past"].shape == (2, 5, 36, 3)
    static = np.asarray(train_split.static["node_static"], bool)
    assert torch.equal(nxt.x[:, static], st.x[:, static])  # world elements never move
    assert torch.all(nxt.v[:, static] == 0)


def test_radius_graph_is_every_pair_closer_than_r_with_self_edges():
    from scipy.spatial import cKDTree

    g = torch.Generator().manual_seed(1)
    pos = torch.rand((3, 50, 3), generator=g, dtype=torch.float64) * 0.5 + 100.0  # far from the origin
    r = 0.12
    snd, rcv = radius_edges(pos, r, max_block_elems=3 * 50 * 7)  # several blocks
    got = set(zip(snd.tolist(), rcv.tolist(), strict=True))
    want = set()
    for b in range(3):
        for i, j in cKDTree(pos[b].numpy()).query_pairs(r, output_type="ndarray"):
            want |= {(b * 50 + i, b * 50 + j), (b * 50 + j, b * 50 + i)}
        want |= {(b * 50 + i, b * 50 + i) for i in range(50)}
    assert got == want


def test_translation_along_the_floor_changes_nothing(train_split, small):
    # GNS sees relative positions, velocities and the floor distance only: a shift in x, y is invisible
    b = _batch(train_split, small)
    xs = torch.cat([b.x_past, b.x[:, None]], 1).double()
    m = small.double()
    try:
        a0 = m(xs, b.ctrl)
        a1 = m(xs + torch.tensor([3.0, -2.0, 0.0], dtype=torch.float64), b.ctrl)
        a2 = m(xs + torch.tensor([0.0, 0.0, 0.05], dtype=torch.float64), b.ctrl)
    finally:
        small.float()
    torch.testing.assert_close(a1, a0, rtol=0, atol=1e-9)  # float64 rounding of the shifted coordinates
    assert (a2 - a0).abs().max() > 1e-6  # a lift changes the floor feature: it is really used


def test_statistics_fold_the_noise_in_and_use_the_training_split(train_split, small):
    x = train_split.x[:, :, train_split.moving].astype(np.float64)
    u, a = np.diff(x, axis=1).reshape(-1, 3), np.diff(x, n=2, axis=1).reshape(-1, 3)
    s2 = SMALL.noise_std ** 2
    np.testing.assert_allclose(small.vel_std.numpy() ** 2, u.var(0) + s2, rtol=1e-5)
    np.testing.assert_allclose(small.acc_std.numpy() ** 2, a.var(0) + s2, rtol=1e-5)
    np.testing.assert_allclose(small.acc_mean.numpy(), a.mean(0), rtol=1e-4, atol=1e-12)


def test_random_walk_noise_has_the_stated_std():
    g = torch.Generator().manual_seed(0)
    n = random_walk_noise((4000, 6, 2, 3), 6.7e-4, g, "cpu")
    assert torch.all(n[:, 0] == 0)  # the oldest position is not perturbed
    vel = n[:, 1:] - n[:, :-1]
    # per-step velocity noise 6.7e-4 / sqrt(5); the last velocity's noise (the sum) has std 6.7e-4.
    # 24000 samples per estimate: relative standard error of a std ~ 1/sqrt(2 * 24000) = 0.5 %, so 3 %.
    assert vel.std().item() == pytest.approx(6.7e-4 / np.sqrt(5), rel=0.03)
    assert n[:, -1].std().item() == pytest.approx(6.7e-4, rel=0.03)


@pytest.mark.parametrize("mode", ["velocity", "position"])
def test_noise_corrected_target_lands_where_it_should(train_split, small, mode):
    m = GNS(replace(small.config, noise_target=mode))
    m.load_state_dict(small.state_dict())
    m.bind(train_split)
    b = _batch(train_split, m, n=8)
    nb = m.perturb(b, torch.Generator().manual_seed(3))
    noisy = torch.cat([nb.x_past, nb.x[:, None]], 1)
    mv = train_split.moving
    assert (nb.x - b.x)[:, mv].abs().max() > 1e-4  # the input really is noisy (std 6.7e-4 m)
    assert torch.equal(nb.x[:, ~mv], b.x[:, ~mv])  # static elements are not noised
    landed = m.integrate(noisy, m.target(noisy, nb.x_next))
    # float32 positions of ~0.5 m: the inverse and forward Euler round to ~1e-7 m; the noise is ~1e-3 m
    tol = dict(rtol=0, atol=1e-6)
    if mode == "position":
        torch.testing.assert_close(landed, b.x_next, **tol)
    else:  # GNS: the true next velocity, from the noisy last position
        torch.testing.assert_close(landed - nb.x, b.x_next - b.x, **tol)
        torch.testing.assert_close(landed - b.x_next, nb.x - b.x, **tol)


def test_rollout_is_given_frames_0_to_5(data, small):
    # zero decoder and zero mean acceleration: the model predicts a = 0, i.e. x' = 2 x^t - x^{t-1}
    d = load_split(data / "test.h5")
    m = GNS(small.config)
    m.load_state_dict(small.state_dict())
    with torch.no_grad():
        for p in m.decoder[-1].parameters():
            p.zero_()
        m.acc_mean.zero_()
    r = rollout(m, d, "cpu")
    assert r.given == 6
    np.testing.assert_array_equal(r.x[:, :6], d.x[:, :6])
    mv = d.moving
    want6 = 2 * d.x[:, 5] - d.x[:, 4]
    np.testing.assert_allclose(r.x[:, 6][:, mv], want6[:, mv], rtol=0, atol=1e-6)  # float32 rounding
    np.testing.assert_array_equal(r.x[:, 6][:, ~mv], d.x[:, 5][:, ~mv])
    want7 = 2 * r.x[:, 6] - d.x[:, 5]
    np.testing.assert_allclose(r.x[:, 7][:, mv], want7[:, mv], rtol=0, atol=1e-6)
    np.testing.assert_allclose(r.v[:, 6], (r.x[:, 6] - d.x[:, 5]) / d.frame_dt, rtol=0, atol=1e-3)
    st = m.initial_state(d, np.arange(d.x.shape[0]), 5)
    np.testing.assert_array_equal(st.extra["x_past"].numpy(), d.x[:, 0:5])
    with pytest.raises(ModelError, match="frame 5 or later"):
        m.initial_state(d, np.arange(1), 4)


def test_two_batch_overfit(train_split):
    torch.manual_seed(0)
    m = GNS.from_data(train_split, replace(SMALL, latent=32, hidden=32))
    pairs = train_split.pairs(5)
    b1, b2 = (batch_of(train_split, pairs[[k, k + 40]], "cpu", 5) for k in (10, 60))
    # Adam at 1e-3 (not the GNS schedule): this tests that the model can fit, not how fast GNS trains
    opt = torch.optim.Adam(m.parameters(), lr=1e-3)

    def total():
        with torch.no_grad():
            return m.losses(b1)["mse"].item() + m.losses(b2)["mse"].item()

    before = total()
    for k in range(200):
        loss = m.losses(b1 if k % 2 == 0 else b2)["mse"]
        opt.zero_grad()
        loss.backward()
        opt.step()
    after = total()
    assert after < before / 20, (before, after)  # measured: 5.6 -> 0.0093 (1/600) at this seed


def test_refuses_too_short_data_and_another_scene(train_split, small):
    short = replace(train_split, x=train_split.x[:, :6], v=train_split.v[:, :6], ctrl=train_split.ctrl[:, :6])
    with pytest.raises(ModelError, match="at least 7"):
        GNS.from_data(short, SMALL)
    fewer = replace(train_split, ctrl=train_split.ctrl[..., :2], control_sign=train_split.control_sign[:2])
    with pytest.raises(ModelError, match="actuators"):
        small.bind(fewer)


def test_scene_without_floor_or_actuators(train_split):
    # the cubli scene with its floor plane and its motors removed: no boundary and no control inputs
    mjcf = re.sub(r"<geom[^>]*type=\"plane\"[^>]*/>", "", train_split.mjcf)
    mjcf = re.sub(r"<actuator>.*?</actuator>", "", mjcf, flags=re.S)
    T, F = train_split.x.shape[:2]
    d = replace(train_split, mjcf=mjcf, ctrl=np.zeros((T, F, 0), np.float32),
                control_sign=np.zeros((0, train_split.x.shape[2]), np.float32))
    m = GNS.from_data(d, SMALL)
    assert (m.config.n_planes, m.config.control_dim) == (0, 0)
    b = _batch(d, m)
    assert torch.isfinite(m.losses(m.perturb(b, torch.Generator().manual_seed(0)))["mse"])


def test_train_and_evaluate_through_the_cli(data, tmp_path):
    out = tmp_path / "gns-run"
    sets = ["--set", "latent=16", "--set", "hidden=16", "--set", "steps=2", "--set", "type_embedding=4"]
    res = runner.invoke(app, ["train", "--data", str(data), "--out", str(out), "--model", "gns", "--epochs", "1",
                              "--max-steps", "3", "--batch-size", "4", "--valid-max-pairs", "16", "--device", "cpu",
                              *sets])
    assert res.exit_code == 0, res.output
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["model_name"] == "gns" and cfg["lr"] == 1e-4  # GNS's own learning rate when --lr is not given
    assert cfg["model"]["steps"] == 2 and cfg["model"]["radius"] > 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics[0]["steps"] == 3 and metrics[0]["lr"] < 1e-4  # decayed per step
    rep_path = tmp_path / "eval.json"
    res = runner.invoke(app, ["evaluate", str(out), "--data", str(data), "--json", str(rep_path), "--device", "cpu"])
    assert res.exit_code == 0, res.output
    rep = json.loads(rep_path.read_text())
    run = rep["runs"][0]
    assert run["model"] == "gns" and run["frames"] == 110 and run["parameters"] > 0
    assert "mse_t40" in rep and "ms_per_frame" in json.dumps(rep)
    res = runner.invoke(app, ["train", "--data", str(data), "--out", str(tmp_path / "bad"), "--model", "gns",
                              "--set", "noise_target=speed"])
    assert res.exit_code == 2 and "noise_target" in res.output and not (tmp_path / "bad").exists()


def test_structure_option_keeps_every_body_rigid_in_rollout(train_split, small):
    m = GNS(replace(small.config, structure=True))
    m.load_state_dict(small.state_dict())
    m.bind(train_split)
    st = m.initial_state(train_split, np.array([0, 1]), 5)
    with torch.no_grad():
        plain = small.step(st, torch.from_numpy(train_split.ctrl[:, 5]))
        snapped = m.step(st, torch.from_numpy(train_split.ctrl[:, 5]))
    body = np.asarray(train_split.static["node_body"])
    ref = np.asarray(train_split.static["node_centroid"])
    for b in np.unique(body[train_split.moving]):
        idx = np.flatnonzero(body == b)
        want = np.linalg.norm(ref[idx, None] - ref[None, idx], axis=-1)
        got = torch.cdist(snapped.x[:, idx].double(), snapped.x[:, idx].double()).numpy()
        np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), rtol=0, atol=1e-5)  # float32 nodes
    assert (plain.x - snapped.x).abs().max() > 0  # the untrained model's step is not rigid by itself


# --- the tree prior (prior = "tree"): GNS's acceleration corrects the rigid tree instead of x^t + u^t ---------------
TREE = dict(prior="tree", prior_substeps=2, noise_target="position")


@pytest.fixture(scope="module")
def tree_model(train_split):
    torch.manual_seed(0)
    return GNS.from_data(train_split, replace(SMALL, **TREE))


def test_tree_prior_with_zero_acceleration_steps_as_the_rigid_tree_reference(data, tree_model):
    # the independent side is the "rigid tree" reference (mdgs.models.references.ConstantTwist), set as the prior
    d = load_split(data / "test.h5")
    m = GNS(tree_model.config)
    m.load_state_dict(tree_model.state_dict())
    m.bind(d)
    with torch.no_grad():
        for p in m.decoder[-1].parameters():
            p.zero_()
        m.acc_mean.zero_()
    ref = MODELS["constant-twist"](ConstantTwistConfig(dynamics=True, joints=True, substeps=2, trapezoidal=True,
                                                      joint_velocities="coordinates", contact="soft"))
    ref.bind(d)
    tr = np.arange(d.x.shape[0])
    a, b = m.initial_state(d, tr, 5), ref.initial_state(d, tr, 5)
    with torch.no_grad():
        for f in range(5, 15):
            c = torch.from_numpy(d.ctrl[tr, f])
            a, b = m.step(a, c), ref.step(b, c)
    # the same tree_step call on the same float32 state: equal to the bit, velocities included (the next
    # frame's tree starts from them)
    assert torch.equal(a.x, b.x) and torch.equal(a.v, b.v)
    moved = (a.x - torch.from_numpy(d.x[:, 5]))[:, d.moving].abs().max()
    assert moved > 1e-3  # ten frames of a tumbling scene: the check compares states that moved
    # and it differs from GNS's own constant-velocity guess
    plain = GNS(replace(m.config, prior="none"))
    plain.load_state_dict(m.state_dict())
    plain.bind(d)
    st = plain.initial_state(d, tr, 5)
    with torch.no_grad():
        assert (plain.step(st, torch.from_numpy(d.ctrl[tr, 5])).x - m.step(st, torch.from_numpy(d.ctrl[tr, 5])).x
                ).abs().max() > 1e-6


def test_tree_prior_statistics_are_the_residual_of_the_tree(train_split, tree_model):
    # acc stats: the tree's residual x^{t+1} - x_p, noise folded in; recomputed here from the tree by hand
    b = batch_of(train_split, train_split.pairs(5), "cpu", 5)
    xp, _ = tree_model._tree(b.x, b.v, b.ctrl)
    r = (b.x_next - xp)[:, train_split.moving].double().reshape(-1, 3)
    want = torch.sqrt(r.var(0, correction=0) + tree_model.config.noise_std ** 2).float()
    torch.testing.assert_close(tree_model.acc_std, want, rtol=1e-4, atol=0)
    plain = GNS.from_data(train_split, SMALL)
    assert (plain.acc_std > 2 * tree_model.acc_std).all()  # the tree leaves far less to learn than x^t + u^t


def test_tree_prior_noisy_velocity_is_the_noisy_last_position_difference(train_split, tree_model):
    b = _batch(train_split, tree_model, n=8)
    nb = tree_model.perturb(b, torch.Generator().manual_seed(3))
    assert torch.equal(nb.x_next, b.x_next)  # noise_target = "position": the target is the true next position
    dn_last = (nb.x - nb.x_past[:, -1]) - (b.x - b.x_past[:, -1])  # n^t - n^{t-1}
    torch.testing.assert_close(nb.v - b.v, dn_last / tree_model.config.dt, rtol=0, atol=1e-3)  # ~1e-7 m / 0.01 s
    assert (nb.v - b.v)[:, train_split.moving].abs().max() > 1e-2  # noise of ~3e-4 m per frame, 0.03 m/s
    xs = torch.cat([nb.x_past, nb.x[:, None]], 1)
    tree = tree_model._tree(nb.x, nb.v, nb.ctrl)
    landed = tree_model.integrate(xs, tree_model.target(xs, nb.x_next, tree), tree)
    torch.testing.assert_close(landed[:, train_split.moving], nb.x_next[:, train_split.moving], rtol=0, atol=1e-6)


def test_tree_prior_settings_are_checked():
    for bad, says in ((dict(prior="mujoco"), "prior must be one of 'none', 'tree'"),
                      (dict(prior_substeps=0), "prior_substeps must be a positive integer"),
                      (dict(prior_contact="sticky"), "contact must be one of"),
                      (dict(prior_joint_velocities="free"), "joint_velocities must be one of"),
                      (dict(prior_trapezoidal="yes"), "prior_trapezoidal must be true or false"),
                      (dict(prior="tree"), 'needs noise_target = "position"')):
        with pytest.raises(ValueError, match=says):
            GNSConfig(**bad)
    GNSConfig(prior="tree", noise_std=0.0)  # without noise the target needs no correction

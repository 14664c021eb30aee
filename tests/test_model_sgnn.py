"""Tests of the SGNN peer (mdgs.models.sgnn): shapes, subequivariance, noise recipe, rigid snap, overfit, CLI.

One module-scoped tiny cubli-triple dataset (gravity along -z, three actuators, a static floor).
Small configurations (hidden 8-32, fewer iterations or a smaller radius, stated per test) keep
the file within a minute on two shared CPU cores; the symmetry does not depend on the sizes.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from mdgs.cli import app
from mdgs.data.split import load_split
from mdgs.models import MODELS, ModelError, State, batch_of
from mdgs.models.sgnn import SGNN, SGNNConfig, SGNNSnap

runner = CliRunner()


@pytest.fixture(scope="module", autouse=True)
def _one_thread(one_torch_thread):
    """Every test of this module runs on one torch thread (tests/conftest.py)."""


@pytest.fixture(scope="module")
def data(tiny_cubli):
    return tiny_cubli


@pytest.fixture(scope="module")
def train_split(data):
    return load_split(data / "train.h5")


def _model(d, cls=SGNN, **kw) -> SGNN:
    torch.manual_seed(0)
    return cls.from_data(d, cls.Config(**kw))


def _rot(axis, angle: float) -> torch.Tensor:
    """Rotation matrix about the unit vector ``axis`` (Rodrigues), float64."""
    a = torch.as_tensor(axis, dtype=torch.float64)
    a = a / a.norm()
    K = torch.tensor([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]], dtype=torch.float64)
    return torch.eye(3, dtype=torch.float64) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _state(d, model, traj=(0, 1), frame=30, dtype=torch.float64):
    s = model.initial_state(d, np.asarray(traj), frame)
    ctrl = torch.from_numpy(d.ctrl[np.asarray(traj), frame]).to(dtype)
    return State(s.x.to(dtype), s.v.to(dtype)), ctrl


def test_registry_and_resolved_settings(train_split):
    assert MODELS["sgnn"] is SGNN and MODELS["sgnn-snap"] is SGNNSnap
    assert not SGNN.Config().rigid_snap and SGNNSnap.Config().rigid_snap
    assert SGNN.default_lr == 1e-4 and SGNN.Config().noise == 3e-4 and SGNN.Config().hidden == 200
    m = _model(train_split, hidden=8)
    c = m.config
    assert c.gravity == "0.0,0.0,-1.0"  # cubli: MuJoCo's default gravity (0, 0, -9.81)
    assert c.control_dim == 3 and c.dt == pytest.approx(train_split.frame_dt)
    assert c.radius == pytest.approx(m._scene.contact_radius) and c.vel_scale > 0
    assert m.history == 1
    # one layer per stage, shared over p_step iterations: parameters do not grow with p_step
    assert _model(train_split, hidden=8, p_step=1).parameter_count() == m.parameter_count()
    with pytest.raises(ValueError, match="noise"):
        SGNNConfig(noise="loud")
    with pytest.raises(ValueError, match="gravity"):
        SGNNConfig(gravity="down")


def test_shapes_initial_state_and_static_nodes(train_split):
    d = train_split
    m = _model(d, hidden=8, p_step=2)
    s = m.initial_state(d, np.array([0, 1]), 5)
    assert s.x.shape == s.v.shape == (2, d.x.shape[2], 3)
    # the input velocity is the finite difference of the frames before
    torch.testing.assert_close(s.v, torch.from_numpy((d.x[[0, 1], 5] - d.x[[0, 1], 4]) / d.frame_dt))
    with torch.no_grad():
        n = m.step(s, torch.from_numpy(d.ctrl[[0, 1], 5]))
    assert n.x.shape == n.v.shape == s.x.shape and torch.isfinite(n.x).all()
    static = torch.from_numpy(np.asarray(d.static["node_static"], bool))
    assert torch.equal(n.x[:, static], s.x[:, static]) and (n.v[:, static] == 0).all()
    # position update of Han et al.: x' = x + dt v'
    torch.testing.assert_close(n.x, s.x + d.frame_dt * n.v)


def test_rotation_about_gravity_and_translation_commute_with_a_step(train_split):
    """Subequivariance: R about the gravity axis (z) and a translation t give
    step(R x + t, R v) = (R x' + t, R v'), with and without the snap; float64, so the stated
    tolerance (1e-10 of the largest velocity, atol on positions 1e-12 m) is rounding only."""
    d = train_split
    for cls in (SGNN, SGNNSnap):
        m = _model(d, cls, hidden=16).double()
        s, ctrl = _state(d, m)
        R, t = _rot([0.0, 0.0, 1.0], 0.83), torch.tensor([0.3, -1.2, 0.05], dtype=torch.float64)
        with torch.no_grad():
            a = m.step(s, ctrl)
            b = m.step(State(s.x @ R.T + t, s.v @ R.T), ctrl)
        scale = a.v.abs().max()
        assert scale > 0
        torch.testing.assert_close(b.v, a.v @ R.T, rtol=0, atol=1e-10 * float(scale))
        torch.testing.assert_close(b.x, a.x @ R.T + t, rtol=0, atol=1e-12)


def test_rotation_about_a_horizontal_axis_is_broken_by_gravity_only(train_split):
    """Tilting the scene (rotation about x) changes the prediction by more than 1e-4 of its
    size: the gravity channel breaks the symmetry. The same model without gravity
    (``gravity='none'``) is equivariant under that tilt (E(3)), to the tolerance above."""
    d = train_split
    R = _rot([1.0, 0.0, 0.0], 0.83)
    errs = {}
    for g in ("auto", "none"):
        m = _model(d, hidden=16, gravity=g).double()
        assert m.has_gravity == (g == "auto")
        s, ctrl = _state(d, m)
        with torch.no_grad():
            a = m.velocity(s.x, s.v, ctrl)
            b = m.velocity(s.x @ R.T, s.v @ R.T, ctrl)
        errs[g] = float((b - a @ R.T).abs().max() / a.abs().max())
    assert errs["auto"] > 1e-4
    assert errs["none"] < 1e-10


def test_noise_recipe_reference_and_corrected(train_split):
    d = train_split
    static = torch.from_numpy(np.asarray(d.static["node_static"], bool))
    pairs = np.repeat(d.pairs(1)[:4], 500, axis=0)  # 2000 scenes: the std to about 2 %
    b = batch_of(d, pairs, "cpu", 1)
    dt = d.frame_dt
    # reference code: one noise vector per scene on the input velocity, std noise / sqrt(2);
    # the input frame moves with it and the target stays the clean next velocity
    m = _model(d, hidden=8)
    p = m.perturb(b, torch.Generator().manual_seed(1))
    n = (p.x - b.x) / dt
    assert (n[:, static] == 0).all()
    nm = n[:, ~static]
    torch.testing.assert_close(nm, nm[:, :1].expand_as(nm), rtol=0, atol=1e-6)  # shared by the scene's nodes
    assert float(nm[:, 0].std()) == pytest.approx(3e-4 / math.sqrt(2), rel=0.05)
    v_in, v_target = m._targets(p)
    v_in0, v_target0 = m._targets(b)
    torch.testing.assert_close(v_in - v_in0, n, rtol=0, atol=1e-4)  # float32 positions / dt
    torch.testing.assert_close(v_target, v_target0, rtol=0, atol=1e-4)
    # corrected (noise_correction, per node): the noisy input plus dt x target lands on the true next position
    m = _model(d, hidden=8, noise_correction=True, noise_per_node=True)
    p = m.perturb(b, torch.Generator().manual_seed(2))
    n = (p.x - b.x)[:, ~static] / dt
    assert float((n - n[:, :1]).abs().max()) > 1e-5  # independent per node
    _, v_target = m._targets(p)
    torch.testing.assert_close(p.x + dt * v_target, b.x_next, rtol=0, atol=1e-6)
    assert not torch.equal(p.x, b.x)


def test_snap_keeps_each_object_rigid_and_training_ignores_it(train_split):
    d = train_split
    plain, snap = _model(d, SGNN, hidden=8), _model(d, SGNNSnap, hidden=8)
    torch.testing.assert_close(dict(plain.state_dict()), dict(snap.state_dict()))
    b = batch_of(d, d.pairs(1)[:3], "cpu", 1)
    torch.testing.assert_close(plain.losses(b)["mse"], snap.losses(b)["mse"], rtol=0, atol=0)
    s, ctrl = _state(d, plain, dtype=torch.float32)
    raw = s
    obj = plain._scene.obj
    ref = plain._scene.ref_shape.float()
    with torch.no_grad():
        for _ in range(5):
            s, raw = snap.step(s, ctrl), plain.step(raw, ctrl)
    moving = ~plain._scene.static
    for o in obj[moving].unique():
        idx = torch.nonzero((obj == o) & moving).flatten()
        if len(idx) < 2:
            continue
        dref = torch.cdist(ref[idx], ref[idx])
        torch.testing.assert_close(torch.cdist(s.x[:, idx], s.x[:, idx]), dref.expand(2, -1, -1), rtol=0, atol=1e-6)
        # five raw steps of the untrained model deform the object (> 100x that): the snap did something
        assert float((torch.cdist(raw.x[:, idx], raw.x[:, idx]) - dref).abs().max()) > 1e-4


def test_snap_model_from_a_trained_sgnn_keeps_weights_and_settings_and_turns_the_snap_on(train_split):
    d = train_split
    plain = _model(d, SGNN, hidden=8, p_step=2)
    with torch.no_grad():
        for p in plain.parameters():
            p.add_(0.01)  # "trained": weights no fresh model has
    snap = SGNNSnap.from_trained(plain)
    assert snap.name == "sgnn-snap" and snap.config.rigid_snap and not plain.config.rigid_snap
    assert snap.config.hidden == 8 and snap.config.p_step == 2
    torch.testing.assert_close(dict(plain.state_dict()), dict(snap.state_dict()), rtol=0, atol=0)
    s, ctrl = _state(d, plain, dtype=torch.float32)
    with torch.no_grad():
        a, b = plain.step(s, ctrl), snap.step(s, ctrl)
    assert not torch.equal(a.x, b.x)  # same net, the snap changes the rollout
    with pytest.raises(ModelError, match="does not share the training"):
        SGNNSnap.from_trained(snap)


def test_bind_refuses_another_actuator_count(train_split):
    m = _model(train_split, hidden=8)
    other = load_split(train_split.path)
    other.ctrl = other.ctrl[..., :2]
    with pytest.raises(ModelError, match="actuators"):
        m.bind(other)


def test_two_batch_overfit(train_split):
    """200 Adam steps (lr 1e-3) alternating over 2 fixed batches of 2 scenes bring the mean loss
    down by at least 20x (measured: ~150x). Hidden 32 and radius 0.1 m keep it to ~10 s."""
    d = train_split
    m = _model(d, hidden=32, radius=0.1)
    bs = [batch_of(d, d.pairs(1)[[10, 150]], "cpu", 1), batch_of(d, d.pairs(1)[[60, 200]], "cpu", 1)]
    opt = torch.optim.Adam(m.parameters(), lr=1e-3)

    def loss():
        with torch.no_grad():
            return sum(m.losses(b)["mse"].item() for b in bs) / 2

    l0 = loss()
    for i in range(200):
        lo = m.losses(bs[i % 2])["mse"]
        opt.zero_grad()
        lo.backward()
        opt.step()
    assert loss() < l0 / 20


def test_train_and_evaluate_through_the_cli(data, tmp_path):
    small = ["--set", "hidden=8", "--set", "p_step=1", "--set", "radius=0.1"]
    common = ["--data", str(data), "--epochs", "1", "--max-steps", "2", "--batch-size", "2",
              "--valid-max-pairs", "4", "--device", "cpu", *small]
    runs = {}
    for name in ("sgnn", "sgnn-snap"):
        out = tmp_path / name
        r = runner.invoke(app, ["train", "--model", name, "--out", str(out), *common])
        assert r.exit_code == 0, r.output
        cfg = json.loads((out / "config.json").read_text())
        assert cfg["lr"] == 1e-4  # the authors' learning rate when no --lr is given
        assert cfg["model"]["rigid_snap"] == (name == "sgnn-snap")
        r = runner.invoke(app, ["evaluate", str(out), "--data", str(data), "--device", "cpu"])
        assert r.exit_code == 0, r.output
        runs[name] = json.loads((out / "evaluation-test.json").read_text())
    a, b = runs["sgnn"]["runs"][0], runs["sgnn-snap"]["runs"][0]
    assert a["model"] == "sgnn" and b["model"] == "sgnn-snap"
    # same seed, same training (the snap acts at rollout only): same one-step error, other rollouts
    assert a["one_step_mse_scaled"] == pytest.approx(b["one_step_mse_scaled"], rel=1e-6)
    g = a["frames_given"]
    assert g == 2 and a["rollout_mse_curve"][g] != b["rollout_mse_curve"][g]
    # a user's mistake is one sentence and exit 2
    r = runner.invoke(app, ["train", "--model", "sgnn", "--out", str(tmp_path / "bad"), *common,
                            "--set", "gravity=down"])
    assert r.exit_code == 2 and "gravity" in r.output

"""Joint constraint module (mdgs.joints): MuJoCo's own states satisfy it, projected states satisfy
the joints as MuJoCo states them (anchors measured independently by mdgs.evaluate.physics from
the compiled model), and an MDGS rollout with it keeps jointed objects together.

Tolerances: the datasets store float32 positions (about 1e-7 relative), so MuJoCo's states
move by at most 1e-6 m (1e-5 relative for velocities) under the projection; projected states are
computed in float64, so anchors coincide to 1e-9 m, and a welded body sits at its MJCF pose
on its parent to 1e-9 (m, and rotation-matrix entries).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from mdgs.data.generate import GenerateConfig, generate
from mdgs.data.split import load_split
from mdgs.evaluate.physics import hinge_anchors, joint_separation
from mdgs.graphs import SceneGraph
from mdgs.joints import joints_of, project_joints
from mdgs.rigid import perturb, twist
from mdgs.structure import kabsch

ROOT = Path(__file__).resolve().parents[1]

# a turntable (hinge) carrying a ball-jointed pendulum and a welded bob (no joint), beside the
# built-in hinge and slide scenes
BALL_WELD = """<mujoco model="ball-weld">
  <option timestep="0.002"/>
  <worldbody>
    <body name="base" pos="0 0 1">
      <joint type="hinge" axis="0 0 1"/>
      <geom type="box" size="0.1 0.1 0.05" density="500"/>
      <body name="arm" pos="0.1 0 -0.05">
        <joint type="ball" pos="0 0 0"/>
        <geom type="box" size="0.03 0.03 0.2" pos="0 0 -0.2" density="500"/>
      </body>
      <body name="bob" pos="-0.2 0 0" quat="0.92 0 0.38 0">
        <geom type="box" size="0.06 0.05 0.04" density="500"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def splits(tmp_path_factory):
    root = tmp_path_factory.mktemp("joints")
    (root / "ball_weld.xml").write_text(BALL_WELD)
    out = {}
    for name, cfg in [
        ("cubli-single", GenerateConfig(scene="cubli-single", preset="tiny", out=str(root / "cubli"))),
        ("cubli-triple", GenerateConfig(scene="cubli-triple", preset="tiny", out=str(root / "cubli3"))),
        ("rotational-center", GenerateConfig(scene="rotational-center", preset="tiny", out=str(root / "rot"))),
        ("hinge_slide_free", GenerateConfig(scene="", mjcf=str(ROOT / "studies" / "hinge_slide_free.xml"),
                                            substeps=10, preset="tiny", out=str(root / "hsf"))),
        ("ball_weld", GenerateConfig(scene="", mjcf=str(root / "ball_weld.xml"), substeps=5, preset="tiny",
                                     out=str(root / "bw"))),
    ]:
        generate(cfg)
        out[name] = load_split(Path(cfg.out) / "test.h5")
    return out


#: the scenes of the fixture; cubli-triple: three hinges on one parent, projected in one batched pass;
#: ball_weld: a tree of two levels (hinge, then ball and weld)
SCENES = ["cubli-single", "cubli-triple", "rotational-center", "hinge_slide_free", "ball_weld"]


def _setup(d):
    sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
    js = joints_of(d.mj_model(), d.static["node_body"], d.static["node_centroid"])
    return sc, js


def _project(x, v, sc, js):
    return project_joints(x, v, js, sc.ref_shape, sc.obj, sc.n_obj, sc.mass)


def _perturbed(d, sc, seed):
    """The last frame of every trajectory with each moving object displaced and re-twisted rigidly (1 cm, 0.1 m/s)."""
    x, v = torch.from_numpy(d.x[:, -1]).double(), torch.from_numpy(d.v[:, -1]).double()
    g = torch.Generator().manual_seed(seed)
    xn, vn = perturb(x, v, 0.01 * torch.randn(x.shape, generator=g, dtype=torch.float64),
                     0.1 * torch.randn(v.shape, generator=g, dtype=torch.float64), sc.obj, sc.n_obj, sc.mass)
    mv = (~sc.static).view(1, -1, 1)
    return torch.where(mv, xn, x), torch.where(mv, vn, v)


def test_joints_are_read_from_the_mjcf(splits):
    kinds = {name: sorted(j.kind for j in _setup(d)[1].joints) for name, d in splits.items()}
    assert kinds["cubli-single"] == ["hinge"]
    assert kinds["cubli-triple"] == ["hinge"] * 3
    assert kinds["rotational-center"].count("hinge") >= 2
    assert kinds["hinge_slide_free"] == ["hinge", "slide"]  # the free box has no joint to enforce
    assert kinds["ball_weld"] == ["ball", "hinge", "weld"]


@pytest.mark.parametrize("name", SCENES)
def test_mujoco_states_already_satisfy_the_joints(splits, name):
    d = splits[name]
    sc, js = _setup(d)
    x, v = torch.from_numpy(d.x[:, -1]).double(), torch.from_numpy(d.v[:, -1]).double()
    xp, vp = _project(x, v, sc, js)
    assert float((xp - x).abs().max()) < 1e-6
    assert float((vp - v).abs().max()) < 1e-5 * max(1.0, float(v.abs().max()))


@pytest.mark.parametrize("name", SCENES)
def test_projection_closes_every_joint_and_is_idempotent(splits, name):
    d = splits[name]
    sc, js = _setup(d)
    x = torch.from_numpy(d.x[:, -1]).double()
    xn, vn = _perturbed(d, sc, 1)
    anchors = hinge_anchors(d.mj_model())  # hinge and ball anchors, from MuJoCo's compiled model
    before = joint_separation(xn.numpy()[None], d.static, anchors).max()
    xp, vp = _project(xn, vn, sc, js)
    after = joint_separation(xp.numpy()[None], d.static, anchors).max()
    if anchors:
        assert before > 1e-3 and after < 1e-9, (before, after)
    xq, vq = _project(xp, vp, sc, js)
    assert float((xq - xp).abs().max()) < 1e-9 and float((vq - vp).abs().max()) < 1e-8
    # every object stays rigid: distances between its nodes are those of the MuJoCo state
    for o in range(sc.n_obj):
        idx = torch.nonzero(sc.obj == o).flatten()
        torch.testing.assert_close(torch.cdist(xp[:, idx], xp[:, idx]), torch.cdist(x[:, idx], x[:, idx]),
                                   rtol=0, atol=1e-6)


@pytest.mark.parametrize("name", SCENES)
def test_projection_on_the_structures_placement_equals_projection_with_its_own_fit(splits, name):
    """MDGS hands the joint projection the placement its structural constraint fitted (``pose``)
    instead of fitting the rigidly placed nodes again: the same projection to float64 round-off, on
    non-rigid (noisy) predictions of every scene, including trees where a parent's pose places a child."""
    from mdgs.structure import align_with_pose

    d = splits[name]
    sc, js = _setup(d)
    xn, vn = _perturbed(d, sc, 2)
    g = torch.Generator().manual_seed(3)
    noisy = xn + 0.003 * torch.randn(xn.shape, generator=g, dtype=torch.float64)  # not rigid any more
    mv = ~sc.static
    aligned, R, t = align_with_pose(noisy, sc.ref_shape, sc.obj, sc.n_obj, mask=mv)
    assert float((aligned - noisy)[:, mv].abs().max()) > 1e-3  # the structure moved the nodes
    a = _project(aligned, vn, sc, js)
    b = project_joints(aligned, vn, js, sc.ref_shape, sc.obj, sc.n_obj, sc.mass, pose=(R, t))
    assert float((a[0] - b[0]).abs().max()) < 1e-9 and float((a[1] - b[1]).abs().max()) < 1e-8


@pytest.mark.parametrize("name", ["cubli-single", "cubli-triple"])
def test_projected_hinge_velocities_rotate_about_the_hinge_axis(splits, name):
    d = splits[name]
    sc, js = _setup(d)
    x, v = torch.from_numpy(d.x[:, -1]).double(), torch.from_numpy(d.v[:, -1]).double()
    g = torch.Generator().manual_seed(2)
    vn = v + 0.3 * torch.randn(v.shape, generator=g, dtype=torch.float64) * (~sc.static).view(1, -1, 1)
    xp, vp = _project(x, vn, sc, js)
    tw = twist(xp, vp, sc.obj, sc.n_obj, sc.mass)
    R, _ = kabsch(sc.ref_shape, xp, sc.obj, sc.n_obj)
    for j in js.joints:
        rel = tw.omega[:, j.child] - tw.omega[:, j.parent]
        axis = R[:, j.child] @ torch.as_tensor(j.axis, dtype=torch.float64)
        # the child turns relative to its parent about the hinge axis only
        assert float(torch.linalg.cross(rel, axis, dim=-1).norm(dim=-1).max()) < 1e-9 * max(1.0, float(rel.norm(dim=-1).max()))
        assert float(rel.norm(dim=-1).max()) > 1e-3  # and it does turn (the check is not vacuous)


def test_projected_weld_keeps_the_welded_pose_below_a_moving_parent(splits):
    """The welded bob of BALL_WELD hangs from the hinged base (a child of a child): after projection its
    pose is its parent's pose composed with the MJCF's body_pos and body quat, read from MuJoCo's compiled
    model, and it turns with its parent."""
    import mujoco

    d = splits["ball_weld"]
    sc, js = _setup(d)
    m = d.mj_model()
    bob, base = (mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in ("bob", "base"))
    obj = {int(b): k for k, b in enumerate(np.unique(d.static["node_body"]))}  # object index of each body
    q0 = np.zeros(9)
    mujoco.mju_quat2Mat(q0, m.body_quat[bob])
    q0, pos = torch.as_tensor(q0.reshape(3, 3)), torch.as_tensor(m.body_pos[bob])

    def weld_error(x):
        R, t = kabsch(sc.ref_shape, x, sc.obj, sc.n_obj)
        Rp, tp = R[:, obj[base]], t[:, obj[base]]
        return max(float((R[:, obj[bob]] - Rp @ q0).abs().max()), float((t[:, obj[bob]] - (Rp @ pos + tp)).abs().max()))

    xn, vn = _perturbed(d, sc, 3)
    xp, vp = _project(xn, vn, sc, js)
    before, after = weld_error(xn), weld_error(xp)
    assert before > 1e-3 and after < 1e-9, (before, after)
    tw = twist(xp, vp, sc.obj, sc.n_obj, sc.mass)
    rel = (tw.omega[:, obj[bob]] - tw.omega[:, obj[base]]).norm(dim=-1).max()
    assert float(rel) < 1e-9 * max(1.0, float(tw.omega[:, obj[base]].norm(dim=-1).max()))


def test_untrained_mdgs_with_joints_keeps_jointed_objects_together(splits):
    from mdgs.models import MODELS, State

    d = splits["hinge_slide_free"]
    torch.manual_seed(0)
    cls = MODELS["mdgs"]
    anchors = hinge_anchors(d.mj_model())
    seps = {}
    for joints in (False, True):
        m = cls.from_data(d, cls.Config(hidden=16, joints=joints, zero_init=False)).eval()  # random outputs
        s = State(torch.from_numpy(d.x[:, 0]), torch.from_numpy(d.v[:, 0]))
        xs = []
        with torch.no_grad():
            for f in range(10):
                s = m.step(s, torch.from_numpy(d.ctrl[:, f]))
                xs.append(s.x.numpy())
        seps[joints] = joint_separation(np.stack(xs, 1), d.static, anchors).max()
    assert seps[False] > 1e-3 and seps[True] < 1e-5, seps  # float32 state: 1e-5 m

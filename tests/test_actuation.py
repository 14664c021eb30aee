"""Motors' known loads (mdgs.actuation): free-body loads give MuJoCo's joint acceleration where the
joint's axis is a free body's principal axis through its mass centre, and a motor's loads sum to
zero; the joint response with the parent held is MuJoCo's ``M^-1 qfrc_actuator`` for one-degree-
of-freedom joints on the world (off-centre axis, a welded child riding along); actuators the module
cannot model are named and skipped; MDGS with ``actuation="prior"`` and the "constant twist +
motors" reference start from that response.

Tolerances: everything is float64 and the inertias are MuJoCo's own, so accelerations agree to
1e-9 relative; the elements' positions are built from MuJoCo's body poses in the test.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch

from mdgs.actuation import (
    actuation_forces,
    coupled_motor_accelerations,
    drives_of,
    motor_accelerations,
)
from mdgs.data.generate import GenerateConfig, generate
from mdgs.data.split import load_split
from mdgs.graphs import SceneGraph
from mdgs.models import MODELS
from mdgs.models.base import State, batch_of
from mdgs.rigid import project, twist

# a tilted disc spinning on a hinge through its centre (a principal axis), a tilted cart on a
# slide, both driven by motors (gear, control and force limits), and a position servo
MOTORS = """<mujoco model="motors">
  <option timestep="0.002" gravity="0 0 0"/>
  <worldbody>
    <body name="disc" pos="0 0 1" quat="0.9 0.3 0.2 0.1">
      <joint name="spin" type="hinge" axis="0 0 1"/>
      <geom type="cylinder" size="0.1 0.02" density="1000"/>
    </body>
    <body name="cart" pos="1 0 1" quat="0.95 0 0.31 0">
      <joint name="rail" type="slide" axis="1 0 0"/>
      <geom type="box" size="0.1 0.05 0.05" density="500"/>
    </body>
    <body name="arm" pos="-1 0 1">
      <joint name="pivot" type="hinge" axis="0 1 0"/>
      <geom type="box" size="0.05 0.05 0.2" density="500"/>
    </body>
    <body name="crank" pos="0 2 1" quat="0.8 0.2 0.5 0.1">
      <joint name="elbow" type="hinge" axis="1 0 0" pos="0 0 0.15" armature="0.01"/>
      <geom type="box" size="0.09 0.07 0.12" density="700"/>
      <body name="load" pos="0.05 0 -0.2" quat="0.9 0.1 0 0.4">
        <geom type="box" size="0.06 0.05 0.04" density="900"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="m_spin" joint="spin" gear="2" ctrlrange="-1 1"/>
    <motor name="m_rail" joint="rail" gear="3" forcerange="-0.5 0.5"/>
    <position name="servo" joint="pivot" kp="10"/>
    <motor name="m_elbow" joint="elbow" gear="1.5"/>
  </actuator>
</mujoco>
"""


# a floating base carrying a driven wheel (armature, axis off its mass centre), a driven slider with a
# ball-jointed bob, a welded plate and a hinged thin pole (its elements on a line): every link kind of
# the coupled response, each motor's load passed on through the tree
TREE = """<mujoco model="tree">
  <option timestep="0.002" gravity="0 0 0"/>
  <worldbody>
    <body name="base" pos="0 0 1" quat="0.9 0.1 0.3 0.2">
      <freejoint/>
      <geom type="box" size="0.2 0.15 0.1" density="800"/>
      <body name="wheel" pos="0.25 0.05 0" quat="0.7 0.7 0 0">
        <joint name="w" type="hinge" axis="0 0 1" pos="0.02 0 0" armature="0.002"/>
        <geom type="cylinder" size="0.08 0.02" density="1200"/>
      </body>
      <body name="slider" pos="-0.1 0 0.15">
        <joint name="s" type="slide" axis="1 0.2 0" armature="0.05"/>
        <geom type="box" size="0.05 0.04 0.03" density="900"/>
        <body name="bob" pos="0 0 0.12">
          <joint name="b" type="ball" pos="0 0 -0.05"/>
          <geom type="sphere" size="0.04" density="700"/>
        </body>
      </body>
      <body name="plate" pos="0 -0.2 0" quat="0.9 0 0 0.4">
        <geom type="box" size="0.06 0.02 0.06" density="600"/>
      </body>
      <body name="pole" pos="0 0.2 0.1">
        <joint name="p" type="hinge" axis="1 0 0" pos="0 0 -0.1"/>
        <geom type="capsule" fromto="0 0 -0.1 0 0 0.2" size="0.015" density="500"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="w" gear="2"/>
    <motor joint="s" gear="5"/>
  </actuator>
</mujoco>
"""


@pytest.fixture(scope="module")
def splits(tmp_path_factory):
    root = tmp_path_factory.mktemp("actuation")
    (root / "motors.xml").write_text(MOTORS)
    (root / "tree.xml").write_text(TREE)
    out = {}
    for name, cfg in [
        ("motors", GenerateConfig(scene="", mjcf=str(root / "motors.xml"), substeps=5, preset="tiny",
                                  out=str(root / "motors"))),
        ("tree", GenerateConfig(scene="", mjcf=str(root / "tree.xml"), substeps=5, preset="tiny",
                                out=str(root / "tree"))),
        ("cubli-triple", GenerateConfig(scene="cubli-triple", preset="tiny", out=str(root / "cubli"))),
    ]:
        generate(cfg)
        out[name] = (load_split(Path(cfg.out) / "train.h5"), load_split(Path(cfg.out) / "test.h5"))
    return out


def _free_response(d, x, ctrl, held=False):
    """(linear, angular) velocity change per unit time [S, 3] of each object under the motors' loads:
    free bodies, or (``held``) each joint with its parent held."""
    sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
    ds = drives_of(d.mj_model(), d.static["node_body"], d.static["node_centroid"])
    mass = sc.mass.double()
    if held:
        acc = motor_accelerations(x, ctrl, ds, sc.ref_shape, sc.obj, sc.n_obj)
        f = acc * mass.view(1, -1, 1)
    else:
        f = actuation_forces(x, ctrl, ds, sc.ref_shape, sc.obj, sc.n_obj, sc.mass)
    tw = twist(x, torch.zeros_like(x), sc.obj, sc.n_obj, mass)
    return (*project(f / mass.view(1, -1, 1), x, tw, sc.obj, sc.n_obj, mass), f, sc, ds)


def test_servos_are_skipped_and_named(splits):
    d = splits["motors"][1]
    ds = drives_of(d.mj_model(), d.static["node_body"], d.static["node_centroid"])
    assert [dr.kind for dr in ds.drives] == ["hinge", "slide", "hinge"]
    assert len(ds.skipped) == 1 and "servo" in ds.skipped[0] and "not a motor" in ds.skipped[0]


def _mujoco_state(d, seed):
    m = d.mj_model()
    m.opt.gravity[:] = 0
    data = mujoco.MjData(m)
    rng = np.random.default_rng(seed)
    data.qpos[:] = rng.normal(size=m.nq)
    for j in range(m.njnt):  # unit quaternions of free and ball joints
        a = m.jnt_qposadr[j] + (3 if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE else 0)
        if m.jnt_type[j] in (mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL):
            data.qpos[a:a + 4] /= np.linalg.norm(data.qpos[a:a + 4])
    data.ctrl[:] = rng.uniform(-2, 2, size=m.nu)  # the spin motor's |ctrl| > 1 is clamped to ctrlrange
    mujoco.mj_forward(m, data)  # qvel = 0: qacc = M^-1 qfrc_actuator
    body, cen = np.asarray(d.static["node_body"]), np.asarray(d.static["node_centroid"])
    x = np.stack([data.xpos[b] + data.xmat[b].reshape(3, 3) @ c for b, c in zip(body, cen, strict=True)])
    return m, data, torch.from_numpy(x)[None], torch.tensor(data.ctrl[None], dtype=torch.float64)


@pytest.mark.parametrize("held", [False, True])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_motor_loads_give_mujocos_joint_acceleration(splits, seed, held):
    d = splits["motors"][1]
    m, data, x, ctrl = _mujoco_state(d, seed)
    body = np.asarray(d.static["node_body"])
    dvc, dw, _, sc, _ = _free_response(d, x, ctrl, held)
    obj = {int(b): k for k, b in enumerate(np.unique(body))}
    disc, cart = obj[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "disc")], obj[
        mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "cart")]
    j_spin, j_rail = (mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n) for n in ("spin", "rail"))
    n_spin = data.xaxis[j_spin]
    n_rail = data.xaxis[j_rail]
    a_spin, a_rail = data.qacc[m.jnt_dofadr[j_spin]], data.qacc[m.jnt_dofadr[j_rail]]
    assert abs(a_spin) > 1 and abs(a_rail) > 0.1  # the motors do push
    np.testing.assert_allclose(dw[0, disc].numpy(), a_spin * n_spin, rtol=1e-9, atol=1e-9 * abs(a_spin))
    np.testing.assert_allclose(dvc[0, cart].numpy(), a_rail * n_rail, rtol=1e-9, atol=1e-9 * abs(a_rail))
    np.testing.assert_allclose(dvc[0, disc].numpy(), 0, atol=1e-9)  # a couple moves no mass centre
    arm = obj[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "arm")]
    assert float(dw[0, arm].abs().max()) == 0.0  # the servo is skipped, not guessed


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_held_joint_response_turns_an_offset_crank_and_its_welded_load_about_the_hinge(splits, seed):
    """MuJoCo's qacc of the elbow (axis off both bodies' mass centres, armature, a welded load):
    the crank and its load turn about the hinge line at qacc, their mass centres on circles about it."""
    d = splits["motors"][1]
    m, data, x, ctrl = _mujoco_state(d, seed)
    dvc, dw, _, sc, _ = _free_response(d, x, ctrl, held=True)
    j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "elbow")
    qacc, n, anchor = data.qacc[m.jnt_dofadr[j]], data.xaxis[j], data.xanchor[j]
    assert abs(qacc) > 1
    obj = {int(b): k for k, b in enumerate(np.unique(d.static["node_body"]))}
    mass = sc.mass.double()
    for name in ("crank", "load"):
        o = obj[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)]
        c = ((mass[sc.obj == o, None] * x[0, sc.obj == o]).sum(0) / mass[sc.obj == o].sum()).numpy()
        np.testing.assert_allclose(dw[0, o].numpy(), qacc * n, rtol=1e-9, atol=1e-9 * abs(qacc))
        np.testing.assert_allclose(dvc[0, o].numpy(), qacc * np.cross(n, c - anchor), rtol=1e-9,
                                   atol=1e-9 * abs(qacc))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_coupled_response_is_mujocos_inverse_mass_matrix_times_the_motor_forces(splits, seed):
    """Every node's acceleration J_i M^-1 qfrc_actuator (mj_solveM; qvel = 0, so no velocity terms): the
    base recoils from both motors, the bob, the plate and the pole are carried (the thin pole's hinge
    placed from its parent); the held response misses the recoil by a sizeable part of the accelerations."""
    d = splits["tree"][1]
    m, data, x, ctrl = _mujoco_state(d, seed)
    sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
    ds = drives_of(m, d.static["node_body"], d.static["node_centroid"])
    assert sorted(lk.kind for lk in ds.links) == ["ball", "free", "hinge", "hinge", "slide", "weld"]
    assert not ds.unlinked and len(ds.drives) == 2
    qacc = np.zeros((1, m.nv))
    mujoco.mj_solveM(m, data, qacc, data.qfrc_actuator.reshape(1, -1).copy())
    jac = np.zeros((3, m.nv))
    expect = []
    for b, y in zip(d.static["node_body"], x[0].numpy(), strict=True):
        mujoco.mj_jac(m, data, jac, None, y, int(b))
        expect.append(jac @ qacc[0])
    expect = np.array(expect)
    got = coupled_motor_accelerations(x, ctrl, ds, sc.ref_shape.double(), sc.obj, sc.n_obj)[0].numpy()
    scale = np.abs(expect).max()
    assert scale > 1
    np.testing.assert_allclose(got, expect, atol=1e-9 * scale)
    held = motor_accelerations(x, ctrl, ds, sc.ref_shape.double(), sc.obj, sc.n_obj)[0].numpy()
    assert np.abs(held - expect).max() > 0.05 * scale


def test_a_motors_loads_sum_to_zero_and_a_wheel_turns_alike_free_or_held(splits):
    d = splits["cubli-triple"][1]
    x = torch.from_numpy(d.x[0, 3:5]).double()
    ctrl = torch.from_numpy(np.array([[0.5, -1.0, 2.0], [12.0, 0.0, -3.0]]))
    dvc, dw, f, sc, ds = _free_response(d, x, ctrl)
    assert len(ds.drives) == 3 and all(dr.kind == "hinge" for dr in ds.drives)
    scale = float(f.abs().max())
    np.testing.assert_allclose(f.sum(1).numpy(), 0, atol=1e-12 * scale)  # internal loads
    cube = ds.drives[0].parent
    assert all(dr.parent == cube for dr in ds.drives) and float(dw[:, cube].norm(dim=-1).min()) > 0
    _, dw_held, f_held, _, _ = _free_response(d, x, ctrl, held=True)
    assert float(f_held[:, sc.obj == cube].abs().max()) == 0.0  # the parent is held
    wheels = [dr.child for dr in ds.drives]  # each wheel's axis is principal, through its centre: the same
    np.testing.assert_allclose(dw_held[:, wheels].numpy(), dw[:, wheels].numpy(), rtol=1e-9,
                               atol=1e-9 * float(dw.abs().max()))  # float32 positions: round-off of the fits


def _untrained_step_twists(tr, te, b, settings: dict) -> tuple[dict, object]:
    """One step of the untrained MDGS (zero_init: g's output starts at zero) from batch ``b`` under each
    named setting -> ``({name: Twist of every object after the step}, the last model)``."""
    cls = MODELS["mdgs"]
    out = {}
    for name, kw in settings.items():
        model = cls.from_data(tr, cls.Config(**kw))
        model.bind(te)
        model.eval()
        sc = model.scene_on("cpu")
        with torch.no_grad():
            p = model.step(State(b.x, b.v), b.ctrl)
        out[name] = twist(p.x.double(), p.v.double(), sc.obj, sc.n_obj, sc.mass.double())
    return out, model


def test_mdgs_motor_prior_starts_from_the_wheels_joint_response(splits):
    tr, te = splits["cubli-triple"]
    b = batch_of(te, te.pairs(0)[:6], "cpu")
    b.ctrl[:] = torch.tensor([3.0, -2.0, 1.0])
    tws, model = _untrained_step_twists(tr, te, b, {act: {"actuation": act} for act in ("none", "prior")})
    omega = {act: tw.omega for act, tw in tws.items()}
    ds = model._drives
    m = te.mj_model()
    for dr in ds.drives:
        bid = int(np.unique(te.static["node_body"])[dr.child])
        q = np.zeros(9)
        mujoco.mju_quat2Mat(q, m.body_iquat[bid])
        q = q.reshape(3, 3)
        i_axis = float(dr.axis @ q @ np.diag(m.body_inertia[bid]) @ q.T @ dr.axis)  # the wheel's axis is principal
        expect = dr.gain * float(b.ctrl[0, dr.actuator]) / i_axis * model.config.dt
        dw = (omega["prior"] - omega["none"])[:, dr.child].numpy()
        np.testing.assert_allclose(np.linalg.norm(dw, axis=-1), abs(expect), rtol=1e-3)


def test_constant_twist_with_motors_turns_only_the_driven_wheels(splits):
    tr, te = splits["cubli-triple"]
    cls = MODELS["constant-twist"]
    b = batch_of(te, te.pairs(0)[:4], "cpu")
    out = {}
    for motors in (False, True):
        ref = cls.from_data(te, cls.Config(motors=motors))
        ref.bind(te)
        for name, ctrl in (("zero", torch.zeros_like(b.ctrl)), ("on", torch.full_like(b.ctrl, 2.0))):
            p = ref.step(State(b.x, b.v), ctrl)
            sc = ref._scene
            out[motors, name] = twist(p.x.double(), p.v.double(), sc.obj, sc.n_obj, sc.mass.double()).omega
    assert torch.equal(out[True, "zero"], out[False, "zero"])  # no control, no change
    dw = (out[True, "on"] - out[False, "on"]).norm(dim=-1)
    ds = drives_of(te.mj_model(), te.static["node_body"], te.static["node_centroid"])
    wheels = [dr.child for dr in ds.drives]
    others = [o for o in range(dw.shape[1]) if o not in wheels]
    assert float(dw[:, wheels].min()) > 1.0 and float(dw[:, others].max()) == 0.0  # the cube keeps its twist


def test_constant_twist_with_joints_keeps_the_wheels_on_their_hinges_and_is_the_untrained_mdgs(splits):
    """The "constant twist + joints" reference: plain constant twist lets a flywheel leave the tumbling
    cube (each keeps its own twist), the projection holds every hinge anchor together (1e-6 m: float32
    node positions of a 0.15 m cube), and an untrained MDGS (zero-initialised head, no motor
    knowledge) simulates the same states (1e-5 m: MDGS steps in float32, the reference in float64)."""
    from mdgs.evaluate.physics import hinge_anchors, joint_separation

    tr, te = splits["cubli-triple"]
    b = batch_of(te, te.pairs(0)[:8], "cpu")
    ct = MODELS["constant-twist"]
    sims = {j: ct.from_data(te, ct.Config(joints=j)) for j in (False, True)}
    net = MODELS["mdgs"].from_data(tr, MODELS["mdgs"].Config())
    sims["mdgs"] = net
    for s in sims.values():
        s.bind(te)
        s.eval()
    # a tumbling cube: give every body the cube's spin on top of what it has
    sc = net.scene_on("cpu")
    w = torch.tensor([0.0, 4.0, 3.0])
    v0 = b.v + torch.linalg.cross(w.expand_as(b.x), b.x - b.x.mean(1, keepdim=True), dim=-1)
    traj = {}
    for name, s in sims.items():
        st = State(b.x, v0)
        xs = []
        with torch.no_grad():
            for _ in range(20):
                st = s.step(st, torch.zeros_like(b.ctrl))
                xs.append(st.x)
        traj[name] = torch.stack(xs, 1).double().numpy()
    anchors = hinge_anchors(te.mj_model())
    sep = {k: float(joint_separation(x, te.static, anchors).max()) for k, x in traj.items()}
    assert sep[False] > 1e-3, sep
    assert sep[True] < 1e-6 and sep["mdgs"] < 1e-5, sep
    moving = ~sc.static.numpy()
    np.testing.assert_allclose(traj["mdgs"][:, :, moving], traj[True][:, :, moving], atol=1e-5)


def test_untrained_coupled_mdgs_is_constant_twist_plus_coupled_motors_and_turns_the_cube(splits):
    """``actuation="coupled"`` untrained steps as the "constant twist + coupled motors + joints" reference
    (1e-5 m over 10 steps: float32 against float64), and unlike the held prior it turns the cube."""
    tr, te = splits["cubli-triple"]
    b = batch_of(te, te.pairs(0)[:4], "cpu")
    ctrl = torch.tensor([[3.0, -2.0, 1.0]]).expand_as(b.ctrl)
    ct = MODELS["constant-twist"]
    ref = ct.from_data(te, ct.Config(motors=True, joints=True, coupled=True))
    mdgs = {a: MODELS["mdgs"].from_data(tr, MODELS["mdgs"].Config(actuation=a)) for a in ("prior", "coupled")}
    traj = {}
    for name, sim in (("ref", ref), *mdgs.items()):
        sim.bind(te)
        sim.eval()
        st, xs = State(b.x, b.v), []
        with torch.no_grad():
            for _ in range(10):
                st = sim.step(st, ctrl)
                xs.append(st.x)
        traj[name] = torch.stack(xs, 1).double()
    sc = mdgs["coupled"].scene_on("cpu")
    moving = ~sc.static
    np.testing.assert_allclose(traj["coupled"][:, :, moving].numpy(), traj["ref"][:, :, moving].numpy(), atol=1e-5)
    cube = drives_of(te.mj_model(), te.static["node_body"], te.static["node_centroid"]).drives[0].parent
    on_cube = sc.obj == cube
    held_gap = float((traj["prior"][:, -1, on_cube] - traj["ref"][:, -1, on_cube]).norm(dim=-1).max())
    assert held_gap > 1e-3, held_gap  # the held prior leaves the cube where constant twist puts it


def test_relative_loss_of_the_untrained_prior_model_is_constant_twist_plus_motors_against_itself(splits):
    """``loss="relative"`` divides each pair's Eq. (10) by that of the zero output (constant twist plus
    the motors' prior) plus the batch median; for an untrained MDGS, whose output is that zero output,
    it is mean(r / (r + median r)) with r the "constant twist + motors" reference's own pair errors
    (1e-4 relative: MDGS steps in float32). The Huber form is half of Eq. (10) where every scaled
    residual is below its delta, and |d| - delta / 2 beyond."""
    from mdgs.losses import pair_mse

    tr, te = splits["cubli-triple"]
    b = batch_of(te, te.pairs(0)[:16], "cpu")
    b.ctrl[:] = torch.tensor([3.0, -2.0, 1.0])
    cls = MODELS["mdgs"]
    rel = cls.from_data(tr, cls.Config(actuation="prior", loss="relative"))
    rel.bind(te)
    sc = rel.scene_on("cpu")
    ct = MODELS["constant-twist"].from_data(te, MODELS["constant-twist"].Config(motors=True))
    ct.bind(te)
    q = ct.step(State(b.x, b.v), b.ctrl)
    r = pair_mse(q.x, q.v, b.x_next, b.v_next, ~sc.static, *rel.scales(sc, "cpu"))
    with torch.no_grad():
        got = float(rel.losses(b)["mse"])
    assert got == pytest.approx(float((r / (r + r.median())).mean()), rel=1e-4)
    # Huber: half of Eq. (10) below delta (1 in the scaled units), linear beyond it
    from mdgs.losses import huber_loss, mse_loss

    x, v = torch.zeros(2, 5, 3), torch.zeros(2, 5, 3)
    small, big = torch.full_like(x, 0.3), torch.full_like(x, 30.0)
    assert float(huber_loss(x, v, small * 2e-3, small * 5.0, None, 2e-3, 5.0)) == pytest.approx(
        0.5 * float(mse_loss(x, v, small * 2e-3, small * 5.0, None, 2e-3, 5.0)))
    assert float(huber_loss(x, v, big * 2e-3, big * 5.0, None, 2e-3, 5.0)) == pytest.approx(30.0 - 0.5)


def test_mdgs_gravity_prior_adds_free_fall_over_one_frame_to_every_moving_body(splits):
    """The untrained MDGS with ``gravity_prior`` is constant twist plus free fall: every moving body's
    mass-centre velocity gains g dt (MJCF opt.gravity, 9.81 m/s^2 x 0.01 s) and its angular velocity
    is unchanged, joints included (a uniform velocity change keeps every hinge), to float32 round-off."""
    tr, te = splits["cubli-triple"]
    cls = MODELS["mdgs"]
    b = batch_of(te, te.pairs(0)[:6], "cpu")
    tw, model = _untrained_step_twists(tr, te, b, {prior: {"gravity_prior": prior} for prior in (False, True)})
    sc = model.scene_on("cpu")
    g_dt = np.asarray(te.mj_model().opt.gravity) * model.config.dt
    assert abs(g_dt[2] + 9.81 * 0.01) < 1e-9
    mv = torch.unique(sc.obj[sc.moving("cpu")])  # the static floor keeps still
    assert 0 < len(mv) < sc.n_obj
    dvc = (tw[True].vc - tw[False].vc)[:, mv].numpy()
    np.testing.assert_allclose(dvc, np.broadcast_to(g_dt, dvc.shape), atol=2e-5)
    np.testing.assert_allclose(tw[True].omega.numpy(), tw[False].omega.numpy(), atol=2e-4)
    still = [o for o in range(sc.n_obj) if o not in set(mv.tolist())]
    np.testing.assert_allclose(tw[True].vc[:, still].numpy(), tw[False].vc[:, still].numpy(), atol=1e-6)
    with pytest.raises(ValueError, match="gravity_prior must be true or false"):
        cls.Config(gravity_prior="yes")


def test_twist_integrator_reads_each_objects_outputs_on_its_own_scale_and_starts_from_the_same_prior(splits):
    """``integrator="twist"`` with ``object_scales``: each object's output scales are its own spread of
    twist increments in the training split (recomputed here from the data: the Cubli's cube turns far
    less per frame than its flywheels, so its angular scale is smaller); an output of one on every node
    changes each object's angular velocity by exactly its own scale; and the untrained model (zero
    output) with the motors' prior steps to the same twists as the rigid integrator's untrained model
    with it (both: constant twist plus the prior's rigid part; 1e-4 rad/s, float32)."""
    from mdgs.models.integrators import twist_space

    tr, te = splits["cubli-triple"]
    m = MODELS["mdgs"].from_data(tr, MODELS["mdgs"].Config(integrator="twist", actuation="prior"))
    m.bind(te)
    c, sc = m.config, m.scene_on("cpu")
    pairs = tr.pairs()
    a = twist(torch.from_numpy(tr.x[pairs[:, 0], pairs[:, 1]]).double(), torch.from_numpy(tr.v[pairs[:, 0], pairs[:, 1]]).double(),
              sc.obj, sc.n_obj, sc.mass.double())
    b = twist(torch.from_numpy(tr.x[pairs[:, 0], pairs[:, 1] + 1]).double(),
              torch.from_numpy(tr.v[pairs[:, 0], pairs[:, 1] + 1]).double(), sc.obj, sc.n_obj, sc.mass.double())
    moving = sorted(set(sc.obj[~sc.static].tolist()))
    dw_std = {o: float((b.omega - a.omega)[:, o].std()) for o in moving}
    bare = MODELS["mdgs"].from_data(tr, MODELS["mdgs"].Config(integrator="twist")).config  # no prior
    assert len(c.dw_scales) == len(c.dvc_scales) == len(bare.dw_scales) == sc.n_obj
    cube = drives_of(te.mj_model(), te.static["node_body"], te.static["node_centroid"]).drives[0].parent
    wheels = [o for o in moving if o != cube]
    assert bare.dw_scales[cube] < min(bare.dw_scales[o] for o in wheels)
    for o in moving:  # without a prior: each body's spread of angular increments in the data
        assert bare.dw_scales[o] == pytest.approx(dw_std[o], rel=0.05), (o, bare.dw_scales[o], dw_std[o])
    assert c.dw_scales == bare.dw_scales  # the data's spreads, whatever the priors

    bt = batch_of(te, te.pairs(0)[:4], "cpu")
    svc, sw = m.twist_scales(sc, "cpu")
    out = torch.cat([torch.ones_like(bt.x), torch.zeros_like(bt.x)], -1)
    x1, v1 = twist_space(bt.x, bt.v, out, sc, dt=c.dt, dvc_scale=svc, dw_scale=sw)
    t0, t1 = (twist(x.double(), v.double(), sc.obj, sc.n_obj, sc.mass.double()) for x, v in ((bt.x, bt.v), (x1, v1)))
    for o in moving:
        np.testing.assert_allclose((t1.omega - t0.omega)[:, o].numpy(), c.dw_scales[o], rtol=1e-4)

    rigid = MODELS["mdgs"].from_data(tr, MODELS["mdgs"].Config(actuation="prior"))
    rigid.bind(te)
    ctrl = torch.tensor([[3.0, -2.0, 1.0]]).expand_as(bt.ctrl)
    steps = {}
    with torch.no_grad():
        for name, sim in (("twist", m), ("rigid", rigid)):
            p = sim(sc, bt.x, bt.v, sim.node_controls(ctrl), ctrl=ctrl)
            steps[name] = twist(p.x.double(), p.v.double(), sc.obj, sc.n_obj, sc.mass.double())
    for k in ("vc", "omega"):
        got, want = getattr(steps["twist"], k)[:, moving], getattr(steps["rigid"], k)[:, moving]
        np.testing.assert_allclose(got.numpy(), want.numpy(), atol=1e-4)
    assert float((steps["rigid"].omega - t0.omega)[:, wheels].abs().max()) > 1.0  # the prior did turn the wheels

"""The whole tree's forward dynamics (:func:`mdgs.actuation.coupled_motor_accelerations` given velocities).

What is checked, against sources independent of the code: in free flight the accelerations of the
Cubli's cube and flywheels (gravity, motors, gyroscopic and joint velocity terms) are MuJoCo's own
(``mj_objectAcceleration`` after ``mj_rnePostConstraint``); on the floor a box follows the
textbook: at rest on a face it stays, held on an edge it falls as a pendulum about the edge
(``alpha = M g d sin(phi) / (I_c + M d^2)``), tipping up from a face it is let go on the rising side
and pulled back by gravity alone, a corner about to strike the floor is stopped within the frame,
sliding it decelerates at ``mu g`` (Coulomb) or, slow enough, is stopped, and a lifted box falls
freely. The "rigid tree" reference and an untrained MDGS with
``actuation = "dynamics"`` simulate the same steps.

Tolerances: float64 throughout and MuJoCo's own inertias, so free flight agrees to 1e-9 of the
largest acceleration; on the floor the held corners are compliant by ``CONTACT_COMPLIANCE``
(1e-6 m/s^2 per N) against loads of a few newtons, so 1e-4 relative (and m/s^2) is far above the
compliance's effect and far below any wrong term (gravity alone is 9.81).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from mdgs.actuation import coupled_motor_accelerations, drives_of
from mdgs.data.split import load_split
from mdgs.graphs import SceneGraph
from mdgs.models import MODELS
from mdgs.models.base import State, batch_of
from mdgs.rigid import project, twist

H = 0.05  # half side of the test box (m)
BOX = f"""<mujoco model="box">
  <option gravity="0 0 -9.81"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="box" pos="0 0 1">
      <freejoint/>
      <geom type="box" size="{H} {H} {H}" mass="2"/>
    </body>
  </worldbody>
</mujoco>
"""
G = 9.81


def _box_nodes(model):
    """Eight elements at the box's half-corners: node body [8], centroids in the body frame [8, 3]."""
    signs = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float)
    return np.ones(8, int), 0.5 * H * signs


def _box_state(R, t, w=(0.0, 0.0, 0.0), vc=(0.0, 0.0, 0.0), xml=BOX):
    """The test box at pose (R, t) with twist (vc at its centre, w): its drives, nodes x and velocities v [1, 8, 3],
    objects seg [8], element masses [8] and nodes in its body frame ref [8, 3]."""
    m = mujoco.MjModel.from_xml_string(xml)
    nb, ref = _box_nodes(m)
    x = torch.tensor(ref @ R.T + t)[None]
    v = torch.tensor(np.asarray(vc) + np.cross(np.asarray(w), ref @ R.T))[None]
    return drives_of(m, nb, ref), x, v, torch.zeros(8, dtype=torch.long), torch.full((8,), 0.25, dtype=torch.float64), ref


def _box_acc(R, t, w=(0.0, 0.0, 0.0), vc=(0.0, 0.0, 0.0), dt=0.01, xml=BOX):
    """Node accelerations [8, 3] of the test box at pose (R, t) with twist (vc at its centre, w)."""
    ds, x, v, seg, mass, ref = _box_state(R, t, w, vc, xml)
    acc = coupled_motor_accelerations(x, torch.zeros(1, 0), ds, torch.tensor(ref), seg, 1, v=v, mass=mass, dt=dt)
    a, alpha = project(acc, x, twist(x, v, seg, 1, mass), seg, 1, mass)
    return acc[0].numpy(), a[0, 0].numpy(), alpha[0, 0].numpy(), x[0].numpy()


def _rot_x(phi):
    c, s = np.cos(phi), np.sin(phi)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def test_free_flight_accelerations_are_mujocos_with_gravity_motors_gyroscopic_and_joint_velocity_terms(tiny_cubli):
    d = load_split(tiny_cubli / "test.h5")
    m = d.mj_model()
    data = mujoco.MjData(m)
    sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
    ds = drives_of(m, d.static["node_body"], d.static["node_centroid"])
    rng = np.random.default_rng(0)
    nb, cen = d.static["node_body"], d.static["node_centroid"]
    for ctrl in (np.zeros(3), np.array([5.0, -3.0, 2.0]), np.array([0.0, 12.0, -12.0])):
        data.qpos[:] = m.qpos0
        data.qpos[2] = 1.0  # far above the floor
        q = rng.normal(size=4)
        data.qpos[3:7] = q / np.linalg.norm(q)
        data.qvel[:] = rng.normal(size=m.nv) * np.r_[np.full(6, 2.0), np.full(m.nv - 6, 300.0)]  # wheels fast
        data.ctrl[:] = ctrl
        mujoco.mj_forward(m, data)
        mujoco.mj_rnePostConstraint(m, data)
        x = np.array([data.xpos[b] + data.xmat[b].reshape(3, 3) @ cen[i] for i, b in enumerate(nb)])
        jac, v = np.zeros((3, m.nv)), []
        for i, b in enumerate(nb):
            mujoco.mj_jac(m, data, jac, None, x[i], int(b))
            v.append(jac @ data.qvel)
        got = coupled_motor_accelerations(torch.tensor(x)[None], torch.tensor(ctrl)[None], ds, sc.ref_shape.double(),
                                          sc.obj, sc.n_obj, v=torch.tensor(np.array(v))[None],
                                          mass=sc.mass.double(), dt=0.01)[0].numpy()
        expect = np.zeros_like(x)
        for i, b in enumerate(nb):
            if b == 0:
                continue
            res = np.zeros(6)  # [angular; linear at the mass centre], MuJoCo's with gravity as a lift
            mujoco.mj_objectAcceleration(m, data, mujoco.mjtObj.mjOBJ_BODY, int(b), res, 0)
            expect[i] = res[3:] + m.opt.gravity + np.cross(res[:3], x[i] - data.xipos[b])
        scale = np.abs(expect).max()
        assert scale > 10
        np.testing.assert_allclose(got, expect, atol=1e-9 * scale)


def test_a_box_resting_on_a_face_stays_at_rest():
    acc, a, alpha, _ = _box_acc(np.eye(3), np.array([0, 0, H]))
    assert np.abs(acc).max() < 1e-4


def test_a_lifted_box_falls_freely():
    acc, a, alpha, _ = _box_acc(_rot_x(0.3), np.array([0, 0, H * 2]))
    np.testing.assert_allclose(acc, np.tile([0, 0, -G], (8, 1)), atol=1e-9)


@pytest.mark.parametrize("phi", [0.05, 0.3, -0.2])
def test_a_box_held_on_an_edge_falls_as_a_pendulum_about_it(phi):
    """Edge along x at the origin, the box's centre at distance d = H sqrt(2) from it, tilted by phi
    from straight above it: alpha_x = -M g d sin(phi) / (I_c + M d^2) = -3 sqrt(2) g sin(phi) / (8 H)
    (sign: a tilt towards +y falls further towards +y, a negative turn about x)."""
    R = _rot_x(np.pi / 4 - phi)  # the edge (y, z) = (-H, -H) of the body goes to the world's origin
    t = -R @ np.array([0, -H, -H])
    _, a, alpha, _ = _box_acc(R, t)
    expect = -3 * np.sqrt(2) * G * np.sin(phi) / (8 * H)
    np.testing.assert_allclose(alpha, [expect, 0, 0], atol=1e-4 * abs(expect) + 1e-9)
    np.testing.assert_allclose(a, np.cross(alpha, t), atol=1e-4 * np.abs(a).max() + 1e-9)  # the edge holds


def test_a_box_tipping_up_from_a_face_is_let_go_where_it_rises_and_gravity_pulls_it_back():
    """Flat on its face, turning about the edge (y, z) = (-H, 0) at 3 rad/s (the far edge rising): the
    rising corners are let go (held, they would pull the box down), and about the held edge gravity
    alone decelerates it, alpha = -M g H / (8 M H^2 / 3) = -3 g / (8 H)."""
    w = np.array([3.0, 0.0, 0.0])  # positive about x: the +y side rises
    t = np.array([0, 0, H])
    vc = np.cross(w, t - np.array([0, -H, 0]))  # the centre turns about the edge
    _, a, alpha, _ = _box_acc(np.eye(3), t, w=w, vc=vc)
    expect = -3 * G / (8 * H)
    np.testing.assert_allclose(alpha, [expect, 0, 0], atol=1e-4 * abs(expect))


def test_a_corner_about_to_strike_the_floor_is_stopped_within_the_frame():
    """Falling at 2 m/s from 5 mm above the floor, with dt = 10 ms the box would pass the floor: its
    lowest face is held and stopped over the frame, a = +v / dt = 200 m/s^2 (no rebound, no rotation)."""
    acc, a, alpha, _ = _box_acc(np.eye(3), np.array([0, 0, H + 0.005]), vc=np.array([0, 0, -2.0]), dt=0.01)
    np.testing.assert_allclose(a, [0, 0, 200.0], atol=1e-2)
    np.testing.assert_allclose(alpha, 0, atol=1e-6)


@pytest.mark.parametrize("speed", [1.0, 0.05])
def test_a_box_sliding_on_its_face_feels_coulomb_friction_or_is_stopped_when_friction_can_stop_it(speed):
    """Sliding along x on its face (MuJoCo's default friction 1 for box and floor, so mu = 1): faster than
    friction can stop within the frame (mu g dt = 0.098 m/s at dt = 10 ms) it decelerates at mu g = 9.81
    m/s^2 and stays on its face (the front corners take more of its weight, no turn); slower, its
    corners stick and it stops over the frame, a = -v / dt."""
    _, a, alpha, _ = _box_acc(np.eye(3), np.array([0, 0, H]), vc=(speed, 0.0, 0.0), dt=0.01)
    expect = -G if speed > G * 0.01 else -speed / 0.01
    np.testing.assert_allclose(a, [expect, 0, 0], atol=1e-4 * G)
    np.testing.assert_allclose(alpha, 0, atol=1e-3)


def test_the_compiled_forward_dynamics_solves_with_static_shapes_and_gives_the_eager_accelerations(tiny_cubli):
    """Under ``torch.compile`` the forward dynamics gives every contact candidate a slot and runs all
    ``CONTACT_PASSES`` passes (shapes that do not follow the state, so the step is one graph and a CUDA
    graph can replay it); eagerly it solves only the held candidates and stops when none pulls. Both must
    give the same accelerations: compared here (dynamo's own ``eager`` backend, so only the tracing
    differs, fullgraph: no graph break allowed) on boxes resting, tipping up (a pass lets the rising
    corners go), striking the floor and sliding, and over 20 frames of the Cubli's rigid tree, bound again halfway
    (traced once: a recompile is an error). Tolerance:
    the solves are float64 and differ in size, 1e-9 of the acceleration's scale."""
    m = mujoco.MjModel.from_xml_string(BOX)
    nb, ref = _box_nodes(m)
    ds = drives_of(m, nb, ref)
    seg, mass = torch.zeros(8, dtype=torch.long), torch.full((8,), 0.25, dtype=torch.float64)
    compiled = torch.compile(coupled_motor_accelerations, backend="eager", fullgraph=True)
    cases = [(np.eye(3), [0, 0, H], [0, 0, 0], [0, 0, 0]),  # resting on a face
             (np.eye(3), [0, 0, H], [3.0, 0, 0], np.cross([3.0, 0, 0], [0, H, H])),  # tipping about an edge
             (np.eye(3), [0, 0, H + 0.005], [0, 0, 0], [0, 0, -2.0]),  # about to strike
             (np.eye(3), [0, 0, H], [0, 0, 0], [1.0, 0, 0]),  # sliding
             (_rot_x(0.4), [0, 0, 0.08], [0.5, 1.0, 0], [0, 0.2, -0.5])]  # on an edge, turning
    for R, t, w, vc in cases:
        x = torch.tensor(ref @ R.T + np.asarray(t, float))[None]
        v = torch.tensor(np.asarray(vc, float) + np.cross(np.asarray(w, float), ref @ R.T))[None]
        args = (x, torch.zeros(1, 0), ds, torch.tensor(ref), seg, 1)
        eager = coupled_motor_accelerations(*args, v=v, mass=mass, dt=0.01)
        got = compiled(*args, v=v, mass=mass, dt=0.01)
        np.testing.assert_allclose(got.numpy(), eager.numpy(), rtol=0, atol=1e-9 * max(1.0, float(eager.abs().max())))
    te = load_split(tiny_cubli / "test.h5")
    tree = MODELS["constant-twist"].from_data(te, MODELS["constant-twist"].Config(dynamics=True)).eval()
    tree.bind(te)
    traj = np.arange(te.x.shape[0])
    a = b = tree.initial_state(te, traj, 0)
    step = torch.compile(type(tree).step.__get__(tree), backend="eager", fullgraph=True)
    with torch._dynamo.config.patch(error_on_recompile=True):  # one graph, kept when the scene is bound again
        for f in range(20):
            ctrl = torch.from_numpy(te.ctrl[traj, f])
            a, b = tree.step(a, ctrl), step(b, ctrl)
            if f == 9:
                tree.bind(te)  # as every rollout and timing does: new scene arrays, the same constants
    assert float(a.v.abs().max()) > 0.1  # the Cubli moved
    np.testing.assert_allclose(b.x.numpy(), a.x.numpy(), rtol=0, atol=1e-5)  # float32 states, 20 frames


@pytest.mark.parametrize(("trapezoidal", "prior_input", "push", "substeps"), [
    (False, False, False, 1), (True, False, False, 1), (True, True, False, 1), (True, False, True, 1),
    (True, True, True, 4), (False, False, False, 3)])
def test_untrained_dynamics_mdgs_steps_as_the_rigid_tree_reference(tiny_cubli, trapezoidal, prior_input, push,
                                                                   substeps):
    """``actuation="dynamics"`` untrained is the "rigid tree + joints" reference, with the trapezoidal
    step as with the semi-implicit one, with g reading the prior's increment, both pushed out of the
    floor, and both in substeps (1e-5 m over 10 steps: float32 against float64)."""
    from mdgs.evaluate import reference_label

    tr, te = load_split(tiny_cubli / "train.h5"), load_split(tiny_cubli / "test.h5")
    b = batch_of(te, te.pairs(0)[:4], "cpu")
    ct = MODELS["constant-twist"]
    ref = ct.from_data(te, ct.Config(dynamics=True, joints=True, trapezoidal=trapezoidal, push_out=push,
                                     substeps=substeps))
    assert reference_label(ref) == ("rigid tree + joints" + (", trapezoidal" if trapezoidal else "")
                                    + (", push-out" if push else "") + (f", {substeps} substeps" if substeps > 1 else ""))
    net = MODELS["mdgs"].from_data(tr, MODELS["mdgs"].Config(actuation="dynamics", trapezoidal=trapezoidal,
                                                              prior_input=prior_input, push_out=push,
                                                              prior_substeps=substeps))
    traj = {}
    for name, sim in (("ref", ref), ("mdgs", net)):
        sim.bind(te)
        sim.eval()
        st, xs = State(b.x, b.v), []
        with torch.no_grad():
            for _ in range(10):
                st = sim.step(st, b.ctrl)
                xs.append(st.x)
        traj[name] = torch.stack(xs, 1).double()
    moving = ~net.scene_on("cpu").static
    np.testing.assert_allclose(traj["mdgs"][:, :, moving].numpy(), traj["ref"][:, :, moving].numpy(), atol=1e-5)


def test_g_reads_the_priors_increment_with_prior_input_and_needs_a_prior(tiny_cubli):
    """With ``prior_input`` g's input gains the prior's node velocity increment over dt in units of
    ``dv_scale``: g's first layer sees three more features, and they are the rigid tree's step (the
    same increment the zero output adds). Without a prior the setting is refused."""
    tr, te = load_split(tiny_cubli / "train.h5"), load_split(tiny_cubli / "test.h5")
    cfg = MODELS["mdgs"].Config(actuation="dynamics", prior_input=True)
    net, plain = (MODELS["mdgs"].from_data(tr, c) for c in (cfg, MODELS["mdgs"].Config(actuation="dynamics")))
    assert net.state.lins[0].in_features == plain.state.lins[0].in_features + 3
    net.bind(te)
    b = batch_of(te, te.pairs(0)[:3], "cpu")
    sc = net.scene_on("cpu")
    seen = {}
    net.state.register_forward_pre_hook(lambda mod, args: seen.update(g_in=args[1]))
    with torch.no_grad():
        net(sc, b.x, b.v, net.node_controls(b.ctrl), ctrl=b.ctrl)
    (prior,) = net._priors(sc, b.x, b.v, b.ctrl)
    sv = net.scales(sc, "cpu")[1]
    np.testing.assert_allclose(seen["g_in"][..., -3:].numpy(), (prior / sv).numpy(), rtol=1e-6, atol=1e-7)
    assert float(prior[:, ~sc.static].abs().max()) > 0  # the Cubli's tree moves under gravity and motors
    with pytest.raises(ValueError, match="prior_input = true needs a prior"):
        MODELS["mdgs"].Config(prior_input=True)


def test_fade_leaves_a_training_state_to_g_and_a_state_far_outside_the_data_to_the_prior(tiny_cubli):
    """With ``fade`` g's correction is kept where every node feature lies inside the training split's
    range and vanishes where the state is far outside it (the Cubli lifted 10 m into the air, 100s of
    standard deviations of height): there the step is the rigid tree's, as with g's output zeroed."""
    import copy

    tr = load_split(tiny_cubli / "train.h5")
    net = MODELS["mdgs"].from_data(tr, MODELS["mdgs"].Config(actuation="dynamics", fade=1.0))
    assert bool((net.z_lo <= net.z_hi).all()) and bool(torch.isfinite(net.z_lo).all())
    torch.nn.init.normal_(net.state.lins[-1].weight, std=0.1)  # g outputs something
    start = copy.deepcopy(net)
    start.state.zero_output()
    b = batch_of(tr, tr.pairs(0)[:3], "cpu")
    moving = ~net.scene_on("cpu").static
    lift = torch.zeros_like(b.x)
    lift[:, moving, 2] = 10.0
    with torch.no_grad():
        inside = [m.step(State(b.x, b.v), b.ctrl).v for m in (net, start)]
        outside = [m.step(State(b.x + lift, b.v), b.ctrl).v for m in (net, start)]
    assert float((inside[0] - inside[1]).abs().max()) > 1e-3
    np.testing.assert_allclose(outside[0].numpy(), outside[1].numpy(), atol=1e-6)
    with pytest.raises(ValueError, match="fade must be"):
        MODELS["mdgs"].Config(fade=-1.0)


def test_residual_scales_are_the_robust_spread_of_what_g_adds_to_the_rigid_tree(tiny_cubli):
    """``scales = "residual"``: ``dv_scale`` is ``1.4826 median |r|`` of the training pairs' node velocity
    residuals ``r`` against the rigid-tree reference's step (stepped here by the reference, not by MDGS; 5e-3
    relative: the states are float32, so velocities of about 1 m/s carry 1e-7 m/s of round-off, a few
    thousandths of a 5e-5 m/s residual), far below the increments' std (the tree does most of the frame); a value given
    is kept, and the twist integrator, whose outputs are twists, is refused."""
    from mdgs.models.mdgs import RESIDUAL_PAIRS

    tr = load_split(tiny_cubli / "train.h5")
    md, ct = MODELS["mdgs"], MODELS["constant-twist"]
    settings = dict(actuation="dynamics", trapezoidal=True, prior_substeps=2)
    res = md.resolve_config(md.Config(**settings, scales="residual"), tr)
    inc = md.resolve_config(md.Config(**settings), tr)
    ref = ct.from_data(tr, ct.Config(dynamics=True, joints=True, trapezoidal=True, substeps=2))
    ref.bind(tr)
    pairs = tr.pairs(0)
    pairs = pairs[np.linspace(0, len(pairs) - 1, min(RESIDUAL_PAIRS, len(pairs))).astype(int)]
    b = batch_of(tr, pairs, "cpu")
    with torch.no_grad():
        v1 = ref.step(State(b.x, b.v), b.ctrl).v
    r = (b.v_next - v1)[:, tr.moving].double().numpy()
    assert res.dv_scale == pytest.approx(1.4826 * np.median(np.abs(r)), rel=5e-3)
    assert res.dv_scale < inc.dv_scale / 10 and res.dx_scale < inc.dx_scale
    assert len(res.dv_scales) == len(inc.dv_scales) and all(a < b for a, b in zip(res.dv_scales[1:], inc.dv_scales[1:], strict=True))
    assert md.resolve_config(md.Config(**settings, scales="residual", dv_scale=0.5), tr).dv_scale == 0.5
    with pytest.raises(ValueError, match="twist"):
        md.Config(integrator="twist", scales="residual")
    with pytest.raises(ValueError, match="scales must be one of"):
        md.Config(scales="median")


def test_gravity_prior_with_the_dynamics_prior_is_refused():
    with pytest.raises(ValueError, match="already adds gravity"):
        MODELS["mdgs"].Config(actuation="dynamics", gravity_prior=True)


def test_the_rigid_tree_is_a_reference_of_mdgs_evaluate_and_does_not_take_the_motors_twice():
    import typer

    from mdgs.cli.evaluate import _parse_reference

    assert _parse_reference("constant-twist:dynamics+joints") == ("constant-twist", {"dynamics": True, "joints": True})
    assert _parse_reference("constant-twist:dynamics+joints+trapezoidal")[1] == {"dynamics": True, "joints": True,
                                                                               "trapezoidal": True}
    assert _parse_reference("constant-twist:dynamics+joints+trapezoidal+push-out")[1] == {
        "dynamics": True, "joints": True, "trapezoidal": True, "push_out": True}
    assert _parse_reference("constant-twist:dynamics+joints+substeps=4")[1] == {"dynamics": True, "joints": True,
                                                                                "substeps": 4}
    assert _parse_reference("constant-twist:dynamics+joints+substeps=4+implicit-gyroscopic")[1] == {
        "dynamics": True, "joints": True, "substeps": 4, "gyroscopic": "implicit"}
    assert _parse_reference("constant-twist:dynamics+midpoint-gyroscopic")[1] == {"dynamics": True, "gyroscopic": "midpoint"}
    assert _parse_reference("constant-twist:dynamics+joints+momentum")[1] == {"dynamics": True, "joints": True,
                                                                            "joint_velocities": "momentum"}
    assert _parse_reference("constant-twist:dynamics+joints+trapezoidal+coordinates")[1] == {
        "dynamics": True, "joints": True, "trapezoidal": True, "joint_velocities": "coordinates"}
    for bad in ("constant-twist:joints+substeps=4", "constant-twist:dynamics+substeps=0", "constant-twist:dynamics+substeps=x",
                "constant-twist:joints+implicit-gyroscopic", "constant-twist:dynamics+sideways-gyroscopic",
                "constant-twist:dynamics+implicit-gyroscopic+midpoint-gyroscopic", "constant-twist:dynamics+momentum",
                "constant-twist:joints+momentum", "constant-twist:dynamics+coordinates",
                "constant-twist:dynamics+joints+momentum+coordinates"):
        with pytest.raises(typer.Exit):
            _parse_reference(bad)
    with pytest.raises(ValueError, match="substeps"):
        MODELS["mdgs"].Config(prior_substeps=4)  # without the dynamics prior
    with pytest.raises(ValueError, match="substeps"):
        MODELS["constant-twist"].Config(substeps=2)
    ct = MODELS["constant-twist"]
    with pytest.raises(ValueError, match="already holds the motors"):
        ct.Config(dynamics=True, motors=True)


LEFT_OUT = """<mujoco model="left-out">
  <compiler angle="radian"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <geom name="ramp" type="plane" size="1 1 0.1" euler="0.3 0 0"/>
    <geom name="post" type="cylinder" size="0.05 0.2" pos="1 0 0.2"/>
    <geom name="rock" type="ellipsoid" size="0.1 0.1 0.05" pos="2 0 0"/>
    <body name="base" pos="0 0 0.5">
      <freejoint/>
      <geom type="box" size="0.1 0.1 0.1" mass="1"/>
      <body name="arm" pos="0.2 0 0">
        <joint name="elbow" type="hinge" axis="0 1 0" range="-1 1" damping="0.1"/>
        <geom name="ball" type="sphere" size="0.05" mass="0.2"/>
        <geom name="arm_box" type="box" size="0.05 0.02 0.02" mass="0.1"/>
      </body>
      <body name="hand" pos="0 0.2 0">
        <joint name="wrist" type="ball" range="0 0.5"/>
        <geom name="hand_box" type="box" size="0.02 0.02 0.02" mass="0.1"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_what_the_forward_dynamics_leaves_out_of_a_scene_is_listed_and_its_users_are_warned(tiny_cubli, monkeypatch):
    m = mujoco.MjModel.from_xml_string(LEFT_OUT)
    nb = np.array([1] * 4 + [2] * 4 + [3] * 4)
    signs = np.array([[a, b, 0.5] for a in (-1, 1) for b in (-1, 1)] * 3) * 0.05
    ds = drives_of(m, nb, signs)
    text = "\n".join(ds.unseen)
    assert "geom rock (ellipsoid of the world): nothing touches it" in text
    assert "geom ball (sphere): no contact points" in text
    assert "joint elbow: its damping" in text  # its range limit is held
    assert "joint wrist: its range limit" in text  # a ball joint's is not
    assert len(ds.unseen) == 4 and len(ds.corner_obj) == 24  # the three boxes' corners
    assert [sf.name for sf in ds.surfaces] == ["floor", "ramp", "post"]
    assert [lk.limit for lk in ds.links if lk.kind == "hinge"] == [(-1.0, 1.0)]
    # the Cubli's wall and block are boxes of the world, touched: nothing to warn of
    tr, te = load_split(tiny_cubli / "train.h5"), load_split(tiny_cubli / "test.h5")
    ct = MODELS["constant-twist"]
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        drives = drives_of(te.mj_model(), te.static["node_body"], te.static["node_centroid"])
        assert drives.unseen == [] and {sf.name for sf in drives.surfaces} >= {"wall", "block"}
    # a scene with something unseen: the rigid tree and MDGS's prior say so when bound
    import mdgs.models.mdgs as mdgs_module
    import mdgs.models.references as references_module

    def with_unseen(*args):
        out = drives_of(*args)
        out.unseen.append("joint hip: its spring")
        return out

    monkeypatch.setattr(references_module, "drives_of", with_unseen)
    monkeypatch.setattr(mdgs_module, "drives_of", with_unseen)
    with pytest.warns(UserWarning, match="rigid tree.*joint hip: its spring"):
        ct.from_data(te, ct.Config(dynamics=True, joints=True)).bind(te)
    with pytest.warns(UserWarning, match="dynamics.* prior .*joint hip: its spring"):
        MODELS["mdgs"].from_data(tr, MODELS["mdgs"].Config(actuation="dynamics")).bind(te)


SURFACES = """<mujoco><compiler angle="radian"/><worldbody>
  <geom name="plane" type="plane" size="1 1 .1" euler="0.3 0.2 0"/>
  <geom name="box" type="box" size=".1 .2 .3" pos="1 0 0" euler="0.1 0.5 0.2"/>
  <geom name="cylinder" type="cylinder" size=".1 .2" pos="2 0 0" euler="0.4 0 0.3"/>
  <geom name="capsule" type="capsule" size=".1 .2" pos="3 0 0" euler="0.4 0 0.3"/>
  <geom name="sphere" type="sphere" size=".15" pos="4 0 0"/>
  <body name="probe" mocap="true"><geom name="point" type="sphere" size="1e-4" contype="0" conaffinity="0"/></body>
</worldbody></mujoco>"""


def test_the_distance_of_a_point_to_each_kind_of_world_surface_is_mujocos():
    """Signed distance (negative inside) from random points near each surface kind, against MuJoCo's
    ``mj_geomDistance`` to a 0.1 mm sphere at the point (plus its radius): 1e-12 m, round-off. The normal
    points from the surface's nearest point to the point (MuJoCo's segment), away from it inside."""
    from mdgs.actuation import SURFACE_KINDS, _surface_distance

    m = mujoco.MjModel.from_xml_string(SURFACES)
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    point = m.ngeom - 1
    for g in range(point):
        kind = mujoco.mjtGeom(int(m.geom_type[g])).name.removeprefix("mjGEOM_").lower()
        assert kind in SURFACE_KINDS
        inside = 0
        for _ in range(100):
            p = m.geom_pos[g] + rng.normal(size=3) * 0.15
            d.mocap_pos[0] = p
            mujoco.mj_forward(m, d)
            seg = np.zeros(6)
            expect = mujoco.mj_geomDistance(m, d, g, point, 1.0, seg) + 1e-4
            rot = d.geom_xmat[g].reshape(3, 3)
            got, n = _surface_distance(torch.tensor((p - d.geom_xpos[g]) @ rot), kind, m.geom_size[g])
            assert abs(float(got) - expect) < 1e-12, kind
            inside += expect < 0
            if abs(expect) > 1e-3:
                towards = (seg[3:] - seg[:3]) / np.linalg.norm(seg[3:] - seg[:3])
                np.testing.assert_allclose(rot @ n.numpy(), np.sign(expect) * towards, atol=1e-6)
        assert 5 < inside < 95  # both sides were tried


def _ramp(theta, mu):
    return f"""<mujoco model="ramp"><compiler angle="radian"/><option gravity="0 0 -9.81"/><worldbody>
      <geom name="ramp" type="plane" size="5 5 0.1" euler="{theta} 0 0" friction="{mu} 0.005 0.0001"/>
      <body name="box" pos="0 0 1"><freejoint/>
        <geom type="box" size="{H} {H} {H}" mass="2" friction="{mu} 0.005 0.0001"/></body>
    </worldbody></mujoco>"""


def test_a_box_sliding_down_a_tilted_plane_accelerates_at_g_sin_minus_mu_g_cos():
    """On a plane tilted by theta about x, flat on its face and sliding down at 0.5 m/s (faster than friction
    stops in a frame), the box accelerates down the slope at g (sin theta - mu cos theta) and not into or
    off the plane: the contact frame follows the surface's normal, not the world's z."""
    theta, mu = 0.3, 0.1
    R = _rot_x(theta)
    down, normal = R @ np.array([0, -1.0, 0]), R @ np.array([0, 0, 1.0])
    _, a, alpha, _ = _box_acc(R, H * normal, vc=0.5 * down, xml=_ramp(theta, mu))
    expect = G * (np.sin(theta) - mu * np.cos(theta))
    np.testing.assert_allclose(a, expect * down, atol=1e-4 * G)
    np.testing.assert_allclose(alpha, 0, atol=1e-3)



@pytest.mark.parametrize(("theta", "mu"), [(0.5, 0.3), (0.2, 0.5)])
def test_a_box_at_rest_on_a_ramp_slides_where_the_friction_cone_cannot_hold_it_and_rests_where_it_can(theta, mu):
    """At rest flat on a plane tilted by theta, the box slides down at g (sin theta - mu cos theta) where the slope
    is steeper than the friction angle (tan 0.5 = 0.55 > mu = 0.3: holding it would take more than mu times the
    push) and stays at rest where it is not (tan 0.2 = 0.20 < 0.5). The rule before the friction cone held any
    corner that slipped slower than mu |g| dt, so the first box stuck."""
    R = _rot_x(theta)
    down, normal = R @ np.array([0, -1.0, 0]), R @ np.array([0, 0, 1.0])
    _, a, alpha, _ = _box_acc(R, H * normal, xml=_ramp(theta, mu))
    expect = max(G * (np.sin(theta) - mu * np.cos(theta)), 0.0)
    np.testing.assert_allclose(a, expect * down, atol=1e-4 * G)
    np.testing.assert_allclose(alpha, 0, atol=1e-3)


def test_a_box_landing_flat_with_a_slight_slip_is_not_thrown_sideways_by_its_friction():
    """Falling flat onto the floor at 3 m/s with a slip of 6 cm/s, over a frame of 2.5 ms (short enough that the
    corners count as sliding, 6 cm/s > mu g dt = 2.5 cm/s): the impact stops the fall and friction stops the
    slip without turning it round (the rule before gave the box 3 m/s sideways: mu times the push of an
    impact that stops 3 m/s, applied along the slip with no bound)."""
    dt = 0.0025
    slip = np.array([-0.036, -0.048, 0.0])
    _, a, alpha, _ = _box_acc(np.eye(3), np.array([0, 0, H + 0.001]), vc=slip + np.array([0, 0, -3.0]), dt=dt)
    v_end = slip + np.array([0, 0, -3.0]) + a * dt
    assert abs(v_end[2]) < 1e-5  # the fall is stopped (to the rows' compliance: 1e-6 per N, 600 N a corner)
    assert np.linalg.norm(v_end[:2]) < 1e-5  # friction stops the slip (it can: the push is large), no more
    np.testing.assert_allclose(alpha, 0, atol=0.1)  # barely turned: 0.1 rad/s^2 over the frame is 2.5e-4 rad/s

WALL = f"""<mujoco model="wall"><option gravity="0 0 -9.81"/><worldbody>
  <geom name="floor" type="plane" size="5 5 0.1"/>
  <geom name="wall" type="box" size="0.1 1 0.5" pos="{H + 0.1} 0 0.5"/>
  <geom name="table" type="box" size="0.3 0.3 0.2" pos="-1 0 0.2"/>
  <body name="box" pos="0 0 1"><freejoint/><geom type="box" size="{H} {H} {H}" mass="2"/></body>
</worldbody></mujoco>"""


def test_a_box_sliding_into_a_wall_is_stopped_and_a_box_on_a_table_rests():
    """World boxes are surfaces: sliding along the floor at 0.5 m/s into a wall it touches, the box stops
    within the frame (a = -v / dt, no turn, the floor still holding it); at rest on a table (a box of the
    world 0.4 m high) it stays at rest."""
    _, a, alpha, _ = _box_acc(np.eye(3), np.array([0, 0, H]), vc=(0.5, 0.0, 0.0), xml=WALL)
    np.testing.assert_allclose(a, [-0.5 / 0.01, 0, 0], atol=1e-3)
    np.testing.assert_allclose(alpha, 0, atol=1e-3)
    acc, _, _, _ = _box_acc(np.eye(3), np.array([-1, 0, 0.4 + H]), xml=WALL)
    assert np.abs(acc).max() < 1e-4


CHAIN = """<mujoco model="chain"><compiler angle="radian"/><option gravity="0 0 -9.81"/><worldbody>
  <body name="base" pos="0 0 1"><freejoint/><geom type="box" size="0.1 0.1 0.1" mass="1"/>
    <body name="arm" pos="0.2 0 0" euler="0.3 -0.2 0.5">
      <joint name="elbow" type="hinge" axis="0.3 1 0.2" pos="-0.05 0 0" ref="0.4" range="-1 1"/>
      <geom type="box" size="0.05 0.02 0.02" mass="0.2"/>
      <body name="hand" pos="0.1 0 0" euler="0 0.4 0">
        <joint name="reach" type="slide" axis="1 0.2 0" ref="0.05" range="-0.1 0.1"/>
        <geom type="box" size="0.02 0.02 0.02" mass="0.1"/>
      </body>
    </body>
  </body>
</worldbody></mujoco>"""


def _chain_momenta(ds, x, v, ref, seg, mass):
    """Linear and angular momentum (about the origin) of the chain's bodies, with the MJCF's masses and inertias,
    each body's pose and twist fitted to its nodes ``x, v`` [1, N, 3]; and its kinetic energy."""
    from mdgs.actuation import pose_of

    T = ds.tensors("cpu")
    R, t, tw = pose_of(x, v, ref, seg, 3, mass)
    xs = (R @ T["com"].unsqueeze(-1)).squeeze(-1) + t
    v_ms = tw.vc + torch.linalg.cross(tw.omega, xs - tw.c, dim=-1)
    inertia = R @ T["inertia"] @ R.transpose(-1, -2)
    Iw = (inertia @ tw.omega.unsqueeze(-1)).squeeze(-1)
    m = T["mass"].view(1, 3, 1)
    P = (m * v_ms).sum(1)[0]
    L = (torch.linalg.cross(xs, m * v_ms, dim=-1) + Iw).sum(1)[0]
    E = 0.5 * float((m * v_ms * v_ms).sum() + (tw.omega * Iw).sum())
    return P.numpy(), L.numpy(), E


def test_the_momentum_projection_puts_the_twists_on_the_joints_keeping_momentum_and_losing_energy():
    """A free-floating chain (free base, hinge, slide) whose bodies move with random twists that break their joints:
    :func:`mdgs.actuation.project_velocities` gives twists that satisfy the joints (their rows to 1e-10), keeps
    the chain's linear and angular momentum (to 1e-10: impulses at the joints only) and lowers its kinetic
    energy, where the parent-first projection of :func:`mdgs.joints.project_joints` changes the momentum (by more
    than 1 %: each child takes its parent's twist across the joint)."""
    from mdgs.actuation import _tree, pose_of, project_velocities
    from mdgs.joints import joints_of, project_joints

    m = mujoco.MjModel.from_xml_string(CHAIN)
    d = mujoco.MjData(m)
    nb = np.repeat([1, 2, 3], 4)
    corners = np.array([[0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01], [0.01, 0.01, 0.01]])
    ref = np.tile(corners, (3, 1))
    ds = drives_of(m, nb, ref)
    rng = np.random.default_rng(0)
    d.qpos[:3] = rng.normal(size=3)
    q = rng.normal(size=4)
    d.qpos[3:7] = q / np.linalg.norm(q)
    d.qpos[7], d.qpos[8] = 0.3, 0.02
    mujoco.mj_kinematics(m, d)
    R, t = d.xmat[1:].reshape(3, 3, 3), d.xpos[1:]
    x = np.einsum("nij,nj->ni", R[nb - 1], ref) + t[nb - 1]
    vc, w = rng.normal(size=(3, 3)), 3 * rng.normal(size=(3, 3))
    v = vc[nb - 1] + np.cross(w[nb - 1], x - t[nb - 1])
    seg, mass, ref_t = torch.as_tensor(nb - 1), torch.full((12,), 0.1, dtype=torch.float64), torch.tensor(ref)
    X, V = torch.tensor(x)[None], torch.tensor(v)[None]
    V2 = project_velocities(X, V, ds, ref_t, seg, 3, mass)
    R_, t_, tw = pose_of(X, V2, ref_t, seg, 3, mass)
    xs, _, _, J, _, _ = _tree(X, R_, t_, ds.tensors("cpu"), ds, 3, None)
    nu = torch.cat([tw.vc + torch.linalg.cross(tw.omega, xs - tw.c, dim=-1), tw.omega], -1).reshape(1, -1, 1)
    assert float((torch.cat(J, 1) @ nu).abs().max()) < 1e-10
    P0, L0, E0 = _chain_momenta(ds, X, V, ref_t, seg, mass)
    P1, L1, E1 = _chain_momenta(ds, X, V2, ref_t, seg, mass)
    np.testing.assert_allclose(P1, P0, atol=1e-10)
    np.testing.assert_allclose(L1, L0, atol=1e-10)
    assert E1 < E0
    js = joints_of(m, nb, ref)
    _, Vp = project_joints(X, V, js, ref_t, seg, 3, mass)
    P2, L2, _ = _chain_momenta(ds, X, Vp, ref_t, seg, mass)
    assert np.linalg.norm(P2 - P0) + np.linalg.norm(L2 - L0) > 0.01 * (np.linalg.norm(P0) + np.linalg.norm(L0))


def test_the_joint_velocity_rule_is_refused_where_it_has_nothing_to_project():
    ct = MODELS["constant-twist"]
    with pytest.raises(ValueError, match="joint_velocities must be one of 'parent', 'momentum'"):
        ct.Config(dynamics=True, joints=True, joint_velocities="average")
    with pytest.raises(ValueError, match="set dynamics = true and joints = true"):
        ct.Config(dynamics=True, joint_velocities="momentum")


def test_the_joint_angles_read_from_the_bodies_poses_are_mujocos_qpos():
    """A hinge (tilted axis, ``ref``, turned body frame) and a slide below it on a free base, at random
    configurations: the angle and displacement read from the bodies' frames (MuJoCo's ``xmat, xpos``)
    are MuJoCo's ``qpos`` to 1e-9."""
    from mdgs.actuation import _joint_angles

    m = mujoco.MjModel.from_xml_string(CHAIN)
    d = mujoco.MjData(m)
    ds = drives_of(m, np.array([1] * 3 + [2] * 3 + [3] * 3), np.tile(np.eye(3) * 0.01, (3, 1)))
    hinge, slide = (next(lk for lk in ds.links if lk.kind == k) for k in ("hinge", "slide"))
    rng = np.random.default_rng(1)
    for _ in range(20):
        d.qpos[:3] = rng.normal(size=3)
        q = rng.normal(size=4)
        d.qpos[3:7] = q / np.linalg.norm(q)
        d.qpos[7], d.qpos[8] = rng.uniform(-3, 3), rng.uniform(-0.2, 0.3)
        mujoco.mj_kinematics(m, d)
        R = torch.tensor(d.xmat[1:].reshape(1, 3, 3, 3))
        t = torch.tensor(d.xpos[1:].reshape(1, 3, 3))
        assert abs(float(_joint_angles(R, t, hinge, ds)[0]) - d.qpos[7]) < 1e-9
        assert abs(float(_joint_angles(R, t, slide, ds)[0]) - d.qpos[8]) < 1e-9


PENDULUM = """<mujoco model="pendulum"><compiler angle="radian"/><option gravity="0 0 -9.81"/><worldbody>
  <body name="rod" pos="0 0 1">
    <joint name="swing" type="hinge" axis="1 0 0" range="0.2 1.0"/>
    <geom type="box" size="0.02 0.02 0.2" pos="0 0 -0.2" mass="1"/>
  </body>
</worldbody></mujoco>"""


@pytest.mark.parametrize("phi, rate", [(0.6, 0.0), (0.6, 1.0), (0.15, 0.0), (0.19, -1.0), (1.05, 2.0),
                                       (1.1, -2.0), (0.25, -2.0)])
def test_a_pendulum_swings_freely_inside_its_range_and_against_its_soft_limit_as_in_mujoco(phi, rate):
    """A 0.4 m rod hinged at its top end, range [0.2, 1.0] rad (it hangs at 0, outside), at angle phi
    turning at ``rate``: inside the range it swings as the textbook pendulum, past a limit MuJoCo's soft
    limit (its ``solref``, ``solimp`` reference acceleration and regularisation) pushes it back: the
    angular acceleration is MuJoCo's ``qacc`` (``mj_forward``) to 1e-6 relative, both ways."""
    m = mujoco.MjModel.from_xml_string(PENDULUM)
    nodes = np.array([[0.0, 0.0, -0.1], [0.0, 0.02, -0.3], [0.02, 0.0, -0.3], [0.0, -0.02, -0.2]])
    ds = drives_of(m, np.ones(4, int), nodes)
    R = _rot_x(phi)
    x = torch.tensor(nodes @ R.T + [0, 0, 1.0])[None]
    v = torch.tensor(np.cross([rate, 0, 0], nodes @ R.T))[None]
    seg, mass = torch.zeros(4, dtype=torch.long), torch.full((4,), 0.25, dtype=torch.float64)
    acc = coupled_motor_accelerations(x, torch.zeros(1, 0), ds, torch.tensor(nodes), seg, 1, v=v, mass=mass, dt=0.01)
    _, alpha = project(acc, x, twist(x, v, seg, 1, mass), seg, 1, mass)
    d = mujoco.MjData(m)
    d.qpos[0], d.qvel[0] = phi, rate
    mujoco.mj_forward(m, d)
    assert (d.nefc > 0) == (not 0.2 <= phi <= 1.0)  # MuJoCo's limit is on past the range only
    np.testing.assert_allclose(float(alpha[0, 0, 0]), d.qacc[0], rtol=1e-6, atol=1e-9)
    if 0.2 <= phi <= 1.0:  # and there it is the textbook's
        inertia = float(m.body_inertia[1][0]) + 1.0 * 0.2 ** 2
        np.testing.assert_allclose(d.qacc[0], -G * 0.2 * np.sin(phi) / inertia, rtol=1e-9)


def test_a_pendulum_about_to_pass_its_limit_within_the_frame_is_pushed_back_already():
    """0.05 rad inside its range at 6 rad/s towards the limit, one 10 ms frame would take it 0.01 rad past:
    the limit acts already (MuJoCo, stepping 20 times finer, would switch it on within the frame), so the
    rod decelerates faster than gravity alone would turn it."""
    m = mujoco.MjModel.from_xml_string(PENDULUM)
    nodes = np.array([[0.0, 0.0, -0.1], [0.0, 0.02, -0.3], [0.02, 0.0, -0.3], [0.0, -0.02, -0.2]])
    ds = drives_of(m, np.ones(4, int), nodes)
    R = _rot_x(0.25)
    x = torch.tensor(nodes @ R.T + [0, 0, 1.0])[None]
    v = torch.tensor(np.cross([-6.0, 0, 0], nodes @ R.T))[None]
    seg, mass = torch.zeros(4, dtype=torch.long), torch.full((4,), 0.25, dtype=torch.float64)
    acc = coupled_motor_accelerations(x, torch.zeros(1, 0), ds, torch.tensor(nodes), seg, 1, v=v, mass=mass, dt=0.01)
    _, alpha = project(acc, x, twist(x, v, seg, 1, mass), seg, 1, mass)
    inertia = float(m.body_inertia[1][0]) + 1.0 * 0.2 ** 2
    assert float(alpha[0, 0, 0]) > 10 * abs(G * 0.2 * np.sin(0.25) / inertia)


def test_the_trapezoidal_rigid_tree_is_exact_for_a_free_fall_and_the_semi_implicit_one_is_not():
    """A box thrown in the air (no contact within the frame): after one 10 ms frame the trapezoidal step
    puts it at x0 + v0 dt + g dt^2 / 2, exactly (1e-9 m), the semi-implicit step at x0 + v0 dt + g dt^2,
    0.49 mm lower; both give the velocity v0 + g dt."""
    from types import SimpleNamespace

    from mdgs.joints import JointSet
    from mdgs.models.references import ConstantTwist, ConstantTwistConfig

    m = mujoco.MjModel.from_xml_string(BOX)
    nb, ref = _box_nodes(m)
    x0 = torch.tensor(ref + [0.0, 0.0, 1.0])[None]
    v0 = torch.tensor([0.3, -0.2, 1.5]).expand(1, 8, 3).double()
    dt = 0.01
    scene = SimpleNamespace(obj=torch.zeros(8, dtype=torch.long), n_obj=1, mass=torch.full((8,), 0.25),
                            ref_shape=torch.tensor(ref), static=torch.zeros(8, dtype=torch.bool))
    for trap, drop in ((True, 0.5), (False, 1.0)):
        sim = ConstantTwist(ConstantTwistConfig(dynamics=True, trapezoidal=trap))
        sim._scene, sim._dt, sim._drives, sim._joints = scene, dt, drives_of(m, nb, ref), JointSet()
        st = sim.step(State(x0, v0), torch.zeros(1, 0))
        expect = x0 + v0 * dt + drop * torch.tensor([0.0, 0.0, -G]) * dt ** 2
        np.testing.assert_allclose(st.x.numpy(), expect.numpy(), atol=1e-9)
        np.testing.assert_allclose(st.v.numpy(), (v0 + torch.tensor([0.0, 0.0, -G]) * dt).numpy(), atol=1e-9)


SLIDER = """<mujoco model="slider"><compiler angle="radian"/><option gravity="0 0 -9.81"/><worldbody>
  <body name="carriage" pos="0 0 1" euler="0 0.4 0">
    <joint name="rail" type="slide" axis="0 0 1" range="-0.1 0.1" ref="0.02"/>
    <geom type="box" size="0.05 0.05 0.05" mass="2"/>
  </body>
</worldbody></mujoco>"""


@pytest.mark.parametrize("q, rate", [(0.0, 0.3), (-0.12, -0.5), (0.13, 0.2), (-0.105, 0.4)])
def test_a_slide_on_a_tilted_rail_moves_as_in_mujoco_inside_and_past_its_range(q, rate):
    """A carriage on a rail tilted by 0.4 rad (``ref`` 0.02): inside its range it slides down at
    g cos(0.4); past either limit MuJoCo's soft limit pushes it back; its acceleration along the rail
    is MuJoCo's ``qacc`` to 1e-6 relative."""
    m = mujoco.MjModel.from_xml_string(SLIDER)
    d = mujoco.MjData(m)
    d.qpos[0], d.qvel[0] = q, rate
    mujoco.mj_forward(m, d)
    nodes = np.array([[0.03, 0.0, 0.0], [0.0, 0.03, 0.0], [0.0, 0.0, 0.03], [-0.02, -0.02, -0.02]])
    R, t = d.xmat[1].reshape(3, 3), d.xpos[1]
    axis = R @ np.array([0.0, 0.0, 1.0])
    x = torch.tensor(nodes @ R.T + t)[None]
    v = torch.tensor(np.tile(rate * axis, (4, 1)))[None]
    seg, mass = torch.zeros(4, dtype=torch.long), torch.full((4,), 0.5, dtype=torch.float64)
    ds = drives_of(m, np.ones(4, int), nodes)
    acc = coupled_motor_accelerations(x, torch.zeros(1, 0), ds, torch.tensor(nodes), seg, 1, v=v, mass=mass, dt=0.01)
    got = float(acc[0].mean(0).numpy() @ axis)
    assert (d.nefc > 0) == (not -0.1 <= q <= 0.1)
    np.testing.assert_allclose(got, d.qacc[0], rtol=1e-6, atol=1e-9)
    if -0.1 <= q <= 0.1:
        np.testing.assert_allclose(got, -G * np.cos(0.4), rtol=1e-9)


def test_large_batched_systems_are_solved_on_a_multithreaded_cpu():
    """torch 2.13's batched CPU solve fails from about 150 unknowns with two threads (oneMKL returns invalid
    pivots); the forward dynamics' solve goes one system at a time there and matches each system's own
    solve to round-off."""
    from mdgs.actuation import _solve

    n_threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        g = torch.Generator().manual_seed(0)
        K = torch.randn(4, 205, 205, dtype=torch.float64, generator=g) + 205 * torch.eye(205, dtype=torch.float64)
        b = torch.randn(4, 205, dtype=torch.float64, generator=g)
        x = _solve(K, b)
        for i in range(4):
            np.testing.assert_allclose(x[i].numpy(), torch.linalg.solve(K[i], b[i]).numpy(), rtol=1e-12, atol=1e-15)
    finally:
        torch.set_num_threads(n_threads)


def test_the_relative_loss_reuses_the_passes_forward_dynamics_and_gives_the_same_loss(tiny_cubli, monkeypatch):
    """The relative loss divides each pair's error by that of g's output zero, whose step needs the
    priors' increments the forward pass has just computed from the same state: reused, the forward
    dynamics is solved once per pass instead of twice, and the loss is the one with the zero step's own
    solve (to float round-off: the same solve on the same inputs)."""
    import mdgs.models.mdgs as mdgs_module

    tr = load_split(tiny_cubli / "train.h5")
    torch.manual_seed(0)
    net = MODELS["mdgs"].from_data(tr, MODELS["mdgs"].Config(actuation="dynamics", loss="relative", noise="none"))
    torch.nn.init.normal_(net.state.lins[-1].weight, std=0.05)
    net.bind(tr)
    b = batch_of(tr, tr.pairs(0)[:8], "cpu")
    calls = []
    real = mdgs_module.coupled_motor_accelerations

    def counted(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(mdgs_module, "coupled_motor_accelerations", counted)
    with torch.no_grad():
        reused = net.losses(b)["mse"]
        assert len(calls) == 1
        original = net._zero_step
        net._zero_step = lambda scene, x, v, priors: original(scene, x, v, net._priors(scene, x, v, b.ctrl))  # again
        again = net.losses(b)["mse"]
    assert len(calls) == 3
    np.testing.assert_allclose(float(reused), float(again), rtol=1e-6)


def test_speculative_contact_lands_a_striking_box_on_the_floor_at_the_frames_end(monkeypatch):
    """``CONTACT_SPECULATIVE`` (off by default; benchmarks/mdgs_probes/speculative_contact.py): falling at 2
    m/s with its lowest face 15 mm above the floor (dt = 10 ms: it would pass the floor), the face ends the
    frame on the floor under the trapezoidal step, dt (u + u') / 2 = -15 mm, so u' = -1 m/s and a = (u' -
    u) / dt = +100 m/s^2, where the default rule stops it (a = +200: u' = 0). A face more than half the
    frame's travel closer keeps the default rule (no rebound is asked for)."""
    import mdgs.actuation as actuation

    monkeypatch.setattr(actuation, "CONTACT_SPECULATIVE", True)
    _, a, alpha, _ = _box_acc(np.eye(3), np.array([0, 0, H + 0.015]), vc=np.array([0, 0, -2.0]), dt=0.01)
    np.testing.assert_allclose(a, [0, 0, 100.0], atol=1e-2)
    np.testing.assert_allclose(alpha, 0, atol=1e-6)
    _, a, _, _ = _box_acc(np.eye(3), np.array([0, 0, H + 0.005]), vc=np.array([0, 0, -2.0]), dt=0.01)
    np.testing.assert_allclose(a, [0, 0, 200.0], atol=1e-2)


def _push_box(R, t, w=(0.0, 0.0, 0.0), vc=(0.0, 0.0, 0.0)):
    """The test box's nodes and velocities before and after :func:`mdgs.actuation.push_out` at pose (R, t)."""
    from mdgs.actuation import push_out

    ds, x, v, seg, mass, ref = _box_state(R, t, w, vc)
    xn, vn = push_out(x, v, ds, torch.tensor(ref), seg, 1, mass)
    return x[0].numpy(), v[0].numpy(), xn[0].numpy(), vn[0].numpy(), ref


def _corner_heights(x, ref):
    """The heights [8] of the test box's corners given its nodes (at half the corners: corners = 2 x nodes - centre)."""
    c = x.mean(0)
    return (c + 2 * (x - c))[:, 2]


def test_push_out_lifts_a_sunken_box_onto_the_floor_and_keeps_its_twist():
    """A box 5 mm into the floor on its face, moving sideways and turning about the vertical: push-out moves it
    straight up by 5 mm (the least mass-weighted displacement that clears its four lowest corners), its nodes
    still the same rigid shape, and its velocity field the same (a split impulse: positions only)."""
    x, v, xn, vn, ref = _push_box(np.eye(3), np.array([0, 0, H - 0.005]), w=(0, 0, 1.0), vc=(0.3, 0, 0))
    # to 1e-8 m: the rows' compliance (1e-6 per unit multiplier, the multipliers here 2 kg x 5 mm / 4) gives way 2.5e-9 m
    np.testing.assert_allclose(xn - x, np.tile([0, 0, 0.005], (8, 1)), atol=1e-8)
    np.testing.assert_allclose(vn, v, atol=1e-12)
    assert _corner_heights(xn, ref).min() == pytest.approx(0.0, abs=1e-8)


def test_push_out_tilts_a_box_whose_one_corner_is_in_the_floor_out_and_leaves_a_box_above_it_alone():
    """Tilted on an edge-to-corner line with one corner 3 mm deep, the box is moved so that corner is on the floor
    again to second order in the correction (a linearised step: (3 mm)^2 over the corner's 8.7 cm lever arm is 0.1 mm) and
    no other corner goes in; a box 1 mm above the floor, or resting on it, is returned as it was."""
    R = _rot_x(0.3) @ np.array([[np.cos(0.4), -np.sin(0.4), 0], [np.sin(0.4), np.cos(0.4), 0], [0, 0, 1]])
    low = (R @ (H * np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)]).T))[2].min()
    x, v, xn, vn, ref = _push_box(R, np.array([0, 0, -low - 0.003]), w=(1.0, -2.0, 0.5))
    before, after = _corner_heights(x, ref), _corner_heights(xn, ref)
    assert before.min() == pytest.approx(-0.003, abs=1e-9)
    assert after.min() == pytest.approx(0.0, abs=1.5e-4)  # and no other corner went in
    assert after[np.argmin(before)] - before.min() == pytest.approx(0.003, abs=1.5e-4)  # the deep corner rose
    d = np.linalg.norm(xn[:, None] - xn[None], axis=-1) - np.linalg.norm(x[:, None] - x[None], axis=-1)
    np.testing.assert_allclose(d, 0, atol=1e-12)  # still rigid
    for z in (H + 0.001, H):
        x, v, xn, vn, _ = _push_box(np.eye(3), np.array([0, 0, z]), vc=(0, 0, -1.0))
        np.testing.assert_array_equal(xn, x)
        np.testing.assert_array_equal(vn, v)


def test_push_out_keeps_the_cubli_flywheels_on_their_hinges(tiny_cubli):
    """The tiny Cubli's first test frame sunk 4 mm into the floor (every body moved down): push-out lifts the
    whole tree together, cube and flywheels by the same 4 mm (the hinges hold: no body moves against another),
    and leaves every body's twist as it was (its nodes' velocities turn with the body's tiny tilt)."""
    from mdgs.actuation import push_out

    d = load_split(tiny_cubli / "test.h5")
    sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
    ds = drives_of(d.mj_model(), d.static["node_body"], d.static["node_centroid"])
    mov = torch.as_tensor(~np.asarray(d.static["node_static"], bool))
    x = torch.as_tensor(d.x[:1, 0], dtype=torch.float64)
    v = torch.as_tensor(d.v[:1, 0], dtype=torch.float64)
    x = torch.where(mov.view(1, -1, 1), x - torch.tensor([0, 0, 0.004], dtype=torch.float64), x)
    xn, vn = push_out(x, v, ds, sc.ref_shape.double(), sc.obj, sc.n_obj, sc.mass.double())
    lift = (xn - x)[0, mov]
    np.testing.assert_allclose(lift.numpy(), np.tile([0, 0, 0.004], (int(mov.sum()), 1)), atol=2e-4)
    assert float((lift - lift.mean(0)).norm(dim=-1).max()) < 1e-4  # one rigid lift of the tree
    before, after = twist(x, v, sc.obj, sc.n_obj, sc.mass.double()), twist(xn, vn, sc.obj, sc.n_obj, sc.mass.double())
    np.testing.assert_allclose(after.vc.numpy(), before.vc.numpy(), atol=1e-9)
    np.testing.assert_allclose(after.omega.numpy(), before.omega.numpy(), atol=1e-9)


def test_push_out_solves_only_the_penetrating_corners_eagerly_and_moves_as_the_compiled_all_slot_system(tiny_cubli):
    """Eagerly, push-out gathers the corners inside a surface into as many slots as the batch's most (the
    others are rows ``l = 0`` of the full system, which the compiled step keeps, shapes not following the
    state): a batch of the tiny Cubli sunk 4 mm, sunk 1 mm and tilted (fewer corners in), and 1 mm above the
    floor (none in) is moved as the compiled system moves it (dynamo's ``eager`` backend, fullgraph; float64
    solves of different sizes, so to 1e-12 m), and the batch's untouched row stays where it was."""
    from mdgs.actuation import push_out

    d = load_split(tiny_cubli / "test.h5")
    sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
    ds = drives_of(d.mj_model(), d.static["node_body"], d.static["node_centroid"])
    mov = torch.as_tensor(~np.asarray(d.static["node_static"], bool)).view(1, -1, 1)
    x0 = torch.as_tensor(d.x[:1, 0], dtype=torch.float64)
    c = x0[0, mov[0, :, 0]].mean(0)
    tilt = torch.as_tensor(_rot_x(0.05)) @ (x0[0] - c).T
    shifts = [x0 - torch.tensor([0, 0, 0.004]), (tilt.T + c - torch.tensor([0, 0, 0.001]))[None],
              x0 + torch.tensor([0, 0, 0.001])]
    x = torch.cat([torch.where(mov, s, x0) for s in shifts])
    v = torch.as_tensor(d.v[:1, 0], dtype=torch.float64).expand(3, -1, -1).clone()
    args = (ds, sc.ref_shape.double(), sc.obj, sc.n_obj, sc.mass.double())
    xe, ve = push_out(x, v, *args)
    xc, vc = torch.compile(push_out, backend="eager", fullgraph=True)(x, v, *args)
    assert float((xe - x)[:2].abs().max()) > 5e-4  # the sunk rows moved
    np.testing.assert_array_equal(xe[2].numpy(), x[2].numpy())  # the row above the floor did not
    np.testing.assert_allclose(xe.numpy(), xc.numpy(), rtol=0, atol=1e-12)
    np.testing.assert_allclose(ve.numpy(), vc.numpy(), rtol=0, atol=1e-9)


def test_the_rigid_tree_leaves_a_fast_flywheels_hinge_without_the_joints_projection_and_warns_of_it(tiny_cubli):
    """The forward dynamics holds the joints through their accelerations only. On the tiny Cubli's test
    trajectory (a flywheel near 870 rad/s on a resting cube) the tree in four substeps with push-out, not
    projected onto its joints, is more than 10 cm off the data by frame 12 (it diverges), and projected it stays
    within 5 mm (the data's nodes move up to 5 cm over those frames); binding the unprojected tree warns."""
    import warnings

    te = load_split(tiny_cubli / "test.h5")
    ct = MODELS["constant-twist"]
    err = {}
    for joints in (False, True):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            tree = ct.from_data(te, ct.Config(dynamics=True, joints=joints, trapezoidal=True, substeps=4,
                                              push_out=True)).eval()
            tree.bind(te)
        assert any("without projecting it onto the joints" in str(w.message) for w in caught) == (not joints)
        s = tree.initial_state(te, np.arange(1), 0)
        with torch.no_grad():
            for f in range(12):
                s = tree.step(s, torch.from_numpy(te.ctrl[:1, f]))
        err[joints] = float(np.nan_to_num(np.abs(s.x[0].numpy() - te.x[0, 12]).max(), nan=np.inf))
    assert err[False] > 0.1
    assert err[True] < 0.005


def test_push_out_is_refused_without_the_dynamics_it_belongs_to():
    with pytest.raises(ValueError, match="dynamics"):
        MODELS["constant-twist"].Config(push_out=True)
    with pytest.raises(ValueError, match="dynamics"):
        MODELS["mdgs"].Config(push_out=True)


GIMBAL = """<mujoco model="gimbal"><option gravity="0 0 0"/><worldbody>
  <body name="hub" pos="0 0 1"><freejoint/><geom type="cylinder" size="0.1 0.02" mass="4.7"/>
    <body name="upper" pos="0 0 0.08"><joint name="fold" type="hinge" axis="1 0 0"/>
      <geom type="box" size="0.01 0.01 0.04" pos="0 0 0.04" mass="0.42"/>
      <body name="rotor" pos="0 0 0.09"><joint name="spin" type="hinge" axis="0 0 1"/>
        <geom type="cylinder" size="0.125 0.01" mass="3.75"/></body></body></body></worldbody></mujoco>"""


def _gimbal_rollout(gyroscopic: str, frames: int = 120) -> tuple[list[float], list[float], float]:
    """The GIMBAL scene (rotational-center's build: a free hub, a light arm on a hinge, a heavy rotor spun at
    90 rad/s on it) in free flight without gravity, stepped by the rigid tree in 4 substeps a frame: its kinetic
    energy (J) and the norm of its angular momentum about the origin every 20 frames, from the bodies' poses and
    twists fitted to the nodes, and MuJoCo's energy of the starting state (``qvel^T M qvel / 2``)."""
    from types import SimpleNamespace

    from mdgs.joints import joints_of
    from mdgs.models.references import ConstantTwist, ConstantTwistConfig
    from mdgs.structure import kabsch

    m = mujoco.MjModel.from_xml_string(GIMBAL)
    d = mujoco.MjData(m)
    tet = np.array([[0.03, 0, 0], [-0.015, 0.026, 0], [-0.015, -0.026, 0], [0, 0, 0.02]])
    body = np.repeat([1, 2, 3], 4)
    ref = np.concatenate([tet + m.body_ipos[b] for b in (1, 2, 3)])  # nodes in their bodies' frames

    def place(q):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        return np.concatenate([ref[body == b] @ d.xmat[b].reshape(3, 3).T + d.xpos[b] for b in (1, 2, 3)])

    qvel = np.array([0.1, 0, 0, 2.0, 1.0, 3.0, 0.0, -90.0])  # the hub tumbling, the rotor spinning
    qp, qm = m.qpos0.copy(), m.qpos0.copy()
    mujoco.mj_integratePos(m, qp, qvel, 1e-6)
    mujoco.mj_integratePos(m, qm, qvel, -1e-6)
    x = torch.tensor(place(m.qpos0))[None]
    v = torch.tensor((place(qp) - place(qm)) / 2e-6)[None]  # central difference: 1e-12 relative
    d.qvel[:] = qvel
    mujoco.mj_forward(m, d)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, M, d.qM) if hasattr(d, "qM") else mujoco.mj_fullM(m, d, M)
    e_mujoco = 0.5 * qvel @ M @ qvel
    ds = drives_of(m, body, ref)
    seg, mass = torch.as_tensor(body - 1), torch.as_tensor(np.repeat(m.body_mass[1:], 4) / 4)
    scene = SimpleNamespace(obj=seg, n_obj=3, mass=mass, ref_shape=torch.tensor(ref), static=torch.zeros(12, dtype=torch.bool))
    sim = ConstantTwist(ConstantTwistConfig(dynamics=True, joints=True, trapezoidal=True, substeps=4, gyroscopic=gyroscopic))
    sim._scene, sim._dt, sim._drives, sim._joints = scene, 0.01, ds, joints_of(m, body, ref)
    energy, momentum = [], []
    s = State(x, v)
    for f in range(frames + 1):
        if f % 20 == 0:
            R, t = kabsch(scene.ref_shape, s.x, seg, 3)
            tw = twist(s.x, s.v, seg, 3, mass)
            e, L = 0.0, torch.zeros(3, dtype=torch.float64)
            for b in range(3):
                inertia = R[0, b] @ torch.as_tensor(ds.inertia[b]) @ R[0, b].T
                com = R[0, b] @ torch.as_tensor(ds.com[b]) + t[0, b]
                w = tw.omega[0, b]
                vc = tw.vc[0, b] + torch.linalg.cross(w, com - tw.c[0, b])
                e += 0.5 * ds.mass[b] * float(vc @ vc) + 0.5 * float(w @ inertia @ w)
                L += ds.mass[b] * torch.linalg.cross(com, vc) + inertia @ w
            energy.append(e)
            momentum.append(float(L.norm()))
        if f < frames:
            s = sim.step(s, torch.zeros(1, 0))
    return energy, momentum, e_mujoco


@pytest.mark.parametrize("rule", ["implicit", "midpoint"])
def test_a_rotor_spun_fast_on_a_light_gimbal_keeps_its_energy_with_later_gyroscopic_terms_and_gains_it_without(rule):
    """Free flight conserves energy and angular momentum. The rotational-center build (a 4.7 kg hub, a 0.42 kg
    arm on a hinge, a 3.75 kg rotor at 90 rad/s on the arm; its nutation is near 175 rad/s) stepped by the
    rigid tree in 2.5 ms substeps for 1.2 s: with ``gyroscopic = "implicit"`` or ``"midpoint"`` the energy stays
    within 1 % (the linearised steps lose a little: 0.16 % implicit, 0.32 % midpoint here) and the angular
    momentum within 10 % (the joints' velocity projection does not conserve it exactly: 5 % here); with the explicit terms the
    energy is more than doubled by then (the step's growth factor per nutation cycle exceeds one). The
    starting energy read from the nodes is MuJoCo's to 1e-6 (it checks the energy function itself)."""
    e, L, e_mujoco = _gimbal_rollout(rule)
    assert abs(e[0] - e_mujoco) < 1e-6 * e_mujoco
    assert max(abs(x - e[0]) for x in e) < 0.01 * e[0], e
    assert max(abs(x - L[0]) for x in L) < 0.1 * L[0], L
    e_explicit, _, _ = _gimbal_rollout("explicit")
    assert not e_explicit[-1] < 2 * e_explicit[0], e_explicit  # NaN or inf count as gained


def test_the_gyroscopic_setting_is_checked_defaults_to_explicit_and_reaches_the_tree():
    """``gyroscopic`` takes "explicit", "implicit" or "midpoint", the latter two only with the rigid tree's
    dynamics (the reference and MDGS's "dynamics" prior); both default to "explicit" (the tree as the committed
    studies ran it); and the setting reaches the step: the rules give different states after 20 frames."""
    from mdgs.models.references import ConstantTwistConfig

    with pytest.raises(ValueError, match="gyroscopic must be one of"):
        ConstantTwistConfig(dynamics=True, gyroscopic="sideways")
    with pytest.raises(ValueError, match="set dynamics = true"):
        ConstantTwistConfig(gyroscopic="implicit")
    cls = MODELS["mdgs"]
    with pytest.raises(ValueError, match="actuation = \"dynamics\""):
        cls.Config(gyroscopic="implicit")
    assert ConstantTwistConfig().gyroscopic == cls.Config().gyroscopic == "explicit"
    ends = {rule: _gimbal_rollout(rule, frames=20)[0][-1] for rule in ("explicit", "implicit", "midpoint")}
    assert len(set(ends.values())) == 3, ends

"""MuJoCo's soft contact in the forward dynamics (``contact = "soft"`` of
:func:`mdgs.actuation.coupled_motor_accelerations`, of the rigid tree and of MDGS's "dynamics" prior).

Checked against MuJoCo itself: a box pressed into the floor, flat or tilted onto an edge, still, moving or sliding,
has MuJoCo's accelerations (``mj_forward`` with the pyramidal cone and the Newton solver run to 1e-14); a paddle
hinged to a spinning free base, sliding on the floor, steps as MuJoCo steps it; a box dropped on the floor comes to
rest at MuJoCo's depth. Tolerances: the accelerations agree to 1e-6 relative (float64 on both sides; both solve the
same problem, the pyramid's four edges as rows that may only push, MuJoCo's Newton solver to 1e-14); the paddle's
step of 1e-5 s to 1e-4 m/s^2 read as an acceleration (its position error over h^2: float64 positions near 0.3 m
resolve about 1e-6 m/s^2 at that step, both integrators are semi-implicit Euler from the same state); the resting
depth (7 microns) to 1e-4 relative: at rest the depth is set by the spring and the regularisation alone, not by the
step (MuJoCo steps 0.5 ms, the tree four 2.5 ms substeps a 10 ms frame), and 0.6 s settles both far below that.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch

from mdgs.actuation import coupled_motor_accelerations, drives_of
from mdgs.joints import joints_of
from mdgs.models import MODELS
from mdgs.rigid import project, twist
from mdgs.tree import tree_step

H = 0.05  # half side of the test box (m)


def _options(timestep: float) -> str:
    """The test scenes' options: MuJoCo's pyramidal cone, its Newton solver run to 1e-14, the studies' contact."""
    return (f'<option gravity="0 0 -9.81" cone="pyramidal" timestep="{timestep}" solver="Newton" tolerance="1e-14" '
            'iterations="200"/>\n  <default><geom friction="0.8 0.005 0.0001" solref="0.01 1" solimp="0.95 0.99 0.001"/>'
            '</default>')


BOX = f"""<mujoco model="box">
  {_options(0.0005)}
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="box" pos="0 0 1">
      <freejoint/>
      <geom type="box" size="{H} {H} {H}" mass="2"/>
    </body>
  </worldbody>
</mujoco>
"""
SIGNS = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float)
REF = 0.5 * H * SIGNS  # eight nodes at the box's half-corners, in its body frame


def _pose(tilt: float, depth: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The box turned by ``tilt`` about x with its lowest corner ``depth`` below the floor: quaternion, R, t."""
    q = np.zeros(4)
    mujoco.mju_axisAngle2Quat(q, np.array([1.0, 0.0, 0.0]), tilt)
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, q)
    R = R.reshape(3, 3)
    low = min(float((R @ (H * s))[2]) for s in SIGNS)
    return q, R, np.array([0.0, 0.0, -low - depth])


@pytest.mark.parametrize("depth, vz, tilt, wx, vx", [
    (2e-4, 0.0, 0.0, 0.0, 0.0),  # resting flat, inside the impedance's width
    (1e-3, -0.1, 0.0, 0.0, 0.0),  # sinking flat, at the width
    (3e-3, 0.02, 0.0, 0.0, 0.0),  # rising flat, past the width
    (5e-4, 0.0, 0.3, 0.0, 0.0),  # on an edge, still
    (5e-4, -0.05, 0.3, 0.5, 0.0),  # on an edge, sinking and turning
    (5e-4, -0.05, 0.0, 0.0, 1.5),  # sliding flat along x: the pyramid's edges against the slip let go
    (5e-4, -0.3, 0.3, 2.0, 0.8),  # an edge landing while it slides and turns (a tumbling cube's impact)
])
def test_soft_contact_accelerations_are_mujocos_for_a_box_pressed_into_the_floor(depth, vz, tilt, wx, vx):
    m = mujoco.MjModel.from_xml_string(BOX)
    d = mujoco.MjData(m)
    q, R, t = _pose(tilt, depth)
    d.qpos[:3], d.qpos[3:7] = t, q
    d.qvel[0], d.qvel[2], d.qvel[3] = vx, vz, wx  # a turn about x is about the body's x as well
    mujoco.mj_forward(m, d)
    assert d.ncon in (2, 4) and d.efc_force.min() >= 0
    # the still and sinking cases keep every edge of every pyramid pushing; a slide lets some go (friction at the
    # cone's edge), the case a normal row and two tangent rows would get wrong
    assert (d.efc_force.min() > 0) == (vx == 0)
    ds = drives_of(m, np.ones(8, int), REF)
    x = torch.tensor(REF @ R.T + t)[None]
    v = torch.tensor(np.array([vx, 0.0, vz]) + np.cross(R @ np.array([wx, 0.0, 0.0]), REF @ R.T))[None]
    seg, mass = torch.zeros(8, dtype=torch.long), torch.full((8,), 0.25, dtype=torch.float64)
    acc = coupled_motor_accelerations(x, torch.zeros(1, 0), ds, torch.tensor(REF), seg, 1, v=v, mass=mass, dt=0.0025,
                                      contact="soft")
    a, alpha = project(acc, x, twist(x, v, seg, 1, mass), seg, 1, mass)
    scale = np.abs(d.qacc).max()
    np.testing.assert_allclose(a[0, 0].numpy(), d.qacc[:3], rtol=1e-6, atol=1e-6 * scale)
    np.testing.assert_allclose(alpha[0, 0].numpy(), R @ d.qacc[3:], rtol=1e-6, atol=1e-6 * scale)


CHAIN = f"""<mujoco model="chain">
  {_options(1e-5)}
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="base" pos="0 0 0.3">
      <freejoint/>
      <geom type="box" size="0.1 0.05 0.03" mass="3"/>
      <body name="paddle" pos="0.12 0 0">
        <joint type="hinge" axis="0 1 0"/>
        <geom type="box" size="0.02 0.04 0.1" pos="0 0 -0.1" mass="0.5"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_a_paddle_hinged_to_a_spinning_base_steps_as_mujoco_steps_it_while_it_slides_on_the_floor():
    """A contact on a child of a chain: MuJoCo's rows hold ``J qacc``, the point's acceleration less the chain's
    Coriolis and centripetal part at ``qacc = 0`` (its ``cdof_dot qvel``), not less the child's own centripetal part
    about its mass centre; with the base spinning at 4 rad/s and the hinge turning, the two differ by tens of m/s^2
    at the paddle. One semi-implicit Euler step of 1e-5 s from MuJoCo's state on both sides."""
    m = mujoco.MjModel.from_xml_string(CHAIN)
    d = mujoco.MjData(m)
    q = np.zeros(4)
    mujoco.mju_axisAngle2Quat(q, np.array([1.0, 0.0, 0.0]), 0.2)
    d.qpos[3:7], d.qpos[7] = q, 0.3
    d.qvel[:] = [0.3, 0.1, -0.05, 0.5, -1.0, 4.0, 3.0]  # the base's origin, its local angular velocity, the hinge
    mujoco.mj_kinematics(m, d)
    corners = [d.geom_xpos[2] + d.geom_xmat[2].reshape(3, 3) @ (m.geom_size[2] * s) for s in SIGNS]
    d.qpos[2] += -min(c[2] for c in corners) - 5e-4  # the paddle's lowest corner 0.5 mm deep
    mujoco.mj_forward(m, d)
    assert d.ncon >= 1 and {int(m.geom_bodyid[d.contact[i].geom2]) for i in range(d.ncon)} == {2}
    assert d.efc_force.min() == 0  # it slides: edges of the pyramid let go
    body = np.repeat([1, 2], 8)
    ref = np.concatenate([0.5 * m.geom_size[1] * SIGNS, m.geom_pos[2] + 0.5 * m.geom_size[2] * SIGNS])

    def nodes_and_velocities():
        x = np.stack([d.xpos[b] + d.xmat[b].reshape(3, 3) @ r for b, r in zip(body, ref, strict=True)])
        vel = np.zeros((3, 6))
        for b in (1, 2):
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, b, vel[b], 0)
        # mj_objectVelocity gives a body's velocity at its mass centre, xipos
        return x, np.stack([vel[b, 3:] + np.cross(vel[b, :3], xi - d.xipos[b]) for b, xi in zip(body, x, strict=True)])

    x, v = nodes_and_velocities()
    ds = drives_of(m, body, ref)
    seg = torch.tensor(body - 1)
    mass = torch.tensor(np.repeat(m.body_mass[1:] / 8, 8))
    xn, _ = tree_step(torch.tensor(x)[None], torch.tensor(v)[None], torch.zeros(1, 0), ds, torch.tensor(ref), seg, 2,
                      mass, m.opt.timestep, joints=joints_of(m, body, ref), joint_velocities="coordinates",
                      contact="soft")
    mujoco.mj_step(m, d)
    mujoco.mj_kinematics(m, d)
    x_mj, _ = nodes_and_velocities()
    as_acc = np.abs(xn[0].numpy() - x_mj).max() / m.opt.timestep ** 2  # m/s^2
    assert as_acc < 1e-4


def test_the_rigid_contact_stops_the_same_sinking_box_where_the_soft_one_lets_it_spring_back():
    """The rule matters: at 1 mm deep and sinking at 0.1 m/s the rigid rule stops the corners within the step
    (``a = 0.1 / dt`` up), the soft one pushes back with MuJoCo's spring and damper, a different number."""
    m = mujoco.MjModel.from_xml_string(BOX)
    ds = drives_of(m, np.ones(8, int), REF)
    _, R, t = _pose(0.0, 1e-3)
    x = torch.tensor(REF @ R.T + t)[None]
    v = torch.tensor(np.tile([0.0, 0.0, -0.1], (8, 1)))[None]
    seg, mass = torch.zeros(8, dtype=torch.long), torch.full((8,), 0.25, dtype=torch.float64)
    az = {rule: float(coupled_motor_accelerations(x, torch.zeros(1, 0), ds, torch.tensor(REF), seg, 1, v=v, mass=mass,
                                                  dt=0.0025, contact=rule)[0, :, 2].mean()) for rule in ("rigid", "soft")}
    assert az["rigid"] == pytest.approx(0.1 / 0.0025, rel=1e-3)
    assert abs(az["soft"] - az["rigid"]) > 5.0


def test_a_box_dropped_on_the_floor_comes_to_rest_at_mujocos_depth_under_soft_contact():
    m = mujoco.MjModel.from_xml_string(BOX)
    d = mujoco.MjData(m)
    q, R, t = _pose(0.0, -0.01)  # 1 cm above the floor
    d.qpos[:3], d.qpos[3:7] = t, q
    for _ in range(1200):  # 0.6 s
        mujoco.mj_step(m, d)
    depth_mj = H - d.qpos[2]
    ds = drives_of(m, np.ones(8, int), REF)
    x = torch.tensor(REF @ R.T + t)[None]
    v = torch.zeros_like(x)
    seg, mass = torch.zeros(8, dtype=torch.long), torch.full((8,), 0.25, dtype=torch.float64)
    for _ in range(60):  # 0.6 s of 10 ms frames
        x, v = tree_step(x, v, torch.zeros(1, 0), ds, torch.tensor(REF), seg, 1, mass, 0.01, substeps=4,
                         trapezoidal=True, contact="soft")
    depth = H - float(x[0, :, 2].mean())
    assert 1e-6 < depth_mj < 1e-4  # a soft contact's depth: sunk, by microns here
    assert depth == pytest.approx(depth_mj, rel=1e-4)
    assert float(v.abs().max()) < 1e-3


def test_the_contact_rule_is_checked_and_the_soft_contact_is_refused_with_push_out():
    ct, md = MODELS["constant-twist"], MODELS["mdgs"]
    with pytest.raises(ValueError, match="contact must be one of 'rigid', 'soft'"):
        ct.Config(dynamics=True, contact="springy")
    with pytest.raises(ValueError, match="set push_out = false with contact"):
        ct.Config(dynamics=True, push_out=True, contact="soft")
    with pytest.raises(ValueError, match="set dynamics = true"):
        ct.Config(contact="soft")
    with pytest.raises(ValueError, match="set push_out = false with contact"):
        md.Config(actuation="dynamics", push_out=True, prior_contact="soft")
    with pytest.raises(ValueError, match="set actuation"):
        md.Config(prior_contact="soft")
    assert ct.Config().contact == md.Config().prior_contact == "rigid"
    with pytest.raises(ValueError, match="set push_out = false with contact"):
        tree_step(torch.zeros(1, 8, 3), torch.zeros(1, 8, 3), torch.zeros(1, 0), drives_of(
            mujoco.MjModel.from_xml_string(BOX), np.ones(8, int), REF), torch.tensor(REF), torch.zeros(8, dtype=torch.long),
            1, torch.ones(8), 0.01, pushed_out=True, contact="soft")


def test_untrained_mdgs_with_the_soft_contact_prior_steps_as_the_soft_contact_rigid_tree(tiny_cubli):
    """``prior_contact = "soft"`` reaches the prior's tree: MDGS untrained (g's output zero) is the "rigid tree ...,
    soft contact" reference, here in the studies' setting (four substeps, joint coordinates, velocity Verlet), to
    2e-6 m over 10 frames (float32 against float64: 1.6e-7 here); the rigid-contact reference, whose cube rests on the
    floor instead of microns deep in it, is 1e-5 m off or more (1.8e-5 here)."""
    from mdgs.data.split import load_split
    from mdgs.models.base import State, batch_of

    tr, te = load_split(tiny_cubli / "train.h5"), load_split(tiny_cubli / "test.h5")
    b = batch_of(te, te.pairs(0)[:4], "cpu")
    ct, md = MODELS["constant-twist"], MODELS["mdgs"]
    tree = dict(joints=True, trapezoidal=True, joint_velocities="coordinates")
    sims = {"soft": ct.from_data(te, ct.Config(dynamics=True, substeps=4, contact="soft", **tree)),
            "rigid": ct.from_data(te, ct.Config(dynamics=True, substeps=4, push_out=True, **tree)),
            "mdgs": md.from_data(tr, md.Config(actuation="dynamics", prior_substeps=4, prior_contact="soft", **tree))}
    traj = {}
    for name, sim in sims.items():
        sim.bind(te)
        sim.eval()
        st, xs = State(b.x, b.v), []
        with torch.no_grad():
            for _ in range(10):
                st = sim.step(st, b.ctrl)
                xs.append(st.x)
        traj[name] = torch.stack(xs, 1).double()
    moving = ~sims["mdgs"].scene_on("cpu").static
    off = {k: float((traj[k] - traj["soft"])[:, :, moving].abs().max()) for k in ("mdgs", "rigid")}
    assert off["mdgs"] < 2e-6 and off["rigid"] > 1e-5


def test_the_compiled_soft_contact_gives_the_eager_accelerations():
    """Traced (``torch.compile``, dynamo's ``eager`` backend, no graph break) the soft contact holds every candidate in
    a slot and runs every pass: the same accelerations as eagerly, for a box just above the floor (nothing held), one
    pressed in flat and sinking, and one on an edge turning, to 1e-9 of the acceleration's scale (float64 solves of
    different sizes)."""
    m = mujoco.MjModel.from_xml_string(BOX)
    ds = drives_of(m, np.ones(8, int), REF)
    seg, mass = torch.zeros(8, dtype=torch.long), torch.full((8,), 0.25, dtype=torch.float64)
    compiled = torch.compile(coupled_motor_accelerations, backend="eager", fullgraph=True)
    for tilt, depth, vz, wx in [(0.0, -1e-3, -0.1, 0.0), (0.0, 1e-3, -0.1, 0.0), (0.3, 5e-4, -0.05, 0.5)]:
        _, R, t = _pose(tilt, depth)
        x = torch.tensor(REF @ R.T + t)[None]
        v = torch.tensor(np.array([0.0, 0.0, vz]) + np.cross(R @ np.array([wx, 0.0, 0.0]), REF @ R.T))[None]
        args = (x, torch.zeros(1, 0), ds, torch.tensor(REF), seg, 1)
        eager = coupled_motor_accelerations(*args, v=v, mass=mass, dt=0.0025, contact="soft")
        got = compiled(*args, v=v, mass=mass, dt=0.0025, contact="soft")
        np.testing.assert_allclose(got.numpy(), eager.numpy(), rtol=0, atol=1e-9 * max(1.0, float(eager.abs().max())))


def _soft_system(g: torch.Generator, B: int, S6: int, C0: int, U: int) -> tuple:
    """A random system of :func:`mdgs.actuation._unilateral_solve`: a positive definite ``M`` [B, S6, S6], forces
    ``F``, ``C0`` bilateral rows ``Jm``, ``b0``, ``U`` unilateral rows ``Ju``, references ``ru``, regularisation ``Ru``
    from 1e-3 to 10 and about half of them held."""
    f64 = dict(dtype=torch.float64)
    L = torch.randn(B, S6, S6, generator=g, **f64)
    M = L @ L.transpose(-1, -2) + S6 * torch.eye(S6, **f64)
    F, Jm, b0 = (torch.randn(B, S6, generator=g, **f64), torch.randn(B, C0, S6, generator=g, **f64),
                 torch.randn(B, C0, generator=g, **f64))
    Ju, ru = torch.randn(B, U, S6, generator=g, **f64), torch.randn(B, U, generator=g, **f64)
    Ru = 10 ** (4 * torch.rand(B, U, generator=g, **f64) - 3)
    return M, F, Jm, b0, Ju, ru, Ru, torch.rand(B, U, generator=g) < 0.5


@pytest.mark.parametrize("static, fixed", [(False, False), (True, False), (False, True), (True, True)])
def test_eliminating_the_soft_rows_gives_the_solution_with_their_forces_as_unknowns(static, fixed):
    """The soft rows' forces ``l = (J z - a_ref) / R`` are eliminated from the system (Schur's complement) and the
    bilateral rows' by solving in the coordinates that random completing rows ``D`` give
    (:func:`mdgs.actuation._unilateral_solve`): on random systems (a positive definite ``M`` of 3 bodies, 9 bilateral
    rows, 40 unilateral ones of which about half are held, ``R`` from 1e-3 to 10: on the study scenes' soft-8 test
    rollouts no R was below 1e-3) the accelerations equal those of the full system written here with every held row's
    force and every bilateral row's an unknown and the same active-set passes, to 1e-9 relative (float64; the full
    systems have 27 to 67 unknowns, the solve's passes 9). With ``fixed`` the first body is held
    still by the first 6 bilateral rows, as the world's elements are, and leaves the system first; ``static`` runs the
    compiled steps' path (every row in every pass). Started from other states (every held row free, or the settled
    ones) the solve settles on the same solution, and given the completing rows' values ``d`` it adds the bias
    accelerations' ``Ju z0`` to the references as a separate solve for ``z0`` does."""
    from mdgs.actuation import SOFT_CONTACT_PASSES, _unilateral_solve

    g = torch.Generator().manual_seed(3)
    B, S6, C0, U = 4, 18, 9, 40
    f64 = dict(dtype=torch.float64)
    M, F, Jm, b0, Ju, ru, Ru, held = _soft_system(g, B, S6, C0, U)
    keep = None
    if fixed:  # body 0 held still: z[:, :6] = 0
        Jm[:, :6], b0[:, :6], keep = torch.eye(6, S6, **f64), 0.0, torch.arange(6, S6)

    def full(active):  # [M Jm^T Ja^T; Jm 0 0; Ja 0 -R_a] [z; l_m; l_a] = [F; b0; a_ref_a], one batch row at a time
        out = []
        for i in range(B):
            a = active[i].nonzero().squeeze(-1)
            Ja, n = Ju[i, a], len(a)
            K = torch.zeros(S6 + C0 + n, S6 + C0 + n, **f64)
            K[:S6, :S6], K[:S6, S6:S6 + C0], K[:S6, S6 + C0:] = M[i], Jm[i].T, Ja.T
            K[S6:S6 + C0, :S6], K[S6 + C0:, :S6] = Jm[i], Ja
            K[S6 + C0:, S6 + C0:] = -torch.diag(Ru[i, a])
            out.append(torch.linalg.solve(K, torch.cat([F[i], b0[i], ru[i, a]]))[:S6])
        return torch.stack(out)

    active = held
    for _ in range(SOFT_CONTACT_PASSES):  # MuJoCo's Newton steps on which rows push
        z = full(active)
        pushes = held & ((Ju @ z.unsqueeze(-1)).squeeze(-1) < ru)
        if bool((pushes == active).all()):
            break
        active = pushes
    assert bool((active != held).any()) and bool(active.any())  # some held rows let go, some push: both cases checked
    D = torch.randn(B, S6 - C0, S6, generator=g, **f64)  # any rows that complete Jm to an invertible square
    got, states = _unilateral_solve(M, F, Jm, b0, D, Ju, ru, Ru, held, static, keep)
    if fixed:
        assert float(z[:, :6].abs().max()) < 1e-12 and bool((got[:, :6] == 0).all())
    np.testing.assert_allclose(got.numpy(), z.numpy(), rtol=0, atol=1e-9 * float(z.abs().max()))
    assert torch.equal(states, active)  # the states the solve settled on, every candidate's (held or not)
    # started elsewhere (every held row free, or from the settled states) it settles on the same solution
    for start in (torch.zeros_like(held), active):
        again, states = _unilateral_solve(M, F, Jm, b0, D, Ju, ru, Ru, held, static, keep, start=start)
        np.testing.assert_allclose(again.numpy(), z.numpy(), rtol=0, atol=1e-9 * float(z.abs().max()))
        assert torch.equal(states, active)
    # given d, the rows hold ru + Ju z0, z0 the bias accelerations of [Jm; D] z0 = [b0; d] (solved here on its own;
    # the solve reads them off its own factorisation): the same solution from the references less Ju z0
    d = torch.randn(B, S6 - C0, generator=g, **f64)
    z0 = torch.linalg.solve(torch.cat([Jm, D], 1), torch.cat([b0, d], -1))
    less = ru - (Ju @ z0.unsqueeze(-1)).squeeze(-1)
    shifted, states = _unilateral_solve(M, F, Jm, b0, D, Ju, less, Ru, held, static, keep, d=d)
    np.testing.assert_allclose(shifted.numpy(), z.numpy(), rtol=0, atol=1e-9 * float(z.abs().max()))
    assert torch.equal(states, active)


@pytest.mark.parametrize("n", [1, 8, 9, 16])
def test_the_compiled_passes_elimination_solves_as_the_librarys_lu(n):
    """:func:`mdgs.actuation._solve_unpivoted`, the compiled soft passes' solve, on random systems like theirs: a
    joint-space inertia (symmetric positive definite, condition up to 1e4 as a light flywheel on a heavy cube gives)
    plus contact stiffness ``(J G)^T W (J G)`` and a small skew term (the step's gyroscopic linearisation), a batch of
    8: the solution of ``torch.linalg.solve`` to 1e-10 relative (float64; elimination without pivoting loses no more
    than the condition number's digits on such systems). Traced (dynamo, no graph break) it gives the same."""
    from mdgs.actuation import _solve_unpivoted

    g = torch.Generator().manual_seed(n)
    f64 = dict(dtype=torch.float64)
    Q, _ = torch.linalg.qr(torch.randn(8, n, n, generator=g, **f64))
    M = Q @ torch.diag_embed(10 ** (4 * torch.rand(8, n, generator=g, **f64) - 2)) @ Q.transpose(-1, -2)
    J = torch.randn(8, 12, n, generator=g, **f64)
    S = torch.randn(8, n, n, generator=g, **f64)
    K = M + J.transpose(-1, -2) @ (torch.rand(8, 12, 1, generator=g, **f64) * J) + 1e-3 * (S - S.transpose(-1, -2))
    b = torch.randn(8, n, generator=g, **f64)
    want = torch.linalg.solve(K, b)
    for got in (_solve_unpivoted(K, b), torch.compile(_solve_unpivoted, backend="eager", fullgraph=True)(K, b)):
        np.testing.assert_allclose(got.numpy(), want.numpy(), rtol=0, atol=1e-10 * float(want.abs().max()))


def test_the_compiled_passes_stop_once_the_states_repeat_with_the_solution_of_every_pass():
    """Compiled for the CPU, the soft solve's passes run in a ``torch.while_loop`` that stops once the rows' states
    repeat (:func:`mdgs.actuation._unilateral_solve`), where the uncompiled static path runs every pass. Compiled by
    inductor (one graph), on random systems as in the elimination test (9 unknowns a pass): the accelerations of the
    uncompiled static path to 1e-9 relative (fused elimination against the library's LU, float64) and the same states,
    from every held row pushing (several passes) and from the settled states (one pass), for a batch of 4 and of 1.
    The completing rows ``D`` span ``Jm``'s null space, as well conditioned as the tree's own (identity rows, joint
    axes): with random ones the passes' systems are ill-conditioned enough that elimination without pivoting and the LU
    part at 1e-8 relative."""
    from mdgs.actuation import _unilateral_solve

    g = torch.Generator().manual_seed(5)
    S6, C0, U = 18, 9, 40
    compiled = torch.compile(_unilateral_solve, fullgraph=True)
    for B in (4, 1):
        M, F, Jm, b0, Ju, ru, Ru, held = _soft_system(g, B, S6, C0, U)
        D = torch.linalg.svd(Jm)[2][:, C0:]  # rows spanning Jm's null space: [Jm; D] conditioned as Jm (about 6)
        want, states = _unilateral_solve(M, F, Jm, b0, D, Ju, ru, Ru, held, True)
        assert bool((states != held).any())  # some held rows let go: the loop runs more than one pass
        for start in (None, states):
            got, got_states = compiled(M, F, Jm, b0, D, Ju, ru, Ru, held, True, start=start)
            np.testing.assert_allclose(got.numpy(), want.numpy(), rtol=0, atol=1e-9 * float(want.abs().max()))
            assert torch.equal(got_states, states)


def test_the_soft_contact_tree_is_a_reference_of_mdgs_evaluate_and_is_refused_with_push_out():
    import typer

    from mdgs.cli.evaluate import _parse_reference

    assert _parse_reference("constant-twist:dynamics+joints+trapezoidal+coordinates+substeps=4+soft-contact")[1] == {
        "dynamics": True, "joints": True, "trapezoidal": True, "joint_velocities": "coordinates", "substeps": 4,
        "contact": "soft"}
    for bad in ("constant-twist:joints+soft-contact", "constant-twist:dynamics+push-out+soft-contact"):
        with pytest.raises(typer.Exit):
            _parse_reference(bad)


@pytest.mark.parametrize("scene", ["cubli-triple", "rotational-center"])
def test_the_soft_tree_at_mujocos_timestep_reproduces_the_recorded_frames_to_round_off(scene, tiny_cubli, tmp_path):
    """Stepped by semi-implicit Euler at MuJoCo's own timestep (MuJoCo's integrator and step), the rigid tree with
    the soft contact is MuJoCo's model of the scene: one frame from every recorded state lands on the next recorded
    frame to the float32 storage's round-off (positions near 0.1 m stored to about 1e-8 m: 1e-16 m^2; bound 1e-13).
    The Cubli's cube touches the floor as a root whose frame's origin is its mass centre; rotational-center's disc
    touches it two hinges down a free base whose mass centre is off its frame's origin (without the chain's bias in
    the rows' references this fails). Frame 0 is left out: a scene placed exactly
    on the floor has MuJoCo's contacts at distance 0, which MuJoCo does not hold, and float32 positions cannot say
    which side of 0 a corner is."""
    from mdgs.data.generate import GenerateConfig, generate
    from mdgs.data.split import load_split
    from mdgs.models.base import State

    if scene == "cubli-triple":
        folder = tiny_cubli
    else:
        folder = tmp_path / scene
        generate(GenerateConfig(scene=scene, out=str(folder), preset="tiny"))
    d = load_split(folder / "test.h5")
    n_mj = round(float(d.frame_dt) / float(d.mj_model().opt.timestep))
    ct = MODELS["constant-twist"]
    m = ct.from_data(d, ct.Config(dynamics=True, joints=True, joint_velocities="coordinates", contact="soft",
                                  substeps=n_mj))
    m.bind(d)
    moving = ~np.asarray(d.static["node_static"], bool)
    x = torch.as_tensor(d.x[:, 1:-1].reshape(-1, *d.x.shape[2:])).double()
    v = torch.as_tensor(d.v[:, 1:-1].reshape(-1, *d.v.shape[2:])).double()
    u = torch.as_tensor(d.ctrl[:, 1:-1].reshape(-1, d.ctrl.shape[-1])).double()
    with torch.no_grad():
        s = m.step(State(x, v), u)
    err = ((s.x.numpy() - d.x[:, 2:].reshape(-1, *d.x.shape[2:]))[:, moving] ** 2).sum(-1).mean(-1)
    assert err.max() < 1e-13

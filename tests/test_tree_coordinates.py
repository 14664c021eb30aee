"""The rigid tree stepped in its joint coordinates (``joint_velocities = "coordinates"`` of :func:`mdgs.tree.tree_step`).

What is checked, against sources independent of the code: without ``trapezoidal`` the step is MuJoCo's own
semi-implicit Euler (``integrator="Euler"``, no damping: ``qvel += h qacc``, then ``qpos += h qvel``), so a cart
with a double pendulum on it (a slide and two hinges, every body's pose read from MuJoCo's ``xmat, xpos``) follows
MuJoCo stepped at the same timestep to 1e-9 m; with ``trapezoidal`` (velocity Verlet) the error against MuJoCo's
RK4 at a 100x finer step falls by 4x per halved step (second order) where Euler's falls by 2x, and a double pendulum
keeps its energy to 1e-3 where the trapezoidal step of the bodies' twists gains 50x more. The joints hold by
construction: on a gimbal whose rotor spins at 90 rad/s the anchors stay together to 1e-9 m with no projection.

Tolerances: float64 throughout; the forward dynamics is MuJoCo's ``qacc`` to 1e-9 relative (tests/test_dynamics.py)
and the twists are fitted to exact rigid placements, so 40 Euler steps agree to 1e-9 m; the order test's ratios (4
and 2) are asserted with margins (above 3, below 2.5) that a first- or second-order error cannot cross.
"""

from __future__ import annotations

from types import SimpleNamespace

import mujoco
import numpy as np
import pytest
import torch
from test_dynamics import GIMBAL  # rotational-center's build

from mdgs.actuation import drives_of
from mdgs.joints import joints_of
from mdgs.models.base import State
from mdgs.models.references import ConstantTwist, ConstantTwistConfig
from mdgs.structure import kabsch

CART = """<mujoco model="cart"><option gravity="0 0 -9.81" timestep="{h}" integrator="{integrator}"/><worldbody>
  <body name="cart" pos="0 0 0.3"><joint name="rail" type="slide" axis="1 0.1 0"/>
    <geom type="box" size="0.2 0.1 0.05" mass="2"/>
    <body name="upper" pos="0 0 0.05" euler="0.1 0 0.2"><joint name="shoulder" type="hinge" axis="0 1 0.1"/>
      <geom type="box" size="0.02 0.03 0.2" pos="0 0 0.2" mass="0.5"/>
      <body name="lower" pos="0 0 0.4"><joint name="elbow" type="hinge" axis="0.1 1 0" pos="0 0 0.01"/>
        <geom type="box" size="0.02 0.02 0.15" pos="0 0 0.15" mass="0.3"/></body></body></body>
</worldbody></mujoco>"""
TET = np.array([[0.03, 0, 0], [-0.015, 0.026, 0], [-0.015, -0.026, 0], [0, 0, 0.02]])  # fixes each body's rotation


def _scene(xml: str):
    """A ConstantTwist bound by hand to the MJCF ``xml`` (bodies 1.. each with four nodes around its mass centre),
    with the MuJoCo model and data and ``place(qpos) -> nodes [N, 3]``."""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    nb = m.nbody - 1
    body = np.repeat(np.arange(1, m.nbody), 4)
    ref = np.concatenate([TET + m.body_ipos[b] for b in range(1, m.nbody)])

    def place(q):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        return np.concatenate([ref[body == b] @ d.xmat[b].reshape(3, 3).T + d.xpos[b] for b in range(1, m.nbody)])

    seg = torch.as_tensor(body - 1)
    mass = torch.as_tensor(np.repeat(m.body_mass[1:], 4) / 4)
    scene = SimpleNamespace(obj=seg, n_obj=nb, mass=mass, ref_shape=torch.tensor(ref),
                            static=torch.zeros(len(body), dtype=torch.bool))

    def sim(dt: float, **settings) -> ConstantTwist:
        s = ConstantTwist(ConstantTwistConfig(dynamics=True, joints=True, **settings))
        s._scene, s._dt, s._drives, s._joints = scene, dt, drives_of(m, body, ref), joints_of(m, body, ref)
        return s

    return m, d, place, sim


def _start(m, place, qpos, qvel):
    """Nodes and their velocities [1, N, 3] at ``qpos, qvel`` (the velocities by a central difference, 1e-12)."""
    qp, qm = qpos.copy(), qpos.copy()
    mujoco.mj_integratePos(m, qp, qvel, 1e-6)
    mujoco.mj_integratePos(m, qm, qvel, -1e-6)
    return torch.tensor(place(qpos))[None], torch.tensor((place(qp) - place(qm)) / 2e-6)[None]


QPOS, QVEL = np.array([0.1, 0.8, -0.5]), np.array([0.5, 2.0, -3.0])


def _cart_rollout(h: float, frames: int, **settings) -> np.ndarray:
    """The cart and double pendulum from ``QPOS, QVEL`` stepped ``frames`` frames of ``h`` (one substep each) by the
    rigid tree in joint coordinates: the nodes at the end [N, 3]."""
    m, _, place, sim = _scene(CART.format(h=h, integrator="Euler"))
    tree = sim(h, joint_velocities="coordinates", **settings)
    s = State(*_start(m, place, QPOS, QVEL))
    for _ in range(frames):
        s = tree.step(s, torch.zeros(1, 0))
    return s.x[0].numpy()


def _mujoco(h: float, frames: int, integrator: str) -> np.ndarray:
    """MuJoCo's own nodes after ``frames`` steps of ``h`` from ``QPOS, QVEL`` [N, 3]."""
    m, d, place, _ = _scene(CART.format(h=h, integrator=integrator))
    d.qpos[:], d.qvel[:] = QPOS, QVEL
    for _ in range(frames):
        mujoco.mj_step(m, d)
    return place(d.qpos.copy())


def test_semi_implicit_euler_in_joint_coordinates_is_mujocos_euler_on_a_cart_with_a_double_pendulum():
    ours = _cart_rollout(0.005, 40, trapezoidal=False)
    theirs = _mujoco(0.005, 40, "Euler")
    assert np.abs(ours - theirs).max() < 1e-9
    m, _, place, _ = _scene(CART.format(h=0.005, integrator="Euler"))
    assert np.abs(ours - place(QPOS)).max() > 0.05  # it moved: the agreement is not two bodies at rest


def test_velocity_verlet_in_joint_coordinates_is_second_order_where_euler_is_first():
    """The error at t = 0.2 s against MuJoCo's RK4 at a 100x finer step: halving the step (10 ms to 5 ms) divides
    Verlet's by more than 3 and Euler's by less than 2.5."""
    truth = _mujoco(0.0001, 2000, "RK4")
    err = {(trap, h): np.abs(_cart_rollout(h, round(0.2 / h), trapezoidal=trap) - truth).max()
           for trap in (True, False) for h in (0.01, 0.005)}
    assert err[True, 0.01] / err[True, 0.005] > 3, err
    assert err[False, 0.01] / err[False, 0.005] < 2.5, err
    assert err[True, 0.005] < err[False, 0.005], err


def _pendulum_energy(frames: int = 100, **settings) -> list[float]:
    """The cart held still (no gravity along its rail) and its double pendulum released from ``QPOS`` at rest,
    stepped in 10 ms frames: the kinetic plus potential energy (J) of the three bodies every 10 frames, from the
    poses and twists fitted to the nodes."""
    from mdgs.rigid import twist

    m, _, place, sim = _scene(CART.format(h=0.01, integrator="Euler"))
    tree = sim(0.01, **settings)
    ds = tree._drives
    s = State(*_start(m, place, QPOS, np.zeros(3)))
    seg, mass, ref = tree._scene.obj, tree._scene.mass, tree._scene.ref_shape
    out = []
    for f in range(frames + 1):
        if f % 10 == 0:
            R, t = kabsch(ref, s.x, seg, 3)
            tw = twist(s.x, s.v, seg, 3, mass)
            e = 0.0
            for b in range(3):
                inertia = R[0, b] @ torch.as_tensor(ds.inertia[b]) @ R[0, b].T
                com = R[0, b] @ torch.as_tensor(ds.com[b]) + t[0, b]
                w = tw.omega[0, b]
                vc = tw.vc[0, b] + torch.linalg.cross(w, com - tw.c[0, b])
                e += 0.5 * ds.mass[b] * float(vc @ vc) + 0.5 * float(w @ inertia @ w) + 9.81 * ds.mass[b] * float(com[2])
            out.append(e)
        if f < frames:
            s = tree.step(s, torch.zeros(1, 0))
    return out


def test_a_double_pendulum_keeps_its_energy_in_joint_coordinates_and_gains_it_with_the_trapezoidal_twists():
    """Released from rest, one substep per 10 ms frame for 1 s (the energy is 10.56 J): velocity Verlet in joint
    coordinates stays within 0.01 J of the start (it measured 0.008), where the trapezoidal twists projected onto the
    joints depart over 50x further (parent-first 0.99 J, momentum 77 J here) and so does semi-implicit Euler in
    joint coordinates, a first-order step (1.6 J)."""
    verlet = np.array(_pendulum_energy(joint_velocities="coordinates", trapezoidal=True))
    drift = np.abs(verlet - verlet[0]).max()
    assert drift < 0.01, verlet
    for settings in (dict(joint_velocities="parent", trapezoidal=True), dict(joint_velocities="momentum", trapezoidal=True),
                     dict(joint_velocities="coordinates", trapezoidal=False)):
        other = np.array(_pendulum_energy(**settings))
        assert np.abs(other - other[0]).max() > 50 * drift, (settings, other, verlet)


@pytest.mark.parametrize("trapezoidal", [True, False])
def test_the_joints_hold_by_construction_on_a_gimbal_whose_rotor_spins_at_90_rad_s(trapezoidal):
    """The gimbal in free flight, 60 frames of 10 ms in 4 substeps, nothing projected: each hinge's anchor, as the
    parent's and the child's poses (fitted to their nodes) place it, stays together to 1e-9 m, and the rotor still
    spins (its rate across the hinge, read the same way, moves the rotor more than 10 m over the run's nodes)."""
    m, _, place, sim = _scene(GIMBAL)
    tree = sim(0.01, joint_velocities="coordinates", trapezoidal=trapezoidal, substeps=4)
    s = State(*_start(m, place, m.qpos0.copy(), np.array([0.1, 0, 0, 2.0, 1.0, 3.0, 0.0, -90.0])))
    x0 = s.x.clone()
    links = [lk for lk in tree._drives.links if lk.kind == "hinge"]
    ref, seg = tree._scene.ref_shape, tree._scene.obj
    apart = 0.0
    for _ in range(60):
        s = tree.step(s, torch.zeros(1, 0))
        R, t = kabsch(ref, s.x, seg, 3)
        for lk in links:
            a_parent = R[0, lk.parent] @ torch.as_tensor(lk.anchor) + t[0, lk.parent]
            a_child = R[0, lk.child] @ torch.as_tensor(lk.frame0.T @ (lk.anchor - lk.origin)) + t[0, lk.child]
            apart = max(apart, float((a_parent - a_child).norm()))
    assert apart < 1e-9
    assert float((s.x - x0).norm()) > 0.1


def test_the_coordinates_step_exports_for_compiling_where_push_out_never_moves_the_bodies():
    """``compile_step`` exports a step after one eager step; push-out then calls the joints' projection, whose groups
    are built with data-dependent shapes (``torch.nonzero``), so they must exist before the export. On the cart
    above a floor it does not reach, the eager step never pushes, while the traced step, which cannot branch on the
    data, always projects: the export still traces (it failed with a data-dependent guard before the groups were
    built up front), and the exported step gives the eager step's nodes to 1e-12 m."""
    floored = CART.replace("<worldbody>", '<worldbody><geom type="plane" size="5 5 0.1" pos="0 0 -2"/>')
    m, _, place, sim = _scene(floored.format(h=0.01, integrator="Euler"))
    tree = sim(0.01, joint_velocities="coordinates", trapezoidal=True, substeps=2, push_out=True)
    assert len(tree._drives.corner_obj)  # the boxes have corners the floor could push, 2 m below them
    s = State(*_start(m, place, QPOS, QVEL))
    c = torch.zeros(1, 0)
    with torch.no_grad():
        eager = tree.step(s, c)

    class Step(torch.nn.Module):
        def forward(self, x, v, u):
            out = tree.step(State(x, v, {}), u)
            return out.x, out.v

    with torch.no_grad():
        program = torch.export.export(Step(), (s.x, s.v, c), strict=False)
        x, _ = program.module()(s.x, s.v, c)
    assert float((x - eager.x).abs().max()) < 1e-12

"""The cart and pole of the user scene left to themselves: how each joint-velocity rule of the rigid tree keeps their
energy, which nothing but the integrator and the projection can change (no control, no damping, no contact: the
cart and pole do not collide; the free box, which lands on the floor, is left out of the sum).

    python benchmarks/mdgs_probes/user_scene_energy.py DATA_FOLDER SPLIT [FRAMES]

DATA_FOLDER holds ``hinge_slide_free/SPLIT.h5`` (``mdgs generate --mjcf studies/hinge_slide_free.xml --substeps 10
--preset small --split SPLIT``). For each of the split's first four trajectories, its recorded starting state with the
controls set to zero, stepped FRAMES frames (default 220) by the "rigid tree + joints, trapezoidal, push-out, 4
substeps" reference (``studies/mdgs-substeps.toml``'s) with ``joint_velocities`` "parent" and "momentum": the cart's
and pole's kinetic plus potential energy (J, the MJCF's masses and inertias, each body's pose and twist fitted to its
nodes) every 20 frames, and how far the pole's angle ends from where MuJoCo at the data's timestep puts it. Then,
for each rule on trajectory 0, the kinetic energy that the projections themselves change, summed over every substep
of the FRAMES frames (the rest of the change is the forward dynamics' and the integrator's). Last, trajectory 0's energy
gain after FRAMES frames and the largest on the way, with each rule, at 4, 8 and 16 substeps: how the gain scales
with the substep.
"""
import sys
from pathlib import Path

import numpy as np
import torch

import mdgs.tree
from mdgs.actuation import drives_of
from mdgs.data.split import load_split
from mdgs.graphs import SceneGraph
from mdgs.models import MODELS
from mdgs.models.base import State
from mdgs.rigid import twist
from mdgs.structure import kabsch

torch.set_num_threads(1)
args = sys.argv[1:]
d = load_split(Path(args[0]) / "hinge_slide_free" / f"{args[1]}.h5")
frames = int(args[2]) if len(args) > 2 else 220
sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
dr = drives_of(d.mj_model(), d.static["node_body"], d.static["node_centroid"])
g = float(np.linalg.norm(dr.gravity))
names = {s: d.mj_model().body(int(b)).name for s, b in enumerate(np.unique(d.static["node_body"][~d.static["node_static"]]))}
moving = [s for s in np.flatnonzero(~np.asarray(dr.fixed, bool))]
keep = [s for s in moving if names.get(s) in ("cart", "pole")]
pole = next(s for s in moving if names.get(s) == "pole")
print(f"objects: {names}; summed: {[names[s] for s in keep]}")


def kinetic(x, v) -> float:
    """The cart's and pole's kinetic energy (J) at ``x, v`` [1, N, 3]."""
    R, t = kabsch(sc.ref_shape.double(), x.double(), sc.obj, sc.n_obj)
    tw = twist(x.double(), v.double(), sc.obj, sc.n_obj, sc.mass.double())
    e = 0.0
    for s in keep:
        inertia = R[0, s] @ torch.as_tensor(dr.inertia[s]) @ R[0, s].T
        com = R[0, s] @ torch.as_tensor(dr.com[s]) + t[0, s]
        w = tw.omega[0, s]
        vcom = tw.vc[0, s] + torch.linalg.cross(w, com - tw.c[0, s])
        e += 0.5 * dr.mass[s] * float(vcom @ vcom) + 0.5 * float(w @ inertia @ w)
    return e


def energy_and_angle(x, v):
    """The cart's and pole's kinetic plus potential energy (J) and the pole's angle from upright (rad) at ``x, v``."""
    R, t = kabsch(sc.ref_shape.double(), x, sc.obj, sc.n_obj)
    potential = sum(dr.mass[s] * g * float(R[0, s, 2] @ torch.as_tensor(dr.com[s]) + t[0, s, 2]) for s in keep)
    axis = R[0, pole] @ torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)  # the pole's long axis in the world
    return kinetic(x, v) + potential, float(torch.atan2(axis[0], axis[2]))


ct, mj = MODELS["constant-twist"], MODELS["mujoco"]
TREE = dict(dynamics=True, joints=True, trapezoidal=True, push_out=True, substeps=4)
for tr in range(min(4, d.x.shape[0])):
    x0, v0 = torch.as_tensor(d.x[tr:tr + 1, 0]).double(), torch.as_tensor(d.v[tr:tr + 1, 0]).double()
    u = torch.zeros(1, d.ctrl.shape[-1], dtype=torch.float64)
    ends = {}
    for label, model in (("mujoco dt x1", mj.from_data(d, mj.Config(dt_factor=1))),
                         ("tree, parent", ct.from_data(d, ct.Config(joint_velocities="parent", **TREE))),
                         ("tree, momentum", ct.from_data(d, ct.Config(joint_velocities="momentum", **TREE)))):
        model.bind(d)
        s = model.initial_state(d, np.array([tr]), model.history)
        s = State(x0.to(s.x.dtype), v0.to(s.x.dtype), s.extra)
        es = []
        for f in range(frames + 1):
            if f % 20 == 0:
                es.append(energy_and_angle(s.x.double(), s.v.double())[0])
            if f < frames:
                s = model.step(s, u.to(s.x.dtype))
        ends[label] = energy_and_angle(s.x.double(), s.v.double())[1]
        off = "" if label.startswith("mujoco") else f"; pole angle {np.degrees(ends[label] - ends['mujoco dt x1']):+8.2f} deg off MuJoCo's"
        print(f"trajectory {tr} {label:15s} energy (J) " + " ".join(f"{e:8.3f}" for e in es) + off, flush=True)

# what the projections themselves do to the kinetic energy: the tree step's calls wrapped
changes: list[float] = []
joints0, velocities0 = mdgs.tree.project_joints, mdgs.tree.project_velocities


def joints_logged(x, v, *a):
    xj, vj = joints0(x, v, *a)
    changes.append(kinetic(xj, vj) - kinetic(x, v))
    return xj, vj


def velocities_logged(xj, v, *a, x_from=None, dt=None):
    out = velocities0(xj, v, *a, x_from=x_from, dt=dt)
    changes[-1] = kinetic(xj, out) - kinetic(x_from, v)  # replaces the parent-first change just logged
    return out


mdgs.tree.project_joints, mdgs.tree.project_velocities = joints_logged, velocities_logged
x0, v0 = torch.as_tensor(d.x[0:1, 0]).double(), torch.as_tensor(d.v[0:1, 0]).double()
for rule in ("parent", "momentum"):
    changes.clear()
    model = ct.from_data(d, ct.Config(joint_velocities=rule, **TREE))
    model.bind(d)
    s = model.initial_state(d, np.array([0]), model.history)
    s = State(x0.to(s.x.dtype), v0.to(s.x.dtype), s.extra)
    u = torch.zeros(1, d.ctrl.shape[-1], dtype=s.x.dtype)
    for _ in range(frames):
        s = model.step(s, u)
    c = np.array(changes)
    print(f"trajectory 0 tree, {rule:8s}: the projections change the kinetic energy by {c.sum():+.3e} J in all over "
          f"{len(c)} substeps (largest gain {c.max():+.1e}, largest loss {c.min():+.1e} J)", flush=True)

mdgs.tree.project_joints, mdgs.tree.project_velocities = joints0, velocities0
for substeps in (4, 8, 16):
    for rule in ("parent", "momentum"):
        model = ct.from_data(d, ct.Config(joint_velocities=rule, **{**TREE, "substeps": substeps}))
        model.bind(d)
        s = model.initial_state(d, np.array([0]), model.history)
        s = State(x0.to(s.x.dtype), v0.to(s.x.dtype), s.extra)
        u = torch.zeros(1, d.ctrl.shape[-1], dtype=s.x.dtype)
        e0 = energy_and_angle(s.x.double(), s.v.double())[0]
        largest = 0.0
        for _ in range(frames):
            s = model.step(s, u)
            largest = max(largest, energy_and_angle(s.x.double(), s.v.double())[0] - e0)
        gain = energy_and_angle(s.x.double(), s.v.double())[0] - e0
        print(f"trajectory 0 tree, {substeps:2d} substeps, {rule:8s}: energy gained {gain:+.4f} J after {frames} frames, "
              f"largest {largest:+.4f} J", flush=True)

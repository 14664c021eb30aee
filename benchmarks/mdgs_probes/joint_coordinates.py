"""The rigid tree stepped in its joints' coordinates (``joint_velocities = "coordinates"``: velocity Verlet with the
trapezoidal setting, semi-implicit Euler without) against the projections onto the joints ("parent", "momentum"), on
the "rigid tree + joints, trapezoidal, push-out, 4 substeps" reference of ``studies/mdgs-substeps.toml``.

    python benchmarks/mdgs_probes/joint_coordinates.py DATA_FOLDER SPLIT [SCENE ...]

DATA_FOLDER holds ``SCENE/SPLIT.h5`` (``mdgs generate SCENE --preset small --split valid --split test``; the user
scene ``hinge_slide_free`` from ``--mjcf studies/hinge_slide_free.xml --substeps 10``) and, for the stability
figures, ``SCENE-long/test.h5`` (SPLIT test) or ``SCENE-vlong/valid.h5`` (SPLIT valid: ``--frames 1100 --n-traj
10``). Three parts, each rule in turn:

1. the user scene's cart and pole left to themselves (each of the split's first four starting states, no control,
   220 frames): their energy (J) every 20 frames, which only the integrator can change, and how far the pole's
   angle ends from MuJoCo's at the data's timestep;
2. rotational-center's first four starting states lifted 10 m, no control, 120 frames of free flight: the energy
   every 40 frames (``_tree_rows.free_flight``);
3. on each SCENE (default: the three study scenes), position MSE at t = 40 and t = 110 (10^-3 m^2, mean and median
   over the trajectories that did not diverge), how many diverged, and on the long set how many stay within the
   study's failure threshold over 1100 frames; constant twist first, for scale.
"""
import sys
from pathlib import Path

import numpy as np
import torch
from _tree_rows import energy_of, free_flight, tree_row

from mdgs.data.split import load_split
from mdgs.evaluate.rollout import divergence_threshold, rollout
from mdgs.graphs import SceneGraph
from mdgs.models import MODELS
from mdgs.models.base import State
from mdgs.structure import kabsch

torch.set_num_threads(1)
ct, mj = MODELS["constant-twist"], MODELS["mujoco"]
args = sys.argv[1:]
root, split = Path(args[0]), args[1]
scenes = args[2:] or ["rotational-center", "cubli-triple", "hinge_slide_free"]
TREE = dict(dynamics=True, joints=True, trapezoidal=True, push_out=True, substeps=4)
RULES = {"parent": dict(joint_velocities="parent"), "momentum": dict(joint_velocities="momentum"),
         "coordinates, Verlet": dict(joint_velocities="coordinates"),
         "coordinates, Euler": dict(joint_velocities="coordinates", trapezoidal=False)}

if "hinge_slide_free" in scenes:
    d = load_split(root / "hinge_slide_free" / f"{split}.h5")
    sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
    m = d.mj_model()
    bodies = np.unique(d.static["node_body"])
    obj = {m.body(int(b)).name: s for s, b in enumerate(bodies)}
    energy = energy_of(d, keep=[obj["cart"], obj["pole"]])

    def pole_angle(x) -> float:
        R, _ = kabsch(sc.ref_shape.double(), x, sc.obj, sc.n_obj)
        axis = R[0, obj["pole"], :, 2]  # the pole's long axis in the world
        return float(torch.atan2(axis[0], axis[2]))

    rules = {"mujoco dt x1": None, **RULES, "coordinates, Verlet, 1 substep": dict(joint_velocities="coordinates",
                                                                                   substeps=1)}
    for tr in range(min(4, d.x.shape[0])):
        ends = {}
        for label, rule in rules.items():
            model = mj.from_data(d, mj.Config(dt_factor=1)) if rule is None else ct.from_data(d, ct.Config(**{**TREE, **rule}))
            model.bind(d)
            s = model.initial_state(d, np.array([tr]), model.history)
            s = State(torch.as_tensor(d.x[tr:tr + 1, 0]).to(s.x.dtype), torch.as_tensor(d.v[tr:tr + 1, 0]).to(s.x.dtype),
                      s.extra)
            u = torch.zeros(1, d.ctrl.shape[-1], dtype=s.x.dtype)
            es = []
            for f in range(221):
                if f % 20 == 0:
                    es.append(energy(s.x.double(), s.v.double()))
                if f < 220:
                    s = model.step(s, u)
            ends[label] = pole_angle(s.x.double())
            off = "" if rule is None else f"; pole {np.degrees(ends[label] - ends['mujoco dt x1']):+8.2f} deg off MuJoCo's"
            print(f"cart and pole, trajectory {tr}, {label:31s} energy (J) " + " ".join(f"{e:7.3f}" for e in es) + off,
                  flush=True)

if "rotational-center" in scenes:
    d = load_split(root / "rotational-center" / f"{split}.h5")
    for tr in range(4):
        for label, rule in RULES.items():
            es = free_flight(d, tr, every=40, **{**TREE, **rule})
            print(f"free flight, trajectory {tr}, {label:20s}: energy (J) " + " ".join(f"{e:9.2f}" for e in es),
                  flush=True)

for scene in scenes:
    d = load_split(root / scene / f"{split}.h5")
    long_path = root / f"{scene}-{'long' if split == 'test' else 'vlong'}" / f"{split}.h5"
    dl = load_split(long_path) if long_path.exists() else None
    for label, rule in {"constant twist": None, **RULES}.items():
        settings = {} if rule is None else {**TREE, **rule}
        line, _ = tree_row(d, **settings)
        if dl is not None:
            r = rollout(ct(ct.Config(**settings)), dl, "cpu")
            err = np.where(np.isfinite(r.pos_mse), r.pos_mse, np.inf)
            kept = int((~(err > divergence_threshold(dl) / 100.0).any(1)).sum())
            line += f"  long: {kept}/{dl.x.shape[0]} within the threshold over {dl.x.shape[1]} frames"
        print(f"{scene:18s} {split} {label:20s} {line}", flush=True)

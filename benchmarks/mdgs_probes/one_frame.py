"""One frame of the rigid tree against the frame MuJoCo recorded, from every recorded state of a split: how much of
the tree's error is its model of the scene and how much its step.

    python benchmarks/mdgs_probes/one_frame.py DATA_FOLDER SPLIT [SCENE ...]

DATA_FOLDER holds ``SCENE/SPLIT.h5`` (``mdgs generate SCENE --preset small --split valid``; the user scene
``hinge_slide_free`` from ``--mjcf studies/hinge_slide_free.xml --substeps 10``). For every (trajectory, frame)
pair of the split, the tree is stepped one frame from the recorded node positions and velocities (float64; the
files store float32) and compared with the next recorded frame: position error per pair (m^2, mean over the moving
nodes), its mean, median, 90th percentile and largest over the pairs, and the velocity error's mean and median
((m/s)^2). Rows: the studies' tree (joint coordinates, velocity Verlet, four substeps) with the rigid contact and
push-out and with MuJoCo's soft contact; the soft tree by semi-implicit Euler, MuJoCo's own integrator, in four
substeps and at MuJoCo's own timestep (the data's frame over ``opt.timestep`` substeps). Where the last row's error
is round-off, the tree is MuJoCo's model of the scene and what remains in the other rows is their step.
"""
import sys
import time
from pathlib import Path

import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.models import MODELS
from mdgs.models.base import State

torch.set_num_threads(1)
ct = MODELS["constant-twist"]
args = sys.argv[1:]
root, split = Path(args[0]), args[1]
scenes = args[2:] or ["cubli-triple", "rotational-center", "hinge_slide_free"]
TREE = dict(dynamics=True, joints=True, joint_velocities="coordinates")

for scene in scenes:
    d = load_split(root / scene / f"{split}.h5")
    n_mj = round(float(d.frame_dt) / float(d.mj_model().opt.timestep))
    rows = {"rigid contact, push-out, Verlet, 4 substeps": dict(TREE, push_out=True, trapezoidal=True, substeps=4),
            "soft contact, Verlet, 4 substeps": dict(TREE, contact="soft", trapezoidal=True, substeps=4),
            "soft contact, Euler, 4 substeps": dict(TREE, contact="soft", trapezoidal=False, substeps=4),
            f"soft contact, Euler, {n_mj} substeps (MuJoCo's)": dict(TREE, contact="soft", trapezoidal=False,
                                                                     substeps=n_mj)}
    moving = ~np.asarray(d.static["node_static"], bool)
    B, T = d.x.shape[:2]
    x = torch.as_tensor(d.x[:, :-1].reshape(-1, *d.x.shape[2:])).double()
    v = torch.as_tensor(d.v[:, :-1].reshape(-1, *d.v.shape[2:])).double()
    u = torch.as_tensor(d.ctrl[:, :-1].reshape(-1, d.ctrl.shape[-1])).double()
    x1 = d.x[:, 1:].reshape(-1, *d.x.shape[2:]).astype(float)
    v1 = d.v[:, 1:].reshape(-1, *d.v.shape[2:]).astype(float)
    print(f"{scene}: {B} trajectories, {x.shape[0]} pairs, MuJoCo's timestep {d.mj_model().opt.timestep:g} s, "
          f"frame {float(d.frame_dt):g} s", flush=True)
    for label, settings in rows.items():
        t0 = time.perf_counter()
        m = ct.from_data(d, ct.Config(**settings))
        m.bind(d)
        with torch.no_grad():
            s = m.step(State(x, v), u)
        ex = ((s.x.numpy() - x1)[:, moving] ** 2).sum(-1).mean(-1)
        ev = ((s.v.numpy() - v1)[:, moving] ** 2).sum(-1).mean(-1)
        print(f"  {label:48s} position {ex.mean():9.3e} (median {np.median(ex):9.3e}, 90% {np.quantile(ex, 0.9):9.3e}, "
              f"max {ex.max():9.3e})  velocity {ev.mean():9.3e} (median {np.median(ev):9.3e})  "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)

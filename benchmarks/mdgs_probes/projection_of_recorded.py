"""Whether the joints' projections leave velocities that already satisfy the joints where they are: each rule of
``joint_velocities`` applied to recorded states, which MuJoCo integrated with its joints exact.

    python benchmarks/mdgs_probes/projection_of_recorded.py DATA_FOLDER SPLIT [SCENE ...]

DATA_FOLDER holds ``SCENE/SPLIT.h5`` (``mdgs generate SCENE --preset small --split SPLIT``). For each SCENE
(default: the three study scenes), every 7th recorded frame of every trajectory, in float64: the parent-first
projection (:func:`mdgs.joints.project_joints`) and the least kinetic-energy one
(:func:`mdgs.actuation.project_velocities`, without contacts) applied to the recorded ``(x, v)``, and how far each
moves the moving nodes' velocities (mean and largest ``|v' - v|``, and the largest per object), beside the mean
speed. A rule whose joint rows disagreed with the MJCF's joints would move them by far more than the recording's
float32 round-off.
"""
import sys
from pathlib import Path

import numpy as np
import torch

from mdgs.actuation import drives_of, project_velocities
from mdgs.data.split import load_split
from mdgs.graphs import SceneGraph
from mdgs.joints import joints_of, project_joints

torch.set_num_threads(1)
args = sys.argv[1:]
root, split = Path(args[0]), args[1]
for scene in args[2:] or ["rotational-center", "cubli-triple", "hinge_slide_free"]:
    d = load_split(root / scene / f"{split}.h5")
    sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
    body, cent = d.static["node_body"], d.static["node_centroid"]
    drives, joints = drives_of(d.mj_model(), body, cent), joints_of(d.mj_model(), body, cent)
    frames = np.arange(0, d.x.shape[1], 7)
    x = torch.from_numpy(d.x[:, frames].reshape(-1, *d.x.shape[2:])).double()
    v = torch.from_numpy(d.v[:, frames].reshape(-1, *d.v.shape[2:])).double()
    ref, mass, mv = sc.ref_shape.double(), sc.mass.double(), ~sc.static
    rules = {"momentum": project_velocities(x, v, drives, ref, sc.obj, sc.n_obj, mass),
             "parent": project_joints(x, v, joints, ref, sc.obj, sc.n_obj, mass)[1]}
    speed = v[:, mv].norm(dim=-1).mean().item()
    for name, w in rules.items():
        dv = (w - v)[:, mv].norm(dim=-1)  # [states, moving nodes]
        per_obj = " ".join(f"{dv[:, sc.obj[mv] == o].max().item():.1e}" for o in torch.unique(sc.obj[mv]).tolist())
        print(f"{scene:18s} {split} {name:8s} {len(x)} states: |v' - v| mean {dv.mean().item():.2e}, largest "
              f"{dv.max().item():.2e} m/s (mean speed {speed:.2e}); largest by object {per_obj}", flush=True)

"""Twists of each body around the largest one-step errors (docs/mdgs-experiments.md: flywheels braked within a frame).

    python benchmarks/mdgs_probes/flywheel_spikes.py DATA/valid.h5
"""
import sys

import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.graphs import SceneGraph
from mdgs.rigid import twist

d = load_split(sys.argv[1])
sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
x = torch.from_numpy(d.x).double()
v = torch.from_numpy(d.v).double()
T, F = x.shape[:2]
tw = twist(x.reshape(T*F, -1, 3), v.reshape(T*F, -1, 3), sc.obj, sc.n_obj, sc.mass)
om = tw.omega.reshape(T, F, -1, 3).numpy()
vc = tw.vc.reshape(T, F, -1, 3).numpy()
print("objects", sc.n_obj, "static", np.unique(sc.obj.numpy()[sc.static.numpy()]), "ctrl_sign\n", d.control_sign)
for t, f in [(4, 57), (0, 87), (9, 8), (5, 54), (5, 31)]:
    print(f"traj {t} frame {f}: ctrl {d.ctrl[t, f-1:f+2].round(3).tolist()}")
    for o in range(sc.n_obj):
        print(f"   obj {o} |w| {np.linalg.norm(om[t, f-1:f+3, o], axis=-1).round(2)}  |vc| {np.linalg.norm(vc[t, f-1:f+3, o], axis=-1).round(3)}")

"""The rigid tree (forward dynamics revision 1) in 1, 2 and 4 substeps a frame, with and without push-out, on
validation splits: where studies/mdgs-substeps.toml's settings were chosen (docs/mdgs-experiments.md,
"Substeps, friction and push-out"); and why one step a frame fails on rotational-center.

    python benchmarks/mdgs_probes/substeps.py DATA_FOLDER SPLIT SCENE [SCENE ...]

DATA_FOLDER is a study's ``data/``. For each scene, the trapezoidal "rigid tree + joints" reference: position
MSE at t = 40 and t = 110 (10^-3 m^2; mean and median over the trajectories that did not diverge), how many
diverged, and the seconds it took. Then, where rotational-center is among the scenes, its energy in free
flight: each of the split's first four trajectories' starting state lifted 10 m, no controls, the sum over
bodies of ``M |v_c|^2 / 2 + w . I w / 2 + M g z_c`` (MJCF masses and inertias, J) every 20 frames: it is
conserved in free flight, so what the integrator gains is its error.
"""
import sys
import time
from pathlib import Path

import numpy as np
import torch
from _tree_rows import tree_row

from mdgs.actuation import drives_of
from mdgs.data.split import load_split
from mdgs.graphs import SceneGraph
from mdgs.models import MODELS
from mdgs.models.base import State
from mdgs.rigid import twist
from mdgs.structure import kabsch

torch.set_num_threads(1)
ct = MODELS["constant-twist"]
root, split = Path(sys.argv[1]), sys.argv[2]
for scene in sys.argv[3:]:
    d = load_split(root / scene / f"{split}.h5")
    for push in (False, True):
        for n in (1, 2, 4):
            t0 = time.time()
            line, _ = tree_row(d, dynamics=True, joints=True, trapezoidal=True, push_out=push, substeps=n)
            print(f"{scene:18s} {split:5s} {'push-out' if push else 'no push-out':11s} {n} substeps  {line}  "
                  f"{time.time() - t0:.0f} s", flush=True)

if "rotational-center" in sys.argv[3:]:
    d = load_split(root / "rotational-center" / f"{split}.h5")
    sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
    dr = drives_of(d.mj_model(), d.static["node_body"], d.static["node_centroid"])
    mov = torch.as_tensor(~np.asarray(d.static["node_static"], bool)).view(1, -1, 1)
    g = float(np.linalg.norm(dr.gravity))

    def energy(x, v):
        R, t = kabsch(sc.ref_shape.double(), x, sc.obj, sc.n_obj)
        tw = twist(x, v, sc.obj, sc.n_obj, sc.mass.double())
        e = 0.0
        for s in np.flatnonzero(~np.asarray(dr.fixed, bool)):
            inertia = R[0, s] @ torch.as_tensor(dr.inertia[s]) @ R[0, s].T
            com = R[0, s] @ torch.as_tensor(dr.com[s]) + t[0, s]
            w = tw.omega[0, s]
            vcom = tw.vc[0, s] + torch.linalg.cross(w, com - tw.c[0, s])
            e += 0.5 * dr.mass[s] * float(vcom @ vcom) + 0.5 * float(w @ inertia @ w) + dr.mass[s] * g * float(com[2])
        return e

    for tr in range(4):
        for n in (1, 4):
            m = ct.from_data(d, ct.Config(dynamics=True, joints=True, trapezoidal=True, substeps=n))
            m.bind(d)
            x = torch.where(mov, torch.as_tensor(d.x[tr:tr + 1, 0]).double() + torch.tensor([0, 0, 10.0]).double(),
                            torch.as_tensor(d.x[tr:tr + 1, 0]).double())
            v = torch.as_tensor(d.v[tr:tr + 1, 0]).double()
            u = torch.zeros(1, d.ctrl.shape[-1], dtype=torch.float64)
            es = []
            for f in range(121):
                if f % 20 == 0:
                    es.append(energy(x, v))
                s = m.step(State(x, v), u)
                x, v = s.x, s.v
            print(f"rotational-center {split} trajectory {tr} free flight, {n} substeps: energy (J) every 20 frames "
                  + " ".join(f"{e:.6g}" for e in es), flush=True)

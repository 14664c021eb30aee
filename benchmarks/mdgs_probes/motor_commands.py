"""How often a Cubli split holds a brake-sized motor command, and how large the motors' free-body loads are
in MDGS's force units (docs/mdgs-experiments.md, "The motors' known loads").

    python benchmarks/mdgs_probes/motor_commands.py DATA_FOLDER

Prints, for the train and test splits, the frames with a command above 1 N m (and, per test
trajectory, the largest command before t = 40 and where), then lambda |F| of the free-body motor
loads (:func:`mdgs.actuation.actuation_forces`, lambda = 1 / force_scale as in Eq. 8) on the
training split: median over nodes that carry a load, 99th percentile and largest.
"""
import sys

import numpy as np
import torch

from mdgs.actuation import actuation_forces
from mdgs.data.split import load_split
from mdgs.models import MODELS
from mdgs.models.base import batch_of

torch.set_num_threads(1)
data = sys.argv[1]
tr, te = load_split(data + "/train.h5"), load_split(data + "/test.h5")
for name, d in (("train", tr), ("test", te)):
    a = np.abs(d.ctrl)
    print(f"{name}: {int((a.max(-1) > 1).sum())} of {a.shape[0] * a.shape[1]} frames with a command above 1 N m")
for t in range(te.ctrl.shape[0]):
    a = np.abs(te.ctrl[t, :40])
    print(f"  test trajectory {t}: largest command before t = 40 {a.max():.2f} at frames {np.argwhere(a > 1)[:, 0].tolist()}")
model = MODELS["mdgs"].from_data(tr, MODELS["mdgs"].Config(actuation="force"))
model.bind(tr)
sc = model.scene_on("cpu")
b = batch_of(tr, tr.pairs(0), "cpu")
f = actuation_forces(b.x, b.ctrl, model._drives, sc.ref_shape, sc.obj, sc.n_obj, sc.mass)
v = (f.norm(dim=-1) / model.config.force_scale)[:, ~sc.static]
nz = v[v > 0]
print(f"lambda |F| of the motor loads (train): median {float(nz.median()):.3g}, 99th percentile "
      f"{float(nz.quantile(0.99)):.3g}, largest {float(v.max()):.3g}")

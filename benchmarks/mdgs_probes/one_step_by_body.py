"""One-step error by body, model against zero output (docs/mdgs-experiments.md, "What was wrong").

    SPLIT=valid python benchmarks/mdgs_probes/one_step_by_body.py DATA_FOLDER RUN_FOLDER
"""
import os
import sys

import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.models import MODELS
from mdgs.models.base import State, batch_of
from mdgs.runs import load_run

torch.set_num_threads(1)
data, run = sys.argv[1], sys.argv[2]
d = load_split(data + "/" + os.environ.get("SPLIT", "valid") + ".h5")
print("traj,frames,N", d.x.shape, "ctrl", d.ctrl.shape, "contact", d.has_contact, "family", d.attrs.get("family"))
model, st = load_run(run, "cpu")
model.bind(d)
ct = MODELS["constant-twist"].from_data(d, MODELS["constant-twist"].Config())
ct.bind(d)
c = model.config
pairs = d.pairs(0)
b = batch_of(d, pairs, "cpu")
scene = model.scene_on("cpu")
mv = ~scene.static
obj = scene.obj.numpy()
with torch.no_grad():
    p = model(scene, b.x, b.v, model.node_controls(b.ctrl))
    q = ct.step(State(b.x, b.v), b.ctrl)
def errs(x, v):
    ex = (((x - b.x_next) / c.dx_scale) ** 2)[:, mv].mean(-1)  # [P, Nm]
    ev = (((v - b.v_next) / c.dv_scale) ** 2)[:, mv].mean(-1)
    return ex.numpy(), ev.numpy()
for name, (x, v) in [("model", (p.x, p.v)), ("const", (q.x, q.v))]:
    ex, ev = errs(x, v)
    per = (ex + ev).mean(1) / 2
    print(f"{name}: mean x {ex.mean():.3g} v {ev.mean():.3g} total {per.mean():.3g}; per-pair quantiles 50/90/99/max",
          np.quantile(per, [.5, .9, .99, 1]).round(3))
    om = obj[mv.numpy()]
    for o in np.unique(om):
        print(f"   obj {o}: x {ex[:, om == o].mean():.3g} v {ev[:, om == o].mean():.3g}")
ex, ev = errs(q.x, q.v)
per = (ex+ev).mean(1)
top = np.argsort(per)[-10:]
print("worst const pairs (traj, frame):", pairs[top].tolist())

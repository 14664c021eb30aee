"""Untrained MDGS (zero-initialised head) without the motor prior, with it, and with its coupled form: rollout and one-step error by body.

    python benchmarks/mdgs_probes/untrained_prior.py DATA_FOLDER [SPLIT]

With ``zero_init`` the untrained model with ``actuation=none`` is the constant-twist reference
(plus the joint projection); with ``actuation=prior`` it is constant twist plus the driven bodies'
joint response to the motors, parents held (docs/mdgs-experiments.md, "The motors' known loads"); with
``actuation=coupled`` the motors' response of the whole tree, parents recoiling (MuJoCo's
``M^-1 qfrc_actuator``; "The whole tree's response"). Prints t = 40 /
t = 110 position MSE (10^-3 m^2, mean over trajectories, how many reached it) and the one-step
L_mse by body in the model's units.
"""
import sys

import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.evaluate.metrics import frame_of
from mdgs.evaluate.rollout import rollout
from mdgs.models import MODELS
from mdgs.models.base import batch_of

torch.set_num_threads(1)
data = sys.argv[1]
split = sys.argv[2] if len(sys.argv) > 2 else "test"
tr, d = load_split(data + "/train.h5"), load_split(f"{data}/{split}.h5")
cls = MODELS["mdgs"]
for act in ("none", "prior", "coupled"):
    model = cls.from_data(tr, cls.Config(actuation=act))
    model.bind(d)
    model.eval()
    r = rollout(model, d, "cpu")
    line = [act]
    for t in (40, 110):
        e = r.pos_mse[:, frame_of(t, r.pos_mse.shape[1])]
        line.append(f"t{t} {1e3 * np.nanmean(e):.3f} ({np.isfinite(e).sum()})")
    b = batch_of(d, d.pairs(0), "cpu")
    sc = model.scene_on("cpu")
    with torch.no_grad():
        p = model(sc, b.x, b.v, model.node_controls(b.ctrl), simulate=True, ctrl=b.ctrl)
    sx, sv = model.scales(sc, "cpu")
    ex, ev = (((p.x - b.x_next) / sx) ** 2).mean(-1), (((p.v - b.v_next) / sv) ** 2).mean(-1)
    obj, mv = sc.obj.numpy(), (~sc.static).numpy()
    line.append(f"one-step x {float(ex[:, mv].mean()):.3g} v {float(ev[:, mv].mean()):.3g}")
    line += [f"obj {o}: x {float(ex[:, obj == o].mean()):.3g} v {float(ev[:, obj == o].mean()):.3g}"
             for o in np.unique(obj[mv])]
    print("  ".join(line))

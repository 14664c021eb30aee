"""Single-seed probe of docs/mdgs-experiments.md: train one MDGS setting at the small study's budget and roll out.

    MDGS_PROBE_DATA=STUDY_OUT/data MDGS_PROBE_OUT=DIR python benchmarks/mdgs_probes/probe_train.py TAG SCENE SEED [key=value ...]

Environment: EPOCHS (default 5), MODEL (default mdgs), LONG=1 adds the 1100-frame set, SELECT (default
last: the epoch kept, ``TrainConfig.select``), EMA (default 0: the weights' moving-average decay, ``TrainConfig.ema``). Appends one JSON
line to DIR/results.jsonl: t = 40 / 110 MSE (mean over trajectories that did not diverge, and how many),
the one-step error of the model and of the same model with its state head zeroed (the constant-twist
step in the same units), and each body's share of the t = 40 error. The page's probes ran on MDGS
revision 0 (commit 5e9095a), with the settings named in each row and e.g. ``joints=false`` for the
paper's method on later revisions.
"""
import copy
import json
import os
import sys
import time

import numpy as np
import torch

from mdgs.cli.train import parse_settings
from mdgs.data.split import load_split
from mdgs.evaluate.physics import hinge_anchors
from mdgs.evaluate.rollout import rollout, rollout_score
from mdgs.models import MODELS, one_step_error
from mdgs.runs import load_run
from mdgs.study.runner import _evaluate_set
from mdgs.train import TrainConfig, train

tag, scene, seed = sys.argv[1], sys.argv[2], int(sys.argv[3])
model_name = os.environ.get("MODEL", "mdgs")
kw = parse_settings(MODELS[model_name].Config, sys.argv[4:])  # typed as `mdgs train --set` types them
epochs = int(os.environ.get("EPOCHS", 5))
data = os.path.join(os.environ["MDGS_PROBE_DATA"], scene)
OUT = os.environ["MDGS_PROBE_OUT"]
run = os.path.join(OUT, "runs", f"{tag}-{scene}-s{seed}")
cls = MODELS[model_name]
t0 = time.time()
select, ema = os.environ.get("SELECT", "last"), float(os.environ.get("EMA", 0))
train(TrainConfig(data=data, out=run, model_name=model_name, epochs=epochs, batch_size=32, seed=seed, device="cpu",
                  valid_max_pairs=512, select=select, ema=ema, model=cls.Config(**kw)), score=rollout_score)
model, st = load_run(run, "cpu")
test = load_split(data + "/test.h5")
one = one_step_error(model, test, "cpu")
rep = _evaluate_set(model, test, "cpu", 1.0, hinge_anchors(test.mj_model()), False)

torch.set_num_threads(1)

z = copy.deepcopy(model)
if hasattr(z, "state"):
    z.state.zero_output()
    one_zero = one_step_error(z, test, "cpu")
else:
    one_zero = None
r = rollout(model, test, "cpu")
sc = model.scene_on("cpu")
objn = sc.obj.numpy()
mv = test.moving
f40 = 40
per_obj = {}
for o in np.unique(objn[mv]):
    sel = (objn == o) & mv
    e = ((r.x[:, f40] - test.x[:, f40]) ** 2)[:, sel].sum(axis=(1, 2)) / (mv.sum() * 3)  # contribution to the MSE
    per_obj[int(o)] = float(np.nanmean(e))
out0 = {"one_zero": one_zero, "t40_by_object": per_obj}
out = {"tag": tag, "scene": scene, "seed": seed, "settings": kw, "select": select, "ema": ema,
       "evaluated_epoch": st["evaluated_epoch"], "one_step": one, "secs": time.time() - t0}
for t in (40, 110):
    a = rep[f"pos_mse_t{t}"]
    ok = [x for x in a if x is not None]
    out[f"t{t}"] = float(np.mean(ok)) if ok else None
    out[f"n{t}"] = len(ok)
if os.environ.get("LONG"):
    ld = load_split(data + "-long/test.h5")
    lr = _evaluate_set(model, ld, "cpu", 1.0, hinge_anchors(ld.mj_model()), True)
    out["within_end"] = lr["fraction_within"][-1]
    out["sep_max"] = lr["joint_separation_max_m"]
out.update(out0)
print(json.dumps(out))
with open(os.path.join(OUT, "results.jsonl"), "a") as f:
    f.write(json.dumps(out) + "\n")

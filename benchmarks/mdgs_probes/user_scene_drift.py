"""Where a trained MDGS leaves the user scene's long trajectories: the error by body, and the free box's path.

    python benchmarks/mdgs_probes/user_scene_drift.py DATA LONG_TEST SEED [key=value ...]

``DATA``: the user scene's dataset folder of a study (``OUT/data/hinge_slide_free``), ``LONG_TEST`` its
long test set (``OUT/data/hinge_slide_free-long``). Trains MDGS as small-select does (5 epochs of
batch 32, 512 validation pairs, ``select = "rollout"``; ``key=value``: model settings, e.g.
``actuation=prior``), rolls it out over the long test trajectories and prints: the first frame at
which each trajectory leaves the failure threshold; the mean squared position error of each body's
elements at a few frames (m^2); and, for trajectory 0, the free box's centroid and velocity (model
against data) over the first frames. About 30 s (one thread). docs/mdgs-experiments.md ("Stable on
one epoch, not on the next") quotes it.
"""
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

from mdgs.cli.train import parse_settings
from mdgs.data.split import load_split
from mdgs.evaluate.rollout import divergence_threshold, rollout, rollout_score
from mdgs.models import MODELS
from mdgs.runs import load_run
from mdgs.train import TrainConfig, train

torch.set_num_threads(1)
data, long_test, seed = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3])
kw = parse_settings(MODELS["mdgs"].Config, sys.argv[4:])
lt = load_split(long_test / "test.h5")
with tempfile.TemporaryDirectory() as tmp:
    train(TrainConfig(data=str(data), out=tmp, model_name="mdgs", epochs=5, batch_size=32, seed=seed, device="cpu",
                      valid_max_pairs=512, select="rollout", model=MODELS["mdgs"].Config(**kw)), score=rollout_score)
    model, state = load_run(tmp, "cpu")
print(f"seed {seed} {kw}: kept epoch {state['evaluated_epoch'] + 1} of 5")
r = rollout(model, lt, "cpu")
x, xd = r.x.astype(np.float64), lt.x.astype(np.float64)
thr = divergence_threshold(lt) / 100.0
err = ((x - xd) ** 2).sum(-1)  # [T, F, N]
mse = err[:, :, lt.moving].mean(-1)
print(f"failure threshold {thr:.3g} m^2; first frame past it per trajectory:",
      [int(np.argmax(m > thr)) if (m > thr).any() else None for m in mse])
body = np.asarray(lt.static["node_body"])
names = lt.static["body_names"]
ids = np.asarray(lt.static["body_id"])
print("mean squared error of each body's elements (m^2), all trajectories:")
for f in (100, 300, 500, 700, 900):
    print(f"  frame {f:4d}: " + ", ".join(f"{names[k]} {err[:, f, body == b].mean():.3g}" for k, b in enumerate(ids)))
box = body == ids[list(names).index("box")]
dt = lt.frame_dt
print("trajectory 0, the free box: centroid (m) and velocity (m/s), model | data")
for f in (0, 10, 20, 30, 40, 50, 60, 80, 100, 150, 200, 300):
    cm, cd = x[0, f, box].mean(0), xd[0, f, box].mean(0)
    vm, vd = (x[0, f + 1, box].mean(0) - cm) / dt, (xd[0, f + 1, box].mean(0) - cd) / dt
    print(f"  frame {f:4d}: c {np.round(cm, 3)} v {np.round(vm, 3)} | c {np.round(cd, 3)} v {np.round(vd, 3)}")

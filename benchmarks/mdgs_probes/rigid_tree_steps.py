"""What the rigid tree's one step per frame costs it: the "rigid tree + joints" reference as the studies run
it (semi-implicit Euler: every body moves over the frame with its new twist) and with the mean of its old
and new twists instead (trapezoidal, exact for a constant acceleration over the frame), on each scene's
test trajectories (docs/mdgs-experiments.md, "The whole tree's dynamics as the prior").

    python benchmarks/mdgs_probes/rigid_tree_steps.py DATA_FOLDER SCENE [SCENE ...]

DATA_FOLDER is a study's ``data/``. Prints the position MSE at t = 40 and t = 110 (10^-3 m^2, mean over
trajectories that did not diverge) and how many of the 10 diverged, for both steps.
"""
import sys

import torch

from mdgs.data.split import load_split
from mdgs.evaluate import evaluate_reference
from mdgs.models import MODELS

torch.set_num_threads(1)
ct = MODELS["constant-twist"]
for scene in sys.argv[2:]:
    d = load_split(f"{sys.argv[1]}/{scene}/test.h5")
    for name, trap in (("semi-implicit Euler (the studies')", False), ("trapezoidal", True)):
        rep, _ = evaluate_reference(ct(ct.Config(dynamics=True, joints=True, trapezoidal=trap)), d, "cpu")
        t110 = rep["mse_t110"] * 1e3 if rep["mse_t110"] is not None else float("nan")
        print(f"{scene:18s} {name:36s} t=40 {rep['mse_t40'] * 1e3:8.4g} ({rep['mse_t40_trajectories']})  "
              f"t=110 {t110:8.4g} ({rep['mse_t110_trajectories']})  diverged {rep['diverged']}/10", flush=True)

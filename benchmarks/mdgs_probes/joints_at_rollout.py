"""Joint projection at rollout only, on a trained run (docs/mdgs-experiments.md): t = 40 / 110 MSE without and with.

    python benchmarks/mdgs_probes/joints_at_rollout.py RUN_FOLDER DATA/test.h5
"""
import dataclasses
import sys

import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.evaluate.rollout import rollout
from mdgs.runs import load_run

torch.set_num_threads(1)

run = sys.argv[1]
test = load_split(sys.argv[2])
for joints in (False, True):
    m, _ = load_run(run, "cpu")
    m.config = dataclasses.replace(m.config, joints=joints)
    r = rollout(m, test, "cpu")
    for t in (40, 110):
        from mdgs.evaluate.metrics import frame_of
        e = r.pos_mse[:, frame_of(t, r.pos_mse.shape[1])]
        print(f"joints={joints} t{t}: {1e3*np.nanmean(e):.3f} ({np.isfinite(e).sum()})", end="  ")
    print()

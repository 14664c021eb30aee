"""Is a trained MDGS's learned correction noise or a step the right way? For a run trained with a prior (e.g.
``actuation = "dynamics"``: the untrained model is the rigid tree), the state network g's output is scaled
by alpha (its last layer's weights and bias times alpha: g's output is linear in them) and the test split
rolled out for each alpha: 0 is the untrained start, 1 the trained model. If the error falls from 0 towards
some alpha > 0, g learned something useful that the rollout overdoes or underdoes; if it rises from 0, what
g adds is harm in rollout whatever its one-step loss says (docs/mdgs-experiments.md).

    python benchmarks/mdgs_probes/correction_scale.py DATA_FOLDER RUN [RUN ...]

DATA_FOLDER is the scene's data (``test.h5``), each RUN a trained run folder (a study's ``runs/KEY``).
Prints, per run and alpha, the position MSE at t = 40 and t = 110 (10^-3 m^2, mean over the test
trajectories that did not diverge) and how many diverged.
"""
import copy
import sys

import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.evaluate.metrics import frame_of
from mdgs.evaluate.rollout import rollout
from mdgs.runs import load_run

ALPHAS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25)
torch.set_num_threads(1)
data, runs = sys.argv[1], sys.argv[2:]
d = load_split(f"{data}/test.h5")
for run in runs:
    trained, _ = load_run(run, "cpu")
    trained.eval()
    for a in ALPHAS:
        m = copy.deepcopy(trained)
        last = m.state.lins[-1]
        with torch.no_grad():
            last.weight.mul_(a)
            last.bias.mul_(a)
            if m.state.selfs is not None:
                m.state.selfs[-1].weight.mul_(a)
        r = rollout(m, d, "cpu")
        F = r.pos_mse.shape[1]
        row = []
        for t in (40, 110):
            e = r.pos_mse[:, frame_of(t, F)]
            ok = np.isfinite(e) & (e < r.threshold)
            row.append(f"t={t} {1e3 * e[ok].mean():8.4g} ({int(ok.sum())}/{len(e)})")
        print(f"{run.rstrip('/').split('/')[-1]} alpha {a:4.2f}  " + "  ".join(row), flush=True)

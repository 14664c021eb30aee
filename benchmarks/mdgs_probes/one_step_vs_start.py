"""Does a trained MDGS beat its own untrained start one step at a time? For a run trained with a prior (e.g.
``actuation = "dynamics"``: the start is the rigid tree), each pair's one-step error (Eq. 10 in the run's
scaled units, moving nodes) of the trained model against that of the same model with its state head zeroed,
on up to 1024 evenly spaced pairs of the training and the validation split (docs/mdgs-experiments.md,
"Limits and obstacles").

    python benchmarks/mdgs_probes/one_step_vs_start.py RUN DATA_FOLDER

RUN is a trained run folder (a study's ``runs/KEY``), DATA_FOLDER the scene's data (``train.h5``,
``valid.h5``). Prints, per split, the median and mean over pairs of the ratio trained / start, and the two
mean errors.
"""
import copy
import sys

import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.losses import pair_mse
from mdgs.models.base import batch_of
from mdgs.runs import load_run

torch.set_num_threads(1)
run, data = sys.argv[1], sys.argv[2]
model, _ = load_run(run, "cpu")
model.eval()
start = copy.deepcopy(model)
start.state.zero_output()
for split in ("train", "valid"):
    d = load_split(f"{data}/{split}.h5")
    pairs = d.pairs()
    pairs = pairs[np.linspace(0, len(pairs) - 1, min(1024, len(pairs))).astype(int)]
    errs = {}
    for name, m in (("trained", model), ("start", start)):
        m.bind(d)
        sc = m.scene_on("cpu")
        out = []
        with torch.no_grad():
            for i in range(0, len(pairs), 128):
                b = batch_of(d, pairs[i:i + 128], "cpu")
                p = m(sc, b.x, b.v, m.node_controls(b.ctrl), simulate=False, ctrl=b.ctrl)
                out.append(pair_mse(p.x, p.v, b.x_next, b.v_next, ~sc.static, *m.scales(sc, "cpu")))
        errs[name] = torch.cat(out).numpy()
    r = errs["trained"] / errs["start"]
    print(f"{split:5s} {len(pairs)} pairs: trained / start median {np.median(r):.3g}, mean {r.mean():.3g}; "
          f"mean error trained {errs['trained'].mean():.4g}, start {errs['start'].mean():.4g}", flush=True)

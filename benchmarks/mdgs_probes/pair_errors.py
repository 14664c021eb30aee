"""Is a trained MDGS better than its own zero output on a typical frame, or only on average?

    python benchmarks/mdgs_probes/pair_errors.py RUN DATA_FOLDER

For every (t, t + 1) pair of ``DATA_FOLDER/test.h5``: the one-step error of Eq. (10) (the model's
scaled units) of the trained MDGS of ``RUN`` and of the same model with its state network's last
layer zeroed (constant twist plus the run's priors, joints projected: what the untrained model
simulates). Prints both means, their quantiles over the pairs and the share of pairs on which the
trained model is worse. docs/mdgs-experiments.md quotes it.
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
model, _ = load_run(sys.argv[1], "cpu")
d = load_split(sys.argv[2] + "/test.h5")
model.bind(d)
model.eval()
zero = copy.deepcopy(model)
zero.state.zero_output()
sc = model.scene_on("cpu")
scales = model.scales(sc, "cpu")
pairs = d.pairs(0)
err = {}
for name, m in (("trained", model), ("zero output", zero)):
    parts = []
    for i in range(0, len(pairs), 256):
        b = batch_of(d, pairs[i:i + 256], "cpu")
        with torch.no_grad():
            p = m(sc, b.x, b.v, m.node_controls(b.ctrl), simulate=True, ctrl=b.ctrl)
        parts.append(pair_mse(p.x, p.v, b.x_next, b.v_next, ~sc.static, *scales).numpy())
    err[name] = np.concatenate(parts)
t, z = err["trained"], err["zero output"]
print(f"{sys.argv[1]} on {sys.argv[2]}/test.h5, {len(t)} pairs; one-step Eq. (10), model units")
print(f"{'':12s}{'mean':>10s}" + "".join(f"{'q' + str(q):>10s}" for q in (0.25, 0.5, 0.75, 0.9, 0.99)))
for name, e in err.items():
    print(f"{name:12s}{e.mean():10.4g}" + "".join(f"{np.quantile(e, q):10.4g}" for q in (0.25, 0.5, 0.75, 0.9, 0.99)))
print(f"pairs on which the trained model is worse than its zero output: {100 * (t > z).mean():.0f} %")
top = np.sort(z)[::-1]
print(f"share of the zero output's error held by its largest 1 % of pairs: {100 * top[:len(z) // 100].sum() / z.sum():.0f} %,"
      f" by its largest 10 %: {100 * top[:len(z) // 10].sum() / z.sum():.0f} %")

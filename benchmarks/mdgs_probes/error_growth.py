"""Does a rollout's error grow at the frames where the true motion jumps (impacts), or smoothly?

    python benchmarks/mdgs_probes/error_growth.py RUN DATA_FOLDER

Rolls the trained ``RUN`` out over ``DATA_FOLDER/test.h5``; per frame of the first 40, the growth of
the RMS node distance to the data, and the largest change of a moving body's centroid velocity in
the data over that frame. Prints the share of the error's growth that falls on the frames whose
velocity jump is above the 90th percentile of all frames, and the correlation of jump and growth.
docs/mdgs-experiments.md quotes it for rotational-center.
"""
import sys

import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.evaluate.rollout import rollout
from mdgs.graphs import SceneGraph
from mdgs.rigid import twist
from mdgs.runs import load_run

torch.set_num_threads(1)
model, _ = load_run(sys.argv[1], "cpu")
d = load_split(sys.argv[2] + "/test.h5")
r = rollout(model, d, "cpu")
sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
mv = ~sc.static.numpy()
T, F = d.x.shape[:2]
x, v = torch.from_numpy(d.x).double(), torch.from_numpy(d.v).double()
vc = twist(x.flatten(0, 1), v.flatten(0, 1), sc.obj, sc.n_obj, sc.mass.double()).vc.view(T, F, -1, 3).numpy()
objs = [o for o in range(sc.n_obj) if not bool(sc.static[sc.obj == o].all())]
jump = np.linalg.norm(vc[:, 1:, objs] - vc[:, :-1, objs], axis=-1).max(-1)  # [T, F - 1], m/s
err = np.sqrt(np.nanmean(((r.x - d.x) ** 2)[:, :, mv].sum(-1), -1))  # [T, F] RMS node distance, m
growth, j = err[:, 1:41] - err[:, :40], jump[:, :40]
big = j > np.quantile(jump, 0.9)
print(f"{sys.argv[2]}: frames with a velocity jump above the 90th percentile: {100 * big.mean():.0f} % of the "
      f"first 40 frames, {100 * growth[big].sum() / growth.sum():.0f} % of the RMS error's growth; "
      f"correlation of jump and growth {np.corrcoef(j.ravel(), growth.ravel())[0, 1]:.2f}")

"""Where the Cubli's rollout error sits: each test trajectory's position MSE at t = 40, with its largest
motor command before then, for the untrained references and any trained runs (docs/mdgs-experiments.md,
"The motors' known loads").

    python benchmarks/mdgs_probes/brake_trajectories.py DATA_FOLDER [LABEL=RUN_FOLDER ...]

DATA_FOLDER holds a cubli-triple ``test.h5`` (e.g. a study's ``data/cubli-triple``); each RUN_FOLDER is
a trained run (a study's ``runs/<cell>``), evaluated with the weights its selection rule kept. Prints,
per model, the mean over trajectories (the study's t = 40 figure, 10^-3 m^2), each trajectory's
error and the share of the total held by the trajectories with a brake command (above 5 N m; the
commands are either below 2 N m or 11-12 N m) before t = 40.
"""
import sys

import numpy as np
import torch
from _brakes import split_models_and_brakes

from mdgs.evaluate.rollout import rollout

torch.set_num_threads(1)
d, models, t, brake = split_models_and_brakes(sys.argv[1:])
print(f"test trajectories with a command above 5 N m (a brake) before t = 40: {np.flatnonzero(brake).tolist()} of {len(brake)}")
for name, m in models.items():
    e = rollout(m, d).pos_mse[:, t] * 1e3
    print(f"{name}: mean {np.nanmean(e):.3g}; braking trajectories hold {np.nansum(e[brake]) / np.nansum(e):.1%}; "
          f"median of the others {np.nanmedian(e[~brake]):.3g}")
    print("    " + "  ".join(f"{k}:{v:.3g}" for k, v in enumerate(e)))

"""What a trained MDGS adds to its priors, body by body, linear and angular: of each body's one-step change
of twist (its mass centre's velocity ``vc``, its angular velocity ``omega``), how much does the trained
network predict beyond its own zero output (docs/mdgs-experiments.md, "Body by body")?

    python benchmarks/mdgs_probes/twist_learned.py DATA_FOLDER RUN_FOLDER [RUN_FOLDER ...]

DATA_FOLDER holds the scene's ``test.h5``; each RUN_FOLDER is a trained MDGS run (a study's
``runs/<cell>``), evaluated with the weights its selection rule kept. Over every (trajectory, frame) pair
of the test split, from the true state at t, one simulated step (joint projection included) of the trained
model and of the same model with its state network's output zeroed (constant twist plus the run's priors
and joints); each body's twist is the mass-weighted rigid fit of its element velocities
(:func:`mdgs.rigid.twist`). Printed per body and component: the least-squares slope of the trained
model's change over the zero output's against the truth's change over it (1: all of what the priors miss
is predicted; 0: nothing) and R^2 of the same (0: no better than the zero output), with the rms of what
the zero output misses (m/s, rad/s).
"""
import copy
import sys

import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.models.base import State
from mdgs.rigid import twist
from mdgs.runs import load_run

torch.set_num_threads(1)
d = load_split(sys.argv[1] + "/test.h5")
body = torch.as_tensor(np.asarray(d.static["node_body"]), dtype=torch.long)
n = int(body.max()) + 1
mass = torch.as_tensor(d.static["node_mass"], dtype=torch.float64)
T = d.x.shape[1] - 1
flat = lambda a: torch.as_tensor(a.reshape(-1, *a.shape[2:]))  # noqa: E731  [traj, frame, ...] -> [pairs, ...]
X, V, C = flat(d.x[:, :T]).float(), flat(d.v[:, :T]).float(), flat(d.ctrl[:, :T]).float()
true = twist(flat(d.x[:, 1:]).double(), flat(d.v[:, 1:]).double(), body, n, mass)
moving = sorted(set(body[torch.as_tensor(d.moving)].tolist()))
mj = d.mj_model()
for run in sys.argv[2:]:
    model, state = load_run(run, "cpu")
    model.bind(d)
    zero = copy.deepcopy(model)
    zero.state.zero_output()
    with torch.no_grad():
        a, b = model.step(State(X, V), C), zero.step(State(X, V), C)
    tm, tz = (twist(s.x.double(), s.v.double(), body, n, mass) for s in (a, b))
    print(f"{run} (epoch {state['evaluated_epoch']}): {len(X)} test pairs")
    for o in moving:
        cols = []
        for k in ("vc", "omega"):
            want = (getattr(true, k) - getattr(tz, k))[:, o].reshape(-1).numpy()
            got = (getattr(tm, k) - getattr(tz, k))[:, o].reshape(-1).numpy()
            ss = float(want @ want)
            if ss == 0:
                cols.append(f"{k:5s} (no change in the data)")
                continue
            slope = float(want @ got) / ss
            r2 = 1 - float(((want - got) ** 2).sum()) / float(((want - want.mean()) ** 2).sum())
            cols.append(f"{k:5s} slope {slope:+.3f} R2 {r2:+.3f} (rms {np.sqrt(ss / len(want)):.3g})")
        print(f"  {mj.body(o).name:10s} " + ";  ".join(cols))

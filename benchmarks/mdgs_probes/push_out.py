"""The rigid tree moved out of the world's surfaces after every step (``push_out``) against the studies' rule,
which leaves a corner that ends a frame inside a surface where it is (mdgs.actuation.push_out;
docs/mdgs-experiments.md, "Pushed out of the floor").

    python benchmarks/mdgs_probes/push_out.py DATA_FOLDER SPLIT SCENE [SCENE ...]

DATA_FOLDER is a study's ``data/``, SPLIT ``valid`` (where the rule and its two constants were chosen) or
``test``. For each scene the trapezoidal "rigid tree + joints" reference without push-out, with it as the
module sets it (all the way out at once, no slop) and with the game engines' usual softer settings (a slop
of 1 mm left in; a fraction of 0.2 or 0.5 of the depth per step): position MSE at t = 40 and t = 110
(10^-3 m^2) as mean and median over the trajectories that did not diverge, how many diverged, and the
lowest node of the rollouts against the lowest recorded one (m), over every trajectory and frame: a body
that sinks into a surface shows there.
"""
import sys
import time
from pathlib import Path

import numpy as np
import torch
from _tree_rows import tree_row

import mdgs.actuation as actuation
from mdgs.data.split import load_split

torch.set_num_threads(1)
VARIANTS = [("off", None, None), ("push-out (slop 0, fraction 1)", 0.0, 1.0), ("slop 1 mm", 1e-3, 1.0),
            ("fraction 0.5", 0.0, 0.5), ("fraction 0.2", 0.0, 0.2)]
default = (actuation.PUSH_OUT_SLOP, actuation.PUSH_OUT_FRACTION)
for scene in sys.argv[3:]:
    d = load_split(Path(sys.argv[1]) / scene / f"{sys.argv[2]}.h5")
    mov = ~np.asarray(d.static["node_static"], bool)
    for name, slop, frac in VARIANTS:
        t0 = time.time()
        if slop is not None:
            actuation.PUSH_OUT_SLOP, actuation.PUSH_OUT_FRACTION = slop, frac
        line, r = tree_row(d, dynamics=True, joints=True, trapezoidal=True, push_out=slop is not None)
        print(f"{scene:20s} {sys.argv[2]:5s} {name:30s} {line}"
              f"  lowest node {np.nanmin(r.x[:, :, mov, 2]):7.4f} m (recorded {d.x[:, :, mov, 2].min():.4f})"
              f"  {time.time() - t0:.0f} s", flush=True)
actuation.PUSH_OUT_SLOP, actuation.PUSH_OUT_FRACTION = default

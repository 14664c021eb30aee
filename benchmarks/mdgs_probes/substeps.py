"""The rigid tree (forward dynamics revision 1) in 1, 2 and 4 substeps a frame, with and without push-out, on
validation splits: where studies/mdgs-substeps.toml's settings were chosen (docs/mdgs-experiments.md,
"Substeps, friction and push-out"); and why one step a frame fails on rotational-center.

    python benchmarks/mdgs_probes/substeps.py DATA_FOLDER SPLIT SCENE [SCENE ...]

DATA_FOLDER is a study's ``data/``. For each scene, the trapezoidal "rigid tree + joints" reference: position
MSE at t = 40 and t = 110 (10^-3 m^2; mean and median over the trajectories that did not diverge), how many
diverged, and the seconds it took. Then, where rotational-center is among the scenes, its energy in free
flight: each of the split's first four trajectories' starting state lifted 10 m, no controls, the sum over
bodies of ``M |v_c|^2 / 2 + w . I w / 2 + M g z_c`` (MJCF masses and inertias, J) every 20 frames: it is
conserved in free flight, so what the integrator gains is its error.
"""
import sys
import time
from pathlib import Path

import torch
from _tree_rows import free_flight, tree_row

from mdgs.data.split import load_split
from mdgs.models import MODELS

torch.set_num_threads(1)
ct = MODELS["constant-twist"]
root, split = Path(sys.argv[1]), sys.argv[2]
for scene in sys.argv[3:]:
    d = load_split(root / scene / f"{split}.h5")
    for push in (False, True):
        for n in (1, 2, 4):
            t0 = time.time()
            line, _ = tree_row(d, dynamics=True, joints=True, trapezoidal=True, push_out=push, substeps=n)
            print(f"{scene:18s} {split:5s} {'push-out' if push else 'no push-out':11s} {n} substeps  {line}  "
                  f"{time.time() - t0:.0f} s", flush=True)

if "rotational-center" in sys.argv[3:]:
    d = load_split(root / "rotational-center" / f"{split}.h5")
    for tr in range(4):
        for n in (1, 4):
            es = free_flight(d, tr, dynamics=True, joints=True, trapezoidal=True, substeps=n)
            print(f"rotational-center {split} trajectory {tr} free flight, {n} substeps: energy (J) every 20 frames "
                  + " ".join(f"{e:.6g}" for e in es), flush=True)

"""The rigid tree's gyroscopic terms explicit or implicit (``gyroscopic`` of the reference and of MDGS's prior): free
flight energy on rotational-center, then the trapezoidal tree's rollouts on a split.

    python benchmarks/mdgs_probes/gyroscopic.py DATA_FOLDER SPLIT [SCENE ...] [--substeps N]

DATA_FOLDER is a study's ``data/``. First, on rotational-center's split: each of its first four trajectories'
starting state lifted 10 m, no controls, in 4 substeps a frame, the energy every 20 frames over 120 frames
(as ``substeps.py``: the sum over bodies of ``M |v_c|^2 / 2 + w . I w / 2 + M g z_c``, conserved in free
flight, so what it gains is the integrator's error), with the terms explicit (each step's start), implicit
(its end) and midpoint (halfway), linearised (:func:`mdgs.actuation.coupled_motor_accelerations`). Then, for each SCENE (default: the three study scenes), the "rigid tree + joints, trapezoidal,
push-out, 4 substeps" reference (``studies/mdgs-substeps.toml``'s; ``--substeps N``: N substeps, in free flight too) with each rule: position MSE at t = 40 and
t = 110 (10^-3 m^2; mean and median over the trajectories that did not diverge) and how many diverged.
Which terms the implicit setting takes was decided with this probe on the validation split at commit 05ac8f8,
where more combinations could be picked (output: ``docs/results/mdgs-probes/gyroscopic-variants.txt``).
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
args = sys.argv[1:]
n_sub = 4
if "--substeps" in args:
    i = args.index("--substeps")
    n_sub = int(args[i + 1])
    del args[i: i + 2]
root, split = Path(args[0]), args[1]
scenes = args[2:] or ["rotational-center", "cubli-triple", "hinge_slide_free"]
RULES = ("explicit", "implicit", "midpoint")

d = load_split(root / "rotational-center" / f"{split}.h5")
for tr in range(4):
    for rule in RULES:
        es = free_flight(d, tr, dynamics=True, joints=True, trapezoidal=True, substeps=n_sub, gyroscopic=rule)
        print(f"rotational-center {split} trajectory {tr} free flight, {n_sub} substeps, gyroscopic {rule:8s}: "
              "energy (J) every 20 frames " + " ".join(f"{e:.6g}" for e in es), flush=True)

for scene in scenes:
    d = load_split(root / scene / f"{split}.h5")
    for rule in RULES:
        t0 = time.time()
        line, _ = tree_row(d, dynamics=True, joints=True, trapezoidal=True, push_out=True, substeps=n_sub, gyroscopic=rule)
        print(f"{scene:18s} {split:5s} {n_sub} substeps, gyroscopic {rule:8s}  {line}  {time.time() - t0:.0f} s", flush=True)

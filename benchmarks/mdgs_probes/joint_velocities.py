"""How the rigid tree's twists are projected onto its joints (``joint_velocities`` of the reference): each child given
its parent's twist across the joint ("parent", :func:`mdgs.joints.project_joints`), or the least kinetic-energy change,
equal and opposite impulses at the joints ("momentum", :func:`mdgs.actuation.project_velocities`).

    python benchmarks/mdgs_probes/joint_velocities.py DATA_FOLDER SPLIT [SCENE ...]

DATA_FOLDER holds ``SCENE/SPLIT.h5`` and, for the stability figures, ``SCENE-long/test.h5`` (SPLIT test) or
``SCENE-vlong/valid.h5`` (SPLIT valid: the validation split's starting states run 1100 frames, ``mdgs generate
... --split valid --frames 1100 --n-traj 10``). For each SCENE (default: the three study scenes), the "rigid tree +
joints, trapezoidal, push-out, 4 substeps" reference (``studies/mdgs-substeps.toml``'s) with each rule: position MSE
at t = 40 and t = 110 (10^-3 m^2; mean and median over the trajectories that did not diverge), how many diverged,
and on the long set how many trajectories stay within the study's failure threshold (position MSE below the split's
position variance) over 1100 frames. First, on rotational-center's split, each of its first four trajectories'
starting state lifted 10 m, no controls, the energy every 40 frames over 120 frames (``_tree_rows.free_flight``):
conserved in free flight, so what changes is the integrator's and the projection's error.
"""
import sys
from pathlib import Path

import numpy as np
import torch
from _tree_rows import free_flight, tree_row

from mdgs.data.split import load_split
from mdgs.evaluate.rollout import divergence_threshold, rollout
from mdgs.models import MODELS

torch.set_num_threads(1)
ct = MODELS["constant-twist"]
args = sys.argv[1:]
root, split = Path(args[0]), args[1]
scenes = args[2:] or ["rotational-center", "cubli-triple", "hinge_slide_free"]
RULES = ("parent", "momentum")
TREE = dict(dynamics=True, joints=True, trapezoidal=True, push_out=True, substeps=4)

d = load_split(root / "rotational-center" / f"{split}.h5")
for tr in range(4):
    for rule in RULES:
        es = free_flight(d, tr, every=40, joint_velocities=rule, **TREE)
        print(f"free flight, trajectory {tr}, {rule:8s}: energy (J) " + " ".join(f"{e:9.2f}" for e in es), flush=True)

for scene in scenes:
    d = load_split(root / scene / f"{split}.h5")
    long_path = root / f"{scene}-{'long' if split == 'test' else 'vlong'}" / f"{split}.h5"
    dl = load_split(long_path) if long_path.exists() else None
    for rule in RULES:
        line, _ = tree_row(d, joint_velocities=rule, **TREE)
        if dl is not None:
            m = ct(ct.Config(joint_velocities=rule, **TREE))
            r = rollout(m, dl, "cpu")
            err = np.where(np.isfinite(r.pos_mse), r.pos_mse, np.inf)
            kept = int((~(err > divergence_threshold(dl) / 100.0).any(1)).sum())
            line += f"  long: {kept}/{dl.x.shape[0]} within the threshold over {dl.x.shape[1]} frames"
        print(f"{scene:18s} {split} {rule:8s} {line}", flush=True)

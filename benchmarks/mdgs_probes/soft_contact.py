"""MuJoCo's soft contact in the rigid tree (``contact = "soft"``) against the rigid contact with push-out, on the
tree the studies step in its joint coordinates by velocity Verlet in four substeps (the ``rigid_tree_coordinates``
reference of ``studies/mdgs-coordinates.toml``).

    python benchmarks/mdgs_probes/soft_contact.py DATA_FOLDER SPLIT [SCENE ...]

DATA_FOLDER holds ``SCENE/SPLIT.h5`` (``mdgs generate SCENE --preset small --split valid --split test``; the user
scene ``hinge_slide_free`` from ``--mjcf studies/hinge_slide_free.xml --substeps 10``) and, for the stability
figures, ``SCENE-long/test.h5`` (SPLIT test) or ``SCENE-vlong/valid.h5`` (SPLIT valid: ``--frames 1100 --n-traj
10``). On each SCENE (default: the three study scenes), for each contact rule, and for the soft contact in 2 and 8
substeps as well: position MSE at t = 40 and t = 110 (10^-3 m^2, mean and median over the trajectories that did not
diverge), how many diverged, and on the long set how many stay within the study's failure threshold over 1100
frames (which ones: 1 kept, 0 lost); constant twist first, for scale. The soft contact goes without push-out, which
would undo its depth (the configuration refuses the two together).
"""
import sys
import time
from pathlib import Path

import numpy as np
import torch
from _tree_rows import tree_row

from mdgs.data.split import load_split
from mdgs.evaluate.rollout import divergence_threshold, rollout
from mdgs.models import MODELS

torch.set_num_threads(1)
ct = MODELS["constant-twist"]
args = sys.argv[1:]
root, split = Path(args[0]), args[1]
scenes = args[2:] or ["cubli-triple", "rotational-center", "hinge_slide_free"]
TREE = dict(dynamics=True, joints=True, trapezoidal=True, substeps=4, joint_velocities="coordinates")
ROWS = {"constant twist": None,
        "rigid contact, push-out": dict(TREE, push_out=True),
        "soft contact": dict(TREE, contact="soft"),
        "soft contact, 2 substeps": dict(TREE, contact="soft", substeps=2),
        "soft contact, 8 substeps": dict(TREE, contact="soft", substeps=8),
        "soft contact, Euler": dict(TREE, contact="soft", trapezoidal=False)}

base_rows = dict(ROWS)
for scene in scenes:
    ROWS = dict(base_rows)
    d = load_split(root / scene / f"{split}.h5")
    n_mj = round(float(d.frame_dt) / float(d.mj_model().opt.timestep))  # MuJoCo's own steps a frame
    ROWS[f"soft contact, Euler, {n_mj} substeps"] = dict(TREE, contact="soft", trapezoidal=False, substeps=n_mj)
    long_path = root / f"{scene}-{'long' if split == 'test' else 'vlong'}" / f"{split}.h5"
    dl = load_split(long_path) if long_path.exists() else None
    for label, settings in ROWS.items():
        t0 = time.perf_counter()
        line, _ = tree_row(d, **(settings or {}))
        out = f"{scene:18s} {split:5s} {label:36s} {line}"
        if dl is not None:
            r = rollout(ct(ct.Config(**(settings or {}))), dl, "cpu")
            thr = divergence_threshold(dl) / 100.0  # the study's failure threshold (failure_factor = 1)
            err = np.where(np.isfinite(r.pos_mse), r.pos_mse, np.inf)
            kept = [int((e <= thr).all()) for e in err]
            out += f"  long kept {sum(kept)}/{len(kept)} {''.join(map(str, kept))}"
        print(out + f"  ({time.perf_counter() - t0:.0f} s)", flush=True)

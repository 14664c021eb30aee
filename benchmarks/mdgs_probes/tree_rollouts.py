"""The soft rigid tree's rollouts of one commit against another's: do two versions of the code step the same?

    python benchmarks/mdgs_probes/tree_rollouts.py DATA_FOLDER SPLIT --save FILE.npz [SCENE ...]
    python benchmarks/mdgs_probes/tree_rollouts.py DATA_FOLDER SPLIT --compare FILE.npz [SCENE ...]

DATA_FOLDER holds ``SCENE/SPLIT.h5`` as for ``soft_contact.py`` (default scenes: the three study scenes). The rigid tree
of ``studies/mdgs-soft-8.toml`` (soft contact, eight substeps, velocity Verlet in joint coordinates) rolls out every
trajectory of the split, eagerly, one torch thread. ``--save`` writes the positions, velocities and position MSE;
run it with PYTHONPATH set to a ``git worktree`` of the other commit. ``--compare`` rolls out again with the code
imported here and prints, per scene, the largest differences of the positions (m) and velocities (m/s) from the saved
ones (the rollouts' own float32) and the mean position MSE of both at t = 40 and t = 110.
"""
import sys
from pathlib import Path

import numpy as np
import torch

import mdgs
from mdgs.data.split import load_split
from mdgs.evaluate.rollout import rollout
from mdgs.models import MODELS

torch.set_num_threads(1)
args = sys.argv[1:]
root, split, mode, path = Path(args[0]), args[1], args[2], args[3]
if mode not in ("--save", "--compare"):
    sys.exit(f"the third argument is --save or --compare, got {mode!r}")
scenes = args[4:] or ["cubli-triple", "rotational-center", "hinge_slide_free"]
TREE = dict(dynamics=True, joints=True, trapezoidal=True, substeps=8, contact="soft", joint_velocities="coordinates")

runs = {}
for scene in scenes:
    d = load_split(root / scene / f"{split}.h5")
    ct = MODELS["constant-twist"]
    r = rollout(ct.from_data(d, ct.Config(**TREE)), d)
    runs.update({f"{scene}/x": r.x, f"{scene}/v": r.v, f"{scene}/mse": r.pos_mse})
if mode == "--save":
    np.savez(path, **runs)
    print(f"saved the rollouts of {mdgs.__file__} to {path}")
    sys.exit(0)
old = np.load(path)
print(f"# python benchmarks/mdgs_probes/tree_rollouts.py {' '.join(args)}")
print(f"{'scene':20s}{'max |dx| m':>12s}{'max |dv| m/s':>14s}{'t40 saved':>11s}{'t40 here':>11s}{'t110 saved':>12s}"
      f"{'t110 here':>11s}")
for scene in scenes:
    x, v, m = (runs[f"{scene}/{k}"] for k in ("x", "v", "mse"))
    xo, vo, mo = (old[f"{scene}/{k}"] for k in ("x", "v", "mse"))
    print(f"{scene:20s}{float(np.abs(x - xo).max()):>12.2g}{float(np.abs(v - vo).max()):>14.2g}"
          f"{np.nanmean(mo[:, 40]):>11.4g}{np.nanmean(m[:, 40]):>11.4g}{np.nanmean(mo[:, -1]):>12.4g}"
          f"{np.nanmean(m[:, -1]):>11.4g}")
print("max |dx|, |dv|: the largest differences of the rollouts here from the saved ones; t40, t110: mean position MSE "
      "(m^2) of each")

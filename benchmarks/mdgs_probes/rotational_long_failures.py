"""Which of rotational-center's long trajectories does the rigid tree lose, and what the true motion does when it
starts to: the tree stepped in its joint coordinates by velocity Verlet (four substeps, push-out: the
``rigid_tree_coordinates`` reference of ``studies/mdgs-coordinates.toml``) on the long set, beside the recorded
contacts of the base with the floor.

    python benchmarks/mdgs_probes/rotational_long_failures.py DATA_FOLDER SPLIT

DATA_FOLDER holds ``rotational-center-long/test.h5`` (SPLIT test) or ``rotational-center-vlong/valid.h5`` (SPLIT
valid: ``mdgs generate rotational-center --preset small --split valid --frames 1100 --n-traj 10``). Per trajectory:
whether the tree keeps it within the study's failure threshold over its 1100 frames, the first frame its position
MSE passes 1 % and 100 % of that threshold (the onset and the failure), and how often the base's contact with the
floor switches on or off over the 30 frames around the onset (``ONSET_WINDOW``) in the recorded motion (MuJoCo's
contacts at the recorded ``qpos, qvel``, ``mj_forward``), with the geoms the floor touches at each change over the
first 300 frames. A base that hops, landing and leaving the floor frame after frame, meets MuJoCo's soft contact
at every landing, which the tree's inelastic contact stops dead (docs/mdgs-experiments.md, "Stepping in the joints'
coordinates").
"""
import sys
from pathlib import Path

import mujoco
import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.evaluate.rollout import divergence_threshold, rollout
from mdgs.models import MODELS

#: Frames before and after the onset over which the base's floor contact is followed.
ONSET_WINDOW = (25, 5)
#: The onset: the position MSE first past this fraction of the failure threshold.
ONSET_FRACTION = 0.01

torch.set_num_threads(1)
root, split = Path(sys.argv[1]), sys.argv[2]
dl = load_split(root / f"rotational-center-{'long' if split == 'test' else 'vlong'}" / f"{split}.h5")
ct = MODELS["constant-twist"]
tree = ct(ct.Config(dynamics=True, joints=True, trapezoidal=True, push_out=True, substeps=4,
                    joint_velocities="coordinates"))
r = rollout(tree, dl, "cpu")
thr = divergence_threshold(dl) / 100.0  # the study's failure threshold (failure_factor = 1)
err = np.where(np.isfinite(r.pos_mse), r.pos_mse, np.inf)  # [T, frames]
m = dl.mj_model()
d = mujoco.MjData(m)


def touching(k: int, f: int) -> list[str]:
    """The geoms touching the floor (by name) or each other ("a+b") at frame ``f`` of trajectory ``k``, from its
    recorded state."""
    d.qpos[:], d.qvel[:] = dl.qpos[k][f], dl.qvel[k][f]
    mujoco.mj_forward(m, d)
    names = {tuple(sorted((m.geom(c.geom1).name, m.geom(c.geom2).name))) for c in d.contact[:d.ncon]}
    return sorted((b if a == "floor" else a) if "floor" in (a, b) else f"{a}+{b}" for a, b in names)


print(f"rotational-center {split}: {dl.x.shape[0]} trajectories of {dl.x.shape[1]} frames; failure threshold "
      f"{thr:.4g} m^2; onset: MSE past {ONSET_FRACTION:g} of it")
print("traj  tree    onset  failure  base-floor switches in [onset-25, onset+5]  | floor contacts as they change "
      "(frame:geoms, first 300 frames)")
switches = {True: [], False: []}
for k in range(dl.x.shape[0]):
    over = np.nonzero(err[k] > thr)[0]
    start = np.nonzero(err[k] > ONSET_FRACTION * thr)[0]
    fail, onset = (int(over[0]) if len(over) else -1), (int(start[0]) if len(start) else -1)
    n = -1
    if onset >= 0:
        frames = range(max(0, onset - ONSET_WINDOW[0]), min(dl.x.shape[1], onset + ONSET_WINDOW[1] + 1))
        on = ["base" in touching(k, f) for f in frames]
        n = sum(a != b for a, b in zip(on, on[1:], strict=False))
        switches[fail >= 0].append(n)
    changes, prev = [], None
    for f in range(min(300, dl.x.shape[1])):
        now = touching(k, f)
        if now != prev:
            changes.append(f"{f}:{'/'.join(now) or '-'}")
            prev = now
    print(f"{k:4d}  {'lost' if fail >= 0 else 'kept'}  {onset:7d}  {fail:7d}  {n:20d}"
          f"{'':22s}| {' '.join(changes[:12])}", flush=True)
for lost, ns in switches.items():
    print(f"{'lost' if lost else 'kept'} trajectories with an onset: {len(ns)}, base-floor switches around it "
          f"{ns} (mean {np.mean(ns) if ns else float('nan'):.1f})")

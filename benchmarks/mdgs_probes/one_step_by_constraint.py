"""Where the rigid tree's one step per frame loses to MuJoCo's own one step per frame: one-step node errors
of both from the recorded states, split by what acts on the bodies at that frame
(docs/mdgs-experiments.md, "What the learned correction adds to the rigid tree").

    python benchmarks/mdgs_probes/one_step_by_constraint.py DATA_FOLDER SCENE [SCENE ...]

DATA_FOLDER is a study's ``data/``. For every pair (trajectory, frame) of the scene's test split, from the
recorded state: the trapezoidal "rigid tree + joints" reference's step and MuJoCo's at one step per frame
(``mujoco`` with ``dt_factor`` = the data's substeps), each against the recorded next frame (position MSE
over moving nodes, 10^-6 m^2). Pairs are grouped by what MuJoCo's own constraints hold at the frame (at
the data's timestep, ``mj_forward`` on the recorded state): a joint's range limit, contact with the world,
both or neither. Printed per group: how many pairs, the mean and the median of each error and the
fraction of pairs where the rigid tree is the worse of the two; then the 8 pairs with its largest error. A
step's error compounds over a rollout, so a group where the rigid tree is much worse is where its physics,
not its integrator, loses.
"""
import sys
from pathlib import Path

import mujoco
import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.models import MODELS

torch.set_num_threads(1)
ct, mj = MODELS["constant-twist"], MODELS["mujoco"]
for scene in sys.argv[2:]:
    folder = Path(sys.argv[1]) / scene
    d = load_split(folder / "test.h5")
    substeps = int(d.attrs["substeps"])
    tree = ct.from_data(d, ct.Config(dynamics=True, joints=True, trapezoidal=True)).eval()
    coarse = mj.from_data(d, mj.Config(dt_factor=substeps)).eval()
    m = d.mj_model()
    data = mujoco.MjData(m)
    T, F = d.x.shape[:2]
    moving = ~np.asarray(d.static["node_static"], bool)
    groups: dict[str, list] = {"neither": [], "limit": [], "contact": [], "limit and contact": []}
    worst: list = []
    for model in (tree, coarse):
        model.bind(d)
    with torch.no_grad():
        for f in range(F - 1):
            traj = np.arange(T)
            ctrl = torch.from_numpy(d.ctrl[traj, f])
            errs = []
            for model in (tree, coarse):
                nxt = model.step(model.initial_state(d, traj, f), ctrl)
                errs.append(((nxt.x.double().numpy() - d.x[:, f + 1]) ** 2)[:, moving].mean(axis=(1, 2)))
            for i in range(T):
                data.qpos[:], data.qvel[:] = d.qpos[i, f], d.qvel[i, f]
                if m.nu:
                    data.ctrl[:] = d.ctrl[i, f]
                mujoco.mj_forward(m, data)
                types = set(int(t) for t in data.efc_type[:data.nefc])
                limit = int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT) in types
                contact = data.ncon > 0
                key = "limit and contact" if limit and contact else "limit" if limit else "contact" if contact else "neither"
                groups[key].append((errs[0][i], errs[1][i]))
                worst.append((errs[0][i], errs[1][i], i, f, key))
    print(f"{scene}: {T} trajectories x {F - 1} pairs; MuJoCo at 1 step per frame = dt_factor {substeps}; errors in 1e-6 m^2")
    for key, rows in groups.items():
        if not rows:
            print(f"  {key:18s} no pairs")
            continue
        a = np.array(rows)
        print(f"  {key:18s} {len(a):5d} pairs | rigid tree mean {1e6 * a[:, 0].mean():9.4g} median {1e6 * np.median(a[:, 0]):9.4g} "
              f"| mujoco mean {1e6 * a[:, 1].mean():9.4g} median {1e6 * np.median(a[:, 1]):9.4g} "
              f"| rigid tree worse on {100 * (a[:, 0] > a[:, 1]).mean():3.0f} %", flush=True)
    total = sum(w[0] for w in worst)
    print("  the 8 pairs with the largest rigid-tree error (share of its summed error; trajectory, frame, group, mujoco's):")
    for e, e_mj, i, f, key in sorted(worst, key=lambda w: -w[0])[:8]:
        print(f"    {1e6 * e:9.4g} ({100 * e / total:4.1f} %)  trajectory {i} frame {f:3d}  {key:18s} mujoco {1e6 * e_mj:9.4g}")

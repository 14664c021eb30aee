"""Is the stability target's failure on the long trajectories model error or chaos? The soft tree at MuJoCo's own
step, and MuJoCo itself from initial velocities perturbed by round-off-sized amounts, on the long test set.

    python benchmarks/mdgs_probes/long_chaos.py DATA_FOLDER [SCENE ...]

DATA_FOLDER holds ``SCENE-long/test.h5`` (``mdgs generate SCENE --preset small --split test --frames 1100 --n-traj
10``, the studies' long set; the user scene ``hinge_slide_free`` from ``--mjcf studies/hinge_slide_free.xml
--substeps 10``). Per scene:

- the soft tree by semi-implicit Euler at MuJoCo's timestep (the data's frame over ``opt.timestep`` substeps;
  ``docs/results/mdgs-probes/one_frame-valid.txt``): for each long trajectory, the one-frame position error from
  every recorded state after frame 0 against the next recorded frame (m^2, mean over the moving nodes; float64,
  the files store float32), its mean and largest over the 1099 frames, and whether the tree's rollout from frame 0
  stays within the study's failure threshold over the 1100 frames (the first frame past it if not);
- MuJoCo at the data's own timestep from the recorded initial state with the initial velocities scaled by
  ``1 + eps N(0, 1)`` per coordinate (the study's sensitivity floor, there at eps = 1e-3), for eps = 1e-12, 1e-9,
  1e-6 and 1e-3: how many long trajectories stay within the threshold (1 kept, 0 lost).

A trajectory whose every frame the tree steps to round-off and which it still loses, and which MuJoCo loses from a
perturbation of the same size, is lost to chaos, not to the tree's model of the scene.
"""
import sys
import time
from pathlib import Path

import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.evaluate.rollout import divergence_threshold, rollout
from mdgs.models import MODELS
from mdgs.models.base import State

torch.set_num_threads(1)
ct, mj = MODELS["constant-twist"], MODELS["mujoco"]
root = Path(sys.argv[1])
scenes = sys.argv[2:] or ["cubli-triple", "rotational-center", "hinge_slide_free"]


def kept(r, thr: float) -> list[int]:
    """Per trajectory: -1 when the rollout stays within ``thr`` throughout, else the first frame past it."""
    err = np.where(np.isfinite(r.pos_mse), r.pos_mse, np.inf)
    return [-1 if (e <= thr).all() else int(np.argmax(e > thr)) for e in err]


for scene in scenes:
    d = load_split(root / f"{scene}-long" / "test.h5")
    B, T = d.x.shape[:2]
    thr = divergence_threshold(d) / 100.0  # the study's failure threshold (failure_factor = 1)
    n_mj = round(float(d.frame_dt) / float(d.mj_model().opt.timestep))
    print(f"{scene}: {B} long test trajectories of {T} frames; failure threshold {thr:.3g} m^2; "
          f"MuJoCo's timestep {d.mj_model().opt.timestep:g} s", flush=True)
    t0 = time.perf_counter()
    cfg = ct.Config(dynamics=True, joints=True, joint_velocities="coordinates", contact="soft", trapezoidal=False,
                    substeps=n_mj)
    m = ct.from_data(d, cfg)
    m.bind(d)
    r = rollout(ct(cfg), d, "cpu")
    lost = kept(r, thr)
    moving = d.moving
    print(f"  soft tree, Euler, {n_mj} substeps (MuJoCo's step): trajectory | one-frame error mean, max over "
          f"frames 1..{T - 2} (m^2) | rollout", flush=True)
    for tr in range(B):
        x = torch.as_tensor(d.x[tr, 1:-1]).double()
        v = torch.as_tensor(d.v[tr, 1:-1]).double()
        u = torch.as_tensor(d.ctrl[tr, 1:-1]).double()
        with torch.no_grad():
            s = m.step(State(x, v), u)
        ex = ((s.x.numpy() - d.x[tr, 2:])[:, moving] ** 2).sum(-1).mean(-1)
        fate = "kept" if lost[tr] < 0 else f"lost at frame {lost[tr]}"
        print(f"    {tr} | {ex.mean():9.2e} {ex.max():9.2e} | {fate}", flush=True)
    print(f"    kept {sum(f < 0 for f in lost)}/{B}  ({time.perf_counter() - t0:.0f} s)", flush=True)
    for eps in (1e-12, 1e-9, 1e-6, 1e-3):
        t0 = time.perf_counter()
        fates = kept(rollout(mj(mj.Config(dt_factor=1, velocity_noise=eps)), d, "cpu"), thr)
        pattern = "".join("1" if f < 0 else "0" for f in fates)
        print(f"  MuJoCo, initial velocities x (1 + {eps:g} N(0, 1)): kept {pattern.count('1')}/{B} {pattern}  "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)

"""Where the Cubli's rollout error sits at t = 40, body by body: the cube's pose, or each wheel's spin
relative to the cube (docs/mdgs-experiments.md, "Where the Cubli's error is left").

    python benchmarks/mdgs_probes/cube_vs_wheels.py DATA_FOLDER [LABEL=RUN_FOLDER ...]

DATA_FOLDER holds a cubli-triple ``test.h5`` (e.g. a study's ``data/cubli-triple``); each RUN_FOLDER is a
trained run (a study's ``runs/<cell>``), evaluated with the weights its selection rule kept. For constant
twist, constant twist + motors + joints and each run, per test trajectory: the position MSE at t = 40
(10^-3 m^2), the angle (degrees) between the cube's rolled-out and true rotation, the distance (mm)
between its rolled-out and true element centroid, and for each wheel the angle between its rolled-out
and true rotation *relative to the cube* (its spin error alone), and the MSE the same rollout would
have with the cube's pose exact (``cube exact``: every body placed by its rolled-out pose relative to
the cube, composed with the cube's true pose): what a perfect model of the cube's motion would leave,
the wheels' own errors. Rotations are Kabsch fits of each body's element centroids
(:func:`mdgs.structure.kabsch`); ``*`` marks a trajectory with a brake command (above 5 N m) before
t = 40.
"""
import sys

import numpy as np
import torch
from _brakes import split_models_and_brakes

from mdgs.evaluate.rollout import rollout
from mdgs.structure import kabsch

torch.set_num_threads(1)
d, models, t, brake = split_models_and_brakes(sys.argv[1:])
mj = d.mj_model()
body = np.asarray(d.static["node_body"])
moving = sorted(set(body[d.moving].tolist()))
cube = next(b for b in moving if mj.body_parentid[b] == 0)  # the free body; the wheels hang from it
wheels = [b for b in moving if b != cube]
ref = torch.as_tensor(d.static["node_centroid"], dtype=torch.float64)
seg, n = torch.as_tensor(body, dtype=torch.long), int(body.max()) + 1


def angle(Ra: torch.Tensor, Rb: torch.Tensor) -> np.ndarray:
    """Degrees of the rotation taking Ra to Rb, [...]."""
    c = ((Ra.transpose(-1, -2) @ Rb).diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2
    return torch.rad2deg(torch.arccos(c.clamp(-1, 1))).numpy()


Rt, tt = kabsch(ref, torch.as_tensor(d.x[:, t], dtype=torch.float64), seg, n)
names = [mj.body(b).name for b in wheels]
print(f"t = 40 is frame {t}; cube: body {mj.body(cube).name!r}; wheels: {names}; '*': a brake command before t = 40")
for name, m in models.items():
    r = rollout(m, d)
    e = r.pos_mse[:, t] * 1e3
    Rp, tp = kabsch(ref, torch.as_tensor(r.x[:, t], dtype=torch.float64), seg, n)
    rot = angle(Rp[:, cube], Rt[:, cube])
    shift = (tp[:, cube] - tt[:, cube]).norm(dim=-1).numpy() * 1e3
    spin = [angle(Rp[:, cube].transpose(-1, -2) @ Rp[:, w], Rt[:, cube].transpose(-1, -2) @ Rt[:, w]) for w in wheels]
    # every body's rolled-out pose relative to the cube, placed on the cube's true pose
    Rrel = Rp[:, cube].transpose(-1, -2).unsqueeze(1) @ Rp  # [T, S, 3, 3]
    trel = (Rp[:, cube].transpose(-1, -2).unsqueeze(1) @ (tp - tp[:, [cube]]).unsqueeze(-1)).squeeze(-1)
    Ro = Rt[:, cube].unsqueeze(1) @ Rrel
    to = (Rt[:, cube].unsqueeze(1) @ trel.unsqueeze(-1)).squeeze(-1) + tt[:, [cube]]
    xo = (Ro[:, seg] @ ref.unsqueeze(-1)).squeeze(-1) + to[:, seg]  # [T, N, 3]
    exact = ((xo.numpy() - d.x[:, t]) ** 2)[:, d.moving].mean(axis=(1, 2)) * 1e3
    print(f"\n{name}: mean MSE {np.nanmean(e):.3g}, with the cube's pose exact {np.nanmean(exact):.3g}; cube "
          f"rotation error median {np.median(rot[~brake]):.1f} deg without a brake, {np.median(rot[brake]):.1f} with one")
    print("  traj   MSE  cube exact  cube deg  cube mm  " + "  ".join(f"{s[:12]:>12s}" for s in names))
    for i in range(len(e)):
        print(f"  {i:2d}{'*' if brake[i] else ' '} {e[i]:6.3f}  {exact[i]:9.3f}  {rot[i]:7.2f}  {shift[i]:7.2f}  "
              + "  ".join(f"{s[i]:12.1f}" for s in spin))

"""Why no simulator that steps the Cubli's dynamics beats doing nothing there at t = 110, trajectory by trajectory.

    python benchmarks/mdgs_probes/cubli_t110.py DATA_FOLDER [LABEL=RUN_FOLDER ...]

DATA_FOLDER holds a cubli-triple ``test.h5`` (e.g. a study's ``data/cubli-triple``); each RUN_FOLDER is a trained
run (a study's ``runs/<cell>``), evaluated with the weights its selection rule kept. Rolled out from the first
frame: constant twist (every body keeps its twist), MuJoCo at 2, 5 and 20 times the data's timestep (the
data's own MJCF and solver; one step a frame is 20x), the rigid tree in 4 substeps with push-out
(``studies/mdgs-substeps.toml``'s reference) and each run. Printed per test trajectory at t = 110:

- how far the true cube turned and moved between the first frame and t = 110 (degrees, mm) and the largest
  motor command over those frames (N m: the wheels' brakes are the commands above 5);
- each model's position MSE (10^-3 m^2) and, in brackets, how far its cube's rotation is off the true one
  (degrees): a cube that tips one way in the data and stays or tips the other way in a model is tens of
  degrees off, and puts every element centroid of the cube and its wheels centimetres away.

Rotations are Kabsch fits of each body's element centroids (:func:`mdgs.structure.kabsch`). The last lines
give each model's mean MSE and the mean over the trajectories where constant twist is the best of the
non-learned rows and over the others.
"""
import sys

import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.evaluate.metrics import frame_of
from mdgs.evaluate.rollout import rollout
from mdgs.models import MODELS
from mdgs.runs import load_run
from mdgs.structure import kabsch

torch.set_num_threads(1)
d = load_split(sys.argv[1] + "/test.h5")
ct, mj_ = MODELS["constant-twist"], MODELS["mujoco"]
models = {"constant twist": ct(ct.Config())}
for k in (2, 5, 20):
    models[f"mujoco dt x{k}"] = mj_(mj_.Config(dt_factor=k))
models["rigid tree, 4 substeps"] = ct(ct.Config(dynamics=True, joints=True, trapezoidal=True, push_out=True, substeps=4))
for arg in sys.argv[2:]:
    label, _, path = arg.partition("=")
    models[label] = load_run(path, "cpu")[0]
t = frame_of(110, d.x.shape[1])
mj = d.mj_model()
body = np.asarray(d.static["node_body"])
moving = sorted(set(body[d.moving].tolist()))
cube = next(b for b in moving if mj.body_parentid[b] == 0)  # the free body; the wheels hang from it
ref = torch.as_tensor(d.static["node_centroid"], dtype=torch.float64)
seg, n = torch.as_tensor(body, dtype=torch.long), int(body.max()) + 1


def angle(Ra: torch.Tensor, Rb: torch.Tensor) -> np.ndarray:
    """Degrees of the rotation taking Ra to Rb, [...]."""
    c = ((Ra.transpose(-1, -2) @ Rb).diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2
    return torch.rad2deg(torch.arccos(c.clamp(-1, 1))).numpy()


R0, t0 = kabsch(ref, torch.as_tensor(d.x[:, 0], dtype=torch.float64), seg, n)
Rt, tt = kabsch(ref, torch.as_tensor(d.x[:, t], dtype=torch.float64), seg, n)
turned = angle(R0[:, cube], Rt[:, cube])
moved = (tt[:, cube] - t0[:, cube]).norm(dim=-1).numpy() * 1e3
command = np.abs(d.ctrl[:, :t]).max((1, 2))
mse, deg = {}, {}
for name, m in models.items():
    r = rollout(m, d)
    mse[name] = r.pos_mse[:, t] * 1e3
    Rp, _ = kabsch(ref, torch.as_tensor(r.x[:, t], dtype=torch.float64), seg, n)
    deg[name] = np.where(np.isfinite(mse[name]), angle(Rp[:, cube], Rt[:, cube]), np.nan)
    print(f"rolled out: {name}", flush=True)
print(f"\nt = 110 is frame {t}; cube: body {mj.body(cube).name!r}; MSE in 10^-3 m^2 [the cube's rotation error, deg]")
print(f"{'traj':>4} {'true cube: deg':>14} {'mm':>6} {'max cmd':>8}  " + "  ".join(f"{k[:22]:>22s}" for k in models))
for i in range(d.x.shape[0]):
    print(f"{i:>4} {turned[i]:14.1f} {moved[i]:6.1f} {command[i]:8.2f}  "
          + "  ".join(f"{mse[k][i]:12.3f} [{deg[k][i]:6.1f}]" for k in models))
refs = [k for k in models if k in ("constant twist", "rigid tree, 4 substeps") or k.startswith("mujoco")]
best_ct = np.argmin(np.stack([mse[k] for k in refs]), 0) == refs.index("constant twist")
print(f"\nconstant twist is the best non-learned row on trajectories {np.flatnonzero(best_ct).tolist()}")
print(f"{'model':>30s} {'mean MSE':>9s} {'where CT is best':>17s} {'elsewhere':>10s} {'median cube deg':>16s}")
for k in models:
    print(f"{k[:30]:>30s} {np.nanmean(mse[k]):9.3f} {np.nanmean(mse[k][best_ct]):17.3f} "
          f"{np.nanmean(mse[k][~best_ct]):10.3f} {np.nanmedian(deg[k]):16.1f}")

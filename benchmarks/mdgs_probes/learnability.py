"""How learnable is one frame of a scene from its data? A plain MLP on the object-level state.

    python benchmarks/mdgs_probes/learnability.py DATA_FOLDER [STEPS] [--body]

For every training pair, the input is the whole system's object-level state at t (each moving
object's centroid, linear and angular velocity and rotation, and the controls; with ``--body`` the
velocities, the world's z axis and the objects' relative rotations in each body's own frame, and
the centroids' heights only) and the target is each object's twist increment over the frame
(``v_c' - v_c``, ``w' - w``, from :func:`mdgs.rigid.twist`; in the body frame with ``--body``). Prints
R^2 on the training and the validation split (per output, averaged over the linear and the angular
block) of a least-squares fit and of a two-layer MLP (256 wide, Adam 1e-3, batch 64). R^2 = 0 is
predicting the training mean; docs/mdgs-experiments.md quotes this script's output.
"""
import sys

import torch

from mdgs.data.split import load_split
from mdgs.graphs import SceneGraph
from mdgs.rigid import twist
from mdgs.structure import kabsch

torch.set_num_threads(1)
torch.manual_seed(0)
args = [a for a in sys.argv[1:] if not a.startswith("--")]
data, steps, body = args[0], int(args[1]) if len(args) > 1 else 4000, "--body" in sys.argv


def pairs_of(d):
    """(inputs [P, D], targets [P, 6 S]) of every (t, t + 1) pair of split ``d``."""
    sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
    p = d.pairs()
    t, f = p[:, 0], p[:, 1]
    x0, v0 = torch.from_numpy(d.x[t, f]).double(), torch.from_numpy(d.v[t, f]).double()
    x1, v1 = torch.from_numpy(d.x[t, f + 1]).double(), torch.from_numpy(d.v[t, f + 1]).double()
    seg, n, mass = sc.obj, sc.n_obj, sc.mass.double()
    a, b = twist(x0, v0, seg, n, mass), twist(x1, v1, seg, n, mass)
    R, _ = kabsch(sc.ref_shape.double(), x0, seg, n)
    mv = [o for o in range(n) if not bool(sc.static[sc.obj == o].all())]
    ctrl = torch.from_numpy(d.ctrl[t, f]).double()
    R, dvc, dw = R[:, mv], (b.vc - a.vc)[:, mv], (b.omega - a.omega)[:, mv]
    if body:
        Rt = R.transpose(-1, -2)
        into = lambda q: (Rt @ q.unsqueeze(-1)).squeeze(-1).flatten(1)  # noqa: E731
        X = torch.cat([into(a.omega[:, mv]), into(a.vc[:, mv]), Rt[..., :, 2].flatten(1), a.c[:, mv][..., 2],
                       (Rt[:, :, None] @ R[:, None]).flatten(1), ctrl], 1)
        Y = torch.cat([into(dvc), into(dw)], 1)
    else:
        X = torch.cat([a.c[:, mv].flatten(1), a.vc[:, mv].flatten(1), a.omega[:, mv].flatten(1), R.flatten(1), ctrl], 1)
        Y = torch.cat([dvc.flatten(1), dw.flatten(1)], 1)
    return X.float(), Y.float(), len(mv)


Xt, Yt, S = pairs_of(load_split(data + "/train.h5"))
Xv, Yv, _ = pairs_of(load_split(data + "/valid.h5"))
VARIES = Yt.std(0) > 1e-6 * Yt.std(0).max()  # outputs that move at all (a slide's body never turns)
mu, sd = Xt.mean(0), Xt.std(0).clamp_min(1e-6)
ym, ys = Yt.mean(0), Yt.std(0).clamp_min(1e-9)
Xt, Xv, Yt, Yv = (Xt - mu) / sd, (Xv - mu) / sd, (Yt - ym) / ys, (Yv - ym) / ys




def r2(p, y):
    """R^2 per output that varies, averaged over the linear and over the angular outputs."""
    r = 1 - ((p - y) ** 2).mean(0) / y.var(0).clamp_min(1e-30)
    lin, ang = VARIES.clone(), VARIES.clone()
    lin[3 * S:], ang[:3 * S] = False, False
    return f"linear {float(r[lin].mean()):+.2f}, angular {float(r[ang].mean()):+.2f}"


one = lambda X: torch.cat([X, torch.ones(len(X), 1)], 1)  # noqa: E731
W = torch.linalg.lstsq(one(Xt), Yt).solution
print(f"{data}: {S} moving objects, {len(Xt)} training pairs, {len(Xv)} validation pairs, "
      f"{'body' if body else 'world'} frame")
print(f"least squares  R^2 train {r2(one(Xt) @ W, Yt)}; valid {r2(one(Xv) @ W, Yv)}")
net = torch.nn.Sequential(torch.nn.Linear(Xt.shape[1], 256), torch.nn.ReLU(), torch.nn.Linear(256, 256),
                          torch.nn.ReLU(), torch.nn.Linear(256, Yt.shape[1]))
opt = torch.optim.Adam(net.parameters(), 1e-3)
for s in range(steps):
    i = torch.randint(0, len(Xt), (64,))
    loss = ((net(Xt[i]) - Yt[i]) ** 2).mean()
    opt.zero_grad()
    loss.backward()
    opt.step()
    if (s + 1) % (steps // 4) == 0:
        with torch.no_grad():
            print(f"MLP step {s + 1:5d}  R^2 train {r2(net(Xt), Yt)}; valid {r2(net(Xv), Yv)}")

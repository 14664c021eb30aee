"""What GNS must learn with and without the tree prior: the spread of its acceleration target on a training split.

    python benchmarks/mdgs_probes/gns_tree_residual.py DATA_FOLDER [SCENE ...]

DATA_FOLDER holds ``SCENE/train.h5`` (``mdgs generate SCENE --preset small``; the user scene ``hinge_slide_free``
from ``--mjcf studies/hinge_slide_free.xml --substeps 10``). Per axis, the std over the moving nodes of every
training pair with a full history (what :meth:`mdgs.models.gns.GNS.fit` computes with ``noise_std = 0``):
GNS's own target ``x^{t+1} - 2 x^t + x^{t-1}`` and, with ``prior = "tree"`` (the soft tree in eight substeps,
studies/gns-soft-8.toml), the tree's residual ``x^{t+1} - x_p``; both in m per frame^2 x 1 frame^2, beside GNS's
training noise at the last input velocity (6.7e-4 m per frame). Then which velocity to hand on after a correction
``a``: on 768 evenly spaced training pairs, the share of the tree's velocity residual ``v^{t+1} - v_p`` (sum of
squares over the moving nodes' components) left unexplained by ``c a / dt`` with ``a`` the exact position residual,
for c = 0 (the tree's velocity kept), 1 (GNS's semi-implicit Euler: the velocity changes by the acceleration over the
frame, the rule ``prior = "tree"`` uses), 2 (a constant acceleration error over the frame) and the least-squares c.
"""
import sys
from pathlib import Path

import numpy as np
import torch

from mdgs.data.split import load_split
from mdgs.models.base import batch_of
from mdgs.models.gns import GNS, GNSConfig

torch.set_num_threads(1)
root = Path(sys.argv[1])
scenes = sys.argv[2:] or ["cubli-triple", "rotational-center", "hinge_slide_free"]
print(f"GNS's training noise at the last input velocity: {GNSConfig().noise_std:.2g} m per frame")
velocity = []
print("scene | GNS's target std x, y, z (m) | tree residual std x, y, z (m) | largest ratio tree / GNS's")
for scene in scenes:
    d = load_split(root / scene / "train.h5")
    own = GNS.from_data(d, GNSConfig(noise_std=0.0)).acc_std
    model = GNS.from_data(d, GNSConfig(prior="tree", noise_std=0.0))
    tree = model.acc_std
    f = lambda s: ", ".join(f"{v:.2g}" for v in s.tolist())  # noqa: E731
    print(f"{scene} | {f(own)} | {f(tree)} | {float((tree / own).max()):.2g}", flush=True)
    velocity.append((scene, model, d))
print("scene | unexplained share of v^{t+1} - v_p by c a / dt at c = 0, 1, 2 | least-squares c, its unexplained share")
for scene, model, d in velocity:
    pairs = d.pairs(model.history)
    b = batch_of(d, pairs[np.linspace(0, len(pairs) - 1, 768).astype(int)], "cpu", model.history)
    xp, vp = model._tree(b.x, b.v, b.ctrl)
    r = ((b.x_next - xp) / model.config.dt)[:, d.moving].double().reshape(-1)
    q = (b.v_next - vp)[:, d.moving].double().reshape(-1)
    c = float((r * q).sum() / (r * r).sum())
    left = lambda k, q=q, r=r: float(((q - k * r) ** 2).sum() / (q ** 2).sum())  # noqa: E731
    print(f"{scene} | {left(0):.3f}, {left(1):.3f}, {left(2):.3f} | {c:.3f}, {left(c):.3f}", flush=True)

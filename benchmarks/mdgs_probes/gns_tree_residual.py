"""What GNS must learn with and without the tree prior: the spread of its acceleration target on a training split.

    python benchmarks/mdgs_probes/gns_tree_residual.py DATA_FOLDER [SCENE ...]

DATA_FOLDER holds ``SCENE/train.h5`` (``mdgs generate SCENE --preset small``; the user scene ``hinge_slide_free``
from ``--mjcf studies/hinge_slide_free.xml --substeps 10``). Per axis, the std over the moving nodes of every
training pair with a full history (what :meth:`mdgs.models.gns.GNS.fit` computes with ``noise_std = 0``):
GNS's own target ``x^{t+1} - 2 x^t + x^{t-1}`` and, with ``prior = "tree"`` (the soft tree in eight substeps,
studies/gns-soft-8.toml), the tree's residual ``x^{t+1} - x_p``; both in m per frame^2 x 1 frame^2, beside GNS's
training noise at the last input velocity (6.7e-4 m per frame).
"""
import sys
from pathlib import Path

import torch

from mdgs.data.split import load_split
from mdgs.models.gns import GNS, GNSConfig

torch.set_num_threads(1)
root = Path(sys.argv[1])
scenes = sys.argv[2:] or ["cubli-triple", "rotational-center", "hinge_slide_free"]
print(f"GNS's training noise at the last input velocity: {GNSConfig().noise_std:.2g} m per frame")
print("scene | GNS's target std x, y, z (m) | tree residual std x, y, z (m) | largest ratio tree / GNS's")
for scene in scenes:
    d = load_split(root / scene / "train.h5")
    own = GNS.from_data(d, GNSConfig(noise_std=0.0)).acc_std
    tree = GNS.from_data(d, GNSConfig(prior="tree", noise_std=0.0)).acc_std
    f = lambda s: ", ".join(f"{v:.2g}" for v in s.tolist())  # noqa: E731
    print(f"{scene} | {f(own)} | {f(tree)} | {float((tree / own).max()):.2g}", flush=True)

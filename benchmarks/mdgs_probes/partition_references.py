"""The non-learned references on each element partition of the same test trajectories.

    python benchmarks/mdgs_probes/partition_references.py DATA_FOLDER

DATA_FOLDER: a study's OUT/data holding ``SCENE/test.h5`` and ``SCENE-r2/test.h5`` (the same trajectories
partitioned by ``mdgs generate --refine 2``). Position MSE is a mean over element centroids, so the same
motion scores differently on another partition (a rotation error weighs each node by its squared distance
from the axis, and finer elements sit, on average, farther out): a refine-2 row must be divided by the
references on refine-2 nodes. Prints t = 40 / t = 110 (10^-3 m^2) of constant twist and of MuJoCo at one
step per frame on both partitions.
"""
import sys

import torch

from mdgs.data.split import load_split
from mdgs.evaluate import evaluate_reference
from mdgs.models import MODELS

torch.set_num_threads(1)
root = sys.argv[1]
for scene, k in (("cubli-triple", 20), ("rotational-center", 20), ("hinge_slide_free", 10)):
    for suffix in ("", "-r2"):
        d = load_split(f"{root}/{scene}{suffix}/test.h5")
        line = [f"{scene + suffix:<22} {d.x.shape[2]:>4} nodes"]
        for name, kw in (("constant-twist", {}), ("mujoco", {"dt_factor": k})):
            cls = MODELS[name]
            m = cls(cls.Config(**kw))
            m.bind(d)
            rep, _ = evaluate_reference(m, d, torch.device("cpu"))
            line.append(f"{rep['label']}: {1e3 * rep['mse_t40']:.4g} / {1e3 * rep['mse_t110']:.4g}")
        print("   ".join(line), flush=True)

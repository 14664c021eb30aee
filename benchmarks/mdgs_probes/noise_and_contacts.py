"""Does B.2's training noise change what the "dynamics" prior does? (docs/mdgs-experiments.md, "The whole
tree's dynamics as the prior").

    python benchmarks/mdgs_probes/noise_and_contacts.py DATA_FOLDER [PAIRS]

DATA_FOLDER holds a scene's ``train.h5`` (e.g. a study's ``data/cubli-triple``). On PAIRS training pairs (default
1024, evenly spaced), each input frame is perturbed as MDGS perturbs it in training (``MDGS.perturb``, the
scene's B.2 noise, rigid per object, seed 0). For each pair: whether the set of held floor corners, or of
sliding ones, differs between the clean and the noisy frame (the rule of
:func:`mdgs.actuation.coupled_motor_accelerations`), and the size of three velocity changes over the frame,
RMS over moving nodes (m/s): the prior's change from the clean frame to the noisy one, the input noise on
the velocities itself, and what g is asked to learn on the clean frame: the pair's true next velocities minus
those of the rigid tree's step from it (the untrained model's step without the joint projection; a node
velocity change of its own would count the turn of a spinning body's velocities over the frame, which the
rigid integrator makes, as if g had to learn it). Prints their medians and 90th percentiles, overall and
over the pairs whose corner sets differ.
"""
import sys

import numpy as np
import torch

from mdgs.actuation import contacts, coupled_motor_accelerations, drives_of
from mdgs.data.split import load_split
from mdgs.models import MODELS
from mdgs.models.base import State, batch_of
from mdgs.rigid import twist
from mdgs.structure import kabsch

torch.set_num_threads(1)
d = load_split(sys.argv[1] + "/train.h5")
n_pairs = int(sys.argv[2]) if len(sys.argv) > 2 else 1024
model = MODELS["mdgs"].from_data(d, MODELS["mdgs"].Config(actuation="dynamics"))
model.bind(d)
pairs = d.pairs()
pairs = pairs[np.linspace(0, len(pairs) - 1, min(n_pairs, len(pairs))).astype(int)]
b = batch_of(d, pairs, "cpu")
noisy = model.perturb(b, torch.Generator().manual_seed(0))
sc = model.scene_on("cpu")
ds = drives_of(d.mj_model(), d.static["node_body"], d.static["node_centroid"])
seg, n, mass, ref = sc.obj, sc.n_obj, sc.mass.double(), sc.ref_shape.double()
dt = float(d.frame_dt)
moving = ~sc.static


def corner_sets(x, v):
    """[B, C] held and sliding (corner, surface) pairs of frame (x, v), by the forward dynamics' own rule."""
    x, v = x.double(), v.double()
    R, t = kabsch(ref, x, seg, n)
    ct = contacts(R, t, twist(x, v, seg, n, mass), ds, dt)
    return ct.held, ct.held & ct.slide


def prior_dv(x, v):
    return dt * coupled_motor_accelerations(x.double(), b.ctrl.double(), ds, ref, seg, n, v=v.double(), mass=mass, dt=dt)


def rms(a):
    return a[:, moving].pow(2).sum(-1).mean(-1).sqrt().numpy()


h0, s0 = corner_sets(b.x, b.v)
h1, s1 = corner_sets(noisy.x, noisy.v)
held_flip = (h0 != h1).any(-1).numpy()
slide_flip = (s0 != s1).any(-1).numpy()
p0, p1 = prior_dv(b.x, b.v), prior_dv(noisy.x, noisy.v)
change = rms(p1 - p0)
noise_v = rms(noisy.v.double() - b.v.double())
ct = MODELS["constant-twist"]
tree = ct.from_data(d, ct.Config(dynamics=True))
tree.bind(d)
with torch.no_grad():
    target = rms(b.v_next.double() - tree.step(State(b.x, b.v), b.ctrl).v.double())
flip = held_flip | slide_flip
print(f"{sys.argv[1]}: {len(pairs)} training pairs, noise as MDGS trains (seed 0)")
print(f"pairs whose held corners differ clean / noisy: {held_flip.mean():.1%}; whose sliding corners differ: "
      f"{slide_flip.mean():.1%}; either: {flip.mean():.1%}")
for name, a in (("prior's change, clean -> noisy", change), ("velocity noise itself", noise_v),
                ("what g learns (true - rigid tree, clean)", target)):
    row = f"{name:40s} median {np.median(a):9.3g}  p90 {np.percentile(a, 90):9.3g} m/s"
    if flip.any():
        row += f"   | on the pairs with a flip: median {np.median(a[flip]):9.3g}  p90 {np.percentile(a[flip], 90):9.3g}"
    print(row)

"""Does the push-out after g's correction undo what g learned? For runs of MDGS on the rigid tree in substeps
with ``push_out`` (the tree's state is already pushed out after every substep, and the rollout step pushes the
corrected state out once more), one-step errors on the validation split and test rollouts with that last
push-out and without it (docs/mdgs-experiments.md, "Output scales from the prior's residual").

    python benchmarks/mdgs_probes/post_push_out.py [LABEL=]RUN ...

Each RUN is a trained run folder whose ``config.json`` names its data. Prints, per run: the median over 512
evenly spaced validation pairs of the one-step position and velocity MSE (m^2, (m/s)^2, moving nodes) of a
rollout step, of the trained model and of its start (g's output zeroed: the rigid tree); then, with and
without the last push-out, the test position MSE at t = 40 and t = 110 (10^-3 m^2, mean over the
trajectories that did not diverge). "Without" replaces the push-out that follows g's correction in
:meth:`mdgs.models.mdgs.MDGS.forward` by the identity; the tree's own push-out (:func:`mdgs.tree.tree_step`) stays.
"""
import copy
import sys
from pathlib import Path

import numpy as np
import torch

import mdgs.models.mdgs as mdgs_module
from mdgs.data.split import load_split
from mdgs.evaluate.rollout import rollout
from mdgs.models.base import batch_of
from mdgs.runs import load_run

torch.set_num_threads(1)
PUSH_OUT = mdgs_module.push_out


def one_step(m, d) -> tuple[float, float]:
    pairs = d.pairs(m.history)
    pairs = pairs[np.linspace(0, len(pairs) - 1, 512).astype(int)]
    m.bind(d)
    sc = m.scene_on("cpu")
    mv = ~sc.static
    ex, ev = [], []
    with torch.no_grad():
        for i in range(0, len(pairs), 128):
            b = batch_of(d, pairs[i:i + 128], "cpu", m.history)
            p = m(sc, b.x, b.v, m.node_controls(b.ctrl), simulate=True, ctrl=b.ctrl)
            ex.append(((p.x - b.x_next)[:, mv] ** 2).sum(-1).mean(-1))
            ev.append(((p.v - b.v_next)[:, mv] ** 2).sum(-1).mean(-1))
    return float(torch.cat(ex).median()), float(torch.cat(ev).median())


for arg in sys.argv[1:]:
    label, _, run = arg.rpartition("=")
    model, state = load_run(run, "cpu")
    start = copy.deepcopy(model)
    start.state.zero_output()
    data = Path(state["config"]["data"])
    va, te = load_split(data / "valid.h5"), load_split(data / "test.h5")
    line = []
    for after in (True, False):
        mdgs_module.push_out = PUSH_OUT if after else (lambda x, v, *a, **k: (x, v))
        (px, pv), (sx, sv) = one_step(model, va), one_step(start, va)
        r = rollout(model, te).pos_mse
        ok = np.isfinite(r[:, 109])
        line.append(f"{'with' if after else 'without'} last push-out: one step pos {px:.3g} (start {sx:.3g}) "
                    f"vel {pv:.3g} (start {sv:.3g}); test t=40 {np.nanmean(r[:, 39]) * 1e3:.4g} "
                    f"t=110 {np.nanmean(r[ok, 109]) * 1e3:.4g} ({ok.sum()}/{len(ok)})")
    mdgs_module.push_out = PUSH_OUT
    print(f"{label or run}\n  " + "\n  ".join(line), flush=True)

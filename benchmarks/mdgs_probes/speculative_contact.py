"""The rigid tree with speculative contact (``mdgs.actuation.CONTACT_SPECULATIVE``) against the studies' rule:
a corner about to strike a surface within the frame is held; the studies' rule stops its approach over the
frame, short of the surface, the speculative one lets it close the gap and arrive (docs/mdgs-experiments.md,
"What the learned correction adds to the rigid tree"; benchmarks/mdgs_probes/one_step_by_constraint.py found
the user scene's largest one-step errors where its free box lands).

    python benchmarks/mdgs_probes/speculative_contact.py DATA_FOLDER SCENE [SCENE ...]

DATA_FOLDER is a study's ``data/``. The trapezoidal "rigid tree + joints" reference on each scene's test
and long trajectories with each rule: position MSE at t = 40 and t = 110 (10^-3 m^2, mean over trajectories
that did not diverge), how many diverged, and how many long trajectories stay within the studies' failure
threshold (failure_factor 1) over 1100 frames; then the lowest node height of the test rollouts, over every
trajectory and frame, beside the recorded one (m), for the body whose rollouts go lowest below its recorded
lowest: a body that sinks into a surface and stays there shows there.
"""
import sys
from pathlib import Path

import numpy as np
import torch

import mdgs.actuation as actuation
from mdgs.data.split import load_split
from mdgs.evaluate import evaluate_reference
from mdgs.evaluate.rollout import divergence_threshold, rollout
from mdgs.models import MODELS

torch.set_num_threads(1)
ct = MODELS["constant-twist"]
for scene in sys.argv[2:]:
    d = load_split(Path(sys.argv[1]) / scene / "test.h5")
    long_path = Path(sys.argv[1]) / f"{scene}-long" / "test.h5"
    for rule in (False, True):
        actuation.CONTACT_SPECULATIVE = rule
        tree = ct(ct.Config(dynamics=True, joints=True, trapezoidal=True))
        rep, _ = evaluate_reference(tree, d, "cpu")
        body = np.asarray(d.static["node_body"], int)
        xr = rollout(ct.from_data(d, tree.config), d).x
        below = {b: (float(np.nanmin(xr[:, :, body == b, 2])), float(d.x[:, :, body == b, 2].min()))
                 for b in np.unique(body[~np.asarray(d.static["node_static"], bool)])}
        b_low = max(below, key=lambda b: below[b][1] - below[b][0])
        t110 = rep["mse_t110"] * 1e3 if rep["mse_t110"] is not None else float("nan")
        line = (f"{scene:18s} {'speculative' if rule else 'stop where it is':17s} t=40 {rep['mse_t40'] * 1e3:8.4g} "
                f"({rep['mse_t40_trajectories']})  t=110 {t110:8.4g} ({rep['mse_t110_trajectories']})  "
                f"diverged {rep['diverged']}/{d.x.shape[0]}")
        if long_path.exists():
            dl = load_split(long_path)
            r = rollout(ct.from_data(dl, ct.Config(dynamics=True, joints=True, trapezoidal=True)), dl)
            thr = divergence_threshold(dl) / 100.0
            err = np.where(np.isfinite(r.pos_mse), r.pos_mse, np.inf)
            line += f"  long within {int((~(err > thr).any(1)).sum())}/{dl.x.shape[0]}"
        line += f"  lowest node of body {b_low} {below[b_low][0]:.4f} m (recorded {below[b_low][1]:.4f})"
        print(line, flush=True)
actuation.CONTACT_SPECULATIVE = False

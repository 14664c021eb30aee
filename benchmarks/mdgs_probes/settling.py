"""How many active-set passes the soft solves of a step need, started cold or from the solve before, and whether the
start changes the rollouts.

    python benchmarks/mdgs_probes/settling.py DATA_FOLDER SPLIT [SCENE ...]

DATA_FOLDER holds ``SCENE/SPLIT.h5`` as for ``soft_solve.py`` (default scenes: the three study scenes). The rigid tree
of ``studies/mdgs-soft-8.toml`` (soft contact, eight substeps, velocity Verlet in joint coordinates: nine solves a
frame) rolls out every trajectory of the split, one at a time (the passes one trajectory's step needs), eagerly,
twice: each solve after a frame's first starting from the states the solve before settled on (``warm`` of
:func:`mdgs.actuation.coupled_motor_accelerations`, as the package does), and every solve started cold, all held rows
pushing (as it did before). Printed per scene and start: how many solves needed 1, 2, ... passes until the rows'
states repeat (``SOFT_CONTACT_PASSES`` at most), split into the frames' first solves (always cold) and the others;
the share of frames whose later solves all settle within K passes (a compiled step, which runs every pass, could stop
at K only where that holds); and the largest differences of the two rollouts' positions and velocities and their
position MSE at t = 40 and t = 110.
"""
import collections
import dataclasses
import sys
from pathlib import Path

import numpy as np
import torch

import mdgs.actuation as actuation
from mdgs.data.split import load_split
from mdgs.evaluate.rollout import rollout
from mdgs.models import MODELS

torch.set_num_threads(1)
args = sys.argv[1:]
root, split = Path(args[0]), args[1]
scenes = args[2:] or ["cubli-triple", "rotational-center", "hinge_slide_free"]
TREE = dict(dynamics=True, joints=True, trapezoidal=True, substeps=8, contact="soft", joint_velocities="coordinates")
SOLVES = TREE["substeps"] + 1  # velocity Verlet: the frame's start, then each substep's end
solve, unilateral = actuation._solve, actuation._unilateral_solve


def counted(cold: bool):
    """``_unilateral_solve`` counting its passes (the solves of its loop, after the one of ``[Jm; D]``), started cold
    if ``cold``."""
    calls: list[tuple[bool, int]] = []  # (warm, passes) per call, in order
    box = {"n": 0}

    def counting_solve(K, b):
        box["n"] += 1
        return solve(K, b)

    def wrapped(M, F, Jm, b0, D, Ju, ru, Ru, held, static, keep=None, start=None, d=None):
        if keep is not None and keep.shape[0] < M.shape[-1]:  # the outer call: it recurses once, keep = None
            return unilateral(M, F, Jm, b0, D, Ju, ru, Ru, held, static, keep, start=None if cold else start, d=d)
        box["n"] = 0
        actuation._solve = counting_solve
        try:
            out = unilateral(M, F, Jm, b0, D, Ju, ru, Ru, held, static, keep, start=None if cold else start, d=d)
        finally:
            actuation._solve = solve
        calls.append((start is not None and not cold, box["n"] - 1))  # the first solve completes [Jm; D]: no pass
        return out

    return wrapped, calls


def one(d, i: int):
    """Trajectory ``i`` of split ``d`` alone."""
    pick = {k: getattr(d, k)[i:i + 1] for k in ("x", "v", "ctrl", "qpos", "qvel", "act") if getattr(d, k) is not None}
    return dataclasses.replace(d, **pick)


print(f"# python benchmarks/mdgs_probes/settling.py {' '.join(args)}")
for scene in scenes:
    d = load_split(root / scene / f"{split}.h5")
    ct = MODELS["constant-twist"]
    x, v, mse, counts = ({"warm": [], "cold": []} for _ in range(4))
    for i in range(len(d.x)):  # one trajectory at a time: the passes one trajectory's step needs
        di = one(d, i)
        for name in ("warm", "cold"):
            fn, calls = counted(name == "cold")
            actuation._unilateral_solve = fn
            try:
                r = rollout(ct.from_data(di, ct.Config(**TREE)), di)
            finally:
                actuation._unilateral_solve = unilateral
            assert len(calls) % SOLVES == 0, "a step without soft rows: the frames cannot be told apart"
            x[name].append(r.x)
            v[name].append(r.v)
            mse[name].append(r.pos_mse)
            counts[name].append(calls)
    dx = max(float(np.abs(a - b).max()) for a, b in zip(x["warm"], x["cold"], strict=True))
    dv = max(float(np.abs(a - b).max()) for a, b in zip(v["warm"], v["cold"], strict=True))
    mw, mc = np.concatenate(mse["warm"]), np.concatenate(mse["cold"])
    n = sum(len(c) for c in counts["warm"])
    print(f"\n{scene}: {len(d.x)} trajectories of {split}, each alone, eager; {n} solves with soft rows")
    for name, per_traj in counts.items():
        first = collections.Counter(n for calls in per_traj for i, (_, n) in enumerate(calls) if i % SOLVES == 0)
        later = collections.Counter(n for calls in per_traj for i, (_, n) in enumerate(calls) if i % SOLVES)
        print(f"  {name}: passes of the frames' first solves {dict(sorted(first.items()))}, "
              f"of the later ones {dict(sorted(later.items()))}")
        if name == "warm":
            frames = [calls[i:i + SOLVES] for calls in per_traj for i in range(0, len(calls), SOLVES)]
            share = {K: float(np.mean([all(n <= K for _, n in f[1:]) for f in frames])) for K in (1, 2, 3, 4)}
            print("  frames whose later solves all settle within K passes: "
                  + ", ".join(f"K = {K}: {100 * v:.1f} %" for K, v in share.items()))
    print(f"  warm against cold: max |dx| {dx:.2g} m, max |dv| {dv:.2g} m/s; position MSE (m^2) at t = 40 "
          f"{np.nanmean(mw[:, 40]):.4g} / {np.nanmean(mc[:, 40]):.4g}, at t = 110 "
          f"{np.nanmean(mw[:, -1]):.4g} / {np.nanmean(mc[:, -1]):.4g} (warm / cold)", flush=True)

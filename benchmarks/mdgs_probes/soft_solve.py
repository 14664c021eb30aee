"""The soft contact's rows eliminated from the forward dynamics' system against the same rows kept as unknowns.

    python benchmarks/mdgs_probes/soft_solve.py DATA_FOLDER SPLIT [SCENE ...]

DATA_FOLDER holds ``SCENE/SPLIT.h5`` as for ``soft_contact.py`` (default scenes: the three study scenes). The rigid tree
of ``studies/mdgs-soft-8.toml`` (soft contact, eight substeps, velocity Verlet in joint coordinates) rolls out every
trajectory of the split twice: with :func:`mdgs.actuation._unilateral_solve` as it is (each pushing row's force
``(J z - a_ref) / R`` eliminated, Schur's complement, the world's still elements out of the system, and each pass
solved in the tree's degrees of freedom, the rows' bias accelerations from its own factorisation), and with it replaced
by the full system written here, every pushing row's force and every joint's an unknown of its own, the world's
elements' rows kept (``[M Jm^T Ja^T; Jm 0 0; Ja 0 -R]``, the form the package solved before these changes) and the
bias from a solve of its own. Printed per scene: the largest difference of the two sets
of accelerations on the same states (every forward-dynamics call of the first rollout, relative to the call's largest
acceleration), the size of the systems each pass solves, the largest differences of the two
rollouts' positions and velocities (the rollouts' own float32), the position MSE of both at t = 40 and t = 110, and the
seconds each rollout spent stepping (one torch thread, eager).
"""
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
eliminated = actuation._unilateral_solve


def full(M, F, Jm, b0, D, Ju, ru, Ru, held, static, keep=None, start=None, d=None):
    """The same accelerations from the system with every pushing row's force an unknown (the same active-set passes
    from the same start, stopping once the states repeat), and the states of its last pass; records the largest
    system solved. With ``d``, the rows' bias ``Ju z0`` from a solve of its own (``[Jm; D] z0 = [b0; d]``)."""
    B, C0, S6 = Jm.shape[0], Jm.shape[1], M.shape[-1]
    if d is not None:
        ru = ru + (Ju @ torch.linalg.solve(torch.cat([Jm, D], 1), torch.cat([b0, d], -1)).unsqueeze(-1)).squeeze(-1)
    active = held if start is None else held & start
    for _ in range(actuation.SOFT_CONTACT_PASSES):
        n = max(int(active.sum(-1).max()), 1)
        sel = torch.argsort((~active).to(torch.int8), dim=-1, stable=True)[:, :n]
        on = torch.gather(active, 1, sel).to(M.dtype)
        Ja = torch.gather(Ju, 1, sel.unsqueeze(-1).expand(-1, -1, S6)) * on.unsqueeze(-1)
        Jall = torch.cat([Jm, Ja], 1)
        diag = torch.cat([M.new_zeros(B, C0), torch.where(on > 0, -torch.gather(Ru, 1, sel), 1.0)], -1)
        K = torch.cat([torch.cat([M, Jall.transpose(-1, -2)], -1), torch.cat([Jall, torch.diag_embed(diag)], -1)], 1)
        stats["full_n"] = max(stats["full_n"], K.shape[-1])
        z = torch.linalg.solve(K, torch.cat([F, b0, torch.gather(ru, 1, sel) * on], -1))[:, :S6]
        pushes = held & ((Ju @ z.unsqueeze(-1)).squeeze(-1) < ru)
        if bool((pushes == active).all()):
            break
        active = pushes
    return z, pushes


def both(M, F, Jm, b0, D, Ju, ru, Ru, held, static, keep=None, start=None, d=None):
    """The eliminated solve, compared on the spot with the full one."""
    z, pushes = eliminated(M, F, Jm, b0, D, Ju, ru, Ru, held, static, keep, start=start, d=d)
    ref, _ = full(M, F, Jm, b0, D, Ju, ru, Ru, held, static, start=start, d=d)
    scale = float(ref.abs().max())
    stats["rel"] = max(stats["rel"], float((z - ref).abs().max()) / max(scale, 1e-300))
    stats["calls"] += 1
    stats["elim_n"] = D.shape[1]  # each pass's unknowns: the tree's degrees of freedom
    return z, pushes


print(f"# python benchmarks/mdgs_probes/soft_solve.py {' '.join(args)}")
print(f"{'scene':20s}{'calls':>7s}{'max rel dz':>12s}{'n elim':>8s}{'n full':>8s}{'max |dx| m':>12s}{'max |dv| m/s':>14s}"
      f"{'t40 elim':>11s}{'t40 full':>11s}{'t110 elim':>11s}{'t110 full':>11s}{'s elim':>8s}{'s full':>8s}")
for scene in scenes:
    d = load_split(root / scene / f"{split}.h5")
    ct = MODELS["constant-twist"]
    stats = {"rel": 0.0, "calls": 0, "full_n": 0, "elim_n": 0}
    actuation._unilateral_solve = both
    check = rollout(ct.from_data(d, ct.Config(**TREE)), d)  # the accelerations compared on its states
    runs = {}
    for name, fn in (("elim", eliminated), ("full", full)):
        actuation._unilateral_solve = fn
        runs[name] = rollout(ct.from_data(d, ct.Config(**TREE)), d)
    actuation._unilateral_solve = eliminated
    e, f = runs["elim"], runs["full"]
    assert np.array_equal(check.x, e.x), "comparing on the spot changed the rollout"
    print(f"{scene:20s}{stats['calls']:>7d}{stats['rel']:>12.2g}{stats['elim_n']:>8d}{stats['full_n']:>8d}"
          f"{float(np.abs(e.x - f.x).max()):>12.2g}{float(np.abs(e.v - f.v).max()):>14.2g}"
          f"{np.nanmean(e.pos_mse[:, 40]):>11.4g}{np.nanmean(f.pos_mse[:, 40]):>11.4g}"
          f"{np.nanmean(e.pos_mse[:, -1]):>11.4g}{np.nanmean(f.pos_mse[:, -1]):>11.4g}"
          f"{e.step_seconds:>8.1f}{f.step_seconds:>8.1f}", flush=True)
print("calls: forward-dynamics calls with soft rows in the first rollout; max rel dz: largest difference of the two "
      "solves' accelerations over the call's largest; n elim, n full: unknowns of each pass's system, eliminated, and the "
      "largest full system solved (eagerly only the held rows enter either); max |dx|, |dv|: the two rollouts' largest "
      "differences; t40, t110: position MSE (m^2) of each; s: seconds stepping each rollout")

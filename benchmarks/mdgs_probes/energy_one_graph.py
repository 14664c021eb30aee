"""The energy peers' rollouts before and after their steps became one graph, from a study's trained cells.

    python benchmarks/mdgs_probes/energy_one_graph.py STUDY_DIR [--seed 0] [--compile]

``STUDY_DIR`` is a folder of ``mdgs study`` holding trained LGNS and HGNS cells (e.g. ``mdgs study
studies/small.toml --out STUDY_DIR --only lgns --only hgns``, ~35 minutes on one core). For every such cell of
``--seed``, every test trajectory of its scene is rolled out eagerly three ways (:func:`mdgs.evaluate.rollout.rollout`,
one torch thread):

- ``before``: the contact forces on the edge list of the pairs in contact (the path of scenes above
  :data:`mdgs.models.energy.DENSE_CONTACT_MAX_PAIRS`, which every scene took before) and the solves with the host-side
  singular check and the pseudo-inverse (reference copies below of the functions the peers used before);
- ``after``: the peers as they are (contact on masked candidate pairs, the branch-free solve);
- with ``--compile``, ``compiled``: ``after`` with the step compiled by ``torch.compile``
  (:func:`mdgs.models.compile_step` ``"inductor"``).

Printed per cell: the scene's contact candidate pairs (what the masked path evaluates per trajectory and
acceleration) and the pairs in contact per recorded test frame on average (what the edge list held); the largest
position difference over all trajectories and frames of ``after`` against ``before``
(and of ``compiled`` against ``after``), in metres, and the trajectories that diverged each way (a diverged frame
holds the recorded one in :class:`~mdgs.evaluate.rollout.Rollout`, so a different divergence frame shows as a large
difference).
"""
from __future__ import annotations

import argparse
import contextlib
import json
from pathlib import Path

import numpy as np
import torch

import mdgs.models.energy as energy
import mdgs.models.mechanics as mech
from mdgs.data.split import load_split
from mdgs.evaluate.cost import quiet_compiler
from mdgs.evaluate.rollout import rollout
from mdgs.graphs import contact_edges
from mdgs.models import compile_step
from mdgs.runs import load_model


def solve_multipliers_before(Minv_JT, J, rhs, eps: float = 1e-12):
    """:func:`mdgs.models.mechanics.solve_multipliers` as it was: the whole batch takes the pseudo-inverse's solution
    where the factorisation meets a zero pivot (a check on the host)."""
    A = J @ Minv_JT
    if A.shape[-1] == 0:
        return rhs
    ridge = eps * A.diagonal(dim1=-2, dim2=-1).abs().mean(-1).clamp_min(1e-300)
    A = A + ridge[:, None, None] * torch.eye(A.shape[-1], dtype=A.dtype, device=A.device)
    sol, info = torch.linalg.solve_ex(A, rhs.unsqueeze(-1))
    if bool((info != 0).any()):
        sol = torch.linalg.pinv(A) @ rhs.unsqueeze(-1)
    return sol[..., 0]


def solve_mass_before(M, b):
    """The mass-matrix solve as it was: the pseudo-inverse for a singular ``M`` (a check on the host)."""
    sol, info = torch.linalg.solve_ex(M, b)
    bad = info != 0
    if bool(bad.any()):
        sol = torch.where(bad[:, None, None], torch.linalg.pinv(M) @ b, sol)
    return sol


@contextlib.contextmanager
def before():
    """Within this block the peers compute as they did before their steps became one graph."""
    saved = mech.solve_multipliers, mech._solve, energy.DENSE_CONTACT_MAX_PAIRS
    mech.solve_multipliers, mech._solve, energy.DENSE_CONTACT_MAX_PAIRS = solve_multipliers_before, solve_mass_before, 0
    try:
        yield
    finally:
        mech.solve_multipliers, mech._solve, energy.DENSE_CONTACT_MAX_PAIRS = saved


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("study_dir", type=Path)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--compile", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(1)
    runs = sorted(p for p in (args.study_dir / "runs").glob("*") if (p / "checkpoint.pt").exists())
    print(f"{'cell':32s}{'candidates':>11s}{'in contact':>11s}{'max |dx| after-before m':>25s}{'diverged before/after':>23s}"
          + (f"{'max |dx| compiled-after m':>27s}{'diverged compiled':>19s}" if args.compile else ""))
    for run in runs:
        cfg = json.loads((run / "config.json").read_text())
        if cfg["seed"] != args.seed or cfg["model_name"] not in ("lgns", "hgns"):
            continue
        state = torch.load(run / "checkpoint.pt", map_location="cpu", weights_only=False)
        d = load_split(Path(cfg["data"]) / "test.h5")
        with before():
            old = rollout(load_model(state, "cpu"), d)
        model = load_model(state, "cpu")
        new = rollout(model, d)
        b = model.bound(torch.device("cpu"))
        scene, x = b["scene"], torch.from_numpy(d.x.reshape(-1, *d.x.shape[2:])).double()
        touching = contact_edges(x, scene.obj, scene.contact_radius, scene.static).shape[1] / len(x)
        line = (f"{cfg['model_name'] + ' ' + Path(cfg['data']).name:32s}{b['pairs'].shape[1]:11d}{touching:11.0f}"
                f"{float(np.abs(new.x - old.x).max()):25.2e}"
                f"{f'{int((old.diverged_at >= 0).sum())}/{int((new.diverged_at >= 0).sum())} of {len(d.x)}':>23s}")
        if args.compile:
            with quiet_compiler():
                comp = rollout(compile_step(load_model(state, "cpu"), "inductor"), d)
            line += f"{float(np.abs(comp.x - new.x).max()):27.2e}{int((comp.diverged_at >= 0).sum()):>19d}"
        print(line, flush=True)


if __name__ == "__main__":
    main()

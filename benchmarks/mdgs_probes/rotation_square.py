"""Rollouts with the rotation's ``K^2`` as a matrix product (before) and as ``phi phi^T - |phi|^2 I`` (after).

    python benchmarks/mdgs_probes/rotation_square.py STUDY_DIR [--seed 0]

:func:`mdgs.rigid.rotation_matrix` (Rodrigues' formula) squares the skew matrix ``K = [phi]_x``; it did so by a
matrix product, and now writes the square elementwise (equal in exact arithmetic), so that a compiled step has no
library call there. Every body's motion over a frame goes through it (:func:`mdgs.rigid.advance`, the rigid tree's
joints and bodies in :mod:`mdgs.tree` and :mod:`mdgs.joints`).

``STUDY_DIR`` is a folder of ``mdgs study`` holding trained cells (e.g. ``studies/mdgs-soft-8.toml``'s, MDGS on the
rigid tree's prior with soft contact in 8 substeps, whose steps rotate bodies in every substep). For every cell of
``--seed`` and, per scene, the non-learned references (constant twist; + joints; + motors + joints; the rigid tree
with its joints, trapezoidal), every test trajectory of the scene is rolled out eagerly both ways
(:func:`mdgs.evaluate.rollout.rollout`, one torch thread). Printed first: how far the two forms' matrices lie apart
for random rotation vectors (float64 round-off: a rollout stores float32 positions every frame). Then per row: the largest position difference over all
trajectories and frames (m, float32 positions) and the trajectories that diverged each way (a diverged frame holds
the recorded one in :class:`~mdgs.evaluate.rollout.Rollout`, so a different divergence frame shows as a large
difference).
"""
from __future__ import annotations

import argparse
import contextlib
import json
from pathlib import Path

import numpy as np
import torch

import mdgs.joints
import mdgs.rigid
import mdgs.tree
from mdgs.data.split import load_split
from mdgs.evaluate.rollout import rollout
from mdgs.models import MODELS
from mdgs.runs import load_model

REFERENCES = {"constant twist": {}, "constant twist + joints": {"joints": True},
              "constant twist + motors + joints": {"motors": True, "joints": True},
              "rigid tree + joints, trap.": {"dynamics": True, "joints": True, "trapezoidal": True}}


def rotation_matrix_before(phi: torch.Tensor) -> torch.Tensor:
    """:func:`mdgs.rigid.rotation_matrix` as it was: ``K^2`` by a matrix product."""
    K = mdgs.rigid._skew_mat(phi)
    t2 = (phi * phi).sum(-1)
    small = t2 < 1e-8
    ts = torch.where(small, torch.ones_like(t2), t2).sqrt()
    a = torch.where(small, 1 - t2 / 6, torch.sin(ts) / ts)
    b = torch.where(small, 0.5 - t2 / 24, (1 - torch.cos(ts)) / (ts * ts))
    eye = torch.eye(3, dtype=phi.dtype, device=phi.device)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


@contextlib.contextmanager
def before():
    """Within this block every module that rotates bodies uses :func:`rotation_matrix_before`."""
    modules = (mdgs.rigid, mdgs.joints, mdgs.tree)
    saved = [m.rotation_matrix for m in modules]
    for m in modules:
        m.rotation_matrix = rotation_matrix_before
    try:
        yield
    finally:
        for m, f in zip(modules, saved, strict=True):
            m.rotation_matrix = f


def compare(label: str, build, d) -> None:
    """Print ``label``'s row: the rollouts of ``build()`` on the split ``d`` before and after."""
    with before():
        old = rollout(build(), d)
    new = rollout(build(), d)
    print(f"{label:56s}{float(np.abs(new.x - old.x).max()):22.2e}"
          f"{f'{int((old.diverged_at >= 0).sum())}/{int((new.diverged_at >= 0).sum())} of {len(d.x)}':>23s}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("study_dir", type=Path)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    phi = torch.randn(100_000, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    phi = phi * (torch.rand(100_000, 1, dtype=torch.float64, generator=torch.Generator().manual_seed(1)) * 3.2
                 / phi.norm(dim=-1, keepdim=True))  # angles uniform in [0, 3.2) rad
    gap = float((mdgs.rigid.rotation_matrix(phi) - rotation_matrix_before(phi)).abs().max())
    print(f"rotation matrices of 100000 random rotation vectors (angles up to 3.2 rad), float64: "
          f"max |R_after - R_before| = {gap:.2e}")
    runs = sorted(p for p in (args.study_dir / "runs").glob("*") if (p / "checkpoint.pt").exists())
    print(f"{'row':56s}{'max |dx| after-before':>22s}{'diverged before/after':>23s}")
    scenes = {}
    for run in runs:
        cfg = json.loads((run / "config.json").read_text())
        if cfg["seed"] != args.seed:
            continue
        state = torch.load(run / "checkpoint.pt", map_location="cpu", weights_only=False)
        d = scenes.setdefault(Path(cfg["data"]).name, load_split(Path(cfg["data"]) / "test.h5"))
        compare(f"{cfg['model_name']} (trained, seed {args.seed}) {Path(cfg['data']).name}",
                lambda state=state: load_model(state, "cpu"), d)
    ct = MODELS["constant-twist"]
    for name, d in scenes.items():
        for label, kw in REFERENCES.items():
            compare(f"{label} {name}", lambda kw=kw, d=d: ct.from_data(d, ct.Config(**kw)), d)


if __name__ == "__main__":
    main()

"""Past one process: 2-process DDP training and 2-shard generation against one process, side by side.

    python benchmarks/bench_distributed.py [--scene cubli-triple] [--preset small] [--procs 2]

One run, this machine, wall seconds (each process one torch / OpenMP thread):

- training: ``mdgs train`` for ``--epochs`` epochs with one process, then the same global batch
  under ``torchrun --nproc_per_node N`` (gloo on CPU, nccl on GPU), and the parameter difference;
- generation: ``mdgs generate`` of the preset with one process, then N shards started at once
  into one folder (the shard that finishes last merges), and whether the files are identical.

Start-up (interpreter, imports, process group) is included: it is what a user waits for.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

ENV = {**os.environ, "OMP_NUM_THREADS": "1"}
CLI = [sys.executable, "-m", "mdgs.cli"]


def _timed(cmds: list[list[str]]) -> float:
    t0 = time.perf_counter()
    procs = [subprocess.Popen(c, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE) for c in cmds]
    for p in procs:
        _, err = p.communicate()
        if p.returncode:
            raise SystemExit(f"failed: {err.decode()[-800:]}")
    return time.perf_counter() - t0


def _arrays_sha(path: Path) -> str:
    import h5py
    import numpy as np

    h = hashlib.sha256()
    with h5py.File(path, "r") as f:
        for name in sorted(f["frames"]):
            h.update(np.ascontiguousarray(f["frames"][name][()]).tobytes())
    return h.hexdigest()[:16]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="cubli-triple")
    ap.add_argument("--preset", default="small")
    ap.add_argument("--procs", type=int, default=2)
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--batch-size", type=int, default=32)
    args = ap.parse_args()
    n = args.procs
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        g1 = _timed([CLI + ["generate", args.scene, "--out", str(tmp / "g1"), "--preset", args.preset]])
        gN = _timed([CLI + ["generate", args.scene, "--out", str(tmp / "gN"), "--preset", args.preset,
                            "--shard", f"{i}/{n}"] for i in range(n)])
        same = all(_arrays_sha(tmp / "g1" / f"{s}.h5") == _arrays_sha(tmp / "gN" / f"{s}.h5")
                   for s in ("train", "valid", "test"))
        common = ["train", "--data", str(tmp / "g1"), "--epochs", str(args.epochs), "--batch-size",
                  str(args.batch_size), "--device", "cpu", "--valid-max-pairs", "256"]
        t1 = _timed([CLI + common + ["--out", str(tmp / "r1")]])
        tN = _timed([[sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", str(n),
                      "-m", "mdgs.cli"] + common + ["--out", str(tmp / "rN")]])
        a = torch.load(tmp / "r1" / "checkpoint.pt", weights_only=False)["model"]
        b = torch.load(tmp / "rN" / "checkpoint.pt", weights_only=False)["model"]
        rel = {k: float((a[k] - b[k]).abs().max() / (a[k].abs().max() + 1e-12)) for k in a if a[k].is_floating_point()}
        worst = max(rel, key=rel.get)
        diff, med = rel[worst], sorted(rel.values())[len(rel) // 2]
    print(f"{args.scene}, preset {args.preset}, {os.cpu_count()} cores, {n} processes")
    print(f"generation: 1 process {g1:.1f} s, {n} shards {gN:.1f} s -> speed-up {g1 / gN:.2f}x; "
          f"arrays identical: {same}")
    print(f"training ({args.epochs} epochs, global batch {args.batch_size}): 1 process {t1:.1f} s, "
          f"{n} processes {tN:.1f} s -> speed-up {t1 / tN:.2f}x; relative parameter difference (max over a tensor / "
          f"its largest entry): median over tensors {med:.1e}, largest {diff:.1e} ({worst})")


if __name__ == "__main__":
    main()

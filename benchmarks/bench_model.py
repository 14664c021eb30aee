"""MDGS step time against MuJoCo and against the machine's dense matmul FLOP rate.

    python benchmarks/bench_model.py [--scene cubli-triple] [--batch 256] [--repeats 20]

Printed side by side, one run, medians over repeats:

- MDGS inference step (no grad) for 1 scene and for a batch of ``--batch`` scenes;
- the same scene's MuJoCo time per frame (``substeps`` integrator steps, instrumented
  model not used: the scene's own MJCF), so "learned step / physics frame" is a ratio;
- FLOPs of one batched step counted by ``torch.utils.flop_counter.FlopCounterMode``
  (matmuls, addmm, bmm, sparse excluded: see note) and the achieved FLOP rate against a
  dense float32 matmul of the same hidden width measured in the same run.

Targets (issue 5): batched inference >= 30 % of the matmul rate.
"""

from __future__ import annotations

import argparse
import statistics
import time

import mujoco
import numpy as np
import torch
from torch.utils.flop_counter import FlopCounterMode

from mdgs.data.engine import load_scene, simulate, static_arrays
from mdgs.graphs import SceneGraph
from mdgs.models.mdgs import MDGS, ModelConfig
from mdgs.scenes import SCENES


def _median_time(fn, repeats: int, warmup: int = 3) -> float:
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def matmul_rate(n: int, k: int, repeats: int) -> float:
    """FLOP/s of a dense float32 [n, k] @ [k, k] matmul (the shape of a GCN layer's linear map)."""
    a, b = torch.randn(n, k), torch.randn(k, k)
    t = _median_time(lambda: a @ b, repeats)
    return 2.0 * n * k * k / t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="cubli-triple")
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--no-structure", action="store_true", help="switch the structural module off")
    ap.add_argument("--integrator", default="rigid", choices=["rigid", "twist", "euler", "direct"])
    args = ap.parse_args()
    torch.set_num_threads(torch.get_num_threads())

    spec = SCENES[args.scene]
    loaded = load_scene(spec)
    static = static_arrays(loaded)
    scene = SceneGraph.from_static(static, spec.has_contact)
    N = scene.num_nodes
    frame_dt = float(loaded.inst.model.opt.timestep) * int(spec.substeps)
    model = MDGS(
        ModelConfig(structure=not args.no_structure, integrator=args.integrator, dt=frame_dt,
                    contact=spec.has_contact),
    ).eval()

    # a real state: frame 1 of a test trajectory of the scene
    fr = simulate(loaded, "test", [0], seed=0, n_frames=2)
    x0 = torch.as_tensor(np.asarray(fr["node_pos"][0, 1]), dtype=torch.float32)
    v0 = torch.as_tensor(np.asarray(fr["node_vel"][0, 1]), dtype=torch.float32)

    def step(B):
        x, v = x0.expand(B, N, 3).contiguous(), v0.expand(B, N, 3).contiguous()

        def f():
            with torch.no_grad():
                model(scene, x, v)

        return f

    t1 = _median_time(step(1), args.repeats)
    tB = _median_time(step(args.batch), max(3, args.repeats // 4))
    with FlopCounterMode(display=False) as fc, torch.no_grad():
        step(args.batch)()
    flops = fc.get_total_flops()
    rate = matmul_rate(args.batch * N, model.config.hidden, args.repeats)

    # MuJoCo: one frame of the scene's own model (substeps integrator steps)
    m = mujoco.MjModel.from_xml_string(loaded.mjcf)
    d = mujoco.MjData(m)
    substeps = int(spec.substeps)
    mujoco.mj_forward(m, d)

    def frame():
        for _ in range(substeps):
            mujoco.mj_step(m, d)

    tm = _median_time(frame, args.repeats * 5)

    print(
        f"scene {args.scene}: {N} nodes, contact branch {'on' if spec.has_contact else 'off'}, "
        f"structure module {'off' if args.no_structure else 'on'}, integrator {args.integrator}, "
        f"torch threads {torch.get_num_threads()}"
    )
    print(f"{'':32s}{'median':>12s}{'per scene':>14s}")
    print(
        f"{'MuJoCo frame (' + str(substeps) + ' steps)':32s}{tm * 1e3:10.3f} ms{tm * 1e3:12.3f} ms"
    )
    print(
        f"{'MDGS step, 1 scene':32s}{t1 * 1e3:10.3f} ms{t1 * 1e3:12.3f} ms   ({t1 / tm:.0f}x MuJoCo)"
    )
    print(
        f"{'MDGS step, batch ' + str(args.batch):32s}{tB * 1e3:10.3f} ms{tB / args.batch * 1e3:12.3f} ms   "
        f"({tB / args.batch / tm:.1f}x MuJoCo)"
    )
    print(
        f"dense matmul [{args.batch * N}x{model.config.hidden}]@[{model.config.hidden}x{model.config.hidden}]: "
        f"{rate / 1e9:.1f} GFLOP/s"
    )
    print(
        f"MDGS batched step: {flops / 1e9:.3f} GFLOP counted -> {flops / tB / 1e9:.1f} GFLOP/s = "
        f"{100 * flops / tB / rate:.0f} % of the matmul rate (target >= 30 %)"
    )
    by_op = {str(k): v for k, v in fc.get_flop_counts().get("Global", {}).items()}
    dense_prop = sum(v for k, v in by_op.items() if "bmm" in k)
    print("  by op: " + ", ".join(f"{k} {v / 1e9:.3f} GFLOP" for k, v in by_op.items()))
    print(
        f"  without the dense graph propagation (bmm, counts zeros of the adjacency): "
        f"{(flops - dense_prop) / tB / 1e9:.1f} GFLOP/s = {100 * (flops - dense_prop) / tB / rate:.0f} % of the matmul rate"
    )


if __name__ == "__main__":
    main()

"""Where a single-trajectory rollout step of every model spends its time: arithmetic or overhead.

    python benchmarks/profile_step.py [--scene cubli-triple] [--models mdgs gns ...] [--frames 10] [--repeats 5]
                                      [--compile [inductor|aot|cudagraphs]] [--widths 100 50] [--device cuda]
                                      [--study studies/mdgs-soft-8.toml ...]

One run, this machine, CPU, one torch thread, batch 1 (one trajectory), untrained weights (the cost
of a step does not depend on training), on a ``tiny`` dataset of the scene written to a temporary
folder (:func:`bench_models.tiny_splits`). Printed per model, medians over ``--repeats``:

- ``ms/step``: wall milliseconds per step without the profiler (:func:`mdgs.evaluate.cost.step_cost`,
  the quantity of the study's speed-accuracy chart; ``cost_step`` where a model has one); with ``--compile``, of
  the step compiled without inductor's per-kernel profiling (below), which costs a compiled step of thousands of
  small loops several times its own time;
- under ``torch.profiler`` (a rollout of ``--frames`` steps after two warm-up steps):
  ``prof ms``: wall ms per step with the profiler on (it adds its own cost to every op);
  ``op ms``: the summed self CPU time of all torch ops per step; ``arith %``: the share of that
  time spent in arithmetic ops (below); ``overhead ms``: wall minus summed self CPU time, the time
  outside any torch op: Python, module calls, argument parsing before dispatch (and, for the
  MuJoCo reference, MuJoCo itself, which is not a torch op); ``outside %``: the share of ``ms/step`` not
  spent in arithmetic ops, ``1 - arith ms / ms/step`` (``arith ms`` the arithmetic ops' summed self time under
  the profiler, which the profiler's own entries around each op do not enter; 0 where that exceeds
  ``ms/step``), the quantity of the aim that no model spends more than half its step outside arithmetic ("-"
  for MuJoCo, whose step is C code the profiler does not see into);
- the 8 ops with the most self CPU time per step, ``*`` marking arithmetic ones (``aten::`` left
  out of the names; ``prims::`` ops come from decompositions, e.g. under ``torch.func``).

Arithmetic ops compute new values from their inputs' values (``ARITHMETIC``, regexes on the
``aten::`` op name): matrix products (mm, addmm, bmm, matmul, linear, einsum, conv, baddbmm,
sparse mm), linear algebra (SVD, solve, det, LU, cross, cdist), elementwise math (add, sub, mul,
div, neg, pow, sqrt, rsqrt, exp, log, trigonometric, relu, clamp, abs, sign, comparisons,
logical ops, where) and reductions (sum, mean, prod, norm, amax/amin, any/all, cumsum, and the
scatter-sums index_add/scatter_add/scatter_reduce/segment_reduce). Everything else is not
arithmetic: tensor creation (empty, zeros, ones, full, eye, arange, tensor/as_tensor, to/copy),
views and shape changes (view, reshape, expand, unsqueeze, transpose, select, slice, as_strided,
contiguous, clone), indexing and data movement (index, index_put, index_select, gather, scatter,
cat, stack, nonzero, unique, masked_select), error checks (``_linalg_check_errors``), ``item``.

``--study TOML ...`` profiles the ``[[models]]`` rows of those study files, with their settings
(:func:`bench_models.study_rows`), after the registry's models (none unless ``--models`` names some).

``--device cuda`` profiles each torch model's step on the GPU instead: kernels run per step, the
GPU time of those kernels and its share of the wall time (a small share: the step is launch-bound),
the host's CUDA calls per step that launch one kernel, replay a CUDA graph or wait for the device
(``RUNTIME``) and the host entries with the most self time. With ``--compile`` there (``cudagraphs``:
inductor's kernels replayed as CUDA graphs), dynamo's graph breaks and inductor's reasons for not
replaying a graph are logged as they happen and the breaks counted at the end.

``--compile`` profiles the ``torch.compile``d step (:func:`mdgs.models.compile_step`, compiled with
inductor's per-kernel profiling on); ``--compile aot`` the step compiled ahead of time (AOTInductor, the
same per-kernel profiling, no dynamo guards at call time). A step that does not compile so runs in the next mode
that works, as on the study's cost axis (:func:`mdgs.evaluate.cost.compiled_cost`: aot, then inductor, then eager;
a step that compiles again at every step counts as not compiling), its row labelled with that mode and preceded by
a line saying why. Each fused C++ kernel of the compiled graph
(``graph_<k>_cpp_fused_<ops>``) counts as arithmetic, as do the library calls it makes
(``aoti_torch_cpu_<op>_out``, classified by ``<op>``); the compiled graph's own entry
(``## Call CompiledFxGraph``: its C++ launcher and buffer allocations), dynamo's guard check
(``TorchDynamo Cache Lookup``) and the compiled region's wrappers are overhead.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import statistics
import sys
import time
from collections import defaultdict
from itertools import chain

import numpy as np
import torch
from bench_models import registry_models, study_rows, tiny_splits
from torch.profiler import ProfilerActivity, profile

from mdgs.evaluate.cost import compiled_cost, step_cost
from mdgs.models import MODELS

#: Regexes on the op name (without ``aten::``) of the ops that count as arithmetic (module docstring).
ARITHMETIC = [
    # matrix products
    r"^_?(mm|addmm|bmm|baddbmm|matmul|linear|einsum|addmv|mv|dot|tensordot)$", r"^_?sparse\w*mm",
    r"^_?(convolution|conv[123]d|conv_transpose\w*|mkldnn_convolution|_convolution)$",
    # linear algebra (not its error checks)
    r"^_?linalg_(?!check_errors)", r"^_?(svd|det|lu_factor\w*|lu_solve|cross|cdist|_cdist_forward|euclidean_dist)$",
    # elementwise math, comparisons, logical ops, where
    r"^(add|sub|rsub|mul|div|neg|reciprocal|pow|sqrt|rsqrt|exp|log|log1p|expm1|sin|cos|tan|atan2|atan|asin|acos"
    r"|sinh|cosh|tanh|sigmoid|relu|threshold|clamp|clamp_min|clamp_max|abs|sign|sgn|maximum|minimum|fmod|remainder"
    r"|floor|ceil|round|trunc|square|addcmul|addcdiv|lerp|where|lt|le|gt|ge|eq|ne|logical_\w+|bitwise_\w+"
    r"|isfinite|isnan|isinf|floor_divide|softplus|silu|gelu|elu)_?$",
    # reductions, scatter-sums included
    r"^(sum|mean|prod|norm|amax|amin|max|min|any|all|cumsum|cumprod|var|std|logsumexp|softmax|_softmax|log_softmax"
    r"|_log_softmax|bincount|index_add|scatter_add|scatter_reduce|segment_reduce|_segment_reduce)_?$",
]
_ARITH = [re.compile(p) for p in ARITHMETIC]


_FUSED = re.compile(r"^graph_\d+_cpp_fused_")  # a compiled graph's fused kernel (--compile)
_AOTI = re.compile(r"^aoti_torch_cpu_(\w+?)_out$")  # a library call from a compiled graph's C++ launcher


def is_arithmetic(op: str) -> bool:
    """Whether the profiler op ``op`` (e.g. ``aten::addmm``) is arithmetic (``ARITHMETIC``; module docstring
    for the entries of a compiled step)."""
    if _FUSED.search(op):
        return True
    name = op.split("::", 1)[-1]
    m = _AOTI.match(name)
    name = m.group(1) if m else name
    return any(p.search(name) for p in _ARITH)


@contextlib.contextmanager
def _quiet_stderr():
    """Silence file descriptor 2 (the profiler's native start/stop log lines) for the block."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _cuda_profiled_rollout(step, state, ctrl) -> tuple[float, float, int, dict[str, int], list]:
    """Wall seconds of ``len(ctrl)`` steps on a CUDA device under the profiler (synchronised at the
    end), the seconds its kernels kept the GPU busy, how many kernels ran, the host-side CUDA runtime
    calls counted by kind (``RUNTIME``: kernel launches, graph launches, synchronising copies and waits)
    and the 5 host entries with the most self CPU time (``(name, seconds)``)."""
    with _quiet_stderr(), profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
        torch.cuda.synchronize()
        t0 = time.perf_counter()
        s = state
        for c in ctrl:
            s = step(s, c)
        torch.cuda.synchronize()
        wall = time.perf_counter() - t0
    busy, kernels = 0.0, 0
    calls: dict[str, int] = defaultdict(int)
    host: dict[str, float] = defaultdict(float)
    for e in prof.events():
        if e.device_type == torch.autograd.DeviceType.CUDA:  # a kernel or copy that ran on the GPU
            busy += e.device_time * 1e-6
            kernels += 1
            continue
        for kind, names in RUNTIME.items():
            if e.name in names:
                calls[kind] += 1
        host[e.name] += e.self_cpu_time_total * 1e-6
    top = sorted(host.items(), key=lambda kv: -kv[1])[:5]
    return wall, busy, kernels, dict(calls), top


#: Host-side CUDA runtime/driver calls counted per step on a GPU: ``launch`` one kernel each, ``graph`` one
#: replay of a captured CUDA graph (all its kernels), ``sync`` a call that waits for the device (a
#: device-to-host copy or an explicit synchronisation; the rollout's final one is counted too).
RUNTIME = {"launch": {"cudaLaunchKernel", "cuLaunchKernel", "cuLaunchKernelEx", "cudaLaunchKernelExC"},
           "graph": {"cudaGraphLaunch"},
           "sync": {"cudaMemcpy", "cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaEventSynchronize"}}


@torch.no_grad()
def profile_model_cuda(model, te, frames: int, repeats: int) -> dict:
    """Per-step medians of one model on one trajectory of ``te`` on a CUDA device: ms (unprofiled),
    kernels launched, GPU-busy ms (the kernels' own time) and its share of the profiled wall time
    (small: the step waits on launches, not arithmetic)."""
    ms = step_cost(model, te, batch=1, frames=frames, repeats=repeats)["ms_per_frame"]
    h = model.history
    frames = max(1, min(frames, te.x.shape[1] - h - 1))
    ctrl = [torch.from_numpy(te.ctrl[[0], h + t]).to(model.device) for t in range(frames)]
    step = getattr(model, "cost_step", model.step)
    walls, busy, kernels, calls, tops = [], [], [], [], []
    for _ in range(repeats):
        state = model.initial_state(te, np.array([0]), h)
        for c in ctrl[:2]:
            step(state, c)
        w, b, k, n, top = _cuda_profiled_rollout(step, state, ctrl)
        walls.append(w)
        busy.append(b)
        kernels.append(k)
        calls.append(n)
        tops.append(top)
    return {"ms": ms, "prof_ms": 1e3 * statistics.median(walls) / frames,
            "kernels": statistics.median(kernels) / frames, "busy_ms": 1e3 * statistics.median(busy) / frames,
            "busy": statistics.median(b / w for b, w in zip(busy, walls, strict=True)),
            **{kind: statistics.median(n.get(kind, 0) for n in calls) / frames for kind in RUNTIME},
            "top": [(name, 1e3 * t / frames) for name, t in tops[-1]]}


def _profiled_rollout(step, state, ctrl) -> tuple[float, dict[str, float]]:
    """Wall seconds of ``len(ctrl)`` steps under the profiler and the self CPU seconds of each op."""
    with _quiet_stderr(), profile(activities=[ProfilerActivity.CPU]) as prof:
        t0 = time.perf_counter()
        s = state
        for c in ctrl:
            s = step(s, c)
        wall = time.perf_counter() - t0
    self_s: dict[str, float] = defaultdict(float)
    for e in prof.key_averages():  # an op can come in several entries (e.g. forward and backward)
        self_s[e.key] += e.self_cpu_time_total * 1e-6
    return wall, self_s


@torch.no_grad()
def profile_model(model, te, frames: int, repeats: int) -> dict:
    """Per-step medians (ms) of one model on one trajectory of ``te`` (module docstring)."""
    ms = step_cost(model, te, batch=1, frames=frames, repeats=repeats)["ms_per_frame"]
    h = model.history
    frames = max(1, min(frames, te.x.shape[1] - h - 1))
    ctrl = [torch.from_numpy(te.ctrl[[0], h + t]) for t in range(frames)]
    step = getattr(model, "cost_step", model.step)
    walls, ops, arith, per_op = [], [], [], defaultdict(float)
    for _ in range(repeats):
        state = model.initial_state(te, np.array([0]), h)
        for c in ctrl[:2]:  # warm-up (first-call allocations, caches)
            step(state, c)
        wall, self_s = _profiled_rollout(step, state, ctrl)
        total = sum(self_s.values())
        walls.append(wall)
        ops.append(total)
        arith.append(sum(t for k, t in self_s.items() if is_arithmetic(k)) / max(total, 1e-12))
        for k, t in self_s.items():
            per_op[k] += t / repeats
    per_step = lambda s: 1e3 * s / frames  # noqa: E731
    return {"ms": ms, "prof_ms": per_step(statistics.median(walls)), "op_ms": per_step(statistics.median(ops)),
            "arith": statistics.median(arith),
            "overhead_ms": per_step(statistics.median(w - o for w, o in zip(walls, ops, strict=True))),
            "top": sorted(((k, per_step(t)) for k, t in per_op.items()), key=lambda kt: -kt[1])[:8]}


def _names(args) -> list[str]:
    """The registry models to profile: ``--models``, else all of them unless ``--study`` names rows instead."""
    return args.models if args.models is not None else ([] if args.study else list(MODELS))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="cubli-triple")
    ap.add_argument("--models", nargs="*", default=None, help="registry names (default: all)")
    ap.add_argument("--frames", type=int, default=10, help="steps per profiled rollout")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--compile", nargs="?", const="inductor", default=None, choices=("inductor", "aot", "cudagraphs"),
                    help="profile the compiled step: inductor (torch.compile, the default), aot or cudagraphs "
                         "(CUDA only; module docstring)")
    ap.add_argument("--widths", nargs="*", type=int, default=[], help="MDGS also at these hidden widths")
    ap.add_argument("--study", nargs="*", default=[], metavar="TOML",
                    help="also the [[models]] rows of these study files, with their settings (e.g. studies/mdgs-soft-8.toml)")
    ap.add_argument("--device", default="cpu", help="cpu, or cuda: kernels per step and GPU-busy share instead "
                                                  "of the op table (MuJoCo is left out there)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    if args.device != "cpu":
        if not torch.cuda.is_available():
            ap.error(f"--device {args.device}: no CUDA device is present (torch.cuda.is_available() is false)")
        return _main_cuda(args)
    if args.compile:
        import torch._inductor.config as inductor_config

        from mdgs.models import compile_step

        inductor_config.fx_graph_cache = False  # a cached graph compiled without those entries would hide them
    tr, te = tiny_splits(args.scene)
    print(f"scene {args.scene}: {tr.x.shape[2]} nodes, batch 1, CPU, 1 torch thread; per step, medians of "
          f"{args.repeats} rollouts of {args.frames} steps" + (f"; compiled steps ({args.compile})" if args.compile else ""))
    print(f"{'model':22s}{'ms/step':>9s}{'prof ms':>9s}{'op ms':>8s}{'arith %':>9s}{'overhead ms':>13s}"
          f"{'outside %':>11s}")
    for label, model in chain(registry_models(_names(args), tr, tuple(args.widths)), study_rows(args.study, tr)):
        if isinstance(model, str):
            print(f"{label:22s} refused: {model}")
            continue
        if args.compile and model.compilable:
            model.bind(te)
            # the step's own cost first, compiled without per-kernel profiling, in the first mode that works for it
            # (aot -> inductor -> none, as the study's cost axis: compiled_cost), then profiled compiled so again
            inductor_config.cpp.enable_kernel_profile = False
            torch._dynamo.reset()  # a graph compiled for another model (or with profiling) is not reused
            cost = compiled_cost(model, te, args.compile, batched=1)
            ms, ran = cost["single"]["ms_per_frame"], cost["compiled"]
            if ran != args.compile:
                print(f"{label:22s} runs as {ran!r}: {cost['note'][:150]}")
            model.step = type(model).step.__get__(model)
            if ran != "none":
                inductor_config.cpp.enable_kernel_profile = True  # each fused kernel a profiler entry
                torch._dynamo.reset()
                compile_step(model, ran)
            r = {**profile_model(model, te, args.frames, args.repeats), "ms": ms}
            label = label if ran == args.compile else f"{label} ({ran})"
        else:
            r = profile_model(model, te, args.frames, args.repeats)
        outside = f"{100 * max(0.0, 1 - r['arith'] * r['op_ms'] / r['ms']):.0f}" if model.compilable else "-"
        print(f"{label:22s}{r['ms']:>9.3f}{r['prof_ms']:>9.3f}{r['op_ms']:>8.3f}{100 * r['arith']:>9.0f}"
              f"{r['overhead_ms']:>13.3f}{outside:>11s}")
        print("    top ops (ms/step): " + ", ".join(f"{'*' if is_arithmetic(k) else ''}{k.removeprefix('aten::')} {t:.3f}"
                                                     for k, t in r["top"]), flush=True)
    print("ms/step: unprofiled" + (" (compiled without per-kernel profiling)" if args.compile else "")
          + "; prof ms: wall with the profiler on; op ms: summed self CPU time of torch ops; "
          "arith %: its arithmetic share; overhead ms: Python/dispatch overhead (wall outside any torch op); "
          "outside %: share of ms/step outside arithmetic ops; * arithmetic op")


def _main_cuda(args) -> None:
    """``--device cuda``: where a single-trajectory step's time goes on a GPU."""
    from mdgs.models import compile_step

    dev = torch.device(args.device)
    tr, te = tiny_splits(args.scene)
    names = [n for n in _names(args) if n != "mujoco"]
    print(f"scene {args.scene}: {tr.x.shape[2]} nodes, batch 1, {torch.cuda.get_device_name(dev)}; per step, medians "
          f"of {args.repeats} rollouts of {args.frames} steps" + (f"; compiled steps ({args.compile})" if args.compile else ""))
    if args.compile:  # dynamo's graph breaks and inductor's reasons for not replaying a CUDA graph, as they happen
        torch._logging.set_logs(graph_breaks=True, perf_hints=True)
    print(f"{'model':22s}{'ms/step':>9s}{'prof ms':>9s}{'kernels':>9s}{'GPU ms':>9s}{'GPU busy %':>12s}"
          f"{'launches':>10s}{'graphs':>8s}{'syncs':>7s}")
    for label, model in chain(registry_models(names, tr, tuple(args.widths), dev), study_rows(args.study, tr, dev)):
        if isinstance(model, str):
            print(f"{label:22s} refused: {model}")
            continue
        try:
            if args.compile:
                model.bind(te)
                compile_step(model, args.compile)
            r = profile_model_cuda(model, te, args.frames, args.repeats)
        except Exception as e:  # noqa: BLE001 - one model that fails here is a row saying so; the table goes on
            print(f"{label:22s} failed: {type(e).__name__}: {str(e).splitlines()[0][:100] if str(e) else ''}")
            continue
        print(f"{label:22s}{r['ms']:>9.3f}{r['prof_ms']:>9.3f}{r['kernels']:>9.0f}{r['busy_ms']:>9.3f}"
              f"{100 * r['busy']:>12.0f}{r['launch']:>10.1f}{r['graph']:>8.1f}{r['sync']:>7.1f}", flush=True)
        print("    top host entries (self ms/step): " + ", ".join(f"{k} {t:.3f}" for k, t in r["top"]), flush=True)
    if args.compile:
        from torch._dynamo.utils import counters

        print(f"dynamo: {sum(counters['graph_break'].values())} graph breaks, "
              f"{counters['stats'].get('unique_graphs', 0)} graphs compiled; "
              + "; ".join(f"{k.splitlines()[0][:90]} x{n}" for k, n in counters["graph_break"].items()))
    print("ms/step: unprofiled; prof ms: wall with the profiler on; kernels: GPU kernels and copies run per "
          "step; GPU ms: their own time per step; GPU busy %: GPU ms over prof ms (the rest is launching and "
          "Python); launches, graphs, syncs: host calls per step that launch one kernel, replay a CUDA graph, "
          "wait for the device (RUNTIME)")


if __name__ == "__main__":
    main()

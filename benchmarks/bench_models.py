"""Every model of the registry side by side on one scene: size, training step, rollout step, FLOP rate.

    python benchmarks/bench_models.py [--scene cubli-triple] [--models mdgs gns ...] [--batches 1 16 256]
                                      [--widths 100 50] [--compile [inductor] [aot]] [--device cuda]

One run, this machine, medians over repeats; printed per model:

- parameters;
- ms per training step (perturb + losses + backward + optimiser step) at ``--train-batch``;
- ms per simulated frame of one trajectory, and per trajectory-frame at each batch size
  (:func:`mdgs.evaluate.cost.step_cost`, the same code the study's speed-accuracy chart uses);
- for the learned models, the achieved FLOP rate of the step at each batch size (FLOPs counted by
  ``torch.utils.flop_counter.FlopCounterMode``) as a fraction of a dense float32 matmul measured
  in the same run, and the floor those FLOPs set at the largest batch: the ms per trajectory-frame of a
  step that ran all its FLOPs at that dense rate (a batched target below it cannot be met on this thread);
- MuJoCo (the ``mujoco`` reference) at the data's timestep and at one step per frame, on the
  same scale.

With ``--compile`` every torch model is measured a second time with its step compiled
(:func:`mdgs.models.compile_step`; ``--compile aot`` ahead of time with AOTInductor, ``--compile
inductor aot`` both, ``cudagraphs`` replayed as CUDA graphs on a GPU), printed as ``NAME compiled`` (``NAME aot``) with the seconds its first steps
spent compiling, and its rollout of the test trajectories is compared with the eager one (largest
position difference). Ahead of time a model may fold products of weights into constants
(:func:`mdgs.models.layers.folded_weights`: MDGS skips one ``[hidden, hidden]`` product a step), so
the FLOP rate of an ``aot`` row counts that folded step's FLOPs, and its floor is printed beside it. A model whose
step does not compile ahead of time gets a ``NAME compiled`` row after its refusal, as the study's cost axis falls
back (:func:`mdgs.evaluate.cost.compiled_cost`), and a ``torch.compile``d step that compiles again while it is timed
(its shapes follow the state: contact or radius edges that change in number) is refused, not timed with its
compiling.

The data is a ``tiny`` dataset of the scene written to a temporary folder. Untrained weights:
the cost of a step does not depend on training.

``--device cuda`` runs every torch model on the GPU (MuJoCo stays on the CPU, where it runs);
the dense-matmul rate is then measured on the GPU with a taller matrix (2^20 rows: the 8192-row
product is launch-bound there), in float32 without TF32, the precision the models run in.
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import tempfile
import time
import traceback
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch
from torch.utils.flop_counter import FlopCounterMode

from mdgs.data.generate import GenerateConfig, generate
from mdgs.data.split import SplitData, load_split
from mdgs.evaluate.cost import _refuse_recompiles, quiet_compiler, step_cost
from mdgs.evaluate.rollout import rollout
from mdgs.models import MODELS, Simulator, batch_of, compile_step
from mdgs.models.base import COMPILE_MODES
from mdgs.models.layers import folded_weights


def median_time(fn, repeats: int, warmup: int = 2) -> float:
    """Median wall time (s) of ``fn()`` over ``repeats`` calls after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def tiny_splits(scene: str) -> tuple[SplitData, SplitData]:
    """The train and test splits of a ``tiny`` dataset of ``scene``, generated into a temporary folder."""
    with tempfile.TemporaryDirectory() as tmp:
        generate(GenerateConfig(scene=scene, out=tmp, preset="tiny"))
        return load_split(Path(tmp) / "train.h5"), load_split(Path(tmp) / "test.h5")


def registry_models(names: list[str], tr: SplitData, widths: tuple[int, ...] = (),
                    device: torch.device | None = None) -> Iterator[tuple[str, Simulator | str]]:
    """``(label, model)`` for each registry name, built from ``tr`` with default settings (untrained);
    MuJoCo twice: at the data's timestep and at one step per frame; MDGS also at each of ``widths``
    (GCN hidden and global width). Torch models are moved to ``device`` (MuJoCo stays on the CPU).
    A model that refuses the scene gives its message (a str) in place of the model, so a table can
    say so and go on."""
    for name in names:
        cls = MODELS[name]
        cfgs = [("", {})] if name != "mujoco" else [(" dt x1", {"dt_factor": 1}),
                                                    (f" dt x{int(tr.attrs['substeps'])}",
                                                     {"dt_factor": int(tr.attrs["substeps"])})]
        if name == "mdgs":
            cfgs += [(f" hidden {w}", {"hidden": w, "global_dim": w}) for w in widths]
        for suffix, kw in cfgs:
            try:
                model = cls.from_data(tr, cls.Config(**kw))
                yield name + suffix, model.to(device) if device is not None and model.compilable else model
            except Exception as e:  # noqa: BLE001 - a model that refuses the scene says so and the table goes on
                yield name + suffix, str(e)


def study_rows(paths: list[str], tr: SplitData, device: torch.device | None = None) -> Iterator[tuple[str, Simulator | str]]:
    """``(label, model)`` for each ``[[models]]`` row of the study files ``paths`` (read and checked by
    :func:`mdgs.study.load_study`: its registry name and settings), built from ``tr`` (untrained), labelled
    ``NAME STUDY#K`` (K counting that study's rows from 1). A row that refuses the scene gives its message, as in
    :func:`registry_models`."""
    from mdgs.study import load_study

    for path in paths:
        study = load_study(path)
        for k, row in enumerate(study.models, 1):
            label = f"{row.name} {study.name}#{k}"
            try:
                cls = MODELS[row.name]
                model = cls.from_data(tr, cls.Config(**row.settings_dict))
                yield label, model.to(device) if device is not None and model.compilable else model
            except Exception as e:  # noqa: BLE001 - a row that refuses the scene says so and the table goes on
                yield label, str(e)


def _col(batch: int) -> int:
    """Width of the ``ms/tf b<batch>`` column: at least two spaces before its label (the docs' table
    reader splits the header on two or more spaces)."""
    return max(12, len(f"ms/tf b{batch}") + 2)


def _matmul_rate(device: torch.device, repeats: int = 20) -> tuple[float, int]:
    """FLOP/s of a dense float32 ``[rows x 200] @ [200 x 200]`` on ``device`` and its rows (8192 on a
    CPU; 2^20 on a GPU, where the smaller product is launch-bound)."""
    rows = 8192 if device.type == "cpu" else 1 << 20
    a, b = torch.randn(rows, 200, device=device), torch.randn(200, 200, device=device)

    def mm():
        a @ b
        if device.type == "cuda":
            torch.cuda.synchronize()
    return 2.0 * rows * 200 * 200 / median_time(mm, repeats), rows


def step_flops(model: Simulator, te: SplitData, batch: int, folded: bool = False) -> int:
    """FLOPs (``FlopCounterMode``) of one eager step of ``model`` on ``batch`` trajectories of ``te``; with
    ``folded``, of the step an ahead-of-time compiled model runs (inside :func:`folded_weights`, its
    weight products computed once before counting, as AOTInductor folds them when the package loads)."""
    model.bind(te)
    st = model.initial_state(te, np.arange(batch) % te.x.shape[0], model.history)
    ctrl = torch.from_numpy(te.ctrl[np.arange(batch) % te.x.shape[0], model.history]).to(model.device)
    with torch.no_grad(), folded_weights() if folded else contextlib.nullcontext():
        if folded:
            model.step(st, ctrl)  # computes (and caches) the weight products outside the count
        with FlopCounterMode(display=False) as fc:
            model.step(st, ctrl)
    return fc.get_total_flops()


def _compiled_line(label: str, model: Simulator, te: SplitData, args, mode: str = "inductor",
                   flops: list[float] | None = None, rate: float = 0.0) -> str:
    """The model with its step compiled: ms per trajectory-frame at each batch (after the compiling
    first steps, whose seconds are printed), the FLOP rate at each batch against ``rate`` where the eager
    step's FLOPs per batch ``flops`` are given (the compiled step's are the same, except ahead of time:
    counted again with the weights folded, :func:`step_flops`), and the largest position difference of a
    rollout of every test trajectory against the eager step."""
    if flops and mode == "aot":
        flops = [step_flops(model, te, b, folded=True) for b in args.batches]
    eager = rollout(model, te, model.device)
    name = label + (" compiled" if mode == "inductor" else f" {mode}")
    t0 = time.perf_counter()
    try:
        compile_step(model, mode)
        with quiet_compiler():  # inductor's notes (e.g. that the SVD has no C shim) would break the table
            for b in args.batches:  # each batch shape compiled once, outside the timings
                step_cost(model, te, batch=b, frames=2, repeats=1)
            compiled = rollout(model, te, model.device)  # (its controls, strided slices, compile once more)
            if mode in ("inductor", "cudagraphs"):  # a step whose shapes follow the state (contact or radius edges)
                _refuse_recompiles(model)  # would compile again at every timed step: refused, as on the study's axis
        compile_s = time.perf_counter() - t0
        costs = [step_cost(model, te, batch=b, frames=args.frames, repeats=args.repeats) for b in args.batches]
    except Exception as e:  # noqa: BLE001 - a model that does not compile says so and the table goes on
        return f"{name:22s} refused: {type(e).__name__}: {str(e).splitlines()[0][:80]}"
    diff = float(np.nanmax(np.abs(compiled.x - eager.x)))
    frac = "/".join(f"{100 * f / (c['ms_per_frame'] * 1e-3) / rate:.0f}" for f, c in zip(flops, costs, strict=True)) \
        if flops else ""
    floor = f", floor {1e3 * flops[-1] / args.batches[-1] / rate:.4f} ms/tf (weights folded)" if flops and mode == "aot" else ""
    return (f"{name:22s}{'':>10s}{'':>10s}" + "".join(f"{c['ms_per_trajectory_frame']:>{_col(c['batch'])}.3f}" for c in costs)
            + f"{frac:>12s}   compile {compile_s:.0f} s, rollout max |dx| {diff:.1e} m{floor}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="cubli-triple")
    ap.add_argument("--models", nargs="*", default=None, help="registry names (default: all)")
    ap.add_argument("--batches", nargs="*", type=int, default=[1, 16, 256])
    ap.add_argument("--train-batch", type=int, default=32)
    ap.add_argument("--frames", type=int, default=10, help="timed frames per rollout measurement")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu", help="cpu or cuda: where the torch models run (MuJoCo: the CPU)")
    ap.add_argument("--widths", nargs="*", type=int, default=[],
                    help="also MDGS at these GCN widths (hidden = global_dim; the default is 200)")
    ap.add_argument("--compile", nargs="*", choices=COMPILE_MODES, default=None,
                    help="also every torch model with its step compiled: torch.compile (inductor, the default), "
                         "ahead of time (aot) and/or CUDA graphs (cudagraphs, --device cuda only)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    dev = torch.device(args.device)
    if dev.type == "cuda" and not torch.cuda.is_available():
        ap.error("--device cuda: no CUDA device is present (torch.cuda.is_available() is false)")
    if dev.type == "cuda":
        torch.backends.cuda.matmul.allow_tf32 = False  # the models' float32, as on the CPU
    names = args.models or list(MODELS)
    tr, te = tiny_splits(args.scene)
    rate, rows = _matmul_rate(dev)
    where = torch.cuda.get_device_name(dev) if dev.type == "cuda" else "CPU"
    print(f"scene {args.scene}: {tr.x.shape[2]} nodes, frame {tr.frame_dt * 1e3:.0f} ms, torch threads "
          f"{args.threads}, torch models on {where}; dense matmul [{rows}x200]@[200x200] {rate / 1e9:.1f} GFLOP/s")
    head = f"{'model':22s}{'params':>10s}{'train ms':>10s}" + "".join(f"{'ms/tf b' + str(b):>{_col(b)}s}" for b in args.batches)
    print(head + f"{'% matmul':>12s}{'floor ms/tf':>13s}")
    rows = []
    for label, model in registry_models(names, tr, tuple(args.widths), dev):
        if isinstance(model, str):
            print(f"{label:22s} refused: {model}")
            continue
        try:
            cls = type(model)
            train_ms = "-"
            if cls.learned:
                opt, _, _ = model.optimizer(cls.default_lr)
                pairs = tr.pairs(model.history)
                idx = pairs[np.linspace(0, len(pairs) - 1, args.train_batch).astype(int)]
                gen = torch.Generator(device=model.device).manual_seed(0)

                def train_step(model=model, opt=opt, idx=idx, gen=gen):
                    b = model.perturb(batch_of(tr, idx, model.device, model.history), gen)
                    loss = sum(w * model.losses(b)[k] for k, w in model.loss_weights().items())
                    opt.zero_grad()
                    loss.backward()
                    opt.step()
                    if model.device.type == "cuda":
                        torch.cuda.synchronize()
                model.train()
                train_ms = f"{1e3 * median_time(train_step, args.repeats, 1):.1f}"
            costs = [step_cost(model, te, batch=b, frames=args.frames, repeats=args.repeats) for b in args.batches]
            frac = floor = "-"
            counted = []
            if cls.learned:  # each batch's FLOPs (counted) over its time, against the dense matmul's rate
                model.bind(te)
                fracs = []
                for b, c in zip(args.batches, costs, strict=True):
                    flops = step_flops(model, te, b)
                    counted.append(flops)
                    fracs.append(f"{100 * flops / (c['ms_per_frame'] * 1e-3) / rate:.0f}")
                frac = "/".join(fracs)
                floor = f"{1e3 * flops / args.batches[-1] / rate:.4f}"
            line = (f"{label:22s}{model.parameter_count():>10d}{train_ms:>10s}"
                    + "".join(f"{c['ms_per_trajectory_frame']:>{_col(c['batch'])}.3f}" for c in costs) + f"{frac:>12s}{floor:>13s}")
            print(line, flush=True)
            rows.append(line)
        except Exception as e:  # noqa: BLE001 - one model that fails here is a row that says so; the table goes on
            where = [f"{Path(f.filename).name}:{f.lineno}" for f in traceback.extract_tb(e.__traceback__)
                     if "/mdgs/" in f.filename or "bench_models" in f.filename][-3:]
            print(f"{label:22s} failed: {type(e).__name__}: {str(e).splitlines()[0][:100] if str(e) else ''} "
                  f"(at {' < '.join(reversed(where))})", flush=True)
            continue
        if args.compile is not None and model.compilable:
            modes = args.compile or ["inductor"]
            for mode in modes:
                line = _compiled_line(label, model, te, args, mode, counted, rate)
                print(line, flush=True)
                vars(model).pop("step", None)  # back to the class's eager step for the next mode
                if mode == "aot" and " refused: " in line[:40] and "inductor" not in modes:  # the study's fallback
                    print(_compiled_line(label, model, te, args, "inductor", counted, rate), flush=True)
                    vars(model).pop("step", None)
    print("ms/tf bN: milliseconds per trajectory-frame of a rollout step at batch N (batch 1: one trajectory); "
          "% matmul: FLOP rate at each batch (in the order of the columns) against the dense matmul above; floor ms/tf: the step's "
          "FLOPs per trajectory at that dense matmul rate, the least a step could cost on this thread"
          + ("; compiled / aot: the same model with torch.compile / AOTInductor (compile: seconds spent compiling "
             "every batch shape, outside the timings; max |dx|: against the eager rollout)"
             if args.compile is not None else ""))


if __name__ == "__main__":
    main()

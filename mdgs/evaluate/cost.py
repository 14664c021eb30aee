"""The cost axis of every chart: wall milliseconds per simulated frame, single and batched, for any Simulator.

One function, used by ``mdgs study`` and by ``benchmarks/``, so the speed-accuracy chart and
the benchmark print the same quantity: the median over ``repeats`` of the wall time of
``frames`` calls of ``model.step`` on a batch of ``batch`` trajectories (recorded states of
the split, trajectories cycled), after two warm-up steps, divided by ``frames`` (ms per frame
of the batch) and by ``batch`` as well (ms per trajectory-frame).

A model may define ``cost_step(state, ctrl)``: what one frame costs it when that differs from
``step`` only by work done for the comparison with the data. The MuJoCo reference does: its
cost is its integrator steps, not the mapping of its state to element nodes that the error
metrics need (a learned model's state *is* its nodes, so its ``step`` is timed).

:func:`compiled_cost` is the same measurement with the step compiled first
(:func:`mdgs.models.compile_step`), which ``mdgs study --recost`` runs for every row of a study.
"""

from __future__ import annotations

import contextlib
import logging
import statistics
import time
import warnings

import numpy as np
import torch

from mdgs.data.split import SplitData
from mdgs.models import ModelError, Simulator, compile_step

__all__ = ["step_cost", "compiled_cost", "quiet_compiler"]


@torch.no_grad()
def step_cost(model: Simulator, d: SplitData, batch: int = 1, frames: int = 20, repeats: int = 3) -> dict:
    """``{"batch", "ms_per_frame", "ms_per_trajectory_frame", "frames", "repeats"}`` of ``model`` on ``d``."""
    model.eval()
    model.bind(d)
    T, F = d.x.shape[:2]
    h = model.history
    traj = np.arange(batch) % T
    frames = max(1, min(frames, F - h - 1))
    dev = model.device
    times = []
    for _ in range(repeats):
        state = model.initial_state(d, traj, h)
        ctrl = [torch.from_numpy(d.ctrl[traj, h + t]).to(dev) for t in range(frames)]
        step = getattr(model, "cost_step", model.step)
        for t in range(min(2, frames)):  # warm-up (first-call allocations, caches)
            step(state, ctrl[t])
        if dev.type == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        s = state
        for t in range(frames):
            s = step(s, ctrl[t])
        if dev.type == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    ms = 1e3 * statistics.median(times) / frames
    return {"batch": int(batch), "ms_per_frame": ms, "ms_per_trajectory_frame": ms / batch,
            "frames": int(frames), "repeats": int(repeats)}


def compiled_cost(model: Simulator, d: SplitData, mode: str = "aot", batched: int = 0, loops: str | None = None) -> dict:
    """:func:`step_cost` of ``model`` at one trajectory and at a batch of ``batched`` trajectories of ``d``
    (0: all of them), with its step compiled by ``mode`` ("none": the eager step; "inductor", "aot",
    "cudagraphs": as :func:`mdgs.models.compile_step`).

    A model that does not compile in ``mode`` is measured in the next mode that works (aot or
    cudagraphs -> inductor -> none), and the result says so: ``{"requested", "compiled", "note", "compile_seconds",
    "single", "batched"}``, ``compiled`` the mode that ran, ``note`` why it is not ``requested`` ("" if
    it is). A model that is not torch code (``compilable`` false: MuJoCo) runs as it is, ``compiled``
    "none". Each batch shape is compiled (and its first step run) before its timed repeats, so
    ``compile_seconds`` holds the compiling and no timing does; a step that compiles again while it is timed
    (its shapes follow the state) is timed eagerly instead. ``model`` keeps the step timed, free to compile
    again for another split or batch shape. ``loops``: as
    :func:`mdgs.models.compile_step`'s (``None``: the model's choice).
    """
    modes = {"aot": ["aot", "inductor", "none"], "inductor": ["inductor", "none"], "none": ["none"],
             "cudagraphs": ["cudagraphs", "inductor", "none"]}
    if mode not in modes:
        raise ValueError(f"compile mode {mode!r} is not one of {', '.join(modes)}")
    sizes = [1, batched or d.x.shape[0]]
    note, t_compile = "", 0.0
    eager_step = model.step
    for m in modes[mode] if model.compilable else ["none"]:
        if m == "none":
            model.step = eager_step
            out = {"compiled": "none", "single": step_cost(model, d, batch=sizes[0]),
                   "batched": step_cost(model, d, batch=sizes[1])}
            break
        try:
            t0 = time.perf_counter()
            compile_step(model, m, loops=loops)
            with quiet_compiler():
                for b in sizes:  # compile each batch shape (two steps: the first of a binding runs eagerly)
                    step_cost(model, d, batch=b, frames=2, repeats=1)
            t_compile += time.perf_counter() - t0
            compiled = model.step
            if m in ("inductor", "cudagraphs"):
                _refuse_recompiles(model)
            out = {"compiled": m, "single": step_cost(model, d, batch=sizes[0]),
                   "batched": step_cost(model, d, batch=sizes[1])}
            model.step = compiled  # timed; later steps (another split, another batch) may compile again
            break
        except (ModelError, RuntimeError, NotImplementedError, TypeError, ValueError) as e:  # inductor's many
            # failure types; MDGS, GNS and constant twist compile in both modes (benchmarks/bench_models.py)
            note += f"{m}: {type(e).__name__}: {str(e).splitlines()[0][:160] if str(e) else ''}; "
            model.step = eager_step
    if not model.compilable:
        note = f"{model.name} is not torch code (nothing to compile)"
    return {"requested": mode, **out, "note": note.rstrip("; "), "compile_seconds": t_compile}


def _refuse_recompiles(model: Simulator) -> None:
    """Make ``model``'s compiled step raise :class:`ModelError` the moment it compiles a new graph: a step
    whose shapes follow the state (SGNN's varying number of contact edges) compiles anew at every
    step under ``dynamic=False``, a minute each, and has no steady state to time."""
    from torch._dynamo.utils import counters

    graphs = counters["stats"]["unique_graphs"]
    inner = model.step

    def step(state, ctrl):
        out = inner(state, ctrl)
        if counters["stats"]["unique_graphs"] > graphs:
            raise ModelError("the compiled step compiles again at later steps (its shapes follow the state, "
                             "e.g. a varying number of contact edges)")
        return out

    model.step = step


@contextlib.contextmanager
def quiet_compiler():
    """Silence torch's own deprecation warnings and inductor's notes while it compiles (one screenful per
    compiled shape, none about the model: e.g. that SVD has no C shim and runs through a fallback)."""
    log = logging.getLogger("torch._inductor")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", category=FutureWarning)
            yield
    finally:
        log.setLevel(level)

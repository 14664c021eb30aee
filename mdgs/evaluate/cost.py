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
"""

from __future__ import annotations

import statistics
import time

import numpy as np
import torch

from mdgs.data.split import SplitData
from mdgs.models import Simulator

__all__ = ["step_cost"]


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

"""Autoregressive rollouts of any Simulator over whole recorded trajectories, with divergence detection.

Each trajectory of a split is rolled out from its frame ``h`` (``h = model.history``: the
model is given the true frames ``0 .. h``) to its last frame under the recorded controls, all
trajectories as one batch. A trajectory **diverges** at the first step whose prediction is
not finite or whose position MSE exceeds ``DIVERGENCE_FACTOR`` (100) times the variance of
the moving nodes' positions in the split (the error of a prediction unrelated to the data is
about twice that variance). From that step on it is masked out (NaN) and continues from the
true frame only to keep the batch finite.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch

from mdgs.data.split import SplitData
from mdgs.models import Simulator

__all__ = ["DIVERGENCE_FACTOR", "Rollout", "rollout", "divergence_threshold", "rollout_score"]

#: A trajectory diverges when its position MSE exceeds this factor times the split's position variance.
DIVERGENCE_FACTOR = 100.0


@dataclass(frozen=True)
class Rollout:
    """Autoregressive rollouts of one split.

    x, v : [T, F, N, 3] predicted positions (m) and velocities (m/s); frames ``0 .. given-1``
        are the true ones; entries at and after a trajectory's divergence step hold the true frame.
    pos_mse, vel_mse : [T, F] per-frame MSE over moving nodes (m^2, m^2/s^2); NaN once diverged.
    diverged_at : [T] first diverged frame index (rollout step), -1 if none.
    threshold : position MSE threshold of divergence, m^2.
    given : frames given to the model (1 + its history).
    step_seconds : wall time spent in ``model.step`` over the whole rollout, s.
    """

    x: np.ndarray
    v: np.ndarray
    pos_mse: np.ndarray
    vel_mse: np.ndarray
    diverged_at: np.ndarray
    threshold: float
    given: int = 1
    step_seconds: float = 0.0

    @property
    def ms_per_frame(self) -> float:
        """Milliseconds of ``model.step`` per simulated frame of the whole batch of trajectories."""
        steps = self.pos_mse.shape[1] - self.given
        return 1e3 * self.step_seconds / max(steps, 1)

    @property
    def ms_per_trajectory_frame(self) -> float:
        """Milliseconds per simulated frame and trajectory (the batched cost)."""
        return self.ms_per_frame / max(self.pos_mse.shape[0], 1)


def divergence_threshold(d: SplitData) -> float:
    """``DIVERGENCE_FACTOR`` x the variance of the moving nodes' positions in ``d``, m^2."""
    return DIVERGENCE_FACTOR * float(d.x[:, :, d.moving].var(axis=(0, 1, 2)).mean())


@torch.no_grad()
def rollout(model: Simulator, d: SplitData, dev=None, threshold: float | None = None) -> Rollout:
    """Roll out every trajectory of ``d`` with ``model`` (bound to ``d``'s scene first)."""
    model.eval()
    model.bind(d)
    dev = dev if dev is not None else model.device
    T, F, N, _ = d.x.shape
    h = model.history
    if h + 1 >= F:
        raise ValueError(f"{d.path} has {F} frames; model {model.name!r} needs more than {h + 1}")
    moving = d.moving
    if threshold is None:
        threshold = divergence_threshold(d)
    idx = np.arange(T)
    state = model.initial_state(d, idx, h)
    xs, vs = np.empty_like(d.x), np.empty_like(d.v)
    xs[:, :h + 1], vs[:, :h + 1] = d.x[:, :h + 1], d.v[:, :h + 1]
    pos = np.full((T, F), np.nan)
    vel = np.full((T, F), np.nan)
    pos[:, :h + 1] = vel[:, :h + 1] = 0.0
    div = np.full(T, -1)
    spent = 0.0
    for t in range(h + 1, F):
        ctrl = torch.from_numpy(d.ctrl[:, t - 1]).to(dev)
        t0 = time.perf_counter()
        state = model.step(state, ctrl)
        if state.x.is_cuda:
            torch.cuda.synchronize()
        spent += time.perf_counter() - t0
        xp, vp = state.x.cpu().numpy(), state.v.cpu().numpy()
        ep = ((xp - d.x[:, t]) ** 2)[:, moving].mean(axis=(1, 2))
        ev = ((vp - d.v[:, t]) ** 2)[:, moving].mean(axis=(1, 2))
        bad = ~np.isfinite(ep) | ~np.isfinite(ev) | (ep > threshold)
        div[bad & (div < 0)] = t
        dead = div >= 0
        if dead.any():  # diverged trajectories continue from the true frame only to keep the batch finite
            state = state.where(torch.from_numpy(dead), model.initial_state(d, idx, t))
            xp, vp = state.x.cpu().numpy(), state.v.cpu().numpy()
        pos[:, t] = np.where(dead, np.nan, ep)
        vel[:, t] = np.where(dead, np.nan, ev)
        xs[:, t], vs[:, t] = xp, vp
    return Rollout(xs, vs, pos, vel, div, threshold, h + 1, spent)


def rollout_score(model: Simulator, d: SplitData, dev=None) -> float:
    """One number for how well ``model`` rolls out ``d``: the position MSE (m^2) averaged over every
    trajectory and frame, each frame's error capped at the position variance of the moving nodes
    (the studies' failure threshold at ``failure_factor`` 1), so a trajectory that fails or diverges
    counts at the cap from there on, never as a large number. Checkpoint selection by validation
    rollout (:class:`mdgs.train.TrainConfig` ``select="rollout"``) minimises it."""
    r = rollout(model, d, dev)
    cap = divergence_threshold(d) / DIVERGENCE_FACTOR
    return float(np.where(np.isfinite(r.pos_mse), np.minimum(r.pos_mse, cap), cap).mean())

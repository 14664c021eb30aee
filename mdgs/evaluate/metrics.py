"""Rollout metrics: MSE at the paper's report times t = 40 and t = 110, per-step curves, means over seeds.

- ``pos_mse[traj, t]`` = mean over moving nodes and coordinates of ``|x_pred - x_true|^2``
  (m^2), ``vel_mse`` likewise for velocities (m^2/s^2);
- **t** counts the paper's 110 time steps of a trajectory from 1: t = 1 is the given first
  frame, so ``mse_t40`` is the error at frame index 39 (39 rollout steps) and ``mse_t110`` at
  frame index 109, the last (109 steps). A dataset with fewer frames reports its last one;
- means over trajectories leave out those diverged by then, and say how many were used;
- several runs (seeds) give the mean +- std (sample std, ddof = 1) of each run's metrics.
"""

from __future__ import annotations

import numpy as np

from mdgs.evaluate.rollout import Rollout

__all__ = ["REPORT_TIMES", "frame_of", "rollout_metrics", "aggregate"]

#: The paper's report times (1-indexed time steps of a trajectory).
REPORT_TIMES = (40, 110)


def frame_of(t: int, F: int) -> int:
    """Frame index of the paper's 1-indexed time step ``t`` (clipped to the last frame)."""
    return min(t, F) - 1


def _mean_valid(a: np.ndarray) -> float | None:
    ok = np.isfinite(a)
    return float(a[ok].mean()) if ok.any() else None


def rollout_metrics(r: Rollout) -> dict:
    """MSE at the report times (mean over trajectories not diverged) and the per-step curves."""
    F = r.pos_mse.shape[1]
    rep = {}
    for t in REPORT_TIMES:
        f = frame_of(t, F)
        rep[f"mse_t{t}"] = _mean_valid(r.pos_mse[:, f])
        rep[f"mse_t{t}_velocity"] = _mean_valid(r.vel_mse[:, f])
        rep[f"mse_t{t}_frame"] = f
        rep[f"mse_t{t}_trajectories"] = int(np.isfinite(r.pos_mse[:, f]).sum())
    with np.errstate(invalid="ignore"):
        n_ok = np.isfinite(r.pos_mse).sum(0)
        rep["rollout_mse_curve"] = [None if n == 0 else float(np.nanmean(c))
                                    for n, c in zip(n_ok, r.pos_mse.T, strict=True)]
        rep["rollout_mse_curve_velocity"] = [None if n == 0 else float(np.nanmean(c))
                                             for n, c in zip(n_ok, r.vel_mse.T, strict=True)]
    rep["rollout_mse_curve_trajectories"] = n_ok.astype(int).tolist()
    rep["frames_given"] = int(r.given)
    rep["ms_per_frame"] = r.ms_per_frame
    rep["ms_per_trajectory_frame"] = r.ms_per_trajectory_frame
    return rep


def aggregate(reports: list[dict]) -> dict:
    """Mean and sample std over runs of each report-time metric (None where some run diverged everywhere)."""
    agg = {"runs": len(reports)}
    keys = [f"mse_t{t}{s}" for t in REPORT_TIMES for s in ("", "_velocity")]
    if all("one_step_mse_scaled" in r for r in reports):
        keys.append("one_step_mse_scaled")
    for key in keys:
        vals = [r[key] for r in reports]
        if any(v is None for v in vals):
            agg[key] = {"mean": None, "std": None, "note": "some runs diverged on every trajectory by then"}
        else:
            a = np.array(vals, float)
            agg[key] = {"mean": float(a.mean()), "std": float(a.std(ddof=1)) if len(a) > 1 else 0.0}
    return agg

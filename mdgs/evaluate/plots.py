"""Plots of an evaluation: rollout MSE against time step, and predicted vs true body mass centres.

matplotlib's Agg backend; files are written atomically (:func:`mdgs.runs.atomic_savefig`).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from mdgs.data.split import SplitData
from mdgs.evaluate.metrics import REPORT_TIMES
from mdgs.evaluate.rollout import Rollout
from mdgs.runs import atomic_savefig

__all__ = ["plot_rollout_mse", "plot_trajectory"]


def _curve(rep: dict) -> np.ndarray:
    return np.array([np.nan if c is None else c for c in rep["rollout_mse_curve"]], float)


def plot_rollout_mse(reports: list[dict], references: list[dict], n_traj: int, path: Path) -> None:
    """Mean rollout position MSE per time step of the runs (+- 1 std band), each reference dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = np.array([_curve(r) for r in reports], float)
    F = curves.shape[1]
    steps = np.arange(F)
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # steps where every run has diverged stay NaN
        mean = np.nanmean(curves, 0) if len(curves) > 1 else curves[0]
        sd = np.nanstd(curves, 0, ddof=1) if len(curves) > 1 else None
    label = reports[0]["model"] + (f" (mean of {len(reports)} runs)" if len(reports) > 1 else "")
    ax.plot(steps[1:] + 1, mean[1:], label=label)
    if sd is not None:
        ax.fill_between(steps[1:] + 1, (mean - sd)[1:], (mean + sd)[1:], alpha=0.3, label="+- 1 std over runs")
    for k, ref in enumerate(references):
        ax.plot(steps[1:] + 1, _curve(ref)[1:], color=f"{0.3 + 0.2 * k:.1f}", ls="--", lw=1,
                label=f"reference: {ref['label']}")
    first = True
    for r in reports:
        for dv in r["diverged"]:
            ax.axvline(dv["step"] + 1, color="r", lw=0.6, alpha=0.5, label="a trajectory diverged" if first else None)
            first = False
    for t in REPORT_TIMES:
        if t <= F:
            ax.axvline(t, color="0.6", ls=":", lw=0.8, label="report times t = 40, 110" if t == REPORT_TIMES[0] else None)
    if np.any(np.isfinite(mean[1:]) & (mean[1:] > 0)):
        ax.set_yscale("log")
    else:
        ax.text(0.5, 0.5, "every trajectory diverged at step 1", transform=ax.transAxes, ha="center")
    ax.set_xlabel("time step t (t = 1: given first frame)")
    ax.set_ylabel("position MSE (m$^2$), moving nodes\nmean over trajectories not yet diverged")
    noun = "trajectory" if n_traj == 1 else "trajectories"
    ax.set_title(f"rollout MSE, {reports[0]['scene']}, {n_traj} test {noun}")
    ax.legend(fontsize=7)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)


def plot_trajectory(r: Rollout, d: SplitData, traj: int, path: Path) -> None:
    """Predicted (dashed) vs true (solid) mass centre of each moving body along one trajectory."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    F = d.x.shape[1]
    nb = np.asarray(d.static["node_body"])
    mass = np.asarray(d.static["node_mass"], float)
    names = list(d.static.get("body_names", []))
    bodies = [b for b in np.unique(nb[d.moving])]
    fig, axes = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
    time_s = np.arange(F) * d.frame_dt
    for j, b in enumerate(bodies):
        sel = (nb == b) & d.moving
        w = mass[sel] / mass[sel].sum()
        true = np.einsum("fnk,n->fk", d.x[traj][:, sel], w)
        pred = np.einsum("fnk,n->fk", r.x[traj][:, sel], w)
        end = r.diverged_at[traj] if r.diverged_at[traj] >= 0 else F
        name = names[b - 1] if 0 < b <= len(names) else f"body {b}"
        for k, ax in enumerate(axes):
            ax.plot(time_s, true[:, k], color=f"C{j}", label=f"{name} true" if k == 0 else None)
            ax.plot(time_s[:end], pred[:end, k], color=f"C{j}", ls="--", label=f"{name} predicted" if k == 0 else None)
    for k, ax in enumerate(axes):
        ax.set_ylabel(f"{'xyz'[k]} (m)")
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title(f"test trajectory {traj}: body mass centres, true (solid) vs predicted (dashed)")
    axes[0].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=110)
    plt.close(fig)

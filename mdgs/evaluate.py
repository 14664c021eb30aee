"""Rollout evaluation of trained MDGS runs: MSE at t=40 and t=110 (Tables 1-4), curves, divergence.

Each test trajectory is rolled out autoregressively from its first frame over its whole
length (frame 0 given, frames 1..F-1 predicted, the recorded controls applied), then:

- ``pos_mse[traj, t]`` = mean over moving nodes and coordinates of ``|x_pred - x_true|^2``
  (m^2), ``vel_mse`` likewise for velocities (m^2/s^2);
- **t** counts the paper's 110 time steps of a trajectory from 1: t = 1 is the given first
  frame, so ``mse_t40`` is the error at frame index 39 (39 rollout steps) and ``mse_t110`` at
  frame index 109, the last (109 steps). A dataset with fewer frames reports its last one;
- **divergence**: a trajectory diverges at the first step whose prediction is not finite or
  whose position MSE exceeds ``DIVERGENCE_FACTOR`` (100) times the variance of the
  moving nodes' positions in the evaluated split (the error of a prediction unrelated to
  the data is about twice that variance). From that step on it is left out of every mean and
  reported with the step; the report's ``status`` is then "diverged" and the CLI says so.

Several runs (seeds) give the mean +- std (sample std, ddof = 1) of each run's metrics.
Plots use matplotlib's Agg backend; the JSON report is written atomically.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from mdgs.data.schema import DatasetError
from mdgs.graphs import SceneGraph
from mdgs.model import MDGS
from mdgs.rigid import advance, twist
from mdgs.train import RunError, SplitData, _device, atomic_json, load_run, load_split, one_step_mse

__all__ = ["DIVERGENCE_FACTOR", "Rollout", "rollout", "constant_twist_step", "reference", "evaluate_run", "evaluate"]

#: A trajectory diverges when its position MSE exceeds this factor times the split's position variance.
DIVERGENCE_FACTOR = 100.0
#: The paper's report times (1-indexed time steps of a trajectory).
REPORT_TIMES = (40, 110)


@dataclass(frozen=True)
class Rollout:
    """Autoregressive rollouts of one split.

    x, v : [T, F, N, 3] predicted positions (m) and velocities (m/s); frame 0 is the true one;
        entries at and after a trajectory's divergence step hold the true frame (masked out).
    pos_mse, vel_mse : [T, F] per-frame MSE over moving nodes (m^2, m^2/s^2); NaN once diverged.
    diverged_at : [T] first diverged frame index (rollout step), -1 if none.
    threshold : position MSE threshold of divergence, m^2.
    """

    x: np.ndarray
    v: np.ndarray
    pos_mse: np.ndarray
    vel_mse: np.ndarray
    diverged_at: np.ndarray
    threshold: float


def constant_twist_step(scene: SceneGraph, dt: float):
    """Reference stepper: every moving body keeps its velocity and angular velocity (no forces, no
    contact) and moves rigidly over ``dt``; ``(x, v, control) -> (x', v')`` [B, N, 3]."""
    seg, n, mass, moving = scene.obj, scene.n_obj, scene.mass, ~scene.static

    def step(x: torch.Tensor, v: torch.Tensor, control=None) -> tuple[torch.Tensor, torch.Tensor]:
        tw = twist(x, v, seg.to(x.device), n, mass.to(x.device))
        xn, vn = advance(x, tw, tw.vc, tw.omega, dt, seg.to(x.device))
        m = moving.to(x.device).view(1, -1, 1)
        return torch.where(m, xn, x), torch.where(m, vn, torch.zeros_like(vn))

    return step


@torch.no_grad()
def rollout(model: MDGS | None, scene: SceneGraph, d: SplitData, dev, threshold: float | None = None,
            step=None) -> Rollout:
    """Roll out every trajectory of ``d`` from its frame 0 (all trajectories as one batch of graphs).

    ``step`` ``(x, v, control) -> (x', v')`` replaces the model (e.g. :func:`constant_twist_step`).
    """
    if step is None:
        model.eval()

        def step(x, v, c):
            p = model(scene, x, v, c)
            return p.x, p.v
    T, F, N, _ = d.x.shape
    moving = d.moving
    if threshold is None:
        threshold = DIVERGENCE_FACTOR * float(d.x[:, :, moving].var(axis=(0, 1, 2)).mean())
    x = torch.from_numpy(d.x[:, 0]).to(dev)
    v = torch.from_numpy(d.v[:, 0]).to(dev)
    xs, vs = np.empty_like(d.x), np.empty_like(d.v)
    xs[:, 0], vs[:, 0] = d.x[:, 0], d.v[:, 0]
    pos = np.full((T, F), np.nan)
    vel = np.full((T, F), np.nan)
    pos[:, 0] = vel[:, 0] = 0.0
    div = np.full(T, -1)
    for t in range(1, F):
        xp, vp = step(x, v, torch.from_numpy(d.control[:, t - 1]).to(dev))
        xp, vp = xp.cpu().numpy(), vp.cpu().numpy()
        ep = ((xp - d.x[:, t]) ** 2)[:, moving].mean(axis=(1, 2))
        ev = ((vp - d.v[:, t]) ** 2)[:, moving].mean(axis=(1, 2))
        bad = ~np.isfinite(ep) | ~np.isfinite(ev) | (ep > threshold)
        newly = bad & (div < 0)
        div[newly] = t
        dead = div >= 0
        # diverged trajectories continue from the true frame only to keep the batch finite; they are masked
        xp[dead], vp[dead] = d.x[dead, t], d.v[dead, t]
        pos[:, t] = np.where(dead, np.nan, ep)
        vel[:, t] = np.where(dead, np.nan, ev)
        xs[:, t], vs[:, t] = xp, vp
        x, v = torch.from_numpy(xp).to(dev), torch.from_numpy(vp).to(dev)
    return Rollout(xs, vs, pos, vel, div, threshold)


def _frame_of(t: int, F: int) -> int:
    """Frame index of the paper's 1-indexed time step ``t`` (clipped to the last frame)."""
    return min(t, F) - 1


def _mean_valid(a: np.ndarray) -> float | None:
    ok = np.isfinite(a)
    return float(a[ok].mean()) if ok.any() else None


def _metrics(r: Rollout) -> dict:
    """MSE at the report times (mean over trajectories not diverged) and the per-step curves."""
    F = r.pos_mse.shape[1]
    rep = {}
    for t in REPORT_TIMES:
        f = _frame_of(t, F)
        rep[f"mse_t{t}"] = _mean_valid(r.pos_mse[:, f])
        rep[f"mse_t{t}_velocity"] = _mean_valid(r.vel_mse[:, f])
        rep[f"mse_t{t}_frame"] = f
        rep[f"mse_t{t}_trajectories"] = int(np.isfinite(r.pos_mse[:, f]).sum())
    with np.errstate(invalid="ignore"):
        n_ok = np.isfinite(r.pos_mse).sum(0)
        rep["rollout_mse_curve"] = [None if n == 0 else float(np.nanmean(c)) for n, c in zip(n_ok, r.pos_mse.T, strict=True)]
        rep["rollout_mse_curve_velocity"] = [None if n == 0 else float(np.nanmean(c))
                                             for n, c in zip(n_ok, r.vel_mse.T, strict=True)]
    rep["rollout_mse_curve_trajectories"] = n_ok.astype(int).tolist()
    return rep


def evaluate_run(run: str | os.PathLike, d: SplitData, dev, batch_size: int = 64) -> tuple[dict, Rollout]:
    """Evaluate one run on a loaded split -> (report dict, rollout). Raises RunError on a mismatch."""
    model, state = load_run(run, dev)
    ident, want = d.identity(), state["data_identity"]
    variant = False
    if ident["mjcf_sha256"] != want["mjcf_sha256"]:
        from mdgs.scenes import SCENES

        spec = SCENES.get(ident["scene"])
        variant = spec is not None and spec.variant_of == want["scene"]
        same_shape = ident["n_nodes"] == want["n_nodes"] and ident["n_actuators"] == want["n_actuators"]
        if not (variant and same_shape):
            raise RunError(f"{run} was trained on scene {want['scene']!r} ({want['n_nodes']} nodes) but {d.path} "
                           f"holds scene {ident['scene']!r} ({ident['n_nodes']} nodes); evaluate it on data of "
                           f"{want['scene']!r} or one of its test variants")
    scene = SceneGraph.from_static(d.static, has_contact=d.has_contact).to(dev)
    r = rollout(model, scene, d, dev)
    T, F = r.pos_mse.shape
    rep = {
        "run": str(run),
        "data": d.path,
        "scene": ident["scene"],
        "trained_on": want["scene"],
        "generalization_variant": variant,
        "model": state["config"]["model"]["variant"],
        "epochs_trained": int(state["epoch"]) + 1,
        "trajectories": T,
        "frames": F,
        "frame_dt_s": d.frame_dt,
        "one_step_mse_scaled": one_step_mse(model, scene, d, dev, batch_size),
        "divergence_threshold_m2": r.threshold,
        "diverged": [{"trajectory": int(i), "step": int(s), "time_s": float(s * d.frame_dt)}
                     for i, s in enumerate(r.diverged_at) if s >= 0],
    }
    rep.update(_metrics(r))
    rep["status"] = "diverged" if rep["diverged"] else "ok"
    return rep, r


#: What the reference rollout of every report is.
REFERENCE = "constant twist: every body keeps its velocity and angular velocity (no forces), moved rigidly"


def reference(d: SplitData, dev) -> tuple[dict, Rollout]:
    """MSE at the report times of the :func:`constant_twist_step` rollout: what a learned
    simulator must beat to have learned any dynamics (gravity, contact, actuation)."""
    scene = SceneGraph.from_static(d.static, has_contact=d.has_contact).to(dev)
    r = rollout(None, scene, d, dev, step=constant_twist_step(scene, d.frame_dt))
    rep = {"name": REFERENCE, **_metrics(r), "diverged": int((r.diverged_at >= 0).sum())}
    return rep, r


def _aggregate(reports: list[dict]) -> dict:
    agg = {"runs": len(reports)}
    for key in [f"mse_t{t}{s}" for t in REPORT_TIMES for s in ("", "_velocity")] + ["one_step_mse_scaled"]:
        vals = [r[key] for r in reports]
        if any(v is None for v in vals):
            agg[key] = {"mean": None, "std": None, "note": "some runs diverged on every trajectory by then"}
        else:
            a = np.array(vals, float)
            agg[key] = {"mean": float(a.mean()), "std": float(a.std(ddof=1)) if len(a) > 1 else 0.0}
    return agg


def _plots(reports: list[dict], rollouts: list[Rollout], d: SplitData, stem: Path, traj: int,
           ref: dict | None = None) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = {}
    F = d.x.shape[1]
    steps = np.arange(F)
    curves = np.array([[np.nan if c is None else c for c in r["rollout_mse_curve"]] for r in reports], float)
    fig, ax = plt.subplots(figsize=(6, 4))
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # steps where every run has diverged stay NaN
        mean = np.nanmean(curves, 0) if len(curves) > 1 else curves[0]
        sd = np.nanstd(curves, 0, ddof=1) if len(curves) > 1 else None
    label = reports[0]["model"] + (f" (mean of {len(reports)} runs)" if len(reports) > 1 else "")
    ax.plot(steps[1:] + 1, mean[1:], label=label)
    if sd is not None:
        ax.fill_between(steps[1:] + 1, (mean - sd)[1:], (mean + sd)[1:], alpha=0.3, label="+- 1 std over runs")
    if ref is not None:
        rc = np.array([np.nan if c is None else c for c in ref["rollout_mse_curve"]], float)
        ax.plot(steps[1:] + 1, rc[1:], color="0.4", ls="--", lw=1, label="reference: constant twist")
    for r in reports:
        for dv in r["diverged"]:
            ax.axvline(dv["step"] + 1, color="r", lw=0.6, alpha=0.5)
    for t in REPORT_TIMES:
        if t <= F:
            ax.axvline(t, color="0.6", ls=":", lw=0.8)
    if np.any(np.isfinite(mean[1:]) & (mean[1:] > 0)):
        ax.set_yscale("log")
    else:
        ax.text(0.5, 0.5, "every trajectory diverged at step 1", transform=ax.transAxes, ha="center")
    ax.set_xlabel("time step t (t = 1: given first frame)")
    ax.set_ylabel("position MSE (m$^2$), moving nodes\nmean over trajectories not yet diverged")
    ax.set_title(f"rollout MSE, {reports[0]['scene']}, {reports[0]['trajectories']} test trajectories")
    ax.legend()
    fig.tight_layout()
    files["rollout_mse"] = str(stem.with_name(stem.name + "-rollout-mse.png"))
    _savefig(fig, Path(files["rollout_mse"]))
    plt.close(fig)

    # predicted vs true mass centre of each moving body, one trajectory, first run
    r0 = rollouts[0]
    nb = np.asarray(d.static["node_body"])
    mass = np.asarray(d.static["node_mass"], float)
    names = list(d.static.get("body_names", []))
    bodies = [b for b in np.unique(nb[d.moving])]
    fig, axes = plt.subplots(3, 1, figsize=(7, 7), sharex=True)
    time_s = steps * d.frame_dt
    for j, b in enumerate(bodies):
        sel = (nb == b) & d.moving
        w = mass[sel] / mass[sel].sum()
        true = np.einsum("fnk,n->fk", d.x[traj][:, sel], w)
        pred = np.einsum("fnk,n->fk", r0.x[traj][:, sel], w)
        end = r0.diverged_at[traj] if r0.diverged_at[traj] >= 0 else F
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
    files["trajectory"] = str(stem.with_name(stem.name + "-trajectory.png"))
    _savefig(fig, Path(files["trajectory"]))
    plt.close(fig)
    return files


def _savefig(fig, path: Path) -> None:
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}.png")
    try:
        fig.savefig(tmp, dpi=110)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def evaluate(runs: list[str | os.PathLike], data: str | os.PathLike, split: str = "test",
             json_path: str | os.PathLike | None = None, device: str = "auto", traj: int = 0) -> dict:
    """Evaluate runs (one per seed) on ``<data>/<split>.h5``; write the JSON report and plots.

    The report goes to ``json_path`` or, by default, ``<run>/evaluation-<split>.json`` for one
    run and ``<parent of the first run>/evaluation-<split>.json`` for several; the plots
    ``<stem>-rollout-mse.png`` and ``<stem>-trajectory.png`` beside it. Returns the report.
    """
    dev = _device(device)
    data = Path(data)
    if not data.is_dir():
        raise DatasetError(f"data folder {data} does not exist; create it with `mdgs generate SCENE --out {data}`")
    d = load_split(data / f"{split}.h5")
    if not 0 <= traj < d.x.shape[0]:
        raise RunError(f"--traj {traj} is out of range; {d.path} has {d.x.shape[0]} trajectories")
    ref, _ = reference(d, dev)
    reps, rolls = [], []
    for run in runs:
        rep, r = evaluate_run(run, d, dev)
        reps.append(rep)
        rolls.append(r)
    if json_path is None:
        base = Path(runs[0]) if len(runs) == 1 else Path(runs[0]).resolve().parent
        json_path = base / f"evaluation-{split}.json"
    json_path = Path(json_path)
    if not json_path.parent.is_dir():
        raise RunError(f"--json {json_path}: folder {json_path.parent} does not exist; create it or choose another path")
    report = {
        "units": {"mse_tN": "m^2, position MSE over moving nodes and x, y, z at time step N (t = 1: first frame)",
                  "mse_tN_velocity": "m^2/s^2", "one_step_mse_scaled": "dimensionless, Eq. (10) on [x/dx_scale, v/dv_scale]",
                  "divergence": f"NaN, or position MSE > {DIVERGENCE_FACTOR:g} x position variance of the split"},
        "split": split,
        "aggregate": _aggregate(reps),
        "reference": ref,
        "runs": reps,
        "status": "diverged" if any(r["diverged"] for r in reps) else "ok",
    }
    for key in ("mse_t40", "mse_t110", "mse_t40_velocity", "mse_t110_velocity"):
        report[key] = report["aggregate"][key]["mean"]
    report["plots"] = _plots(reps, rolls, d, json_path.with_suffix(""), traj, ref)
    atomic_json(report, json_path)
    report["json"] = str(json_path)
    return report

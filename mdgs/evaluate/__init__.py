"""Rollout evaluation of trained runs and non-learned references (``mdgs evaluate``): Tables 1-4 metrics.

:func:`evaluate` rolls out every test trajectory with each run (one per seed) and with the
references, and writes one JSON report and two plots. Every report carries the constant-twist
reference (what a learned simulator must beat to have learned any dynamics); more references
(e.g. MuJoCo at a coarser timestep) are added with ``references``.
Stages: :mod:`~mdgs.evaluate.rollout`, :mod:`~mdgs.evaluate.metrics`, :mod:`~mdgs.evaluate.plots`.
"""

from __future__ import annotations

import os
from pathlib import Path

from mdgs.data.io import output_problem
from mdgs.data.split import SplitData, load_splits
from mdgs.evaluate import rollout as _rollout
from mdgs.evaluate.metrics import REPORT_TIMES, aggregate, rollout_metrics
from mdgs.evaluate.plots import plot_rollout_mse, plot_trajectory
from mdgs.evaluate.rollout import DIVERGENCE_FACTOR, Rollout
from mdgs.models import Simulator, get_model, one_step_error
from mdgs.models.base import COMPILE_MODES
from mdgs.runs import RunError, atomic_json, check_run_folder, load_run, resolve_device

__all__ = ["DIVERGENCE_FACTOR", "REPORT_TIMES", "Rollout", "evaluate", "evaluate_run",
           "evaluate_reference", "reference_label"]


def _check_identity(run, d: SplitData, want: dict) -> bool:
    """True if ``d`` is a test variant of the run's scene; RunError if it is another scene."""
    ident = d.identity()
    if ident["mjcf_sha256"] == want["mjcf_sha256"]:
        if ident["n_nodes"] != want["n_nodes"]:  # the same scene partitioned otherwise (`mdgs generate --refine`)
            raise RunError(f"{run} was trained on scene {want['scene']!r} partitioned into {want['n_nodes']} nodes "
                           f"but {d.path} partitions it into {ident['n_nodes']}; evaluate it on data generated "
                           f"with the partition it was trained on (the same --refine)")
        return False
    from mdgs.scenes import SCENES

    spec = SCENES.get(ident["scene"])
    variant = spec is not None and spec.variant_of == want["scene"]
    same_shape = ident["n_nodes"] == want["n_nodes"] and ident["n_actuators"] == want["n_actuators"]
    if not (variant and same_shape):
        raise RunError(f"{run} was trained on scene {want['scene']!r} ({want['n_nodes']} nodes) but {d.path} "
                       f"holds scene {ident['scene']!r} ({ident['n_nodes']} nodes); evaluate it on data of "
                       f"{want['scene']!r} or one of its test variants")
    return True


def evaluate_run(run: str | os.PathLike, d: SplitData, dev, batch_size: int = 64,
                 compile_mode: str = "none") -> tuple[dict, Rollout]:
    """Evaluate one run on a loaded split -> (report dict, rollout). Raises RunError on a mismatch.

    ``compile_mode``: "none" (the eager step), or a mode of :func:`mdgs.models.compile_step` ("inductor",
    "aot"), compiled for the rollout's batch shape before the rollout, so ``ms_per_frame`` times the
    compiled step and not its compiling."""
    model, state = load_run(run, dev)
    variant = _check_identity(run, d, state["data_identity"])
    if compile_mode != "none":
        from mdgs.evaluate.cost import step_cost
        from mdgs.models import compile_step

        compile_step(model, compile_mode)
        step_cost(model, d, batch=d.x.shape[0], frames=2, repeats=1)  # the eager first step, then compiling
    r = _rollout.rollout(model, d, dev)
    T, F = r.pos_mse.shape
    rep = {
        "run": str(run),
        "data": d.path,
        "scene": d.identity()["scene"],
        "trained_on": state["data_identity"]["scene"],
        "generalization_variant": variant,
        "model": state["model_name"],
        "parameters": model.parameter_count(),
        "compiled": compile_mode,
        "epochs_trained": int(state["epoch"]) + 1,
        "trajectories": T,
        "frames": F,
        "frame_dt_s": d.frame_dt,
        "one_step_mse_scaled": one_step_error(model, d, dev, batch_size),
        "divergence_threshold_m2": r.threshold,
        "diverged": [{"trajectory": int(i), "step": int(s), "time_s": float(s * d.frame_dt)}
                     for i, s in enumerate(r.diverged_at) if s >= 0],
    }
    rep.update(rollout_metrics(r))
    rep["status"] = "diverged" if rep["diverged"] else "ok"
    return rep, r


def reference_label(model: Simulator) -> str:
    """How a reference is named in reports and plots: ``constant twist``, ``mujoco dt x20``, ..."""
    if model.name == "mujoco":
        return f"mujoco dt x{model.config.dt_factor}"
    if model.name == "constant-twist":
        c = model.config
        trap = ", trapezoidal" if c.trapezoidal else ""
        if c.dynamics:
            return ("rigid tree" + (" + joints" if c.joints else "") + trap + (", push-out" if c.push_out else "")
                    + (f", {c.substeps} substeps" if c.substeps > 1 else "")
                    + (f", {c.gyroscopic} gyroscopic" if c.gyroscopic != "explicit" else "")
                    + {"momentum": ", momentum projection", "coordinates": ", joint coordinates"}.get(c.joint_velocities, "")
                    + (", soft contact" if c.contact == "soft" else ""))
        motors = " + coupled motors" if c.motors and c.coupled else " + motors" if c.motors else ""
        return "constant twist" + motors + (" + joints" if c.joints else "") + trap
    return model.name.replace("-", " ")


def evaluate_reference(model: Simulator, d: SplitData, dev) -> tuple[dict, Rollout]:
    """Rollout metrics of a non-learned model on ``d`` -> (report dict, rollout)."""
    model = model.to(dev)
    r = _rollout.rollout(model, d, dev)
    rep = {"name": model.summary, "model": model.name, "label": reference_label(model),
           "config": model.config_dict(), **rollout_metrics(r), "diverged": int((r.diverged_at >= 0).sum())}
    return rep, r


def evaluate(runs: list[str | os.PathLike], data: str | os.PathLike, split: str = "test",
             json_path: str | os.PathLike | None = None, device: str = "auto", traj: int = 0,
             references: list[tuple[str, dict]] = (), compile_mode: str = "none") -> dict:
    """Evaluate runs (one per seed) on ``<data>/<split>.h5``; write the JSON report and plots.

    ``references``: extra non-learned models as ``(name, config kwargs)``, e.g.
    ``[("mujoco", {"dt_factor": 20})]``; the constant-twist reference is always included
    (report key ``reference``; every reference also in ``references``). ``compile_mode``: the learned
    models' step, as :func:`evaluate_run` takes it (the references run eagerly).
    The report goes to ``json_path`` or, by default, ``<run>/evaluation-<split>.json`` for one
    run and ``<parent of the first run>/evaluation-<split>.json`` for several; the plots
    ``<stem>-rollout-mse.png`` and ``<stem>-trajectory.png`` beside it. Returns the report.
    """
    dev = resolve_device(device)
    if compile_mode not in ("none", *COMPILE_MODES):
        raise RunError(f"--compile {compile_mode} is not one of none, {', '.join(COMPILE_MODES)}")
    if not runs:
        raise RunError("name at least one run folder to evaluate")
    for run in runs:  # the run folders first: a default report path lies inside one
        check_run_folder(run)
    if json_path is None:
        base = Path(runs[0]) if len(runs) == 1 else Path(runs[0]).resolve().parent
        json_path = base / f"evaluation-{split}.json"
    json_path = Path(json_path)
    if not json_path.parent.is_dir():
        raise RunError(f"--json {json_path}: folder {json_path.parent} "
                       + ("is a file, not a folder" if json_path.parent.exists() else "does not exist")
                       + "; create it or choose another path")
    problem = output_problem(json_path, "--json", "file", f"evaluation-{split}.json")
    if problem:
        raise RunError(problem)
    d = load_splits(data, (split,))[split]
    if not 0 <= traj < d.x.shape[0]:
        raise RunError(f"--traj {traj} is out of range; {d.path} has {d.x.shape[0]} trajectories")
    refs = []
    for name, kw in [("constant-twist", {}), *references]:
        cls = get_model(name)
        if cls.learned:
            raise RunError(f"{name!r} is a learned model, not a reference; train it and pass its run folder")
        refs.append(evaluate_reference(cls(cls.Config(**kw)), d, dev)[0])
    reps, rolls = [], []
    for run in runs:
        rep, r = evaluate_run(run, d, dev, compile_mode=compile_mode)
        reps.append(rep)
        rolls.append(r)
    report = {
        "units": {"mse_tN": "m^2, position MSE over moving nodes and x, y, z at time step N (t = 1: first frame)",
                  "mse_tN_velocity": "m^2/s^2", "one_step_mse_scaled": "dimensionless, the model's one-step loss",
                  "divergence": f"NaN, or position MSE > {DIVERGENCE_FACTOR:g} x position variance of the split",
                  "ms_per_frame": "ms of model.step per frame for all trajectories at once (batched)"},
        "split": split,
        "aggregate": aggregate(reps),
        "reference": refs[0],
        "references": refs,
        "runs": reps,
        "status": "diverged" if any(r["diverged"] for r in reps) else "ok",
    }
    for key in ("mse_t40", "mse_t110", "mse_t40_velocity", "mse_t110_velocity"):
        report[key] = report["aggregate"][key]["mean"]
    stem = json_path.with_suffix("")
    report["plots"] = {"rollout_mse": str(stem.with_name(stem.name + "-rollout-mse.png")),
                       "trajectory": str(stem.with_name(stem.name + "-trajectory.png"))}
    plot_rollout_mse(reps, refs, d.x.shape[0], Path(report["plots"]["rollout_mse"]))
    plot_trajectory(rolls[0], d, traj, Path(report["plots"]["trajectory"]))
    atomic_json(report, json_path)
    report["json"] = str(json_path)
    return report

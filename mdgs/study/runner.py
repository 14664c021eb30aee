"""The resumable study runner: expands a study into cells, runs each, appends one line per finished cell.

Cells (each has a stable ``key``, a hash of everything that decides its result):

- ``learned``: train one model of the registry with one seed on one scene (the study's
  budget; resumable), then evaluate it on the scene's test set, its test variants and the long
  test set;
- ``reference``: a non-learned model (constant twist; MuJoCo at each ``dt_factor``) on the same sets;
- ``sensitivity``: MuJoCo at the data's own timestep from initial velocities perturbed by the
  study's ``sensitivity`` (one cell per perturbation seed), on the test set and the long test set:
  the floor below which no model's error, and no model's stability, can be told from chaos
  (revision 1 of these cells added the long set);
- ``resolution``: the resolution model (MDGS) trained on data partitioned ``refine`` times finer.

Layout of the output folder ``OUT``: ``study.json`` (which study it holds), ``data/<scene>[-r<k>]``
and ``data/<scene>-long`` (datasets, made by :mod:`mdgs.data.generate`, resumable),
``runs/<cell key>`` (run folders), ``results.jsonl`` (or ``results-I-of-N.jsonl`` for a share of
the grid). A line is appended only when its cell is finished, in one ``write`` of the whole
line followed by ``fsync``, so ``kill -9`` at any moment loses at most the cell in flight; a
rerun skips cells whose key is already in a results file, repairs a torn last line, and
resumes the cell in flight from its run folder (training resumes from its last epoch).
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import platform
import time
import warnings
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, fields, replace
from importlib import metadata
from pathlib import Path

import numpy as np
import torch

from mdgs.actuation import FORWARD_DYNAMICS_REVISION, SOFT_CONTACT_REVISION
from mdgs.data.generate import GenerateConfig, generate
from mdgs.data.io import output_problem
from mdgs.data.split import SplitData, load_split
from mdgs.evaluate.cost import compiled_cost, step_cost
from mdgs.evaluate.metrics import REPORT_TIMES, frame_of
from mdgs.evaluate.physics import energy_error, hinge_anchors, joint_separation, rigidity_violation
from mdgs.evaluate.rollout import divergence_threshold, rollout, rollout_score
from mdgs.models import MODELS, ModelError, Simulator, one_step_error
from mdgs.partition import PartitionParams
from mdgs.runs import LOCK_NAME, FolderBusy, atomic_json, folder_lock, load_run, resolve_device
from mdgs.study.config import SceneEntry, StudyConfig, StudyError
from mdgs.train import TrainConfig, TrainingError, train

__all__ = ["Cell", "cells_of", "select_cells", "run_study", "recost_study", "read_results", "RESULTS_VERSION", "COSTS_NAME"]

#: Revision of the sensitivity cells: 1 evaluates them on the long test set too (the stability table's
#: chaos floor); lines of revision 0 (test set only) give way to these in :func:`read_results`.
SENSITIVITY_REVISION = 1
#: Version of the results line layout.
RESULTS_VERSION = 1
#: Frames of the curves stored per line are subsampled to at most this many points.
CURVE_POINTS = 240


@dataclass(frozen=True)
class Cell:
    """One unit of work of a study (see the module docstring)."""

    kind: str
    scene: SceneEntry
    model: str
    label: str
    settings: tuple = ()
    seed: int = 0
    refine: int = 1

    def spec(self, study: StudyConfig) -> dict:
        """Everything that decides this cell's result (hashed into :attr:`key`)."""
        d = {"kind": self.kind, "scene": asdict(self.scene), "model": self.model, "label": self.label,
             "settings": dict(self.settings), "seed": self.seed, "refine": self.refine,
             "preset": study.preset, "long_frames": study.long_frames,
             "long_trajectories": study.long_trajectories, "failure_factor": study.failure_factor}
        if study.trajectories:  # absent at the preset's count: keys of cells run before the setting existed hold
            d["trajectories"] = study.trajectories
        if MODELS[self.model].learned:  # select absent at "last", select_frames and ema at 0: earlier keys hold
            d["budget"] = {k: v for k, v in asdict(study.budget).items()
                           if not (k == "select" and v == "last") and not (k in ("select_frames", "ema") and not v)}
        revision = MODELS[self.model].revision + (FORWARD_DYNAMICS_REVISION if self.runs_forward_dynamics else 0)
        revision += SOFT_CONTACT_REVISION if self.runs_soft_contact else 0
        if revision:  # absent for revision 0: keys of cells run before revisions existed hold
            d["revision"] = revision
        if self.kind == "sensitivity":  # revision 1: also on the long set (earlier lines are superseded)
            d["revision"] = SENSITIVITY_REVISION
        return d

    def _setting(self, name: str):
        """The cell's value of the model setting ``name``: its row's, else the model config's default (None when
        the model has no such setting)."""
        s = dict(self.settings)
        if name in s:
            return s[name]
        f = {f.name: f for f in fields(MODELS[self.model].Config)}.get(name)
        return None if f is None else f.default

    @property
    def runs_forward_dynamics(self) -> bool:
        """Whether this cell steps :mod:`mdgs.actuation`'s forward dynamics (MDGS's "dynamics" prior, the
        rigid-tree references, GNS's tree prior): its revision then counts ``FORWARD_DYNAMICS_REVISION`` too."""
        return (self._setting("actuation") == "dynamics" or self._setting("dynamics") is True
                or self._setting("prior") == "tree")

    @property
    def runs_soft_contact(self) -> bool:
        """Whether this cell's forward dynamics uses MuJoCo's soft contact (``contact`` of the rigid-tree references,
        ``prior_contact`` of MDGS and GNS): its revision then counts ``SOFT_CONTACT_REVISION`` too."""
        return self.runs_forward_dynamics and "soft" in (self._setting("contact"), self._setting("prior_contact"))

    def key(self, study: StudyConfig) -> str:
        return hashlib.sha256(json.dumps(self.spec(study), sort_keys=True).encode()).hexdigest()[:16]


def cells_of(study: StudyConfig) -> list[Cell]:
    """The study's cells in run order: references first (cheap), then the learned cells model by model
    (in the study file's order: put cheap models first), each over all seeds and scenes, so a study
    stopped early has complete rows (every seed) for the models it reached."""
    out = []
    for sc in study.scenes:
        out += _reference_cells(study, sc)
        if study.sensitivity > 0:
            for s in study.sensitivity_seeds:
                out.append(Cell("sensitivity", sc, "mujoco", "sensitivity floor",
                                (("dt_factor", 1), ("noise_seed", s), ("velocity_noise", study.sensitivity)), seed=s))
    for m in study.models:
        for seed in study.seeds:
            for sc in study.scenes:
                out.append(Cell("learned", sc, m.name, m.label, m.settings, seed))
    for r in study.resolution_refine:
        for seed in study.resolution_seeds:
            for sc in study.scenes:
                out.append(Cell("resolution", sc, study.resolution_model, f"{study.resolution_label} refine {r}",
                                study.resolution_settings, seed, r))
    # the references on each finer partition's own nodes (errors of two partitions differ), last: a
    # study that had run before they existed keeps every earlier cell at its index, so in its share
    for r in study.resolution_refine:
        for sc in study.scenes:
            out += _reference_cells(study, sc, r)
    return out


def _reference_cells(study: StudyConfig, sc: SceneEntry, refine: int = 1) -> list[Cell]:
    """The study's non-learned references on one scene partitioned ``refine`` times finer: constant
    twist (with the motor and joint variants the study asks for) and MuJoCo at each timestep factor.
    Position MSE averages over element centroids, so a finer partition's rows are compared with the
    references on its own nodes (labels end in ``" refine 2"`` etc.; refine 1 keeps the plain labels)."""
    tail = "" if refine == 1 else f" refine {refine}"
    specs = [("constant-twist", "constant twist", ())]
    if study.motor_twist:
        specs.append(("constant-twist", "constant twist + motors", (("motors", True),)))
    if study.joint_twist:
        specs.append(("constant-twist", "constant twist + joints", (("joints", True),)))
        if study.motor_twist:
            specs.append(("constant-twist", "constant twist + motors + joints", (("joints", True), ("motors", True))))
    if study.rigid_tree:
        specs.append(("constant-twist", "rigid tree + joints", (("dynamics", True), ("joints", True))))
    if study.rigid_tree_trapezoidal:
        specs.append(("constant-twist", "rigid tree + joints, trapezoidal",
                      (("dynamics", True), ("joints", True), ("trapezoidal", True))))
    if study.rigid_tree_push_out:
        specs.append(("constant-twist", "rigid tree + joints, trapezoidal, push-out",
                      (("dynamics", True), ("joints", True), ("push_out", True), ("trapezoidal", True))))
    if study.rigid_tree_substeps:  # the last rigid tree row in N substeps a frame
        _, last, settings = specs[-1]
        specs += [("constant-twist", f"{last}, {n} substeps", tuple(sorted(settings + (("substeps", n),))))
                  for n in study.rigid_tree_substeps]
    if study.rigid_tree_gyroscopic:  # the last rigid tree row with its gyroscopic terms later in each step
        _, last, settings = specs[-1]
        specs += [("constant-twist", f"{last}, {g} gyroscopic", tuple(sorted(settings + (("gyroscopic", g),))))
                  for g in study.rigid_tree_gyroscopic]
    if study.rigid_tree_momentum:  # the last rigid tree row with its twists projected onto the joints by impulses
        _, last, settings = specs[-1]
        specs.append(("constant-twist", f"{last}, momentum projection",
                      tuple(sorted(settings + (("joint_velocities", "momentum"),)))))
    if study.rigid_tree_coordinates:  # the last rigid tree row (before the momentum one) stepped in joint coordinates
        _, last, settings = next(s for s in reversed(specs) if ("joint_velocities", "momentum") not in s[2])
        specs.append(("constant-twist", f"{last}, joint coordinates",
                      tuple(sorted(settings + (("joint_velocities", "coordinates"),)))))
    if study.rigid_tree_soft:  # the last rigid tree row (not the momentum one) with soft contact instead of push-out
        _, last, settings = next(s for s in reversed(specs) if ("joint_velocities", "momentum") not in s[2])
        specs.append(("constant-twist", last.replace(", push-out", "") + ", soft contact",
                      tuple(sorted([kv for kv in settings if kv[0] != "push_out"] + [("contact", "soft")]))))
    specs += [("mujoco", f"mujoco dt x{k}", (("dt_factor", k),)) for k in study.mujoco_dt_factors]
    return [Cell("reference", sc, model, label + tail, settings, refine=refine) for model, label, settings in specs]


# --------------------------------------------------------------------------- data

#: Seconds between looks at a dataset that another share of the study is generating.
DATA_WAIT_SECONDS = 2.0


def _dataset(study: StudyConfig, out: Path, sc: SceneEntry, refine: int = 1, long: bool = False,
             variant: str | None = None, valid_frames: int = 0) -> Path:
    """Generate (or find) a dataset of the study; returns its folder. ``long``: the long test set (the
    test split's starting states run for ``long_frames``); ``valid_frames``: the validation split's
    starting states run for that many frames (``[budget] select_frames``), ``long_trajectories`` of
    each. A scene whose control schedule spans the trajectory (the Cubli's brake commands) draws its
    controls over the longer horizon, so only the starting states are the short splits' own."""
    name = variant or sc.name
    folder = out / "data" / (name + (f"-r{refine}" if refine != 1 else "") + ("-long" if long else "")
                             + (f"-valid{valid_frames}" if valid_frames else ""))
    kw = {"n_traj": study.trajectories} if study.trajectories else {}
    if long:
        kw = {"n_frames": study.long_frames, "splits": ("test",), "n_traj": study.long_trajectories}
    if valid_frames:
        kw = {"n_frames": valid_frames, "splits": ("valid",), "n_traj": study.long_trajectories}
    cfg = GenerateConfig(scene="" if sc.mjcf else name, out=str(folder), preset=study.preset, mjcf=sc.mjcf,
                         substeps=sc.substeps, partition=PartitionParams(refine=refine), **kw)
    if variant:
        cfg = GenerateConfig(scene=variant, out=str(folder), preset=study.preset, n_traj=study.trajectories or None)
    while True:  # one process generates a dataset; another share that needs it waits (no duplicated work,
        # and no share removing the parts folder while the other still writes into it)
        try:
            with folder_lock(folder.parent, f"mdgs study {study.name}: generating {folder.name}",
                             name=f"{LOCK_NAME}-data-{folder.name}"):
                res = generate(cfg)
            break
        except FolderBusy:
            time.sleep(DATA_WAIT_SECONDS)
    if not res.merged:
        raise StudyError(f"dataset {folder} is incomplete (another process is generating it?); rerun the study")
    return folder


# --------------------------------------------------------------------------- metrics

def _subsample(curve: np.ndarray) -> tuple[list[int], list]:
    F = len(curve)
    idx = np.unique(np.linspace(0, F - 1, min(F, CURVE_POINTS)).astype(int))
    return idx.tolist(), [None if not np.isfinite(c) else float(c) for c in curve[idx]]


def _per_traj_at(r, t: int) -> list:
    f = frame_of(t, r.pos_mse.shape[1])
    return [None if not np.isfinite(e) else float(e) for e in r.pos_mse[:, f]]


def _evaluate_set(model: Simulator, d: SplitData, dev, failure_factor: float, anchors, long: bool) -> dict:
    """Rollout metrics of one set: per-trajectory MSE at the report times (None = diverged), curves,
    and on the long set the stability figures (fraction within the failure threshold, time to failure)."""
    r = rollout(model, d, dev)
    T, F = r.pos_mse.shape
    rep = {"trajectories": T, "frames": F, "divergence_threshold_m2": r.threshold,
           "diverged_at": r.diverged_at.tolist(), "ms_per_frame_batched": r.ms_per_frame,
           "ms_per_trajectory_frame_batched": r.ms_per_trajectory_frame, "batch": T}
    if not long:
        for t in REPORT_TIMES:
            rep[f"pos_mse_t{t}"] = _per_traj_at(r, t)
            f = frame_of(t, F)
            rep[f"vel_mse_t{t}"] = [None if not np.isfinite(e) else float(e) for e in r.vel_mse[:, f]]
        with warnings.catch_warnings():  # frames where every trajectory has diverged: NaN, said as None
            warnings.simplefilter("ignore", RuntimeWarning)
            idx, curve = _subsample(np.nanmean(np.where(np.isfinite(r.pos_mse), r.pos_mse, np.nan), 0))
        rep["curve_frames"], rep["pos_mse_curve"] = idx, curve
        return rep
    # stability: failure = position MSE above failure_factor x the split's position variance
    thr = failure_factor * divergence_threshold(d) / 100.0
    err = np.where(np.isfinite(r.pos_mse), r.pos_mse, np.inf)
    failed = np.maximum.accumulate(err > thr, axis=1)
    ttf = [int(np.argmax(row)) if row.any() else None for row in failed]
    x, v = r.x.astype(np.float64), r.v.astype(np.float64)
    alive = ~failed
    g = np.asarray(d.attrs["gravity"], float)

    def masked_mean(a):
        with np.errstate(invalid="ignore"):
            m = np.where(alive, a, np.nan)
            return np.array([np.nanmean(c) if np.isfinite(c).any() else np.nan for c in m.T])

    idx, within = _subsample(alive.mean(0))
    rep.update({
        "failure_threshold_m2": thr, "time_to_failure": ttf, "curve_frames": idx, "fraction_within": within,
        "energy_error_J": _subsample(masked_mean(energy_error(x, v, d.x, d.v, d.static, g)))[1],
        "rigidity_violation_m": _subsample(masked_mean(rigidity_violation(x, d.static)))[1],
        "joint_separation_m": _subsample(masked_mean(joint_separation(x, d.static, anchors)))[1],
        "joint_separation_max_m": float(np.nanmax(np.where(alive, joint_separation(x, d.static, anchors), np.nan)))
        if alive.any() else None,
    })
    return rep


def _versions() -> dict:
    out = {"python": platform.python_version()}
    for pkg in ("torch", "mujoco", "numpy", "mdgs"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    return out


def _fingerprint(folder: Path, split: str) -> str:
    import h5py

    with h5py.File(folder / f"{split}.h5", "r") as f:
        return str(f.attrs["config_sha256"])


# --------------------------------------------------------------------------- cells

class CellBusy(Exception):
    """The run a cell evaluates is being trained by another share of the study (``wait=False``)."""


def run_cell(study: StudyConfig, out: Path, cell: Cell, progress: Callable[[dict], None],
             wait: bool = True) -> dict:
    """Run one cell -> its results line (a dict).

    A cell that cannot run is still a finished cell with a line saying why, never a crash of the
    study: ``status`` is ``ok``, ``not applicable`` (the model refuses the scene or setting, e.g. a
    MuJoCo timestep factor that does not divide the data's substeps), ``failed`` (training
    diverged: the model counts as failed on every trajectory of the cell) or ``error`` (an
    unexpected exception, i.e. a bug: the line keeps its message and the last traceback lines,
    the report lists it, and a rerun retries the cell). ``wait=False``: raise :class:`CellBusy`
    instead of waiting while another share trains the cell's run (a twin cell, e.g. ``sgnn-snap``
    of ``sgnn``), so the share can run other cells meanwhile.
    """
    t0 = time.perf_counter()
    try:
        return _run_cell(study, out, cell, progress, t0, wait)
    except ModelError as e:
        status, reason = "not applicable", str(e)
    except TrainingError as e:
        status, reason = "failed", str(e)
    except (KeyboardInterrupt, StudyError, CellBusy):
        raise
    except Exception as e:  # noqa: BLE001 - a bug in one cell must not stop a study of hundreds
        import traceback

        status = "error"
        reason = f"{type(e).__name__}: {e}; " + " | ".join(traceback.format_exc().strip().splitlines()[-4:])
    return {"version": RESULTS_VERSION, "study": study.name, "cell": cell.key(study), **cell.spec(study),
            "scene": cell.scene.name, "status": status, "reason": reason, "sets": {}, "versions": _versions(),
            "wall_seconds": time.perf_counter() - t0}


def _run_cell(study: StudyConfig, out: Path, cell: Cell, progress, t0: float, wait: bool = True) -> dict:
    dev = resolve_device(study.device)
    data = _dataset(study, out, cell.scene, cell.refine)
    test = load_split(data / "test.h5")
    line = {"version": RESULTS_VERSION, "study": study.name, "cell": cell.key(study), **cell.spec(study),
            "scene": cell.scene.name, "status": "ok", "data_fingerprint": _fingerprint(data, "test")}
    model, train_info = _cell_model(study, out, cell, data, dev, progress, wait)
    if train_info:
        line["one_step_mse"] = one_step_error(model, test, dev)
    line["parameters"] = model.parameter_count()
    line["train"] = train_info
    anchors = hinge_anchors(test.mj_model())
    progress({"kind": "evaluate", "set": "test"})
    sets = {"test": _evaluate_set(model, test, dev, study.failure_factor, anchors, False)}
    if cell.kind in ("learned", "reference") and cell.refine == 1:  # the variants exist on the default partition
        for v in cell.scene.variants:
            vd = load_split(_dataset(study, out, cell.scene, variant=v) / "test.h5")
            progress({"kind": "evaluate", "set": v})
            sets[v] = _evaluate_set(model, vd, dev, study.failure_factor, anchors, False)
    if cell.kind in ("learned", "reference", "sensitivity", "resolution") and study.long_frames:
        ld = load_split(_dataset(study, out, cell.scene, cell.refine, long=True) / "test.h5")
        progress({"kind": "evaluate", "set": "long"})
        sets["long"] = _evaluate_set(model, ld, dev, study.failure_factor, anchors, True)
    line["sets"] = sets
    line["cost"] = {"single": step_cost(model, test, batch=1), "batched": step_cost(model, test, batch=test.x.shape[0])}
    line["versions"] = _versions()
    line["wall_seconds"] = time.perf_counter() - t0
    return line


def _cell_model(study: StudyConfig, out: Path, cell: Cell, data: Path, dev, progress,
                wait: bool = True, trained: bool = False) -> tuple[Simulator, dict]:
    """The model a cell evaluates and what its training did (``{}`` for a model that does not learn):
    a learned cell trains its run (or resumes it, or finds it finished; a twin such as ``sgnn-snap``
    loads its trainee's weights), a reference is built from the test split. ``trained``: the cell has
    finished, load its run's weights as they are (the code may have moved on since it trained)."""
    cls = MODELS[cell.model]
    if not cls.learned:
        test = load_split(data / "test.h5")
        return MODELS[cell.model].from_data(test, MODELS[cell.model].Config(**dict(cell.settings))).to(dev), {}
    trainee = _training_cell(study, cell)
    run = out / "runs" / trainee.key(study)
    b = study.budget
    tcls = MODELS[trainee.model]
    sel = (str(_dataset(study, out, cell.scene, cell.refine, valid_frames=b.select_frames))
           if b.select_frames and not trained else "")
    cfg = TrainConfig(data=str(data), out=str(run), model_name=trainee.model, epochs=b.epochs,
                      batch_size=b.batch_size, seed=cell.seed, device=study.device, max_steps=b.max_steps,
                      valid_max_pairs=b.valid_max_pairs, select=b.select, select_data=sel, ema=b.ema,
                      model=tcls.Config(**dict(cell.settings)))
    t1 = time.perf_counter()
    if not trained:
        _train_or_wait(cfg, progress, wait)
    model, state = load_run(run, dev)
    if trainee is not cell:
        model = cls.from_trained(model)
    hist = state["history"]
    train_info = {"epochs": len(hist), "steps": int(sum(h["steps"] for h in hist)),
                  "train_seconds": float(sum(h["train_seconds"] for h in hist)),
                  "wall_seconds_this_run": time.perf_counter() - t1,
                  "valid_mse_last": hist[-1]["valid_mse"] if hist else None}
    if b.select != "last":  # which epoch's weights this cell evaluates
        train_info["select"], train_info["evaluated_epoch"] = b.select, state["evaluated_epoch"]
        if b.select_frames:
            train_info["select_frames"] = b.select_frames
    if b.ema:
        train_info["ema"] = b.ema
    if trainee is not cell:
        train_info["trained_as"] = {"model": trainee.model, "cell": trainee.key(study)}
    return model, train_info


def _training_cell(study: StudyConfig, cell: Cell) -> Cell:
    """The cell whose run trains ``cell``'s weights: ``cell`` itself, or for a model that trains as
    another (:attr:`~mdgs.models.base.Simulator.trains_as`, e.g. ``sgnn-snap``) the study's cell of
    that model with the same scene, seed and settings (trained once, evaluated as both), or a cell
    of its own if the study has no such cell."""
    name = MODELS[cell.model].trains_as
    if name is None:
        return cell
    for c in cells_of(study):
        if (c.kind == cell.kind and c.model == name and c.scene == cell.scene and c.seed == cell.seed
                and c.settings == cell.settings and c.refine == cell.refine):
            return c
    return replace(cell, model=name, label=f"{cell.label} (trained as {name})")


#: Seconds between looks at a run folder that another share of the study is training.
WAIT_SECONDS = 30.0


def _train_or_wait(cfg: TrainConfig, progress, wait: bool = True) -> None:
    """Train (or resume, or find finished) the run ``cfg.out``; while another process holds its lock
    (a twin cell in another share), wait for it rather than train the same weights twice, or with
    ``wait=False`` raise :class:`CellBusy` at once."""
    while True:
        try:
            train(cfg, progress=lambda e: progress({"kind": "train", **e}), score=rollout_score)
            return
        except FolderBusy:
            if not wait:
                raise CellBusy(cfg.out) from None
            progress({"kind": "wait", "run": cfg.out})
            time.sleep(WAIT_SECONDS)


# --------------------------------------------------------------------------- results file

def _results_path(out: Path, share: tuple[int, int], tag: str = "") -> Path:
    """``results.jsonl``, ``results-I-of-N.jsonl`` for a share, ``results-<tag>[-I-of-N].jsonl`` for a
    selection of cells (``--only``): every process appends to a file of its own."""
    i, n = share
    return out / ("results" + (f"-{tag}" if tag else "") + ("" if n == 1 else f"-{i}-of-{n}") + ".jsonl")


def _selection_tag(only) -> str:
    """A file-name tag for a selection of cells (``only-`` and a hash of the names; "" for none)."""
    if not only:
        return ""
    return "only-" + hashlib.sha256(json.dumps(sorted(set(only))).encode()).hexdigest()[:8]


def read_results(out: str | os.PathLike, usable: bool = False) -> list[dict]:
    """Every finished line of every results file in ``out`` (torn last lines ignored), one per cell;
    ``usable``: only the cells that ran (``status`` ok) or failed (they count as failed rows)."""
    out = Path(out)
    lines, seen = [], set()
    for p in sorted(out.glob("results*.jsonl")):
        for raw in p.read_text(encoding="utf-8").splitlines():
            try:
                rec = json.loads(raw)
            except json.JSONDecodeError:
                continue  # a torn last line of a killed run
            key = rec.get("cell")
            if key in seen and rec.get("status") != "error":  # a retried cell replaces its error line
                lines = [ln for ln in lines if not (ln.get("cell") == key and ln.get("status") == "error")]
                seen.discard(key)
            if key not in seen:
                seen.add(key)
                lines.append(rec)
    lines = _newest_revisions(lines)
    _merge_costs(out, lines)
    if usable:
        lines = [ln for ln in lines if ln.get("status", "ok") in ("ok", "failed")]
    return lines


def _newest_revisions(lines: list[dict]) -> list[dict]:
    """Keep, for each table row (a cell's identity but for ``seed`` and ``revision``, absent for 0),
    only the lines of the newest revision present: a row being rerun after a revision bump shows
    the seeds rerun so far, never a mean over seeds of two versions of the model."""
    def ident(ln):
        return json.dumps({k: v for k, v in ln.items() if k in _SPEC_KEYS and k != "seed"}, sort_keys=True)

    newest: dict[str, int] = {}
    for ln in lines:
        newest[ident(ln)] = max(newest.get(ident(ln), 0), int(ln.get("revision", 0)))
    return [ln for ln in lines if int(ln.get("revision", 0)) == newest[ident(ln)]]


#: The keys of :meth:`Cell.spec` but ``revision``: what makes two results lines the same cell.
_SPEC_KEYS = ("kind", "scene", "model", "label", "settings", "seed", "refine", "preset", "trajectories",
              "long_frames", "long_trajectories", "failure_factor", "budget")


def _row(ln: dict) -> str:
    """A results line's table row: its cell's identity but for ``seed`` (``revision`` included)."""
    return json.dumps({k: v for k, v in ln.items() if k in _SPEC_KEYS + ("revision",) and k != "seed"},
                      sort_keys=True)


#: The file of ``mdgs study --recost`` in a study folder: one line per row measured.
COSTS_NAME = "costs.jsonl"


def _merge_costs(out: Path, lines: list[dict]) -> None:
    """Give every line of a row that ``--recost`` measured (``OUT/costs.jsonl``, its last line for the
    row) that measurement as ``cost``; the cost its cell measured while the study ran moves to
    ``cost_in_run``."""
    path = out / COSTS_NAME
    if not path.exists():
        return
    costs = {}
    for raw in path.read_text(encoding="utf-8").splitlines():
        try:
            rec = json.loads(raw)
        except json.JSONDecodeError:
            continue  # a torn last line
        costs[rec["row"]] = rec
    for ln in lines:
        rec = costs.get(_row(ln)) if ln.get("status", "ok") == "ok" else None
        if rec is not None:
            ln["cost_in_run"] = ln["cost"]
            ln["cost"] = {"single": rec["single"], "batched": rec["batched"], "compiled": rec["compiled"],
                          "requested": rec["requested"], "recost": True}


def _repair(path: Path) -> None:
    """Cut a torn last line (a kill during the write) so the next append starts on a fresh line."""
    if not path.exists():
        return
    raw = path.read_bytes()
    if raw and not raw.endswith(b"\n"):
        cut = raw.rfind(b"\n") + 1
        with open(path, "r+b") as f:
            f.truncate(cut)


def _append(path: Path, rec: dict) -> None:
    data = (json.dumps(rec, sort_keys=True) + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, data)
        os.fsync(fd)
    finally:
        os.close(fd)


def _check_folder(study: StudyConfig, out: Path) -> None:
    """Check, writing nothing, that ``out`` can hold this study: new, empty, or holding this study."""
    marker = out / "study.json"
    problem = output_problem(out, "--out")
    if problem:
        raise StudyError(problem)
    if marker.exists():
        try:
            theirs = json.loads(marker.read_text(encoding="utf-8"))
        except ValueError:  # not JSON, not UTF-8
            theirs = {}
        if not isinstance(theirs, dict):
            theirs = {}
        if theirs.get("name") != study.name:
            raise StudyError(f"{out} holds results of study {theirs.get('name')!r}, not {study.name!r}; "
                             "choose another --out")
        return
    # a folder holding only data/ (e.g. a symlink to another study's datasets, to reuse them) can host one
    if out.exists() and any(not p.name.startswith(LOCK_NAME) and p.name != "data" for p in out.iterdir()):
        raise StudyError(f"{out} is not empty and holds no study; choose an empty or new folder for --out "
                         "(one holding only a data/ folder of datasets to reuse is fine)")


def _claim_folder(study: StudyConfig, out: Path) -> None:
    """Mark ``out`` (created and locked by the caller) as holding this study."""
    marker = out / "study.json"
    if not marker.exists():
        atomic_json({"name": study.name, "path": study.path, "fingerprint": study.fingerprint()}, marker)


def select_cells(study: StudyConfig, only: tuple[str, ...] | list[str] = ()) -> list[Cell]:
    """The cells of :func:`cells_of` whose row label or scene is named in ``only`` (all cells if empty).

    Each name is a row label (``"sgnn"``, ``"mdgs + motor prior"``, ``"mujoco dt x10"``, ``"constant
    twist"``, ``"sensitivity floor"``, ``"mdgs refine 2"``) or a scene name; a cell is kept when its
    label is among the labels named (or none is named) and its scene among the scenes named (or none
    is). A name that is neither raises :class:`StudyError` listing both. Cell keys do not depend on the
    selection, so cells run under one selection are finished for every other and for the whole study.
    """
    cells = cells_of(study)
    if not only:
        return cells
    labels = list(dict.fromkeys(c.label for c in cells))
    scenes = [sc.name for sc in study.scenes]
    unknown = [o for o in only if o not in labels and o not in scenes]
    if unknown:
        raise StudyError(f"{study.path}: --only {', '.join(map(repr, unknown))} names no row or scene of "
                         f"study {study.name!r}; rows: {', '.join(labels)}; scenes: {', '.join(scenes)}")
    want_l = {o for o in only if o in labels}
    want_s = {o for o in only if o in scenes}
    return [c for c in cells if (not want_l or c.label in want_l) and (not want_s or c.scene.name in want_s)]


def run_study(study: StudyConfig, out: str | os.PathLike, share: tuple[int, int] = (0, 1),
              progress: Callable[[dict], None] | None = None, only: tuple[str, ...] | list[str] = ()) -> dict:
    """Run this process's share of the study's cells; returns counts ``{"cells", "done", "ran"}``.

    ``only``: run just the cells of these rows or scenes (:func:`select_cells`), shared out among the
    ``N`` of ``share`` after selecting them. Other cells already in ``out`` stay, and the tables are
    drawn from everything finished."""
    progress = progress or (lambda e: None)
    out = Path(out)
    cells = select_cells(study, only)
    _check_folder(study, out)
    i, n = share
    # one process per share (of one selection) of a study folder; each cell has its own lock as well
    tag = _selection_tag(only)
    with folder_lock(out, f"mdgs study {study.name} (cells {i}/{n}{' of ' + ', '.join(only) if only else ''})",
                     name=LOCK_NAME + (f"-{tag}" if tag else "") + ("" if n == 1 else f"-{i}-of-{n}")):
        _claim_folder(study, out)
        return _run_share(study, out, share, progress, cells, _results_path(out, share, tag))


def recost_study(study: StudyConfig, out: str | os.PathLike, mode: str = "aot",
                 progress: Callable[[dict], None] | None = None) -> dict:
    """Measure the cost of every row of the study's finished cells again, in one pass, with the step
    compiled by ``mode`` (:func:`mdgs.evaluate.cost.compiled_cost`; "none": eager), into
    ``OUT/costs.jsonl``; the tables and charts then use these figures (:func:`read_results`).

    One cell per row is measured (its lowest seed: the seeds of a row share the architecture and
    the scene, so their step does the same work), on the test split the row was evaluated on, one
    row after another, each in a process of its own: run it on an otherwise idle machine, and every cost of the
    chart is measured alike, which costs taken while the study's cells trained beside each other
    are not. Resumable: a row already measured in ``mode`` is skipped (a row measured in another
    mode is measured again, and the newer line counts). Each row is timed in a process of its own; a
    row that cannot be timed is skipped (a rerun retries it) and named in the result. Returns
    ``{"rows", "measured", "failed"}``."""
    progress = progress or (lambda e: None)
    out = Path(out)
    _check_folder(study, out)
    if not (out / "study.json").exists():
        raise StudyError(f"{out} holds no study yet; run `mdgs study {study.path} --out {out}` first")
    cells = {c.key(study): c for c in cells_of(study)}
    rows: dict = {}
    for ln in sorted(read_results(out, usable=True), key=lambda ln: ln["seed"]):
        if ln.get("status", "ok") == "ok" and ln["kind"] != "sensitivity" and ln["cell"] in cells:
            rows.setdefault(_row(ln), ln)
    path = out / COSTS_NAME
    with folder_lock(out, f"mdgs study {study.name} --recost", name=f"{LOCK_NAME}-recost"):
        _repair(path)
        done = set()
        if path.exists():
            for raw in path.read_text(encoding="utf-8").splitlines():
                try:
                    rec = json.loads(raw)
                except json.JSONDecodeError:
                    continue
                if rec.get("requested") == mode:
                    done.add(rec["row"])
        todo = [(r, ln) for r, ln in rows.items() if r not in done]
        progress({"kind": "plan", "cells": len(rows), "todo": len(todo)})
        failed = []
        for k, (r, ln) in enumerate(todo):
            cell = cells[ln["cell"]]
            label = f"{cell.scene.name} {cell.label} (seed {cell.seed})"
            progress({"kind": "cell", "index": k, "total": len(todo), "label": label})
            if MODELS[cell.model].learned:
                run = out / "runs" / _training_cell(study, cell).key(study)
                if not (run / "checkpoint.pt").exists():  # a results line whose weights are not here
                    failed.append(f"{label}: its weights are not in {run} (a results line copied without its "
                                  f"run folder?); recost in the folder that trained it, or delete the line "
                                  f"and rerun the study to train it again")
                    progress({"kind": "row failed", "label": label, "reason": failed[-1]})
                    continue
            # each row in a fresh process: a compiler that fails half-way (an energy model's autograd
            # step under torch.compile) can leave torch's tracing state broken for every later export
            # in that process; and no row's timing inherits another's caches
            try:
                with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
                    cost = pool.submit(_time_row, study.path, str(out), ln["cell"], mode,
                                       torch.get_num_threads()).result()
            except Exception as e:  # noqa: BLE001 - one row that cannot be timed must not stop the others
                failed.append(f"{label}: {type(e).__name__}: {str(e)[:200]} (rerun to retry)")
                progress({"kind": "row failed", "label": label, "reason": failed[-1]})
                continue
            _append(path, {"row": r, "cell": ln["cell"], "scene": ln["scene"], "label": ln["label"],
                           "kind": ln["kind"], **cost, "versions": _versions(),
                           "measured": time.strftime("%Y-%m-%dT%H:%M:%S")})
    return {"rows": len(rows), "measured": len(todo) - len(failed), "failed": failed}


def _time_row(study_file: str, out: str, key: str, mode: str, threads: int) -> dict:
    """:func:`~mdgs.evaluate.cost.compiled_cost` of the finished cell ``key`` (run in a process of its own)."""
    from mdgs.study.config import load_study

    torch.set_num_threads(threads)
    study = load_study(study_file)
    cell = {c.key(study): c for c in cells_of(study)}[key]
    data = _dataset(study, Path(out), cell.scene, cell.refine)
    model, _ = _cell_model(study, Path(out), cell, data, resolve_device(study.device), lambda e: None, trained=True)
    return compiled_cost(model, load_split(data / "test.h5"), mode)


def _finished(out: Path) -> set[str]:
    """Keys of the cells some results file of ``out`` holds (an ``error`` line is retried, not finished)."""
    return {r["cell"] for r in read_results(out) if r.get("status") != "error"}


def _run_share(study: StudyConfig, out: Path, share: tuple[int, int], progress, cells: list[Cell],
               path: Path) -> dict:
    """Run the share's unfinished cells in study order. Each cell is run under its own lock
    (``OUT/.lock-cell-<key>``) after a fresh look at the results files, so processes whose shares
    overlap (``--cells 1/2`` beside ``--cells 3/4``, a job array resubmitted with another N) never run
    a cell twice; a cell that another process holds, or whose run another process is training, goes
    to the back of the queue, and the last cell left waits for it."""
    _repair(path)
    i, n = share
    mine = [c for k, c in enumerate(cells) if k % n == i]
    done0 = _finished(out)
    todo = [c for c in mine if c.key(study) not in done0]
    progress({"kind": "plan", "cells": len(mine), "todo": len(todo)})
    torch.set_num_threads(max(1, torch.get_num_threads()))
    pending, ran, elsewhere = list(todo), 0, 0
    while pending:
        cell = pending.pop(0)
        key = cell.key(study)
        try:
            with folder_lock(out, f"mdgs study {study.name} cell {key}", name=f"{LOCK_NAME}-cell-{key}"):
                if key in _finished(out):  # another process finished it meanwhile
                    elsewhere += 1
                    continue
                progress({"kind": "cell", "index": ran + elsewhere, "total": len(todo),
                          "label": f"{cell.scene.name} {cell.label} seed {cell.seed}"
                                   + (f" refine {cell.refine}" if cell.refine != 1 else "")})
                line = run_cell(study, out, cell, progress, wait=not pending)  # the last one left waits
                _append(path, line)
                ran += 1
        except (CellBusy, FolderBusy):  # its run, or the cell itself, is another process's now
            progress({"kind": "defer", "label": cell.label})
            if not pending:
                time.sleep(WAIT_SECONDS)
            pending.append(cell)
    return {"cells": len(mine), "done": len(mine) - len(todo) + elsewhere, "ran": ran}

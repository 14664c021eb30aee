"""The training loop, generic over the Simulator contract: batches, noise, named losses, resume.

Each epoch is one pass over all (trajectory, frame) training pairs in an order drawn from a
generator seeded by ``(seed, epoch)``; each batch is perturbed by the model's own noise
recipe (:meth:`~mdgs.models.base.Simulator.perturb`, its torch generator seeded from the same
stream), its named losses (:meth:`~mdgs.models.base.Simulator.losses`) are summed with the
model's weights, and the model's optimiser steps. After every epoch the one-step validation
error (:meth:`~mdgs.models.base.Simulator.validation_error`) drives the model's scheduler, and
the checkpoint, metrics and step log are written atomically (:mod:`mdgs.runs`). With
``select`` other than ``"last"`` the weights of the best epoch so far by that rule are kept in
the checkpoint too, and :func:`mdgs.runs.load_run` evaluates those.

Running the same ``mdgs train`` command again resumes from the last finished epoch; since the
random stream of epoch ``e`` depends only on ``(seed, e)``, a resumed run continues exactly as
an uninterrupted one would (up to floating-point nondeterminism of the device).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import MISSING, asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mdgs.data.io import output_problem
from mdgs.data.schema import DatasetError
from mdgs.data.split import SplitData, load_splits
from mdgs.models import ModelError, batch_of, get_model, one_step_error
from mdgs.runs import (
    RunError,
    atomic_json,
    folder_lock,
    read_checkpoint,
    resolve_device,
    write_checkpoint,
)
from mdgs.train.distributed import setup, teardown

__all__ = ["TrainConfig", "TrainingError", "train"]


class _Losses(torch.nn.Module):
    """``forward(batch) = model.losses(batch)``: what DistributedDataParallel wraps (it hooks forward)."""

    def __init__(self, model):
        super().__init__()
        self.model = model

    def forward(self, batch):
        return self.model.losses(batch)


class TrainingError(RunError):
    """Training that cannot go on (a diverged loss); the message says what to change."""


#: Checkpoint selection rules of :attr:`TrainConfig.select`.
SELECT = ("last", "valid", "rollout", "rollout-or-start")
#: The score each rule minimises (a key of an epoch's record in ``history``).
SELECT_KEY = {"valid": "valid_mse", "rollout": "valid_rollout", "rollout-or-start": "valid_rollout"}


@dataclass
class TrainConfig:
    """Training run settings; every default documented here.

    Attributes
    ----------
    data
        folder with ``train.h5`` and ``valid.h5`` (``mdgs generate`` output).
    out
        run folder (:mod:`mdgs.runs`).
    model_name
        a key of :data:`mdgs.models.MODELS` (a learned model).
    epochs
        passes over all (trajectory, frame) training pairs.
    batch_size
        graphs per optimisation step.
    lr
        learning rate of the model's optimiser; ``None``: the model's own ``default_lr`` (MDGS, B.2:
        Adam 1e-3; GNS 1e-4).
    seed
        seeds parameter initialisation, batch order and noise.
    device
        "auto" (CUDA when present), "cpu" or "cuda".
    max_steps
        cap on optimisation steps per epoch (0: no cap, a full pass).
    valid_max_pairs
        cap on validation pairs per epoch (0: all; an even subsample otherwise).
    log_every
        steps between entries of ``steps.json``.
    select
        which epoch's weights the run keeps for evaluation: ``"last"`` (default; every study so
        far), ``"valid"`` (lowest one-step validation error) or ``"rollout"`` (lowest validation
        rollout score, :func:`mdgs.evaluate.rollout.rollout_score` passed to :func:`train`: position
        MSE over every frame of every validation trajectory, capped at the failure threshold), or
        ``"rollout-or-start"`` (the same, with the weights training started from as one more
        candidate, scored before the first step: the run keeps them, epoch ``-1``, when no epoch
        rolls out better; for a model that starts as a physical prior, e.g. MDGS's zero-initialised
        state network, "training did not help" is then a possible outcome, not a worse model). The
        same rule for every model of a comparison (``../shared/baselines.md``: best checkpoint on the
        validation split).
    select_data
        a folder whose ``valid.h5`` (trajectories of the same scene) the rollout rules score in place of
        ``data``'s validation split, e.g. the validation trajectories run ten times longer, so that the
        kept epoch is the one that rolls out best over the horizon of a stability test (a study's
        ``[budget] select_frames``; ``mdgs generate --split valid --frames N`` writes one). ``""``
        (default): ``data``'s own. The one-step validation error (scheduler, ``select="valid"``) always
        uses ``data``'s.
    ema
        decay of an exponential moving average of the weights (Polyak averaging, updated after every
        optimiser step: ``w_ema <- ema * w_ema + (1 - ema) * w``), 0 (default): off. With it the
        averaged weights are the model: validated (scheduler), scored and selected after each epoch,
        and evaluated; the optimiser trains its own weights as before. The window is about
        ``1 / (1 - ema)`` steps (0.99: the last ~100).
    model
        the model's config (``MODELS[model_name].Config``); ``None``: its defaults.
        Settings the model takes from data are filled by its ``resolve_config``.
    """

    data: str = "data"
    out: str = "runs/mdgs"
    model_name: str = "mdgs"
    epochs: int = 20
    batch_size: int = 32
    lr: float | None = None
    seed: int = 0
    device: str = "auto"
    max_steps: int = 0
    valid_max_pairs: int = 0
    log_every: int = 10
    select: str = "last"
    select_data: str = ""
    ema: float = 0.0
    model: Any = None

    def __post_init__(self):
        for name, lo in (("epochs", 1), ("batch_size", 1), ("max_steps", 0), ("valid_max_pairs", 0), ("log_every", 1)):
            val = getattr(self, name)
            if not isinstance(val, int) or val < lo:
                raise RunError(f"--{name.replace('_', '-')} {val} must be an integer of at least {lo}")
        if self.lr is not None and not (isinstance(self.lr, float | int) and np.isfinite(self.lr) and self.lr > 0):
            raise RunError(f"--lr {self.lr} must be a positive number")
        if self.select not in SELECT:
            raise RunError(f"--select {self.select!r} is not one of {', '.join(SELECT)}")
        if self.select_data and not self.select.startswith("rollout"):
            raise RunError(f"--select-data scores validation rollouts; it needs --select rollout or rollout-or-start, "
                           f"not {self.select!r}")
        if not (isinstance(self.ema, float | int) and 0 <= self.ema < 1):
            raise RunError(f"--ema {self.ema} must be a number from 0 (off) up to, not including, 1 (e.g. 0.99)")
        if not isinstance(self.seed, int) or not 0 <= self.seed < 2**63:
            raise RunError(f"--seed {self.seed} must be an integer from 0 to 2**63 - 1")


def _fingerprint(cfg: TrainConfig, model_cfg: dict) -> dict:
    """The settings that must agree for a resume (not epochs, step caps or device: a run may be extended)."""
    d = asdict(cfg) | {"model": model_cfg}
    for k in ("data", "out", "epochs", "device", "log_every", "max_steps", "valid_max_pairs", "select_data"):
        d.pop(k)
    return d


def _with_absent(old: dict, config_cls) -> dict:
    """A checkpoint's fingerprint with the model settings it predates filled in with what they meant then:
    ``Config.ABSENT`` where a setting changed behaviour, else its default (a setting that changes nothing
    unless asked for), so adding a setting to a model does not make every unfinished run unresumable."""
    if "model" not in old:
        return old
    absent = {f.name: f.default for f in fields(config_cls) if f.default is not MISSING}
    absent |= getattr(config_cls, "ABSENT", {})
    return {**old, "model": {**{k: v for k, v in absent.items() if k not in old["model"]}, **old["model"]}}


def _selected(history: list[dict], select: str, start_score: float | None = None) -> int:
    """The epoch whose weights the run keeps under rule ``select`` (the first of equal scores; ``-1``:
    the weights training started from, scored ``start_score``, under ``"rollout-or-start"``)."""
    if select == "last":
        return history[-1]["epoch"]
    key = SELECT_KEY[select]
    best = min(history, key=lambda r: r[key])
    if select == "rollout-or-start" and start_score is not None and start_score <= best[key]:
        return -1
    return best["epoch"]


def _averaged(model, decay: float):
    """The exponential moving average of ``model``'s weights (``TrainConfig.ema``; its buffers follow the
    model's), or None."""
    if not decay:
        return None
    from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn
    return AveragedModel(model, multi_avg_fn=get_ema_multi_avg_fn(decay))  # buffers follow the model


def starting_model(cls, mcfg, tr: SplitData, seed: int):
    """The model a run of ``cls`` with config ``mcfg`` and ``seed`` starts training from (its weights
    initialised under ``torch.manual_seed(seed)``, bound and fitted to the training split ``tr``)."""
    torch.manual_seed(seed)
    model = cls(mcfg)
    model.bind(tr)
    model.fit(tr)
    return model


def _load_splits(cfg: TrainConfig, splits: dict | None) -> tuple[SplitData, SplitData, SplitData]:
    """``(train, valid, scored)``: ``scored`` is the split the rollout rules score (``select_data``'s, else valid)."""
    if splits is None:
        splits = load_splits(cfg.data, ("train", "valid"))
    tr, va = splits["train"], splits["valid"]
    if tr.identity()["mjcf_sha256"] != va.identity()["mjcf_sha256"]:
        raise DatasetError(f"{va.path} is of another scene than {tr.path}; use the three files of one `mdgs generate` run")
    scored = va
    if cfg.select_data:
        if not (Path(cfg.select_data) / "valid.h5").is_file():
            raise DatasetError(f"--select-data {cfg.select_data} holds no valid.h5; write one with `mdgs generate "
                               f"SCENE --split valid --frames N --n-traj K --out {cfg.select_data}`")
        scored = load_splits(cfg.select_data, ("valid",))["valid"]
        if scored.identity()["mjcf_sha256"] != tr.identity()["mjcf_sha256"]:
            raise DatasetError(f"--select-data {cfg.select_data}: its valid.h5 is of another scene than {tr.path}; "
                               "generate it from the same scene (`mdgs generate --split valid --frames N`)")
    return tr, va, scored


def train(cfg: TrainConfig, progress: Callable[[dict], None] | None = None, splits: dict | None = None,
          score: Callable[[Any, SplitData, Any], float] | None = None) -> dict:
    """Train (or resume) the run ``cfg.out``; returns the last epoch's metrics.

    ``progress(event)`` is called with ``{"kind": "start"|"step"|"epoch", ...}``.
    ``splits`` (``{"train": SplitData, "valid": SplitData}``) bypasses the files.
    ``score(model, valid_split, device) -> float``: the validation rollout score that
    ``select="rollout"`` minimises (:func:`mdgs.evaluate.rollout.rollout_score`; passed in, since
    training and evaluation do not import each other; ``mdgs train`` and ``mdgs study`` pass it).
    Raises :class:`~mdgs.runs.RunError`, :class:`~mdgs.models.ModelError` or
    :class:`~mdgs.data.schema.DatasetError` for user errors, before anything is written.
    """
    progress = progress or (lambda e: None)
    cls = get_model(cfg.model_name)
    if not cls.learned:
        raise ModelError(f"model {cfg.model_name!r} is a non-learned reference with nothing to train; "
                         f"evaluate it directly with `mdgs evaluate --model {cfg.model_name} --data DIR`")
    if cfg.lr is None:
        cfg = replace(cfg, lr=cls.default_lr)
    if cfg.select.startswith("rollout") and score is None:
        raise RunError(f"select={cfg.select!r} needs the rollout score: call train(cfg, score=mdgs.evaluate.rollout.rollout_score)")
    problem = output_problem(cfg.out, "--out")
    if problem:  # before reading any data: a run that cannot be written fails at once
        raise RunError(problem)
    tr, va, scored = _load_splits(cfg, splits)
    dist_, device = setup(cfg.device)
    try:
        dev = resolve_device(device)
        # rank 0 writes the run folder; it holds the folder's lock, so no other process writes it too
        with folder_lock(cfg.out, f"mdgs train ({cfg.model_name})") if dist_.is_main else nullcontext():
            return _train(cfg, progress, tr, va, cls, dist_, dev, score, scored)
    finally:
        teardown(dist_)


def _train(cfg: TrainConfig, progress, tr: SplitData, va: SplitData, cls, dist_, dev, score=None,
           scored: SplitData | None = None) -> dict:
    scored = va if scored is None else scored
    out = Path(cfg.out)
    if not dist_.is_main:  # one progress report per job
        progress = lambda e: None  # noqa: E731
    if cfg.batch_size % dist_.world:
        raise RunError(f"--batch-size {cfg.batch_size} is not divisible by the {dist_.world} processes; "
                       "choose a multiple of the process count")
    mcfg = cls.resolve_config(cfg.model if cfg.model is not None else cls.Config(), tr)
    model_dict = dict(asdict(mcfg))
    resolved = {**asdict(cfg), "model": model_dict, "device": str(dev), "data_identity": tr.identity(),
                "frame_dt_s": tr.frame_dt, "train_pairs": int(len(tr.pairs()))}
    ckpt_path = out / "checkpoint.pt"
    state = read_checkpoint(ckpt_path, dev) if ckpt_path.exists() else None
    fp = _fingerprint(cfg, model_dict)
    if state is not None:
        if state["format"] < 2:
            raise RunError(f"{ckpt_path} was written by an mdgs version before the model registry and cannot be "
                           "resumed; it still evaluates with `mdgs evaluate`; choose another --out to train anew")
        if state["model_name"] != cls.name:
            raise RunError(f"{out} holds a run of model {state['model_name']!r}, not {cls.name!r}; rerun with "
                           f"--model {state['model_name']}, choose another --out, or delete {ckpt_path}")
        if state["data_identity"]["mjcf_sha256"] != tr.identity()["mjcf_sha256"]:
            raise RunError(f"{out} holds a run trained on scene {state['data_identity']['scene']!r}, not on "
                           f"{tr.identity()['scene']!r} from {cfg.data}; choose another --out or delete {ckpt_path}")
        if state["data_identity"]["n_nodes"] != tr.identity()["n_nodes"]:
            raise RunError(f"{out} holds a run trained on the scene partitioned into {state['data_identity']['n_nodes']} "
                           f"nodes, but {cfg.data} partitions it into {tr.identity()['n_nodes']} (another --refine); "
                           f"choose another --out or delete {ckpt_path}")
        # runs before select / ema: last, none
        old = {"select": "last", "ema": 0.0, **_with_absent(state["train_fingerprint"], cls.Config)}
        if old != fp:
            diff = sorted(k for k in fp if old.get(k) != fp[k])
            diff += sorted(f"model.{k}" for k in fp["model"] if old.get("model", {}).get(k) != fp["model"][k])
            raise RunError(f"{out} holds a run with other settings ({', '.join(x for x in diff if x != 'model')} "
                           f"differ); rerun with the settings in {out / 'config.json'}, choose another --out, "
                           f"or delete {ckpt_path}")
        if state["epoch"] + 1 >= cfg.epochs:
            progress({"kind": "done", "epoch": state["epoch"], "epochs": cfg.epochs})
            return {}
    model = starting_model(cls, mcfg, tr, cfg.seed).to(dev)
    step_model = dist_.wrap(_Losses(model), dev)
    opt, sched, when = model.optimizer(cfg.lr)
    avg = _averaged(model, cfg.ema)
    history, steps_log, start = [], [], 0
    best_weights = None  # the selected epoch's weights (select other than "last"), kept in the checkpoint
    if state is not None:
        model.load_state_dict(state["trained_model"] if avg is not None else state["model"])
        if avg is not None:
            avg.module.load_state_dict(state["model"])
            avg.n_averaged.fill_(state["n_averaged"])
        opt.load_state_dict(state["opt"])
        sched.load_state_dict(state["sched"])
        history, steps_log, start = state["history"], state["steps"], state["epoch"] + 1
        best_weights = state.get("selected_model")
    start_score = state.get("start_rollout") if state is not None else None
    if state is None and cfg.select == "rollout-or-start" and dist_.is_main:  # the start is a candidate
        start_score = score(model, scored, dev)
        best_weights = {k: v.detach().clone() for k, v in model.state_dict().items()}
    resolved["processes"] = dist_.world
    if dist_.is_main:
        out.mkdir(parents=True, exist_ok=True)
        atomic_json(resolved, out / "config.json")
    weights = model.loss_weights()
    pairs_all = tr.pairs(model.history, model.future)
    n_steps = max(1, len(pairs_all) // cfg.batch_size)
    if cfg.max_steps:
        n_steps = min(n_steps, cfg.max_steps)
    progress({"kind": "start", "epoch": start, "epochs": cfg.epochs, "steps": n_steps, "device": str(dev),
              "model": cls.name})
    for epoch in range(start, cfg.epochs):
        t0 = time.perf_counter()
        rng = np.random.default_rng([cfg.seed, epoch])  # same stream whether resumed or not
        gen = torch.Generator(device=dev).manual_seed(int(rng.integers(2**62)))
        pairs = rng.permutation(pairs_all)
        model.train()
        tot: dict[str, float] = {}
        for s in range(n_steps):
            batch = batch_of(tr, pairs[s * cfg.batch_size:(s + 1) * cfg.batch_size], dev, model.history,
                             model.future)
            batch = model.perturb(batch, gen)  # noise of the global batch: the same for any process count
            if dist_.enabled:
                batch = batch.rows(dist_.rows(len(batch)))
            losses = step_model(batch)
            loss = None
            for k, w in weights.items():
                term = losses[k] if w == 1.0 else w * losses[k]
                loss = term if loss is None else loss + term
            if not torch.isfinite(loss):
                raise TrainingError(f"training diverged at epoch {epoch}, step {s} (loss {loss.item()}); "
                                    f"lower --lr or the noise, or delete {ckpt_path} to restart from scratch")
            opt.zero_grad()
            loss.backward()
            opt.step()
            if avg is not None:
                avg.update_parameters(model)
            if when == "step":
                sched.step()
            vals = dist_.mean({k: v.item() for k, v in losses.items()})
            loss_val = dist_.mean({"loss": loss.item()})["loss"]
            for k, v in vals.items():
                tot[k] = tot.get(k, 0.0) + v
            if s % cfg.log_every == 0 or s == n_steps - 1:
                steps_log.append({"epoch": epoch, "step": s, "loss": loss_val, **{f"l_{k}": v for k, v in vals.items()}})
            if dist_.is_main:
                progress({"kind": "step", "epoch": epoch, "step": s + 1, "steps": n_steps, "loss": loss_val,
                          "losses": vals})
        train_s = time.perf_counter() - t0
        judged = model if avg is None else avg.module  # the weights validated, scored and kept
        val = one_step_error(judged, va, dev, max(cfg.batch_size, 64), cfg.valid_max_pairs)
        if when == "epoch":
            sched.step(val)
        rec = {"epoch": epoch, **{f"train_{k}": v / n_steps for k, v in tot.items()},
               "valid_mse": val, "lr": opt.param_groups[0]["lr"], "steps": n_steps,
               "train_seconds": train_s}
        if cfg.select.startswith("rollout") and dist_.is_main:
            rec["valid_rollout"] = score(judged, scored, dev)
        rec["seconds"] = time.perf_counter() - t0
        history.append(rec)
        best = _selected(history, cfg.select, start_score) if dist_.is_main else None  # the rollout score is rank 0's
        if dist_.is_main and cfg.select != "last" and best == epoch:
            best_weights = {k: v.detach().clone() for k, v in judged.state_dict().items()}
        if dist_.is_main:  # only rank 0 writes; the others wait so a resume sees a finished epoch
            averaged = {} if avg is None else {"trained_model": model.state_dict(), "n_averaged": int(avg.n_averaged)}
            write_checkpoint(ckpt_path, {
                "model_name": cls.name, "model": judged.state_dict(), **averaged, "opt": opt.state_dict(),
                "sched": sched.state_dict(), "epoch": epoch, "config": resolved, "train_fingerprint": fp,
                "data_identity": tr.identity(), "has_contact": tr.has_contact, "history": history,
                "steps": steps_log, "selected_epoch": best, "selected_model": best_weights,
                "start_rollout": start_score})
            atomic_json(history, out / "metrics.json")
            atomic_json(steps_log, out / "steps.json")
            progress({"kind": "epoch", **rec})
        dist_.barrier()
    return history[-1] if history else {}

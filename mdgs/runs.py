"""A run folder: its configuration, checkpoints, resume, the device, and the one atomic writer.

A run folder ``OUT`` (written by ``mdgs train``) holds:

- ``config.json``   the resolved configuration (model name and config, training settings,
  data identity, device);
- ``checkpoint.pt`` model, optimiser, scheduler, history; written atomically after every epoch;
- ``metrics.json``  one record per epoch (the model's named losses, valid one-step error, lr, seconds);
- ``steps.json``    the training loss every ``log_every`` steps.

Every file any ``mdgs`` command writes goes through :func:`atomic_write` (a temporary
sibling renamed onto the target, :func:`mdgs.data.io.atomic_path`), so an interrupted
command leaves either the old file or the new one, never half of one.

Checkpoint format 2 names its model (``model_name``, a key of :data:`mdgs.models.MODELS`)
and stores that model's config; format 1 (before the model registry, MDGS only) still
loads for evaluation, and is refused for resuming with one sentence.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import fields
from pathlib import Path

import torch

from mdgs.data.io import atomic_path

__all__ = [
    "RunError",
    "CHECKPOINT_FORMAT",
    "atomic_write",
    "atomic_json",
    "atomic_savefig",
    "resolve_device",
    "read_checkpoint",
    "write_checkpoint",
    "load_model",
    "load_run",
]

#: Version of the checkpoint layout written by :func:`write_checkpoint`.
CHECKPOINT_FORMAT = 2


class RunError(Exception):
    """A run folder, checkpoint or run setting that cannot be used; the message names it and the fix."""


def atomic_write(path: str | os.PathLike, write: Callable[[Path], None]) -> None:
    """Call ``write(tmp)`` on a temporary sibling of ``path``, then rename it onto ``path``."""
    with atomic_path(Path(path)) as tmp:
        write(tmp)


def atomic_json(obj, path: str | os.PathLike) -> None:
    """Write ``obj`` as indented JSON to ``path`` atomically."""
    atomic_write(path, lambda p: p.write_text(json.dumps(obj, indent=2) + "\n"))


def atomic_savefig(fig, path: str | os.PathLike, **kw) -> None:
    """``fig.savefig`` to ``path`` atomically (the format follows ``path``'s suffix)."""
    fmt = Path(path).suffix.lstrip(".") or "png"
    atomic_write(path, lambda p: fig.savefig(p, format=fmt, **kw))


def resolve_device(name: str) -> torch.device:
    """``auto`` (CUDA when present), ``cpu`` or ``cuda`` -> a torch device; RunError otherwise."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise RunError("--device cuda was asked for but no CUDA device is present; use --device auto or cpu")
    if name not in ("cpu", "cuda") and not (name.startswith("cuda:") and name[5:].isdigit()):
        raise RunError(f"--device {name!r} is not known; use auto, cpu or cuda")
    return torch.device(name)


_NEED = ("model", "opt", "sched", "epoch", "config", "train_fingerprint", "data_identity", "history", "steps")


def read_checkpoint(path: str | os.PathLike, dev) -> dict:
    """Read a checkpoint file -> dict (format 1 or 2); RunError naming the file if it is unusable."""
    path = Path(path)
    try:
        state = torch.load(path, map_location=dev, weights_only=False)
    except Exception as e:  # noqa: BLE001 - any unreadable file is the same user error
        raise RunError(f"{path} cannot be read ({type(e).__name__}); delete it to start the run afresh, "
                       "or point to another run folder") from None
    if not isinstance(state, dict) or any(k not in state for k in _NEED):
        raise RunError(f"{path} is not a checkpoint of `mdgs train`; delete it to start the run "
                       "afresh, or point to another run folder")
    state.setdefault("format", 1)
    if state["format"] == 1:  # before the registry: always MDGS, contact flag beside the config
        state["model_name"] = state["config"]["model"].get("variant", "mdgs")
    return state


def write_checkpoint(path: str | os.PathLike, state: dict) -> None:
    """Write a format-2 checkpoint dict atomically."""
    atomic_write(path, lambda p: torch.save({**state, "format": CHECKPOINT_FORMAT}, p))


def load_model(state: dict, dev):
    """Rebuild the model of a checkpoint dict on ``dev`` in eval mode -> a Simulator."""
    from mdgs.models import MODELS

    name = state["model_name"]
    if name not in MODELS:
        raise RunError(f"the checkpoint names model {name!r}, which this version of mdgs does not know; "
                       f"known: {', '.join(MODELS)}")
    cls = MODELS[name]
    mc = dict(state["config"]["model"])
    if state["format"] == 1:
        mc["contact"] = bool(state["has_contact"])
    known = {f.name for f in fields(cls.Config)}
    cfg = cls.Config(**{k: v for k, v in mc.items() if k in known})
    model = cls(cfg).to(dev)
    try:
        model.load_state_dict(state["model"])
    except RuntimeError:
        raise RunError(f"the checkpoint of model {name!r} does not match its configuration (edited or from "
                       "another mdgs version); retrain the run with `mdgs train`") from None
    model.eval()
    return model


def load_run(run: str | os.PathLike, dev) -> tuple:
    """Load ``<run>/checkpoint.pt`` -> (model on ``dev`` in eval mode, checkpoint dict)."""
    path = Path(run) / "checkpoint.pt"
    if not Path(run).is_dir():
        raise RunError(f"run folder {run} is not a folder; train one with `mdgs train --data DIR --out {run}`")
    if not path.exists():
        raise RunError(f"{run} has no checkpoint.pt (no epoch finished yet); run `mdgs train` with --out {run} first")
    state = read_checkpoint(path, dev)
    return load_model(state, dev), state

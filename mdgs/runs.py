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

Two processes never write one run folder at once: :func:`folder_lock` holds ``OUT/.lock``
(created with ``O_EXCL``, holding the writer's host and pid) while ``mdgs train`` or ``mdgs
study`` writes the folder. It works on a network file system shared by several machines: a
process id means something only on its own host, so a lock is judged stale (its process gone,
e.g. after ``kill -9``) and taken over only by a process on the host that wrote it; a lock of
another host is refused with one sentence saying how to remove it.

Checkpoint format 2 names its model (``model_name``, a key of :data:`mdgs.models.MODELS`)
and stores that model's config; format 1 (before the model registry, MDGS only) still
loads for evaluation, and is refused for resuming with one sentence.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import fields
from pathlib import Path

import torch

from mdgs.data.io import _alive, atomic_path, host_tag, output_problem

__all__ = [
    "RunError",
    "FolderBusy",
    "CHECKPOINT_FORMAT",
    "atomic_write",
    "atomic_json",
    "atomic_savefig",
    "resolve_device",
    "read_checkpoint",
    "write_checkpoint",
    "load_model",
    "load_run",
    "check_run_folder",
    "folder_lock",
    "LOCK_NAME",
]

#: Name of the lock file of a run (or study) folder.
LOCK_NAME = ".lock"

#: Version of the checkpoint layout written by :func:`write_checkpoint`.
CHECKPOINT_FORMAT = 2


class RunError(Exception):
    """A run folder, checkpoint or run setting that cannot be used; the message names it and the fix."""


class FolderBusy(RunError):
    """A folder is locked by another live process (:func:`folder_lock`): waiting may help."""


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


def _lock_holder(path: Path) -> dict | None:
    """The lock file's ``{"host", "pid", ...}``; None if it is gone or unreadable."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


@contextmanager
def folder_lock(folder: str | os.PathLike, what: str, flag: str = "--out", name: str = LOCK_NAME) -> Iterator[Path]:
    """Hold ``folder/name`` while the block writes ``folder`` (created if missing); RunError if another
    process holds it.

    The lock file is created with ``O_CREAT | O_EXCL`` (atomic on local and NFSv3+ file systems) and
    holds ``{"host", "pid", "command", "since"}``. A lock whose host is this host
    (:func:`mdgs.data.io.host_tag`) and whose process is gone is stale and taken over; a lock of
    another host is never judged from here. On leaving, the lock is removed (if it is still ours),
    and a folder this call created is removed again if nothing was written into it, so a command
    refused after taking the lock leaves no trace.
    """
    folder = Path(folder)
    problem = output_problem(folder, flag)
    if problem:
        raise RunError(problem)
    created = not folder.exists()
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    me = {"host": host_tag(), "pid": os.getpid(), "command": what,
          "since": time.strftime("%Y-%m-%d %H:%M:%S")}
    try:
        for attempt in range(3):
            try:
                fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                holder = _lock_holder(path)
                if holder is None:
                    if attempt < 2:  # being written or removed right now: look again
                        time.sleep(0.05)
                        continue
                    raise RunError(f"{folder} is locked by {path}, which names no process; if no mdgs command "
                                   f"writes {folder}, delete {path} and rerun") from None
                ours = holder.get("host") == me["host"]
                pid = holder.get("pid")
                if ours and isinstance(pid, int) and pid != os.getpid() and not _alive(pid):
                    if _lock_holder(path) == holder:  # stale: its process is gone; take it over
                        path.unlink(missing_ok=True)
                    continue
                where = "this machine" if ours else f"host {holder.get('host')}"
                hint = ("wait for it to finish or stop it" if ours else
                        f"wait for it to finish; if that process no longer runs on {holder.get('host')}, "
                        f"delete {path}")
                raise FolderBusy(f"{folder} is in use by {holder.get('command', 'another command')} (process {pid} "
                               f"on {where}, since {holder.get('since', '?')}); {hint}, or choose another {flag}") from None
            with os.fdopen(fd, "w") as f:
                f.write(json.dumps(me) + "\n")
                f.flush()
                os.fsync(f.fileno())
            break
        else:
            raise RunError(f"{folder}: could not take the lock {path}; rerun the command")
        try:
            yield path
        finally:
            if _lock_holder(path) == me:
                path.unlink(missing_ok=True)
    finally:
        if created and folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()


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


def model_config(state: dict):
    """The model class and config of a checkpoint dict -> ``(cls, cls.Config)``."""
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
    mc = {**getattr(cls.Config, "ABSENT", {}), **mc}  # settings newer than the checkpoint: their old meaning
    return cls, cls.Config(**{k: v for k, v in mc.items() if k in known})


def load_model(state: dict, dev):
    """Rebuild the model of a checkpoint dict on ``dev`` in eval mode -> a Simulator."""
    cls, cfg = model_config(state)
    name = state["model_name"]
    model = cls(cfg).to(dev)
    try:
        model.load_state_dict(state["model"])
    except RuntimeError:
        raise RunError(f"the checkpoint of model {name!r} does not match its configuration (edited or from "
                       "another mdgs version); retrain the run with `mdgs train`") from None
    model.eval()
    return model


def check_run_folder(run: str | os.PathLike) -> Path:
    """``<run>/checkpoint.pt`` if ``run`` is a run folder with a finished epoch; RunError saying what it is instead.

    A folder with ``config.json`` but no checkpoint is a run interrupted (or still running) in its
    first epoch: rerunning its ``mdgs train`` command resumes it.
    """
    run = Path(run)
    path = run / "checkpoint.pt"
    if not run.exists():
        raise RunError(f"run folder {run} does not exist; train one with `mdgs train --data DIR --out {run}`")
    if not run.is_dir():
        raise RunError(f"run folder {run} is a file, not a folder; pass a folder written by `mdgs train --out`")
    if not path.exists():
        if (run / "config.json").exists():
            raise RunError(f"{run} holds no finished epoch yet (its training was interrupted in the first epoch, "
                           f"or is still running); rerun its `mdgs train ... --out {run}` command (settings in "
                           f"{run / 'config.json'}) to resume it")
        raise RunError(f"{run} is not a run folder (no checkpoint.pt, no config.json); train one with "
                       f"`mdgs train --data DIR --out {run}`")
    return path


def load_run(run: str | os.PathLike, dev) -> tuple:
    """Load ``<run>/checkpoint.pt`` -> (model on ``dev`` in eval mode, checkpoint dict).

    A run trained with a checkpoint selection rule (``select`` other than ``"last"``) evaluates the
    weights of its selected epoch, kept in the checkpoint beside the last epoch's (the returned
    dict's ``model`` and ``evaluated_epoch`` say so)."""
    path = check_run_folder(run)
    state = read_checkpoint(path, dev)
    state["evaluated_epoch"] = state.get("epoch")
    sel = state.get("selected_epoch")
    if sel is not None and sel != state.get("epoch") and state.get("selected_model") is not None:
        state = {**state, "model": state["selected_model"], "evaluated_epoch": sel}
    try:
        return load_model(state, dev), state
    except RunError as e:  # name the file: several runs may be evaluated at once
        raise RunError(f"{path}: {e}") from None

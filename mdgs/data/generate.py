"""``mdgs generate``: trajectories of a scene, in parallel, sharded and resumable.

The unit of work is a *batch* of consecutive trajectories of one split (``Preset.batch``
of them); each batch is simulated and written atomically to
``OUT/.parts/{split}/{start}-{stop}.h5``. A run skips batches whose part already
exists, so an interrupted run resumes where it stopped, losing at most the batches in
flight and duplicating none. ``--shard I/N`` runs batches ``j`` with ``j % N == I`` of
the global batch list, so N machines can share one ``OUT`` (or copy their parts into
one). When every part of every split exists, the run that notices merges them, in
order, into ``OUT/{split}.h5`` (atomically; chunks are copied verbatim) and removes the
parts. ``OUT/generate.json`` holds the resolved configuration; its hash is stamped on
every file, and a run with different settings refuses to mix its output with it.

A run first deletes the temporaries that killed runs left behind (``.NAME.tmpPID-HOST`` of
processes of this host that no longer exist; shards on other machines sharing the folder
keep theirs, :func:`mdgs.data.io.host_tag`). MuJoCo's warnings never land in ``MUJOCO_LOG.TXT``:
those of loading the model are passed to ``on_warning`` (stderr by default) and stored
in the files' ``mujoco_warnings``; a warning while simulating (an unstable model, a full
constraint arena) stops the run before anything is written
(:class:`mdgs.data.record.SceneError`), as does an error of MuJoCo's. Contacts beyond the
recorded slots are reported the same way and counted in ``contact_overflow``.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import hashlib
import json
import multiprocessing as mp
import shutil
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import h5py
import numpy as np

from mdgs.data.engine import (
    LoadedScene,
    load_scene,
    mujoco_messages,
    scene_attrs,
    simulate,
    static_arrays,
)
from mdgs.data.io import (
    atomic_path,
    merge_files,
    open_dataset,
    output_problem,
    remove_stale_temporaries,
    sha256_text,
    write_file,
)
from mdgs.data.presets import PRESETS, split_counts
from mdgs.data.record import CONTACT_SLOTS
from mdgs.data.schema import SCHEMA_VERSION, DatasetError
from mdgs.partition import PartitionParams
from mdgs.scenes import SceneSpec, get_scene, user_scene

__all__ = ["GenerateConfig", "GenerateResult", "generate", "resolve_scene", "plan"]


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("mdgs")
    except Exception:
        return "0+unknown"


@dataclass(frozen=True)
class GenerateConfig:
    """Everything ``mdgs generate`` needs. Defaults are the CLI's defaults."""

    scene: str
    """A registered scene name, or '' with ``mjcf`` set."""
    out: str
    preset: str = "tiny"
    n_traj: int | None = None
    """Total trajectories (split in the paper's proportions); the preset's counts if None."""
    seed: int = 0
    workers: int = 1
    shard: tuple[int, int] = (0, 1)
    mjcf: str | None = None
    """A user's MJCF file (then ``scene`` is its stem)."""
    substeps: int = 10
    """Integrator steps per frame for user MJCF files (built-in scenes define their own)."""
    partition: PartitionParams = field(default_factory=PartitionParams)
    batch: int | None = None
    """Trajectories per part file (the preset's if None)."""
    n_frames: int | None = None
    """Frames per trajectory (the preset's 110 if None); e.g. 1100 for a stability test set."""
    splits: tuple[str, ...] | None = None
    """Only these splits (e.g. ``("test",)`` for a long test set); the scene's splits if None."""

    def __post_init__(self):
        """Refuse every out-of-range number here, before anything is written (issue 15, item 5):
        a refused run must leave no ``generate.json`` behind to block the corrected command."""
        if self.preset not in PRESETS:
            raise DatasetError(f"unknown preset '{self.preset}'; choose one of {', '.join(PRESETS)}")
        for flag, val, lo in (("--seed", self.seed, 0), ("--workers", self.workers, 1),
                              ("--substeps", self.substeps, 1), ("--n-traj", self.n_traj, 1),
                              ("--frames", self.n_frames, 2), ("batch", self.batch, 1),
                              ("--refine", self.partition.refine, 1)):
            if val is None and flag in ("--n-traj", "--frames", "batch"):
                continue
            if isinstance(val, bool) or not isinstance(val, int | np.integer) or val < lo:
                raise DatasetError(f"{flag} {val} must be an integer of at least {lo}")
        if self.seed >= 2**63:
            raise DatasetError(f"--seed {self.seed} must be below 2**63")
        i, n = self.shard
        if not (n >= 1 and 0 <= i < n):
            raise DatasetError(f"--shard {i}/{n} is out of range; use I/N with 0 <= I < N")


@dataclass(frozen=True)
class GenerateResult:
    out: Path
    scene: str
    files: dict[str, Path]
    """Split files written (empty if this shard left the merge to others)."""
    trajectories: int
    """Trajectories simulated by this run (0 when everything was already there)."""
    steps: int
    """Integrator steps simulated by this run."""
    seconds: float
    merged: bool
    n_nodes: int
    warnings: tuple[str, ...] = ()
    """Warning lines of this run (MuJoCo's, changes made to the model, contact overflow),
    each also passed to ``on_warning``."""


def resolve_scene(cfg: GenerateConfig) -> SceneSpec:
    if cfg.mjcf:
        return user_scene(cfg.mjcf, cfg.substeps)
    return get_scene(cfg.scene)


def _content(cfg: GenerateConfig, loaded: LoadedScene) -> dict:
    """What determines the bits of the output (hashed into config_sha256)."""
    spec = loaded.spec
    preset = PRESETS[cfg.preset]
    splits = spec.splits
    if cfg.splits is not None:
        unknown = [s for s in cfg.splits if s not in spec.splits]
        if unknown or not cfg.splits:
            raise ValueError(f"splits {', '.join(cfg.splits) or '(none)'}: scene {spec.name} has splits "
                             f"{', '.join(spec.splits)}")
        splits = tuple(s for s in spec.splits if s in cfg.splits)
    if cfg.n_frames is not None and cfg.n_frames < 2:
        raise ValueError(f"--frames {cfg.n_frames} must be at least 2")
    counts = split_counts(cfg.n_traj, splits) if cfg.n_traj is not None else preset.counts(splits)
    content = {
        "schema_version": SCHEMA_VERSION,
        "scene": spec.name,
        "mjcf_sha256": sha256_text(loaded.mjcf),
        "scene_params": json.loads(json.dumps(spec.params(), default=list)),
        "partition": cfg.partition.as_dict(),
        "seed": int(cfg.seed),
        "n_frames": int(cfg.n_frames or preset.n_frames),
        "counts": counts,
        "batch": int(cfg.batch or preset.batch),
        "mujoco": __import__("mujoco").__version__,
    }
    if loaded.assets:  # the files the MJCF reads determine the model too
        content["assets_sha256"] = sha256_text(
            json.dumps({k: hashlib.sha256(v).hexdigest() for k, v in loaded.assets.items()})
        )
    return content


def plan(counts: dict[str, int], batch: int) -> list[tuple[str, int, int]]:
    """The global batch list: (split, start, stop) in split order."""
    jobs = []
    for split, n in counts.items():
        jobs += [(split, s, min(n, s + batch)) for s in range(0, n, batch)]
    return jobs


def _part_path(out: Path, split: str, start: int, stop: int) -> Path:
    return out / ".parts" / split / f"{start:07d}-{stop:07d}.h5"


def _part_ok(path: Path, sha: str) -> bool:
    """A part that exists and belongs to this configuration (a mismatch is an error)."""
    if not path.exists():
        return False
    try:
        with h5py.File(path, "r") as f:
            theirs = str(f.attrs["config_sha256"])
    except (OSError, KeyError):
        path.unlink()  # unreadable: an atomic rename never leaves one, so it was damaged
        return False
    if theirs != sha:
        raise DatasetError(
            f"{path} was generated with different settings; use another --out or delete {path.parent.parent}"
        )
    return True


# --- workers ---------------------------------------------------------------------------
_WORKER: dict = {}


def _worker_init(cfg: GenerateConfig) -> None:
    if _WORKER.get("cfg") == cfg:
        return  # forked from a parent that already loaded the scene
    spec = resolve_scene(cfg)
    loaded = load_scene(spec, cfg.partition)
    _WORKER.update(cfg=cfg, loaded=loaded, static=static_arrays(loaded), attrs=scene_attrs(loaded))


def _run_job(job: tuple[str, int, int], base_attrs: dict) -> tuple[str, int, int, int]:
    split, start, stop = job
    cfg, loaded = _WORKER["cfg"], _WORKER["loaded"]
    n_frames = int(base_attrs["n_frames"])
    with mujoco_messages():  # unstable runs raise SceneError from the warning counters
        frames = simulate(loaded, split, range(start, stop), cfg.seed, n_frames)
    overflow = int(frames["contact_overflow"].sum())
    attrs = {
        **_WORKER["attrs"],
        **base_attrs,
        "split": split,
        "n_traj": stop - start,
        "traj_start": start,
        "complete": False,
        "contact_overflow": overflow,
    }
    path = _part_path(Path(cfg.out), split, start, stop)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        write_file(path, attrs, loaded.mjcf, _WORKER["static"], frames, loaded.assets)
    except FileNotFoundError:
        # another run on the same OUT merged the split and removed the parts meanwhile: this batch is in it
        if not (Path(cfg.out) / f"{split}.h5").exists():
            raise
    return split, start, stop, (stop - start) * n_frames * loaded.spec.substeps, overflow


def _stderr_line(line: str) -> None:
    print(f"warning: {line}", file=sys.stderr)


def generate(
    cfg: GenerateConfig,
    progress: Callable[[int, int], None] | None = None,
    on_warning: Callable[[str], None] | None = _stderr_line,
) -> GenerateResult:
    """Generate (or resume, or finish the merge of) the dataset described by ``cfg``.

    ``progress(done, total)`` is called with trajectory counts of this shard;
    ``on_warning(line)`` with each warning line (default: ``warning: LINE`` on stderr;
    they are also in :attr:`GenerateResult.warnings`).

    Raises :class:`mdgs.data.record.SceneError` for a model that cannot be recorded or
    that MuJoCo warns about while simulating (nothing of it is written).
    """
    lines: list[str] = []

    def warn(line: str) -> None:
        lines.append(line)
        if on_warning is not None:
            on_warning(line)

    with mujoco_messages() as stray:
        res = _generate(cfg, progress, warn)
    known = set(_WORKER["loaded"].warnings) if "loaded" in _WORKER else set()
    for msg in dict.fromkeys(stray):  # outside loading and stepping: the scene's check
        if msg not in known:  # (resolve_scene compiles the model too)
            warn(f"MuJoCo: {msg}")
    return dataclasses.replace(res, warnings=tuple(lines))


def _generate(cfg: GenerateConfig, progress, warn: Callable[[str], None]) -> GenerateResult:
    t0 = time.perf_counter()
    if cfg.preset not in PRESETS:
        raise ValueError(f"unknown preset '{cfg.preset}'; choose one of {', '.join(PRESETS)}")
    i, n = cfg.shard
    if not (n >= 1 and 0 <= i < n):
        raise ValueError(f"shard {i}/{n} is invalid; use I/N with 0 <= I < N")
    problem = output_problem(cfg.out, "--out")
    if problem:
        raise DatasetError(problem)
    spec = resolve_scene(cfg)
    _worker_init(cfg)  # also validates the scene in this process
    loaded: LoadedScene = _WORKER["loaded"]
    for msg in loaded.warnings:
        warn(f"MuJoCo, loading {spec.name}: {msg}")
    for note in loaded.inst.notes:
        warn(f"{spec.name}: {note}")
    content = _content(cfg, loaded)
    sha = sha256_text(json.dumps(content, sort_keys=True))
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(out)
    _write_config(out, cfg, content, sha)
    base_attrs = {
        "seed": int(cfg.seed),
        "n_frames": content["n_frames"],
        "preset": cfg.preset,
        "config_sha256": sha,
        "mdgs_version": _version(),
    }
    counts = content["counts"]
    jobs = plan(counts, content["batch"])
    finished = {s for s in counts if _final_ok(out / f"{s}.h5", sha)}
    todo = [
        j
        for k, j in enumerate(jobs)
        if k % n == i and j[0] not in finished and not _part_ok(_part_path(out, *j), sha)
    ]
    total = sum(stop - start for k, (s, start, stop) in enumerate(jobs) if k % n == i)
    done = total - sum(stop - start for _, start, stop in todo)
    if progress:
        progress(done, total)
    steps = 0
    ran = 0
    overflow = 0
    if todo:
        if cfg.workers <= 1:
            for job in todo:
                _, a, b, st, ov = _run_job(job, base_attrs)
                steps, ran, done, overflow = steps + st, ran + b - a, done + b - a, overflow + ov
                if progress:
                    progress(done, total)
        else:
            # compile (or load from numba's cache) the recorder's loops here, once: forked
            # workers inherit them instead of each compiling its own on a cold cache
            split0, start0 = todo[0][0], todo[0][1]
            simulate(loaded, split0, [start0], cfg.seed, min(2, int(base_attrs["n_frames"])))
            ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
            with cf.ProcessPoolExecutor(
                max_workers=cfg.workers, mp_context=ctx, initializer=_worker_init, initargs=(cfg,)
            ) as pool:
                futs = [pool.submit(_run_job, job, base_attrs) for job in todo]
                for fut in cf.as_completed(futs):
                    _, a, b, st, ov = fut.result()
                    steps, ran, done = steps + st, ran + b - a, done + b - a
                    overflow += ov
                    if progress:
                        progress(done, total)
    if overflow:
        warn(
            f"{spec.name}: {overflow} body-substeps had more than {CONTACT_SLOTS} contacts; the "
            "rest of such a body's contact force is put on one element (counted per frame in "
            "/frames/contact_overflow, in total in the contact_overflow attribute)"
        )
    files, merged = _merge_if_ready(out, counts, jobs, sha)
    return GenerateResult(
        out,
        spec.name,
        files,
        ran,
        steps,
        time.perf_counter() - t0,
        merged,
        loaded.inst.partition.n_nodes,
    )


def _final_ok(path: Path, sha: str) -> bool:
    if not path.exists():
        return False
    with open_dataset(path) as ds:
        if str(ds.attrs["config_sha256"]) != sha:
            raise DatasetError(
                f"{path} was generated with different settings; use another --out or delete {path}"
            )
    return True


def _merge_if_ready(
    out: Path, counts: dict[str, int], jobs, sha: str
) -> tuple[dict[str, Path], bool]:
    files = {}
    for split in counts:
        final = out / f"{split}.h5"
        if _final_ok(final, sha):
            files[split] = final
            continue
        parts = [_part_path(out, s, a, b) for s, a, b in jobs if s == split]
        if not all(p.exists() for p in parts):
            return {}, False
        try:
            merge_files(parts, final, {"complete": True})
        except FileNotFoundError:
            if not _final_ok(final, sha):  # another shard merged and cleaned up first
                raise
        files[split] = final
    if all(s in files for s in counts):
        shutil.rmtree(out / ".parts", ignore_errors=True)
        return files, True
    return files, False


def _write_config(out: Path, cfg: GenerateConfig, content: dict, sha: str) -> None:
    path = out / "generate.json"
    doc = {
        "config_sha256": sha,
        "content": content,
        "run": {k: v for k, v in asdict(cfg).items() if k not in ("shard", "workers", "out")},
    }
    text = json.dumps(doc, indent=2, sort_keys=True, default=list) + "\n"
    if path.exists():
        try:
            theirs = json.loads(path.read_text()).get("config_sha256")
        except json.JSONDecodeError:
            theirs = None
        if theirs not in (None, sha):
            raise DatasetError(
                f"{out} holds a dataset generated with different settings; use another --out or delete {out}"
            )
        if theirs == sha:
            return
    with atomic_path(path) as tmp:
        tmp.write_text(text)

"""Reading and writing dataset files (format: :mod:`mdgs.data.schema`).

Writes are atomic: a file is written under a temporary name in the same directory and
renamed into place, so an interrupted run leaves either the whole file or none.
HDF5 output is byte-for-byte reproducible (no timestamps, fixed order, fixed
chunking), so the same inputs give the same file hash.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import h5py
import numpy as np

from mdgs.data.schema import (
    FRAME_ARRAYS,
    OPTIONAL_ATTRS,
    ROOT_ATTRS,
    SCHEMA_VERSION,
    STATIC_ARRAYS,
    STRING_LISTS,
    DatasetError,
)

__all__ = [
    "write_file",
    "merge_files",
    "open_dataset",
    "Dataset",
    "atomic_path",
    "sha256_text",
    "model_from_dataset",
    "remove_stale_temporaries",
    "output_problem",
    "path_kind",
]

# Sparse arrays (mostly zeros) are compressed with LZF (fast, built into h5py; without
# the shuffle filter, which makes LZF both slower and larger on them); dense kinematics,
# controls and actuator torques are stored raw, which is faster to write and read. A
# chunk (one trajectory) that holds only zeros is not stored at all: HDF5 reads it as
# the fill value, 0 (a stored chunk always carries its fletcher32 checksum).
_COMPRESSED = {
    "node_contact_force",
    "node_joint_force",
    "body_contact_force",
    "body_contact_torque",
    "body_actuator_force",
    "contact_overflow",
    "contact_count",
    "act",
}
_LIBVER = ("v110", "v110")
_REGEN = "delete it and run the same `mdgs generate` command again"


def sha256_text(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


@contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary sibling of ``path``; rename it onto ``path`` if the block succeeds."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}-{host_tag()}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def path_kind(path: str | os.PathLike) -> str:
    """``"missing"``, ``"folder"`` or ``"file"`` (anything that exists and is not a folder)."""
    p = Path(path)
    return "folder" if p.is_dir() else "file" if p.exists() else "missing"


def output_problem(path: str | os.PathLike, flag: str, kind: str = "folder", example: str = "") -> str | None:
    """Why ``path`` cannot receive a command's output, in one sentence naming ``flag``; None if it can.

    ``kind`` is ``"folder"`` (a folder the command creates or fills) or ``"file"`` (a file it
    writes). Checked before anything is written, so a refused command leaves nothing behind:
    a file where the folder belongs, a folder where the file belongs, a parent that is a file,
    and the nearest existing folder not writable (:func:`os.access`; root passes that test, and
    what still fails at write time is an ``OSError`` naming the path, exit 2 in the CLI).
    ``example`` is a file name for the hint when a folder is given for a file.
    """
    p = Path(path)
    if kind == "folder" and p.exists() and not p.is_dir():
        return f"{flag} {p} is a file, not a folder; choose a folder path (it is created if missing)"
    if kind == "file" and p.is_dir():
        return f"{flag} {p} is a folder, not a file; give a file path such as {p / (example or 'report.json')}"
    a = p if kind == "folder" else p.parent
    while not a.exists() and a != a.parent:
        a = a.parent
    if a.exists() and not a.is_dir():
        return f"{flag} {p}: {a} is a file, not a folder; choose a path whose folders are folders"
    if a.exists() and not os.access(a, os.W_OK | os.X_OK):
        return f"{flag} {p}: folder {a} is not writable; choose a folder you can write to"
    return None


_TMP = re.compile(r"^\..+\.tmp(\d+)(?:-([-A-Za-z0-9_.]+))?$")


def host_tag() -> str:
    """This machine's name as it appears in temporary file names (``$MDGS_HOST`` overrides it).

    Shards of one dataset may run on several machines that share only the output folder (a
    network file system): a process id means something only on the machine that issued it, so
    every temporary carries its writer's host, and only that host ever judges it stale.
    """
    import socket

    name = os.environ.get("MDGS_HOST") or socket.gethostname() or "host"
    return re.sub(r"[^-A-Za-z0-9_.]", "_", name)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists on this machine."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def remove_stale_temporaries(folder: Path) -> list[Path]:
    """Delete the temporaries of :func:`atomic_path` under ``folder`` whose writer is dead.

    A killed run leaves ``.NAME.tmpPID-HOST`` behind (its rename never happened); a rerun
    removes those written on this host by processes that no longer exist, and keeps those of
    live processes and of other hosts (another worker or shard may be writing; see
    :func:`host_tag`). Returns the removed paths.
    """
    gone = []
    folder = Path(folder)
    if not folder.is_dir():
        return gone
    me = host_tag()
    for f in folder.rglob(".*.tmp*"):
        m = _TMP.match(f.name)
        if not m or (m.group(2) or me) != me:  # another machine's temporary: not ours to judge
            continue
        if f.is_file() and int(m.group(1)) != os.getpid() and not _alive(int(m.group(1))):
            f.unlink(missing_ok=True)
            gone.append(f)
    return gone


def _dataset_kwargs(name: str, shape: tuple[int, ...]) -> dict:
    kw = {"fletcher32": True, "track_times": False}
    if len(shape) >= 2 and shape[0] > 0 and all(shape):
        kw["chunks"] = (1,) + tuple(shape[1:])
        kw["fillvalue"] = 0
        if name in _COMPRESSED:
            kw["compression"] = "lzf"
    return kw


def _write_rows(d: h5py.Dataset, a: np.ndarray, row: int = 0) -> None:
    """Write ``a`` at ``row`` of the chunked (one row per chunk) dataset ``d``, skipping all-zero rows."""
    nonzero = a.reshape(a.shape[0], -1).any(1)
    if nonzero.all():
        d[row : row + len(a)] = a
        return
    edges = np.flatnonzero(np.diff(np.concatenate([[0], nonzero.view(np.int8), [0]])))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        d[row + start : row + stop] = a[start:stop]


def _same_storage(src: h5py.Dataset, dst: h5py.Dataset) -> bool:
    """Whether ``src``'s stored chunks can be copied verbatim into ``dst`` (same chunks and filters)."""
    return (
        dst.chunks is not None
        and src.chunks == dst.chunks
        and src.compression == dst.compression
        and src.shuffle == dst.shuffle
        and src.fletcher32 == dst.fletcher32
        and src.dtype == dst.dtype
    )


def _set_attrs(f: h5py.File, attrs: dict) -> None:
    for key in ROOT_ATTRS:
        if key in attrs:
            f.attrs[key] = attrs[key]
    for key in OPTIONAL_ATTRS:  # written only when there is something to say
        if key in attrs and attrs[key] not in (None, 0, "", "[]"):
            f.attrs[key] = attrs[key]


def _write_static(f: h5py.File, mjcf: str, static: dict, assets: dict | None = None) -> None:
    g = f.create_group("static")
    g.create_dataset("mjcf", data=mjcf, dtype=h5py.string_dtype(), track_times=False)
    if assets:  # files the MJCF reads, by the name it reads them (only when it reads any)
        a = g.create_group("assets", track_order=True)
        for i, (name, data) in enumerate(assets.items()):
            d = a.create_dataset(
                f"{i:05d}", data=np.frombuffer(data, np.uint8), fletcher32=True, track_times=False
            )
            d.attrs["path"] = name
    for spec in STATIC_ARRAYS:
        g.create_dataset(
            spec.name,
            data=np.asarray(static[spec.name], dtype=spec.dtype),
            fletcher32=True,
            track_times=False,
        )
    for name in STRING_LISTS:
        g.create_dataset(
            name, data=[str(s) for s in static[name]], dtype=h5py.string_dtype(), track_times=False
        )


def write_file(
    path: Path, attrs: dict, mjcf: str, static: dict, frames: dict, assets: dict | None = None
) -> None:
    """Write one dataset (or part) file atomically (``assets``: files the MJCF reads)."""
    with atomic_path(path) as tmp, h5py.File(tmp, "w", libver=_LIBVER) as f:
        _set_attrs(f, {**attrs, "schema_version": SCHEMA_VERSION, "mjcf_sha256": sha256_text(mjcf)})
        _write_static(f, mjcf, static, assets)
        g = f.create_group("frames")
        for spec in FRAME_ARRAYS:
            a = np.ascontiguousarray(frames[spec.name], dtype=spec.dtype)
            kw = _dataset_kwargs(spec.name, a.shape)
            if "chunks" in kw and not a.reshape(a.shape[0], -1).any(1).all():
                _write_rows(g.create_dataset(spec.name, shape=a.shape, dtype=a.dtype, **kw), a)
            else:
                g.create_dataset(spec.name, data=a, **kw)


def merge_files(parts: Sequence[Path], path: Path, attrs: dict) -> None:
    """Concatenate part files (in order) into ``path``, copying compressed chunks verbatim."""
    srcs = [h5py.File(p, "r") for p in parts]
    try:
        first = srcs[0]
        total = sum(int(s.attrs["n_traj"]) for s in srcs)
        with atomic_path(path) as tmp, h5py.File(tmp, "w", libver=_LIBVER) as f:
            overflow = sum(int(s.attrs.get("contact_overflow", 0)) for s in srcs)
            _set_attrs(
                f,
                {
                    **{k: first.attrs[k] for k in first.attrs},
                    **attrs,
                    "n_traj": total,
                    "traj_start": 0,
                    "contact_overflow": overflow,
                },
            )
            mjcf = (
                first["static/mjcf"][()].decode()
                if isinstance(first["static/mjcf"][()], bytes)
                else first["static/mjcf"][()]
            )
            _write_static(
                f,
                mjcf,
                {k: first["static"][k][()] for k in first["static"] if k not in ("mjcf", "assets")}
                | {
                    n: [s.decode() if isinstance(s, bytes) else s for s in first["static"][n][()]]
                    for n in STRING_LISTS
                },
                _read_assets(first),
            )
            g = f.create_group("frames")
            for spec in FRAME_ARRAYS:
                src0 = first["frames"][spec.name]
                shape = (total,) + src0.shape[1:]
                dst = g.create_dataset(
                    spec.name, shape=shape, dtype=spec.dtype, **_dataset_kwargs(spec.name, shape)
                )
                row = 0
                for s in srcs:
                    src = s["frames"][spec.name]
                    n = src.shape[0]
                    if _same_storage(src, dst) and 0 not in src.shape:
                        # the stored chunks, verbatim (all-zero rows are not stored)
                        for j in range(src.id.get_num_chunks()):
                            at = src.id.get_chunk_info(j).chunk_offset
                            mask, data = src.id.read_direct_chunk(at)
                            dst.id.write_direct_chunk((row + at[0], *at[1:]), data, mask)
                    elif n and dst.chunks is not None:
                        _write_rows(dst, src[()], row)
                    elif n:
                        dst[row : row + n] = src[()]
                    row += n
    finally:
        for s in srcs:
            s.close()


def _read_assets(f: h5py.File) -> dict[str, bytes]:
    g = f["static"].get("assets")
    if g is None:
        return {}
    return {str(d.attrs["path"]): d[()].tobytes() for d in (g[k] for k in sorted(g))}


class Dataset:
    """An opened, checked dataset file. Use as a context manager or call :meth:`close`."""

    def __init__(self, path: Path, f: h5py.File):
        self.path = Path(path)
        self._f = f
        self.attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
        st = f["static"]
        raw = st["mjcf"][()]
        self.mjcf = raw.decode() if isinstance(raw, bytes) else str(raw)
        self.static = {}
        self.assets = _read_assets(f)
        """Files the MJCF reads (includes, meshes, textures), by the name it reads them."""
        for k in st:
            if k in ("mjcf", "assets"):
                continue
            v = st[k][()]
            if k in STRING_LISTS:
                v = [s.decode() if isinstance(s, bytes) else str(s) for s in v]
            self.static[k] = v

    @property
    def n_traj(self) -> int:
        return int(self.attrs["n_traj"])

    @property
    def n_frames(self) -> int:
        return int(self.attrs["n_frames"])

    @property
    def scene(self) -> str:
        return str(self.attrs["scene"])

    def frames(self, name: str, traj=slice(None)) -> np.ndarray:
        """Read ``/frames/<name>`` for trajectories ``traj`` (index or slice)."""
        try:
            return self._f["frames"][name][traj]
        except KeyError:
            raise DatasetError(
                f"{self.path}: no array '{name}' in /frames; known: {', '.join(self._f['frames'])}"
            ) from None
        except (OSError, RuntimeError) as e:
            raise DatasetError(f"{self.path} is corrupted ({_short(e)}); {_REGEN}") from None

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> Dataset:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _short(e: Exception) -> str:
    msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    return msg[:160]


def _probe_seconds() -> float:
    try:
        return float(os.environ.get("MDGS_H5_PROBE_SECONDS", "30"))
    except ValueError:
        return 30.0


def _read_metadata(path: str) -> None:
    """Read every attribute of ``path`` (root, groups, arrays): what a damaged file can hang in."""
    with h5py.File(path, "r") as f:
        [f.attrs[k] for k in f.attrs]
        f.visititems(lambda name, obj: [obj.attrs[k] for k in obj.attrs])


_PROBED: dict = {}


def _metadata_hangs(path: Path) -> bool:
    """Whether reading the metadata of ``path`` hangs the HDF5 library (seen with a zeroed block in an
    attribute message: h5py 3.16 / HDF5 2.0 loop forever in ``attrs[...]``, and no Python code can
    interrupt them). Read first in a forked child with a time limit (``MDGS_H5_PROBE_SECONDS``,
    default 30 s); once per file version and process. Where processes cannot fork, not checked."""
    import multiprocessing as mp

    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key in _PROBED:
        return _PROBED[key]
    if "fork" not in mp.get_all_start_methods():
        return False
    child = mp.get_context("fork").Process(target=_read_metadata, args=(str(path),), daemon=True)
    child.start()
    child.join(_probe_seconds())
    hung = child.is_alive()
    if hung:
        child.kill()
        child.join()
    _PROBED[key] = hung
    return hung


def open_dataset(
    path: str | os.PathLike, *, verify: bool = False, allow_incomplete: bool = False
) -> Dataset:
    """Open ``path`` and check it against the schema; raise :class:`DatasetError` if it is unusable.

    Checks: an HDF5 file; schema version; every attribute and array of the schema with
    mutually consistent shapes; the MJCF hash; node masses summing to body masses; the
    file marked complete. With ``verify=True`` every array is also read, so a corrupted
    chunk fails its fletcher32 checksum here rather than later.
    """
    path = Path(path)
    if not path.exists():
        raise DatasetError(
            f"{path} does not exist; generate it with `mdgs generate SCENE --out {path.parent}`"
        )
    if path.is_dir():
        raise DatasetError(
            f"{path} is a folder, not a dataset file; pass one of its split files, e.g. {path / 'train.h5'}"
        )
    if path.stat().st_size == 0:
        raise DatasetError(f"{path} is empty (0 bytes), not a dataset; {_REGEN}")
    if _metadata_hangs(path):
        raise DatasetError(f"{path} is corrupted: the HDF5 library does not return from reading its metadata "
                           f"within {_probe_seconds():g} s; {_REGEN}")
    try:
        f = h5py.File(path, "r")
    except OSError as e:
        raise DatasetError(
            f"{path} is not a readable HDF5 file, probably truncated or corrupted ({_short(e)}); {_REGEN}"
        ) from None
    try:
        _check(path, f, verify, allow_incomplete)
        return Dataset(path, f)
    except DatasetError:
        f.close()
        raise
    except (OSError, RuntimeError, KeyError, ValueError, TypeError) as e:  # h5py: RuntimeError for a bad
        f.close()  # metadata checksum
        raise DatasetError(f"{path} is corrupted ({_short(e)}); {_REGEN}") from None


def _check(path: Path, f: h5py.File, verify: bool, allow_incomplete: bool) -> None:
    a = f.attrs
    if "schema_version" not in a:
        raise DatasetError(
            f"{path} is an HDF5 file but not an MDGS dataset (no schema_version attribute); point to a file written by `mdgs generate`"
        )
    if int(a["schema_version"]) != SCHEMA_VERSION:
        raise DatasetError(
            f"{path} has schema version {int(a['schema_version'])} but this mdgs reads version {SCHEMA_VERSION}; regenerate it with this version of `mdgs generate`"
        )
    missing = [k for k in ROOT_ATTRS if k not in a]
    if missing:
        raise DatasetError(f"{path} lacks attributes {', '.join(missing)}; {_REGEN}")
    if not allow_incomplete and not bool(a["complete"]):
        raise DatasetError(
            f"{path} is incomplete (generation was interrupted or is still running); rerun the same `mdgs generate` command to finish it"
        )
    for grp, specs in (("static", STATIC_ARRAYS), ("frames", FRAME_ARRAYS)):
        if grp not in f:
            raise DatasetError(f"{path} lacks the /{grp} group; {_REGEN}")
        absent = [s.name for s in specs if s.name not in f[grp]]
        if absent:
            raise DatasetError(f"{path} lacks /{grp}/{absent[0]}; {_REGEN}")
    mjcf = f["static/mjcf"][()]
    mjcf = mjcf.decode() if isinstance(mjcf, bytes) else str(mjcf)
    if sha256_text(mjcf) != str(a["mjcf_sha256"]):
        raise DatasetError(
            f"{path}: the stored MJCF does not match its hash (file corrupted or edited); {_REGEN}"
        )
    st = f["static"]
    dims = {
        "T": int(a["n_traj"]),
        "F": int(a["n_frames"]),
        "N": st["node_body"].shape[0],
        "B": st["body_id"].shape[0],
        "E": st["adjacency"].shape[0],
        "nq": f["frames/qpos"].shape[-1],
        "nv": f["frames/qvel"].shape[-1],
        "nu": f["frames/ctrl"].shape[-1],
        "na": f["frames/act"].shape[-1],
        "3": 3,
        "4": 4,
        "2": 2,
    }
    for grp, specs in (("static", STATIC_ARRAYS), ("frames", FRAME_ARRAYS)):
        for s in specs:
            want = tuple(dims[d] for d in s.shape)
            got = f[grp][s.name].shape
            if got != want:
                raise DatasetError(
                    f"{path}: /{grp}/{s.name} has shape {got}, expected {want} from the file's own sizes; {_REGEN}"
                )
    mass, body = st["node_mass"][()], st["node_body"][()]
    static = st["node_static"][()]
    for bi, b in enumerate(st["body_id"][()]):
        sel = (body == b) & ~static
        if sel.any() and not np.isclose(mass[sel].sum(), st["body_mass"][bi], rtol=1e-9, atol=0):
            raise DatasetError(
                f"{path}: element masses of body {int(b)} do not sum to its mass; {_REGEN}"
            )
    for s in STATIC_ARRAYS:
        if s.dtype == "float64" and not np.isfinite(st[s.name][()]).all():
            raise DatasetError(f"{path}: /static/{s.name} holds NaN or Inf; {_REGEN}")
    if verify:
        for s in FRAME_ARRAYS:
            d = f["frames"][s.name]
            for i in range(d.shape[0]):
                row = d[i]
                if row.dtype.kind == "f" and not np.isfinite(row).all():
                    raise DatasetError(
                        f"{path}: /frames/{s.name} holds NaN or Inf (trajectory {i}), so the "
                        f"simulation that wrote it was unstable or the file was edited; {_REGEN} "
                        "(this version refuses to write unstable simulations)"
                    )


def model_from_dataset(ds: Dataset | str | os.PathLike):
    """The dataset's MuJoCo model (``mujoco.MjModel``), rebuilt from the file alone.

    Compiles ``/static/mjcf`` with ``/static/assets`` (its includes, meshes and textures),
    so it needs neither the original folder nor its files: the model as the user wrote
    it, without the recorder's sensors. ``ds``: an open :class:`Dataset` or a path.
    """
    import mujoco

    if not isinstance(ds, Dataset):
        with open_dataset(ds) as opened:
            return model_from_dataset(opened)
    try:
        return mujoco.MjModel.from_xml_string(ds.mjcf, ds.assets or None)
    except Exception as e:
        raise DatasetError(
            f"{ds.path}: its MJCF does not compile with this MuJoCo {mujoco.__version__} "
            f"(written by {ds.attrs.get('mujoco_version', '?')}: {_short(e)}); regenerate it with this version"
        ) from None


def read_json_attr(ds: Dataset, key: str):
    return json.loads(ds.attrs[key])

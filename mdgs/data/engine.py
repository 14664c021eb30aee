"""Simulate a batch of trajectories of one scene and reduce them to recorded frames.

``simulate(scene, split, ids, seed, n_frames)`` returns the per-frame arrays of
:data:`mdgs.data.schema.FRAME_ARRAYS` for trajectories ``ids`` of ``split``. A
trajectory depends only on (scene, seed, split, index): its random generator is
``SeedSequence([seed, SPLIT_CODE[split], index])``, each simulation of the
:class:`mujoco.batch.Batch` is stepped on its own (bit-identical at any batch size and
chunking: the solver's warm start is part of its state), and every reduction is per
trajectory, so batches, workers and shards never change its bits.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import mujoco.batch
import numpy as np

from mdgs.data.record import KINEMATICS, FrameReducer, Instrumented, SceneError, instrument
from mdgs.partition import PartitionParams
from mdgs.scenes import SceneSpec

__all__ = [
    "SPLIT_CODE",
    "LoadedScene",
    "load_scene",
    "simulate",
    "static_arrays",
    "scene_attrs",
    "rng_for",
    "mujoco_messages",
    "self_contained_mjcf",
]

SPLIT_CODE = {"train": 0, "valid": 1, "test": 2}
_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS
_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION
# share of trajectories in contact under which the lean model (no contact sensors) steps a
# block: re-running the few in contact costs less than the sensors for all (hysteresis)
_LEAN_ENTER, _LEAN_STAY = 0.05, 0.15


def rng_for(seed: int, split: str, index: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([int(seed), SPLIT_CODE[split], int(index)]))


@dataclass(frozen=True)
class LoadedScene:
    """A scene ready to simulate: its spec, the MJCF text and the instrumented model."""

    spec: SceneSpec
    mjcf: str
    """Self-contained MJCF: includes inlined, file assets renamed to keys of ``assets``."""
    inst: Instrumented
    mjcf_path: str = ""
    assets: dict[str, bytes] = field(default_factory=dict)
    """Bytes of the files the MJCF reads (meshes, textures, ...), by the name it uses."""
    warnings: tuple[str, ...] = ()
    """MuJoCo's warnings while loading and compiling the model (e.g. deprecated attributes)."""


@contextmanager
def mujoco_messages() -> Iterator[list[str]]:
    """Collect MuJoCo's warnings (``mju_user_warning``) in the yielded list while inside.

    Without a handler MuJoCo prints them and appends them to ``MUJOCO_LOG.TXT`` in the
    current folder; here they go to the caller, who prints them and stores them in the
    dataset (``mujoco_warnings``). The previous handler is restored on exit.
    """
    got: list[str] = []
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda msg: got.append(str(msg).strip()))
    try:
        yield got
    finally:
        mujoco.set_mju_user_warning(previous)


def self_contained_mjcf(path: str | Path) -> tuple[str, dict[str, bytes]]:
    """The MJCF file ``path`` as its text and every file it reads, by the name it reads it.

    The text is the file's own, unchanged; the dict holds the ``<include>`` files
    (recursively) and the assets' files (meshes, skins, height fields, textures) under
    the names MuJoCo looks them up by (the attribute, prefixed with ``meshdir`` or
    ``texturedir``), so ``mujoco.MjModel.from_xml_string(text, assets)`` builds the same
    model with no base directory, on any machine (:func:`mdgs.data.io.model_from_dataset`).
    Generation compiles the model that way too, so a file the dict lacks is an error
    there, never on another machine.
    """
    import xml.etree.ElementTree as ET

    path = Path(path).resolve()
    root = path.parent
    assets: dict[str, bytes] = {}

    def read(name: str, f: Path) -> None:
        if name in assets:
            return
        try:
            assets[name] = f.read_bytes()
        except OSError as e:
            raise SceneError(
                f"{path} reads {f}, which cannot be read ({e.strerror or e}); put the file there or fix the path"
            ) from None

    def includes(f: Path) -> None:
        try:
            tree = ET.fromstring(f.read_text())
        except (OSError, ET.ParseError) as e:
            raise SceneError(f"{f} is not a readable MJCF file ({e}); fix the XML") from None
        for inc in tree.iter("include"):
            name = inc.get("file", "")
            g = Path(name) if Path(name).is_absolute() else root / name
            if name and name not in assets:
                read(name, g)
                includes(g)

    includes(path)
    try:
        spec = mujoco.MjSpec.from_file(str(path))
    except Exception as e:
        raise SceneError(f"MuJoCo cannot parse {path}: {str(e).strip().splitlines()[0]}") from None

    comp = spec.compiler
    files = [(m.file, comp.meshdir) for m in spec.meshes]
    files += [(k.file, comp.meshdir) for k in spec.skins]
    files += [(h.file, comp.meshdir) for h in spec.hfields]
    for t in spec.textures:
        files += [(t.file, comp.texturedir)] + [(c, comp.texturedir) for c in t.cubefiles]
    for name, folder in files:
        if not name:
            continue
        key = name
        if not Path(name).is_absolute() and folder:
            key = (folder if folder.endswith("/") else folder + "/") + name
        read(key, Path(key) if Path(key).is_absolute() else root / key)
    return path.read_text(), assets


def load_scene(spec: SceneSpec, partition: PartitionParams = PartitionParams()) -> LoadedScene:
    """Instrument ``spec``'s model; a user's MJCF file is first made self-contained.

    MuJoCo's warnings are collected in :attr:`LoadedScene.warnings` (never written to
    ``MUJOCO_LOG.TXT``).
    """
    path = getattr(spec.builder, "path", None)
    with mujoco_messages() as got, warnings.catch_warnings(record=True) as py:
        warnings.simplefilter("always")
        assets: dict[str, bytes] = {}
        if path is not None:
            mjcf, assets = self_contained_mjcf(path)
        else:
            mjcf = spec.mjcf()
        inst = instrument(mjcf, assets=assets, partition=partition)
    msgs = tuple(dict.fromkeys(got + [str(w.message).strip() for w in py]))
    return LoadedScene(
        spec=spec, mjcf=mjcf, inst=inst, mjcf_path=str(path or ""), assets=assets, warnings=msgs
    )


def _state_slices(model: mujoco.MjModel) -> dict[str, slice]:
    out, off = {}, 0
    for name, bit in (
        ("time", mujoco.mjtState.mjSTATE_TIME),
        ("qpos", mujoco.mjtState.mjSTATE_QPOS),
        ("qvel", mujoco.mjtState.mjSTATE_QVEL),
        ("act", mujoco.mjtState.mjSTATE_ACT),
    ):
        n = mujoco.mj_stateSize(model, bit)
        out[name] = slice(off, off + n)
        off += n
    return out


_REDUCERS: dict[tuple[int, int], tuple[Instrumented, FrameReducer]] = {}


def _reducer(inst: Instrumented, substeps: int) -> FrameReducer:
    """The scene's :class:`FrameReducer`, built once per process (its node lookup grids take
    a while) and reused by every batch."""
    key = (id(inst), int(substeps))
    hit = _REDUCERS.get(key)
    if hit is None or hit[0] is not inst:
        if len(_REDUCERS) >= 8:
            _REDUCERS.clear()
        hit = _REDUCERS[key] = (inst, FrameReducer(inst, substeps))
    return hit[1]


_W = mujoco.mjtWarning
_WARNING_FIX = {
    int(_W.mjWARN_INERTIA): "give every moving body positive mass and inertia",
    int(_W.mjWARN_CONTACTFULL): 'enlarge MuJoCo\'s arena with <size memory="..."/> in the MJCF',
    int(_W.mjWARN_CNSTRFULL): 'enlarge MuJoCo\'s arena with <size memory="..."/> in the MJCF',
    int(_W.mjWARN_BADCTRL): "keep the controls finite (actuator ctrlrange)",
}


def _refuse_warnings(
    batch: mujoco.batch.Batch, scene: LoadedScene, split: str, ids: Sequence[int], f: int
) -> None:
    """Raise :class:`SceneError` if MuJoCo warned in any simulation of the last call.

    A warning means MuJoCo reset the state (NaN, Inf or huge values), dropped contacts or
    constraints, or clamped inputs; :meth:`mujoco.batch.Batch.rollout` then stops that
    simulation and repeats its last records. Such data is never written.
    """
    counts = batch.warning[:, :, 1]
    if not counts.any():
        return
    r, w = (int(i) for i in np.argwhere(counts)[0])
    text = mujoco.mju_warningText(w, int(batch.warning[r, w, 0])).strip().rstrip(".")
    m = scene.inst.model
    integ = [n for n in scene.inst.notes if n.startswith("integrator")]
    fix = _WARNING_FIX.get(
        w,
        f"the model is unstable as simulated (Euler, timestep {m.opt.timestep:g} s"
        + (f"; {integ[0]}" if integ else "")
        + "): lower <option timestep> or add joint damping or armature",
    )
    raise SceneError(
        f"MuJoCo warned while simulating {split} trajectory {ids[r]} in frame {f} ({text}); "
        f"no data was written, since its state was reset or its forces cut short: {fix}"
    )


def simulate(
    scene: LoadedScene,
    split: str,
    ids: Sequence[int],
    seed: int,
    n_frames: int,
    *,
    block_bytes: int = 8 << 20,
) -> dict[str, np.ndarray]:
    """Per-frame arrays ``[len(ids), n_frames, ...]`` (see :mod:`mdgs.data.schema`).

    The batch is stepped one frame per call, on one thread (closed-loop controllers read
    the state at each frame), and the per-step records of a block of frames (about
    ``block_bytes``) are reduced together.

    Contact sensors cost time even when nothing touches, so while few trajectories are
    in contact the batch steps the instrumented model without them
    (``Instrumented.lean_model``, identical dynamics) and steps again just the
    trajectories that had contacts (``ncon > 0``) in the frame, from the saved state,
    with them, for their sensor data. The recorded values never depend on which model
    stepped a frame, only the time does.
    """
    spec, inst = scene.spec, scene.inst
    m = inst.model
    R, k = len(ids), spec.substeps
    rngs = [rng_for(seed, split, i) for i in ids]
    sl = _state_slices(m)
    nphys = sl["act"].stop  # time, qpos, qvel, act lead the state vector
    data = mujoco.MjData(m)
    full = mujoco.batch.Batch(m, nsim=R, nthread=1)
    lean_m = inst.lean_model
    lean = mujoco.batch.Batch(lean_m, nsim=R, nthread=1) if lean_m is not None else None
    if lean is not None and lean.nstate != full.nstate:
        raise AssertionError("internal: the lean model's state differs from the model's")
    for r, rng in enumerate(rngs):
        mujoco.mj_resetData(m, data)
        spec.builder.initial_state(m, data, rng)
        mujoco.mj_getState(m, data, full.state[r], _INTEGRATION)
    state = full.state[:, :nphys].copy()
    ctrl = spec.builder.controller(m, rngs, n_frames, state[:, sl["qpos"]].copy())
    reduce = _reducer(inst, k)
    frames = np.empty((R, n_frames, nphys))
    ctrls = np.empty((R, n_frames, m.nu))
    out: dict[str, np.ndarray] = {}
    N = inst.partition.n_nodes
    loads: dict[str, np.ndarray] = {}  # per-frame loads [R, F, ...]
    kin = {key: np.empty((R, n_frames) + getattr(data, key).shape) for key in KINEMATICS}

    # a block: [frames, R, k, ...] per field, each frame's rows contiguous (rollout's out)
    lean_d = mujoco.MjData(lean_m) if lean_m is not None else None

    def buffers(d, fields):
        step = sum(4 if f == "ncon" else getattr(d, f).nbytes for f in fields)
        nfb = int(max(1, min(n_frames, block_bytes // max(1, R * k * step))))
        return {
            f: np.empty((nfb, R, k) + np.shape(getattr(d, f)), np.int32 if f == "ncon" else float)
            for f in fields
        }

    # per mode (lean: the model without contact sensors): record fields, block buffers
    record = {False: reduce.fields, True: reduce.lean_fields}
    bufs = {False: buffers(data, reduce.fields)}
    if lean is not None:
        bufs[True] = buffers(lean_d, reduce.lean_fields)
    def _checked(b: mujoco.batch.Batch, f: int, k: int, **kw) -> dict[str, np.ndarray]:
        """``b.rollout(k, **kw)``, refusing to go on once MuJoCo raised or warned."""
        try:
            out = b.rollout(k, **kw)
        except mujoco.batch.SimulationError as e:
            r = int(e.ids[0])
            raise SceneError(
                f"MuJoCo failed while simulating {split} trajectory {ids[r]} in frame {f}: "
                f"{' '.join(b.error(r).split())}; no data was written"
            ) from None
        _refuse_warnings(b, scene, split, ids, f)
        return out

    use_lean = False  # the first frame tells whether contacts are rare
    batch = full
    b0 = 0
    reruns, rerun_rows = [], []
    for f in range(n_frames):
        j = f - b0
        buf = bufs[use_lean]
        frames[:, f] = state
        u = ctrl(f, state[:, sl["qpos"]], state[:, sl["qvel"]]) if ctrl.closed_loop else ctrl(f)
        ctrls[:, f] = u
        control = np.repeat(u[:, None, :], k, axis=1) if m.nu else None
        saved = batch.state.copy() if use_lean else None
        rec = _checked(
            batch, f, k, control=control, record=record[use_lean],
            out={key: v[j] for key, v in buf.items()},
        )  # fmt: skip
        want = use_lean
        if lean is not None:
            hit = np.flatnonzero(rec["ncon"].any(1))
            if use_lean and len(hit):  # contacts: the same steps again, with the sensors
                full.state[hit] = saved[hit]
                reruns.append(
                    _checked(
                        full, f, k,
                        control=None if control is None else control[hit],
                        record=reduce.contact_fields,
                        ids=hit.astype(np.int32),
                    )  # fmt: skip
                )
                if not np.array_equal(full.state[hit], batch.state[hit]):
                    raise AssertionError("internal: the lean model's dynamics differ")
                rerun_rows.append(j * R + hit)
            # the cheaper model for the contacts of this frame, with hysteresis
            want = len(hit) <= R * (_LEAN_STAY if use_lean else _LEAN_ENTER)
        state = batch.state[:, :nphys].copy()
        if j + 1 < len(buf["cfrc_int"]) and f + 1 < n_frames and want == use_lean:
            continue
        # reduce the block [b0, f]: per-frame loads, frame-start fields
        nf = j + 1
        rec = {key: v[:nf].reshape((nf * R,) + v.shape[2:]) for key, v in buf.items()}
        qvel0 = None
        if reduce.implicit:  # rows of rec are frame-major: (frame j, trajectory r) -> j R + r
            qvel0 = np.swapaxes(frames[:, b0 : f + 1, sl["qvel"]], 0, 1).reshape(nf * R, -1)
        if use_lean:
            rows = np.concatenate(rerun_rows) if reruns else np.zeros(0, int)
            contact = {
                key: np.concatenate([c[key] for c in reruns]) if reruns else None
                for key in reduce.contact_fields
            }
            lo = reduce.loads(rec, contact, rows, qvel0=qvel0)
        else:
            lo = reduce.loads(rec, qvel0=qvel0)
        for key, v in lo.items():
            if v is None:
                continue
            if key not in loads:
                loads[key] = np.zeros((R, n_frames) + v.shape[1:], v.dtype)
            loads[key][:, b0 : f + 1] = np.swapaxes(v.reshape((nf, R) + v.shape[1:]), 0, 1)
        for key in KINEMATICS:
            kin[key][:, b0 : f + 1] = np.swapaxes(buf[key][:nf, :, 0], 0, 1)
        b0 = f + 1
        reruns, rerun_rows = [], []
        if want != use_lean:
            (lean if want else full).state[:] = batch.state
            use_lean, batch = want, (lean if want else full)

    # whole frames: actuator and joint loads, kinematics
    node_cf = loads.pop("node_cf", None)
    out["node_contact_force"] = np.zeros((R, n_frames, N, 3)) if node_cf is None else node_cf
    X = R * n_frames

    def flat(v):  # [R, F, ...] -> [X, ...] (a view)
        return v.reshape((X,) + v.shape[2:])

    res = reduce.finish({key: flat(v) for key, v in loads.items()})
    res.update(reduce.kinematics(*(flat(kin[key]) for key in KINEMATICS)))
    for key, v in res.items():
        out[key] = v.reshape((R, n_frames) + v.shape[1:])
    out["time"] = frames[:, :, sl["time"]][..., 0]
    out["qpos"] = frames[:, :, sl["qpos"]]
    out["qvel"] = frames[:, :, sl["qvel"]]
    out["act"] = frames[:, :, sl["act"]]
    out["ctrl"] = ctrls
    return out


def static_arrays(scene: LoadedScene) -> dict[str, np.ndarray]:
    """The ``/static`` group (see :data:`mdgs.data.schema.STATIC_ARRAYS`)."""
    inst, m, part = scene.inst, scene.inst.model, scene.inst.partition
    b = np.arange(1, m.nbody)
    R = np.zeros((len(b), 9))
    for i, bi in enumerate(b):
        mujoco.mju_quat2Mat(R[i], m.body_iquat[bi])
    R = R.reshape(-1, 3, 3)
    free = np.array(
        [
            m.body_parentid[x] == 0
            and m.body_jntnum[x] > 0
            and m.jnt_type[m.body_jntadr[x]] == mujoco.mjtJoint.mjJNT_FREE
            for x in b
        ],
        bool,
    )

    def names(objtype, n):
        return np.array([(mujoco.mj_id2name(m, objtype, i) or "") for i in n], dtype=object)

    return {
        "node_body": part.body.astype(np.int32),
        "node_geom": part.geom.astype(np.int32),
        "node_static": part.static,
        "node_mass": part.mass,
        "node_volume": part.volume,
        "node_tau": part.tau,
        "node_inertia": part.inertia,
        "node_centroid": part.centroid,
        "adjacency": part.adjacency.astype(np.int32),
        "body_id": b.astype(np.int32),
        "body_parent": m.body_parentid[b].astype(np.int32),
        "body_root": m.body_rootid[b].astype(np.int32),
        "body_free": free,
        "body_static": m.body_weldid[b] == 0,
        "body_mass": m.body_mass[b].astype(float),
        "body_inertia": R * m.body_inertia[b][:, None, :] @ R.transpose(0, 2, 1),
        "body_anchor_node": inst.anchor_node[b].astype(np.int32),
        "body_parent_anchor_node": inst.child_anchor_node[b].astype(np.int32),
        "body_names": names(mujoco.mjtObj.mjOBJ_BODY, b),
        "actuator_names": names(mujoco.mjtObj.mjOBJ_ACTUATOR, range(m.nu)),
        "joint_names": names(mujoco.mjtObj.mjOBJ_JOINT, range(m.njnt)),
    }


def scene_attrs(scene: LoadedScene) -> dict:
    """Root attributes that describe the scene (the generation adds seed, split, ...)."""
    m, spec = scene.inst.model, scene.spec
    return {
        "scene": spec.name,
        "family": spec.family,
        "summary": spec.summary,
        "mjcf_path": scene.mjcf_path,
        "dt": float(m.opt.timestep),
        "substeps": int(spec.substeps),
        "frame_dt": float(m.opt.timestep) * int(spec.substeps),
        "integrator": mujoco.mjtIntegrator(m.opt.integrator).name.removeprefix("mjINT_"),
        "mujoco_version": mujoco.__version__,
        "gravity": np.array(m.opt.gravity, float),
        "has_contact": bool(spec.has_contact),
        "free_floating": bool(spec.free_floating),
        "partition": json.dumps(scene.inst.partition.params.as_dict(), sort_keys=True),
        "node_counts": json.dumps(scene.inst.partition.summary()["per_body"]),
        "scene_params": json.dumps(spec.params(), sort_keys=True, default=list),
        "notes": json.dumps(list(scene.inst.notes)),
        "mujoco_warnings": json.dumps(list(scene.warnings)) if scene.warnings else "",
    }

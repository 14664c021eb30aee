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
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import mujoco.batch
import numpy as np

from mdgs.data.record import KINEMATICS, FrameReducer, Instrumented, instrument
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
    inst: Instrumented
    mjcf_path: str = ""


def load_scene(spec: SceneSpec, partition: PartitionParams = PartitionParams()) -> LoadedScene:
    mjcf = spec.mjcf()
    path = getattr(spec.builder, "path", None)
    inst = instrument(mjcf, path=path, partition=partition)
    return LoadedScene(spec=spec, mjcf=mjcf, inst=inst, mjcf_path=str(path or ""))


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
        rec = batch.rollout(
            k, control=control, record=record[use_lean], out={key: v[j] for key, v in buf.items()}
        )
        want = use_lean
        if lean is not None:
            hit = np.flatnonzero(rec["ncon"].any(1))
            if use_lean and len(hit):  # contacts: the same steps again, with the sensors
                full.state[hit] = saved[hit]
                reruns.append(
                    full.rollout(
                        k,
                        control=None if control is None else control[hit],
                        record=reduce.contact_fields,
                        ids=hit.astype(np.int32),
                    )
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
        if use_lean:
            rows = np.concatenate(rerun_rows) if reruns else np.zeros(0, int)
            contact = {
                key: np.concatenate([c[key] for c in reruns]) if reruns else None
                for key in reduce.contact_fields
            }
            lo = reduce.loads(rec, contact, rows)
        else:
            lo = reduce.loads(rec)
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
    }

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

from mdgs.data.record import RECORD_FIELDS, FrameReducer, Instrumented, instrument
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


def simulate(
    scene: LoadedScene,
    split: str,
    ids: Sequence[int],
    seed: int,
    n_frames: int,
    *,
    frames_per_call: int = 4,
    reduce_every: int = 10,
) -> dict[str, np.ndarray]:
    """Per-frame arrays ``[len(ids), n_frames, ...]`` (see :mod:`mdgs.data.schema`).

    The batch is stepped ``frames_per_call`` frames at a time (one frame at a time for
    closed-loop controllers, which read the state at each frame), on one thread.
    """
    spec, m = scene.spec, scene.inst.model
    R, k = len(ids), spec.substeps
    rngs = [rng_for(seed, split, i) for i in ids]
    sl = _state_slices(m)
    nstate = mujoco.mj_stateSize(m, _STATE)
    data = mujoco.MjData(m)
    batch = mujoco.batch.Batch(m, nsim=R, nthread=1)
    state = np.empty((R, nstate))
    for r, rng in enumerate(rngs):
        mujoco.mj_resetData(m, data)
        spec.builder.initial_state(m, data, rng)
        mujoco.mj_getState(m, data, batch.state[r], _INTEGRATION)
        mujoco.mj_getState(m, data, state[r], _STATE)
    ctrl = spec.builder.controller(m, rngs, n_frames, state[:, sl["qpos"]].copy())
    fpc = 1 if ctrl.closed_loop else max(1, frames_per_call)
    # open loop: reduce each call's records in place; closed loop (one frame per call):
    # frames are recorded straight into a block, numpy's per-call cost is paid per block
    reduce_frames = max(1, reduce_every)
    reduce = FrameReducer(scene.inst, k)
    record = (*RECORD_FIELDS, int(_STATE))
    out: dict[str, np.ndarray] = {}
    frames = np.empty((R, n_frames, nstate))
    ctrls = np.empty((R, n_frames, m.nu))

    def store(red: dict, f0: int, f1: int, frame_major: bool) -> None:
        for key, v in red.items():
            if key not in out:
                out[key] = np.empty((R, n_frames) + v.shape[1:], v.dtype)
            if frame_major:  # rows ordered (frame, trajectory)
                out[key][:, f0:f1] = np.swapaxes(v.reshape((f1 - f0, R) + v.shape[1:]), 0, 1)
            else:  # rows ordered (trajectory, frame)
                out[key][:, f0:f1] = v.reshape((R, f1 - f0) + v.shape[1:])

    bufs: dict | None = None
    block: dict | None = None  # closed loop: [frames, R, k, ...] so that each frame is contiguous
    block_start = 0
    for f0 in range(0, n_frames, fpc):
        f1 = min(n_frames, f0 + fpc)
        nf = f1 - f0
        if ctrl.closed_loop:
            u = ctrl(f0, state[:, sl["qpos"]], state[:, sl["qvel"]])[:, None, :]
        else:
            u = ctrl.block(f0, f1)
        ctrls[:, f0:f1] = u
        control = np.repeat(u, k, axis=1) if m.nu else None
        frames[:, f0] = state
        if ctrl.closed_loop:
            j = f0 - block_start
            rec = batch.rollout(
                k,
                control=control,
                record=record,
                out=None if block is None else {key: v[j] for key, v in block.items()},
            )
            if block is None:
                block = {
                    key: np.empty((reduce_frames,) + v.shape, v.dtype) for key, v in rec.items()
                }
                for key, v in rec.items():
                    block[key][0] = v
            state = rec[int(_STATE)][:, -1].copy()
            if j + 1 == reduce_frames or f1 == n_frames:
                rows = j + 1
                red = reduce.frames(
                    {key: v[:rows].reshape((rows * R,) + v.shape[2:]) for key, v in block.items()}
                )
                store(red, block_start, f1, frame_major=True)
                block_start = f1
        else:
            reuse = bufs if (bufs is not None and nf == fpc) else None
            rec = batch.rollout(nf * k, control=control, record=record, out=reuse)
            if nf == fpc:
                bufs = rec  # output buffers reused by every full-size call (no page faults)
            st = rec[int(_STATE)]
            if nf > 1:
                frames[:, f0 + 1 : f1] = st[:, k - 1 : (nf - 1) * k : k]
            state = st[:, -1].copy()
            store(
                reduce.frames(
                    {key: v.reshape((R * nf, k) + v.shape[2:]) for key, v in rec.items()}
                ),
                f0,
                f1,
                frame_major=False,
            )
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

"""Simulate a batch of trajectories of one scene and reduce them to recorded frames.

``simulate(scene, split, ids, seed, n_frames)`` returns the per-frame arrays of
:data:`mdgs.data.schema.FRAME_ARRAYS` for trajectories ``ids`` of ``split``. A
trajectory depends only on (scene, seed, split, index): its random generator is
``SeedSequence([seed, SPLIT_CODE[split], index])``, rollout starts from a zero solver
warm start at every call, and every reduction is per trajectory, so batches, workers
and shards never change its bits.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from mujoco import rollout

from mdgs.data.record import FrameReducer, Instrumented, instrument
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
    frames_per_call: int = 10,
) -> dict[str, np.ndarray]:
    """Per-frame arrays ``[len(ids), n_frames, ...]`` (see :mod:`mdgs.data.schema`)."""
    spec, m = scene.spec, scene.inst.model
    R, k = len(ids), spec.substeps
    rngs = [rng_for(seed, split, i) for i in ids]
    nstate = mujoco.mj_stateSize(m, _STATE)
    sl = _state_slices(m)
    data = mujoco.MjData(m)
    state = np.empty((R, nstate))
    for r, rng in enumerate(rngs):
        mujoco.mj_resetData(m, data)
        spec.builder.initial_state(m, data, rng)
        mujoco.mj_getState(m, data, state[r], _STATE)
    ctrl = spec.builder.controller(m, rngs, n_frames, state[:, sl["qpos"]].copy())
    fpc = 1 if ctrl.closed_loop else max(1, frames_per_call)
    reduce = FrameReducer(scene.inst, k)
    datas = [mujoco.MjData(m)]
    warm = np.zeros((R, m.nv))
    out: dict[str, np.ndarray] = {}
    frames = np.empty((R, n_frames, nstate))
    ctrls = np.empty((R, n_frames, m.nu))
    pending: list[np.ndarray] = []
    pending_start = 0
    reduce_frames = max(fpc, frames_per_call)
    for f0 in range(0, n_frames, fpc):
        f1 = min(n_frames, f0 + fpc)
        nf = f1 - f0
        if ctrl.closed_loop:
            u = ctrl(f0, state[:, sl["qpos"]], state[:, sl["qvel"]])[:, None, :]
        else:
            u = ctrl.block(f0, f1)
        ctrls[:, f0:f1] = u
        control = np.ascontiguousarray(np.repeat(u, k, axis=1)) if m.nu else None
        st, sd = rollout.rollout(m, datas, state, control, nstep=nf * k, initial_warmstart=warm)
        frames[:, f0] = state
        if nf > 1:
            frames[:, f0 + 1 : f1] = st[:, k - 1 : (nf - 1) * k : k]
        pending.append(sd)
        if f1 - pending_start >= reduce_frames or f1 == n_frames:
            # reduce several frames at once: numpy's per-call cost is paid once per block
            red = reduce(pending[0] if len(pending) == 1 else np.concatenate(pending, axis=1))
            for key, v in red.items():
                if key not in out:
                    out[key] = np.empty((R, n_frames) + v.shape[2:], v.dtype)
                out[key][:, pending_start:f1] = v
            pending, pending_start = [], f1
        state = np.ascontiguousarray(st[:, -1])
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

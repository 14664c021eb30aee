"""One dataset split in memory, as the models, the trainer and the evaluator read it.

:func:`load_split` reads a ``{split}.h5`` written by ``mdgs generate`` (checked by
:func:`mdgs.data.io.open_dataset`) into a :class:`SplitData`: node states for the learned
models, MuJoCo's own state (``qpos``, ``qvel``, ``act``) for the MuJoCo reference, the
actuator controls, and the static description of the scene.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from mdgs.data.schema import DatasetError

__all__ = ["SplitData", "load_split", "load_splits", "control_map"]


@dataclass
class SplitData:
    """One split in memory.

    x, v : [T, F, N, 3] float32 node positions (m) and velocities (m/s).
    ctrl : [T, F, nu] float32 actuator controls (actuator units), held over frame t -> t+1.
    control_sign : [nu, N] float32, +1 on nodes of the body actuator k drives, -1 on its
        parent's (:func:`control_map`); per-node control features are ``ctrl @ control_sign``.
    qpos, qvel, act : [T, F, nq | nv | na] float64 MuJoCo state of every frame.
    static : the file's ``/static`` arrays.  attrs : root attributes.  mjcf : the MJCF text.
    frame_dt : s.  has_contact : the scene can have contact.  path : the file.
    """

    x: np.ndarray
    v: np.ndarray
    ctrl: np.ndarray
    control_sign: np.ndarray
    static: dict
    attrs: dict
    frame_dt: float
    has_contact: bool
    mjcf: str = ""
    qpos: np.ndarray | None = None
    qvel: np.ndarray | None = None
    act: np.ndarray | None = None
    path: str = ""
    assets: dict | None = None

    def mj_model(self):
        """The scene's ``mujoco.MjModel``, compiled from the stored MJCF and the files it reads."""
        import mujoco

        return mujoco.MjModel.from_xml_string(self.mjcf, self.assets or None)

    @property
    def control(self) -> np.ndarray:
        """Per-node control features ``[T, F, N, nu]``: ``control[t, f, i, k] = sign[k, i] * ctrl_k``."""
        return np.einsum("tfk,kn->tfnk", self.ctrl, self.control_sign).astype(np.float32)

    def pairs(self, history: int = 0, future: int = 0) -> np.ndarray:
        """All (trajectory, frame) indices with ``history`` past frames, a next frame and ``future`` more -> [P, 2]."""
        T, F = self.x.shape[:2]
        return np.stack(np.meshgrid(np.arange(T), np.arange(history, F - 1 - future), indexing="ij"),
                        -1).reshape(-1, 2)

    @property
    def moving(self) -> np.ndarray:
        """[N] bool: nodes that move (not world geometry)."""
        return ~np.asarray(self.static["node_static"], bool)

    def identity(self) -> dict:
        """What a checkpoint must agree with: scene, MJCF hash, node and actuator counts."""
        return {"scene": str(self.attrs["scene"]), "family": str(self.attrs.get("family", "")),
                "mjcf_sha256": str(self.attrs["mjcf_sha256"]), "n_nodes": int(self.x.shape[2]),
                "n_actuators": int(self.ctrl.shape[-1])}


def control_map(mjcf, node_body: np.ndarray) -> np.ndarray:
    """Signs ``[nu, N]``: +1 on nodes of the body actuator k drives, -1 on its parent's, 0 elsewhere.

    The driven body is read from the MJCF compiled by MuJoCo: the body of the actuator's
    joint (transmission ``joint``/``jointinparent``) or of its site (``site``). Tendon and
    other transmissions drive no single body and get no nodes. Nodes of the world (body 0)
    get no reaction. The feature of node i is then ``control[i, k] = sign[k, i] * ctrl_k``.
    """
    import mujoco

    m = mujoco.MjModel.from_xml_string(mjcf) if isinstance(mjcf, str) else mjcf  # MJCF text or a compiled model
    node_body = np.asarray(node_body)
    sign = np.zeros((m.nu, len(node_body)), np.float32)
    for k in range(m.nu):
        typ, tid = int(m.actuator_trntype[k]), int(m.actuator_trnid[k, 0])
        if typ in (int(mujoco.mjtTrn.mjTRN_JOINT), int(mujoco.mjtTrn.mjTRN_JOINTINPARENT)):
            body = int(m.jnt_bodyid[tid])
        elif typ == int(mujoco.mjtTrn.mjTRN_SITE):
            body = int(m.site_bodyid[tid])
        else:
            continue
        parent = int(m.body_parentid[body])
        sign[k, node_body == body] = 1.0
        if parent != 0:
            sign[k, node_body == parent] = -1.0
    return sign


def load_split(path: str | os.PathLike) -> SplitData:
    """Read one dataset file (checked by :func:`mdgs.data.io.open_dataset`); reject non-finite states.

    Raises :class:`~mdgs.data.schema.DatasetError` naming the file and the fix.
    """
    from mdgs.data.io import model_from_dataset, open_dataset

    with open_dataset(path) as ds:
        x = ds.frames("node_pos").astype(np.float32)
        v = ds.frames("node_vel").astype(np.float32)
        ctrl = ds.frames("ctrl").astype(np.float32)  # [T, F, nu]
        qpos, qvel, act = ds.frames("qpos"), ds.frames("qvel"), ds.frames("act")
        static = dict(ds.static)
        attrs = dict(ds.attrs)
        mjcf = ds.mjcf
        assets = dict(getattr(ds, "assets", None) or {})
        model = model_from_dataset(ds) if ctrl.shape[-1] else None
    for name, a in (("node_pos", x), ("node_vel", v), ("ctrl", ctrl), ("qpos", qpos), ("qvel", qvel), ("act", act)):
        if not np.isfinite(a).all():  # also MuJoCo's state: the reference and the evaluation start from it
            t = int(np.argwhere(~np.isfinite(a))[0][0])
            raise DatasetError(f"{path}: /frames/{name} holds NaN or infinite values (first in trajectory {t}); "
                               "regenerate the dataset with `mdgs generate` or remove that trajectory")
    if x.shape[1] < 2:
        raise DatasetError(f"{path} has fewer than 2 frames per trajectory; generate a dataset with more frames")
    sign = control_map(model, static["node_body"]) if ctrl.shape[-1] else np.zeros((0, x.shape[2]), np.float32)
    return SplitData(x=x, v=v, ctrl=ctrl, control_sign=sign, static=static, attrs=attrs,
                     frame_dt=float(attrs["frame_dt"]), has_contact=bool(attrs["has_contact"]), mjcf=mjcf,
                     qpos=qpos, qvel=qvel, act=act, path=str(path), assets=assets)


def load_splits(folder: str | os.PathLike, names: tuple[str, ...]) -> dict[str, SplitData]:
    """``{name: load_split(folder / f"{name}.h5")}``; DatasetError if ``folder`` is missing or not a folder."""
    from pathlib import Path

    folder = Path(folder)
    if not folder.exists():
        raise DatasetError(f"data folder {folder} does not exist; create it with `mdgs generate SCENE --out {folder}`")
    if not folder.is_dir():
        raise DatasetError(f"data folder {folder} is a file, not a folder; pass the folder that "
                           "`mdgs generate --out` wrote (it holds train.h5, valid.h5, test.h5)")
    return {n: load_split(folder / f"{n}.h5") for n in names}

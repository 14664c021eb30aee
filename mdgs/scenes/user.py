"""A user's own MJCF file as a scene: ``mdgs generate --mjcf FILE``.

Any MJCF of rigid bodies works: primitive geoms are partitioned exactly, mesh geoms
through their convex hull. What cannot be recorded faithfully is refused with one
sentence naming the element and the fix (flex bodies, mocap bodies, equality
constraints, fluid forces, gravity compensation, actuators applying external forces,
height fields or SDF geoms on moving bodies); see :func:`mdgs.data.record.instrument`.

Initial state: the model's first keyframe if it has one, else ``qpos0``, with small
random joint velocities (0.05 rad/s or m/s, std). Controls: smooth random signals
(sums of sinusoids, 0.2-2 Hz) inside each actuator's ``ctrlrange`` ([-1, 1] if
unlimited). The integrator is forced to Euler (see ``notes`` in the file).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from mdgs.scenes._spec import SceneBuilder, SceneSpec
from mdgs.scenes.controls import smooth_targets

__all__ = ["UserScene", "user_scene"]


@dataclass(frozen=True)
class UserScene(SceneBuilder):
    path: str
    timestep: float
    substeps: int = 10
    velocity_noise: float = 0.05

    def mjcf(self) -> str:
        return Path(self.path).read_text()

    def initial_state(
        self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator
    ) -> None:
        if model.nkey:
            mujoco.mj_resetDataKeyframe(model, data, 0)
        data.qvel[:] = data.qvel + rng.normal(0, self.velocity_noise, model.nv)

    def controls(
        self, model: mujoco.MjModel, rng: np.random.Generator, qpos0: np.ndarray, n_frames: int
    ) -> np.ndarray:
        """Smooth random signals inside each actuator's ctrlrange ([-1, 1] if unlimited)."""
        if model.nu == 0:
            return np.zeros((n_frames, 0))
        lim = model.actuator_ctrllimited.astype(bool)
        low = np.where(lim, model.actuator_ctrlrange[:, 0], -1.0)
        high = np.where(lim, model.actuator_ctrlrange[:, 1], 1.0)
        return smooth_targets(rng, n_frames, self.frame_dt, low, high)


def user_scene(path: str, substeps: int = 10) -> SceneSpec:
    """Describe the MJCF file ``path`` as a scene (name: the file's stem)."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"MJCF file {path} " + ("is a folder, not a file" if p.is_dir() else "does not exist"))
    try:
        model = mujoco.MjModel.from_xml_path(str(p))
    except Exception as e:
        raise ValueError(f"MuJoCo cannot load {path}: {str(e).strip().splitlines()[0]}") from None
    contact = not (model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_CONTACT)) and bool(
        np.any((model.geom_contype | model.geom_conaffinity) != 0)
    )
    free = bool(np.any(model.jnt_type == int(mujoco.mjtJoint.mjJNT_FREE)))
    builder = UserScene(
        path=str(p.resolve()), timestep=float(model.opt.timestep), substeps=int(substeps)
    )
    return SceneSpec(
        p.stem, "user", f"User MJCF {p.name}.", builder, has_contact=contact, free_floating=free
    )

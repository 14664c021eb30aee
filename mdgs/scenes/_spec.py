"""What a scene is: a parameterised MJCF builder plus its initial states and controls."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from mdgs.scenes.controls import Controller, OpenLoop

__all__ = ["SceneBuilder", "SceneSpec", "SPLITS"]

SPLITS = ("train", "valid", "test")


class SceneBuilder:
    """Base of the frozen dataclasses of physical parameters that write one family's MJCF.

    A builder writes the MJCF (:meth:`mjcf`), sets a trajectory's initial state
    (:meth:`initial_state`) and gives the batch's controls (:meth:`controller`). Open-loop
    builders write only :meth:`controls`, the table of one trajectory; a closed-loop one
    (the Cubli's balance controller) overrides :meth:`controller`. The base has no
    dataclass fields, so a builder's parameters (``dataclasses.asdict``) are its own.
    """

    timestep: float  # s, integrator step h
    substeps: int  # integrator steps per recorded frame

    @property
    def frame_dt(self) -> float:
        """Time between recorded frames (s): ``timestep * substeps``."""
        return self.timestep * self.substeps

    def mjcf(self) -> str:
        """The scene's MJCF text."""
        raise NotImplementedError

    def initial_state(
        self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator
    ) -> None:
        """Set ``data.qpos``/``data.qvel`` (and ``ctrl`` if needed) of one trajectory."""
        raise NotImplementedError

    def controller(
        self,
        model: mujoco.MjModel,
        rngs: Sequence[np.random.Generator],
        n_frames: int,
        qpos0: np.ndarray,
    ) -> Controller:
        """Controls of a batch; ``qpos0 [R, nq]`` are the trajectories' initial positions.

        By default open loop: :meth:`controls` of each trajectory, from its own generator
        (drawn after :meth:`initial_state` used it).
        """
        per_traj = zip(rngs, qpos0, strict=True)
        return OpenLoop(np.stack([self.controls(model, r, q, n_frames) for r, q in per_traj]))

    def controls(
        self, model: mujoco.MjModel, rng: np.random.Generator, qpos0: np.ndarray, n_frames: int
    ) -> np.ndarray:
        """Open-loop controls ``[n_frames, nu]`` of one trajectory starting at ``qpos0 [nq]``."""
        raise NotImplementedError


@dataclass(frozen=True)
class SceneSpec:
    """One registered scene (see :data:`mdgs.scenes.SCENES`)."""

    name: str
    family: str
    summary: str
    """One sentence: what moves and what it touches."""
    builder: SceneBuilder
    has_contact: bool
    """Whether contacts can occur (a model may skip its contact branch when False)."""
    free_floating: bool
    """Whether the scene has a free-floating system (free joint), for Eq. (11) checks."""
    splits: tuple[str, ...] = SPLITS
    variant_of: str | None = None
    """For the generalization variants (Table 3): the scene a model is trained on."""

    @property
    def timestep(self) -> float:
        return float(self.builder.timestep)

    @property
    def substeps(self) -> int:
        return int(self.builder.substeps)

    @property
    def frame_dt(self) -> float:
        return self.timestep * self.substeps

    def mjcf(self) -> str:
        return self.builder.mjcf()

    def params(self) -> dict:
        return {"builder": type(self.builder).__name__, **dataclasses.asdict(self.builder)}

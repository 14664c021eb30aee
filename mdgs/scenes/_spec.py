"""What a scene is: a parameterised MJCF builder plus its initial states and controls."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import mujoco
import numpy as np

from mdgs.scenes.controls import Controller

__all__ = ["SceneBuilder", "SceneSpec", "SPLITS"]

SPLITS = ("train", "valid", "test")


class SceneBuilder(Protocol):
    """A frozen dataclass of physical parameters that writes one family's MJCF."""

    timestep: float  # s, integrator step h
    substeps: int  # integrator steps per recorded frame

    def mjcf(self) -> str: ...

    def initial_state(
        self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator
    ) -> None:
        """Set ``data.qpos``/``data.qvel`` (and ``ctrl`` if needed) of one trajectory."""
        ...

    def controller(
        self,
        model: mujoco.MjModel,
        rngs: Sequence[np.random.Generator],
        n_frames: int,
        qpos0: np.ndarray,
    ) -> Controller:
        """Controls of a batch; ``qpos0 [R, nq]`` are the trajectories' initial positions."""
        ...


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

"""Scenes of the MDGS datasets (paper section 4.1, Appendix B.4), built as MJCF by code.

``SCENES`` maps a scene name to its :class:`SceneSpec`: 15 training scenes (3 Cubli,
3 complex rotational bodies, 3 space robots, 4 vehicles, 2 UR5-Husky) and the four
generalization variants of the triple-flywheel Cubli (Table 3), which are test sets.
A user's own MJCF file becomes a scene with :func:`user_scene`.
"""

from __future__ import annotations

from mdgs.scenes._spec import SPLITS, SceneBuilder, SceneSpec
from mdgs.scenes.cubli import Cubli

__all__ = [
    "SCENES",
    "SceneSpec",
    "SceneBuilder",
    "SPLITS",
    "TRAINING_SCENES",
    "VARIANTS",
    "get_scene",
    "user_scene",
]


def _cubli(name, summary, variant_of=None, **kw) -> SceneSpec:
    splits = ("test",) if variant_of else SPLITS
    return SceneSpec(
        name,
        "cubli",
        summary,
        Cubli(**kw),
        has_contact=True,
        free_floating=True,
        splits=splits,
        variant_of=variant_of,
    )


_ALL: list[SceneSpec] = [
    _cubli(
        "cubli-single",
        "Cube with one flywheel (x): jumps from a face onto an edge by braking the wheel and balances on the edge.",
        wheels="x",
    ),
    _cubli(
        "cubli-double",
        "Cube with two flywheels (x, y): jumps onto edges and balances on an edge or a corner.",
        wheels="xy",
    ),
    _cubli(
        "cubli-triple",
        "Cube with three flywheels (x, y, z): jumps onto edges and balances on an edge or a corner.",
        wheels="xyz",
    ),
]

_VARIANTS: list[SceneSpec] = [
    _cubli(
        "cubli-triple-intense",
        "cubli-triple with 1.8x disturbances, tilts and jump strength (Table 3: more intense motion).",
        variant_of="cubli-triple",
        wheels="xyz",
        intensity=1.8,
    ),
    _cubli(
        "cubli-triple-gentle",
        "cubli-triple with 0.5x disturbances, tilts and jump strength (Table 3: less intense motion).",
        variant_of="cubli-triple",
        wheels="xyz",
        intensity=0.5,
    ),
    _cubli(
        "cubli-triple-shape",
        "cubli-triple with a 0.15 x 0.15 x 0.18 m box instead of the cube (Table 3: shape varied).",
        variant_of="cubli-triple",
        wheels="xyz",
        size=(0.15, 0.15, 0.18),
    ),
    _cubli(
        "cubli-triple-density",
        "cubli-triple with a 1.5x denser frame (1.2 kg instead of 0.8 kg; Table 3: density varied).",
        variant_of="cubli-triple",
        wheels="xyz",
        frame_mass=1.2,
    ),
]

SCENES: dict[str, SceneSpec] = {s.name: s for s in _ALL + _VARIANTS}
TRAINING_SCENES: tuple[str, ...] = tuple(s.name for s in _ALL)
VARIANTS: tuple[str, ...] = tuple(s.name for s in _VARIANTS)


def get_scene(name: str) -> SceneSpec:
    """The registered scene ``name``; ``KeyError`` names the known scenes."""
    try:
        return SCENES[name]
    except KeyError:
        raise KeyError(f"unknown scene '{name}'; known scenes: {', '.join(SCENES)}") from None


def user_scene(path: str, substeps: int = 10) -> SceneSpec:
    """A scene from a user's MJCF file (see :mod:`mdgs.scenes.user`)."""
    from mdgs.scenes.user import user_scene as _user

    return _user(path, substeps)

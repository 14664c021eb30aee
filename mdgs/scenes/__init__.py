"""Scenes of the MDGS datasets (paper section 4.1, Appendix B.4), built as MJCF by code.

``SCENES`` maps a scene name to its :class:`SceneSpec`: 15 training scenes (3 Cubli,
3 complex rotational bodies, 3 space robots, 4 vehicles, 2 UR5-Husky) and the four
generalization variants of the triple-flywheel Cubli (Table 3), which are test sets.
A user's own MJCF file becomes a scene with :func:`user_scene`.
"""

from __future__ import annotations

from mdgs.scenes._spec import SPLITS, SceneBuilder, SceneSpec
from mdgs.scenes.cubli import Cubli
from mdgs.scenes.rotational import RotationalBody
from mdgs.scenes.space import SpaceRobot
from mdgs.scenes.ur5husky import UR5Husky
from mdgs.scenes.vehicle import Vehicle

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


def _scene(
    family: str, builder: SceneBuilder, name: str, summary: str, variant_of: str | None = None
) -> SceneSpec:
    """A built-in scene: each has contacts and a free-floating system; a variant is a test set."""
    splits = ("test",) if variant_of else SPLITS
    return SceneSpec(
        name, family, summary, builder, has_contact=True, free_floating=True, splits=splits,
        variant_of=variant_of,
    )  # fmt: skip


def _cubli(name, summary, variant_of=None, **kw) -> SceneSpec:
    return _scene("cubli", Cubli(**kw), name, summary, variant_of)


def _rot(name, summary, hinges) -> SceneSpec:
    return _scene("rotational", RotationalBody(hinges=hinges), name, summary)


def _space(name, summary, **kw) -> SceneSpec:
    return _scene("space", SpaceRobot(**kw), name, summary)


def _car(name, summary, variant) -> SceneSpec:
    return _scene("vehicle", Vehicle(variant=variant), name, summary)


def _ur5(name, summary, interaction) -> SceneSpec:
    return _scene("ur5husky", UR5Husky(interaction=interaction), name, summary)


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
    _rot(
        "rotational-none",
        "Gyroscope: a hub spinning on the floor with a motor-driven rotor in a bearing; wobbles, precesses, hits posts.",
        "none",
    ),
    _rot(
        "rotational-side",
        "The gyroscope with two arms hinged at the sides of its base, swung by servos (governor-like).",
        "side",
    ),
    _rot(
        "rotational-center",
        "The gyroscope with its column cut by a centre hinge whose motor tilts the spinning rotor.",
        "center",
    ),
    _space(
        "space-single",
        "Free-floating satellite (no gravity) with one 6-DoF arm tracking random joint targets; the base reacts.",
        arms=1,
    ),
    _space(
        "space-double",
        "Free-floating satellite with two 6-DoF arms on opposite faces, moving independently.",
        arms=2,
    ),
    _space(
        "space-strike",
        "Free-floating satellite with one arm, struck by a free 4 kg box thrown at it.",
        arms=1,
        strike=True,
    ),
    _car(
        "vehicle-original",
        "Four-wheeled car with rear-wheel drive and steering, driven by random throttle and steering on a floor.",
        "original",
    ),
    _car(
        "vehicle-fixed-obstacle",
        "The car driving towards a fixed wall and block, which it may hit.",
        "fixed_obstacle",
    ),
    _car(
        "vehicle-damaged",
        "The car with a flat rear-left tyre, a dead rear-left motor and a bent front-right axle.",
        "damaged",
    ),
    _car(
        "vehicle-movable-obstacle",
        "The car driving into a free 8 kg crate, which it pushes.",
        "movable_obstacle",
    ),
    _ur5(
        "ur5husky-original",
        "Skid-steered Husky base carrying a UR5-sized 6-DoF arm; base and arm follow random commands.",
        False,
    ),
    _ur5(
        "ur5husky-interaction",
        "The UR5-Husky creeping towards a table and sweeping a box and a can off it with the arm.",
        True,
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

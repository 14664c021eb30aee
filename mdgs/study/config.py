"""Study files (TOML): the grid of scenes, models, seeds and budgets that ``mdgs study`` runs.

A study file has these tables (every key optional unless marked; defaults in the dataclasses)::

    [study]
    name = "small"                      # required; an output folder holds one study
    preset = "small"                    # data preset of every scene (tiny, small, paper)
    trajectories = 440                  # total trajectories instead of the preset's, in the paper's
                                        # proportions (400/20/20); default 0: the preset's
    seeds = [0, 1, 2]
    device = "cpu"
    long_frames = 1100                  # stability test: frames of the long test trajectories (0: none)
    long_trajectories = 10              # how many long test trajectories
    failure_factor = 1.0                # failure: position MSE > factor x position variance of the split
    sensitivity = 1e-3                  # sensitivity floor: relative perturbation of initial velocities
    sensitivity_seeds = [0, 1, 2]

    [budget]                            # the same for every learned model
    epochs = 30
    max_steps = 0                       # cap on steps per epoch (0: a full pass)
    batch_size = 32
    valid_max_pairs = 0
    select = "last"                     # weights evaluated: last epoch, or best by "valid" / "rollout" / "rollout-or-start"
    select_frames = 0                   # rollout rules: score validation trajectories of this many frames
                                        # (0: the data's own; e.g. long_frames, to keep the epoch that is stable)
    ema = 0.0                           # weights evaluated as their moving average with this decay (0: off)

    [[scenes]]
    name = "cubli-triple"               # a built-in scene, or
    # mjcf = "examples/user.xml"        # a user's MJCF file (relative to the study file)
    variants = ["cubli-triple-intense"] # test-only variants the models are also evaluated on (Table 3)

    [[models]]
    name = "mdgs"                       # a key of mdgs.models.MODELS
    label = "mdgs"                      # row name (default: name)
    set = { hidden = 200 }              # config fields of the model

    [references]
    mujoco_dt_factors = [1, 2, 5, 10, 20]
    motors = true                       # also "constant twist + motors" (default false)
    joints = true                       # also "constant twist + joints" (and "+ motors + joints" with motors;
                                        # default false): what an MDGS whose network outputs zero simulates
    rigid_tree = true                   # also "rigid tree + joints" (default false): the scene's MJCF as a rigid
                                        # tree with contact, friction and limits, one step per frame (mdgs.actuation)
    rigid_tree_trapezoidal = true       # also "rigid tree + joints, trapezoidal" (default false): the same moving
                                        # each body with the mean of its old and new twist
    rigid_tree_push_out = true          # also "rigid tree + joints, trapezoidal, push-out" (default false): the
                                        # trapezoidal tree moved out of the world's surfaces after every step
    rigid_tree_substeps = [4]           # also the last rigid tree row in N substeps a frame, for each N (default [])
    rigid_tree_gyroscopic = ["implicit"] # also the last rigid tree row with its gyroscopic terms at each step's end
                                        # or halfway ("midpoint"), for each (default []; ConstantTwistConfig.gyroscopic)
    rigid_tree_momentum = true          # also the last rigid tree row with its twists projected onto the joints by
                                        # impulses (default false; ConstantTwistConfig.joint_velocities = "momentum")
    rigid_tree_coordinates = true       # also the last rigid tree row stepped in its joint coordinates (default
                                        # false; ConstantTwistConfig.joint_velocities = "coordinates")
    rigid_tree_soft = true              # also the last rigid tree row (not the momentum one) with MuJoCo's soft
                                        # contact instead of push-out (default false; ConstantTwistConfig.contact)

    [resolution]                        # MDGS error and cost against the element resolution
    model = "mdgs"                      # a registry name, or the label of a [[models]] row (its settings)
    refine = [1, 2]
    seeds = [0]

:func:`load_study` checks all of it and raises :class:`StudyError` naming the key and the fix.
"""

from __future__ import annotations

import hashlib
import json
import os
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

from mdgs.actuation import GYROSCOPIC
from mdgs.train.loop import SELECT

__all__ = ["StudyError", "SceneEntry", "ModelEntry", "Budget", "StudyConfig", "load_study"]


class StudyError(Exception):
    """A study file or output folder that cannot be used; the message names it and the fix."""


@dataclass(frozen=True)
class SceneEntry:
    """One scene of the grid: a built-in scene (``name``) or a user's MJCF file (``mjcf``)."""

    name: str
    mjcf: str | None = None
    substeps: int = 10
    variants: tuple[str, ...] = ()

    @property
    def key(self) -> str:
        return self.name


@dataclass(frozen=True)
class ModelEntry:
    """One model row: a registry name, its row label and config settings."""

    name: str
    label: str
    settings: tuple[tuple[str, object], ...] = ()

    @property
    def settings_dict(self) -> dict:
        return dict(self.settings)


@dataclass(frozen=True)
class Budget:
    """Training budget of every learned model (the same for all: an honest comparison)."""

    epochs: int = 30
    max_steps: int = 0
    batch_size: int = 32
    valid_max_pairs: int = 0
    select: str = "last"
    select_frames: int = 0
    ema: float = 0.0


@dataclass(frozen=True)
class StudyConfig:
    """A parsed study file (see the module docstring for the meaning of each field)."""

    name: str
    path: str
    preset: str = "small"
    trajectories: int = 0
    seeds: tuple[int, ...] = (0, 1, 2)
    device: str = "cpu"
    long_frames: int = 1100
    long_trajectories: int = 10
    failure_factor: float = 1.0
    sensitivity: float = 1e-3
    sensitivity_seeds: tuple[int, ...] = (0, 1, 2)
    budget: Budget = field(default_factory=Budget)
    scenes: tuple[SceneEntry, ...] = ()
    models: tuple[ModelEntry, ...] = ()
    mujoco_dt_factors: tuple[int, ...] = (1, 2, 5, 10, 20)
    motor_twist: bool = False
    joint_twist: bool = False
    rigid_tree: bool = False
    rigid_tree_trapezoidal: bool = False
    rigid_tree_push_out: bool = False
    rigid_tree_substeps: tuple[int, ...] = ()
    rigid_tree_gyroscopic: tuple[str, ...] = ()
    rigid_tree_momentum: bool = False
    rigid_tree_coordinates: bool = False
    rigid_tree_soft: bool = False
    resolution_model: str = "mdgs"
    resolution_label: str = "mdgs"
    resolution_settings: tuple[tuple[str, object], ...] = ()
    resolution_refine: tuple[int, ...] = ()
    resolution_seeds: tuple[int, ...] = (0,)

    def fingerprint(self) -> str:
        """Hash of everything that decides the results (not the file's path)."""
        d = asdict(self)
        d.pop("path")
        return hashlib.sha256(json.dumps(d, sort_keys=True, default=str).encode()).hexdigest()[:16]


_TOP = {"study", "budget", "scenes", "models", "references", "resolution"}


def _take(table: dict, key: str, kind, where: str, default=None, required: bool = False):
    if key not in table:
        if required:
            raise StudyError(f"{where}: the key {key!r} is missing; add it (see `mdgs study --help`)")
        return default
    val = table[key]
    ok = isinstance(val, kind) and not (kind in (int, float, (int, float)) and isinstance(val, bool))
    if not ok:
        name = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
        raise StudyError(f"{where}: {key} = {val!r} should be of type {name}")
    return val


def _ints(table, key, where, default, lo=0) -> tuple[int, ...]:
    vals = _take(table, key, list, where, list(default))
    if not all(isinstance(v, int) and not isinstance(v, bool) and v >= lo for v in vals):
        raise StudyError(f"{where}: {key} = {vals!r} should be a list of integers >= {lo}")
    return tuple(vals)


def _unknown(table: dict, known: set, where: str) -> None:
    extra = sorted(set(table) - known)
    if extra:
        raise StudyError(f"{where}: unknown key {extra[0]!r}; known keys are {', '.join(sorted(known))}")


def load_study(path: str | os.PathLike) -> StudyConfig:
    """Parse and check a study file -> :class:`StudyConfig`; StudyError naming what is wrong."""
    from mdgs.data.presets import PRESETS
    from mdgs.models import MODELS
    from mdgs.scenes import SCENES

    path = Path(path)
    if not path.is_file():
        raise StudyError(f"study file {path} " + ("is a folder" if path.is_dir() else "does not exist")
                         + "; pass a TOML file such as studies/tiny.toml")
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise StudyError(f"{path} is not valid TOML ({e})") from None
    f = str(path)
    _unknown(doc, _TOP, f)
    st = _take(doc, "study", dict, f, required=True)
    where = f"{f} [study]"
    _unknown(st, {"name", "preset", "trajectories", "seeds", "device", "long_frames", "long_trajectories",
                  "failure_factor", "sensitivity", "sensitivity_seeds"}, where)
    name = _take(st, "name", str, where, required=True)
    if not name.strip() or any(c in name for c in "/\\"):
        raise StudyError(f"{where}: name {name!r} must be a non-empty word without slashes")
    preset = _take(st, "preset", str, where, "small")
    if preset not in PRESETS:
        raise StudyError(f"{where}: preset {preset!r} is unknown; choose one of {', '.join(PRESETS)}")
    trajectories = _take(st, "trajectories", int, where, 0)
    if trajectories and trajectories < 3:
        raise StudyError(f"{where}: trajectories must be 0 (the preset's count) or at least 3 (one per split)")
    seeds = _ints(st, "seeds", where, (0, 1, 2))
    if not seeds:
        raise StudyError(f"{where}: seeds is empty; give at least one seed")
    device = _take(st, "device", str, where, "cpu")
    if device not in ("auto", "cpu", "cuda"):
        raise StudyError(f"{where}: device {device!r} is not one of auto, cpu, cuda")
    long_frames = _take(st, "long_frames", int, where, 1100)
    long_traj = _take(st, "long_trajectories", int, where, 10)
    if long_frames and long_frames < 2 or long_traj < 1:
        raise StudyError(f"{where}: long_frames must be 0 or >= 2 and long_trajectories >= 1")
    failure = float(_take(st, "failure_factor", (int, float), where, 1.0))
    sens = float(_take(st, "sensitivity", (int, float), where, 1e-3))
    if failure <= 0 or sens < 0:
        raise StudyError(f"{where}: failure_factor must be > 0 and sensitivity >= 0")
    sens_seeds = _ints(st, "sensitivity_seeds", where, (0, 1, 2))

    bt = _take(doc, "budget", dict, f, {})
    where = f"{f} [budget]"
    _unknown(bt, {"epochs", "max_steps", "batch_size", "valid_max_pairs", "select", "select_frames", "ema"}, where)
    budget = Budget(epochs=_take(bt, "epochs", int, where, 30), max_steps=_take(bt, "max_steps", int, where, 0),
                    batch_size=_take(bt, "batch_size", int, where, 32),
                    valid_max_pairs=_take(bt, "valid_max_pairs", int, where, 0),
                    select=_take(bt, "select", str, where, "last"),
                    select_frames=_take(bt, "select_frames", int, where, 0),
                    ema=float(_take(bt, "ema", (int, float), where, 0.0)))
    if not 0 <= budget.ema < 1:
        raise StudyError(f"{where}: ema = {budget.ema} must be from 0 (off) up to, not including, 1 (e.g. 0.99)")
    if budget.select not in SELECT:
        raise StudyError(f"{where}: select = {budget.select!r} is not one of {', '.join(SELECT)}")
    if budget.select_frames and (budget.select_frames < 2 or not budget.select.startswith("rollout")):
        raise StudyError(f"{where}: select_frames = {budget.select_frames} needs select = \"rollout\" or "
                         "\"rollout-or-start\" and at least 2 frames (0: the data's own validation trajectories)")
    if budget.epochs < 1 or budget.batch_size < 1 or budget.max_steps < 0 or budget.valid_max_pairs < 0:
        raise StudyError(f"{where}: epochs and batch_size must be >= 1, max_steps and valid_max_pairs >= 0")

    scenes = []
    for k, sc in enumerate(_take(doc, "scenes", list, f, required=True)):
        where = f"{f} [[scenes]] #{k + 1}"
        if not isinstance(sc, dict):
            raise StudyError(f"{where}: each scene is a table with name = ... or mjcf = ...")
        _unknown(sc, {"name", "mjcf", "substeps", "variants"}, where)
        mjcf = _take(sc, "mjcf", str, where)
        if mjcf is not None:
            mj = (path.parent / mjcf).resolve()
            if not mj.is_file():
                raise StudyError(f"{where}: MJCF file {mj} does not exist")
            sname = _take(sc, "name", str, where, Path(mjcf).stem)
            substeps = _take(sc, "substeps", int, where, 10)
            if substeps < 1:
                raise StudyError(f"{where}: substeps {substeps} must be at least 1")
            scenes.append(SceneEntry(sname, str(mj), substeps))
            continue
        sname = _take(sc, "name", str, where, required=True)
        if sname not in SCENES:
            raise StudyError(f"{where}: scene {sname!r} is unknown; see `mdgs generate --list`")
        variants = tuple(_take(sc, "variants", list, where, []))
        for v in variants:
            if v not in SCENES or SCENES[v].variant_of != sname:
                raise StudyError(f"{where}: {v!r} is not a test variant of {sname!r}")
        scenes.append(SceneEntry(sname, None, 10, variants))
    if not scenes:
        raise StudyError(f"{f}: [[scenes]] is empty; name at least one scene")
    if len({s.key for s in scenes}) != len(scenes):
        raise StudyError(f"{f}: a scene appears twice in [[scenes]]")

    models = []
    for k, m in enumerate(_take(doc, "models", list, f, required=True)):
        where = f"{f} [[models]] #{k + 1}"
        if not isinstance(m, dict):
            raise StudyError(f"{where}: each model is a table with name = ...")
        _unknown(m, {"name", "label", "set"}, where)
        mname = _take(m, "name", str, where, required=True)
        if mname not in MODELS:
            raise StudyError(f"{where}: model {mname!r} is unknown; choose one of {', '.join(MODELS)}")
        if not MODELS[mname].learned:
            raise StudyError(f"{where}: {mname!r} is a reference; references go in [references]")
        settings = _take(m, "set", dict, where, {})
        known = set(MODELS[mname].Config.__dataclass_fields__)
        bad = sorted(set(settings) - known)
        if bad:
            raise StudyError(f"{where}: model {mname!r} has no setting {bad[0]!r}; its settings are {', '.join(sorted(known))}")
        try:  # the values too, before anything runs (a model's Config checks its own ranges)
            MODELS[mname].Config(**settings)
        except (TypeError, ValueError) as e:
            raise StudyError(f"{where}: set = {settings!r} is not a valid setting of {mname!r} ({e})") from None
        models.append(ModelEntry(mname, _take(m, "label", str, where, mname), tuple(sorted(settings.items()))))
    if len({m.label for m in models}) != len(models):
        raise StudyError(f"{f}: two [[models]] share a label; give each a distinct label")

    rf = _take(doc, "references", dict, f, {})
    _unknown(rf, {"mujoco_dt_factors", "motors", "joints", "rigid_tree", "rigid_tree_trapezoidal",
                  "rigid_tree_push_out", "rigid_tree_substeps", "rigid_tree_gyroscopic", "rigid_tree_momentum",
                  "rigid_tree_coordinates", "rigid_tree_soft"},
             f"{f} [references]")
    dts = _ints(rf, "mujoco_dt_factors", f"{f} [references]", (1, 2, 5, 10, 20), lo=1)
    motors = _take(rf, "motors", bool, f"{f} [references]", False)
    joints = _take(rf, "joints", bool, f"{f} [references]", False)
    rigid_tree = _take(rf, "rigid_tree", bool, f"{f} [references]", False)
    rigid_trap = _take(rf, "rigid_tree_trapezoidal", bool, f"{f} [references]", False)
    rigid_push = _take(rf, "rigid_tree_push_out", bool, f"{f} [references]", False)
    rigid_sub = _ints(rf, "rigid_tree_substeps", f"{f} [references]", (), lo=2)
    if rigid_sub and not rigid_tree:
        raise StudyError(f"{f} [references]: rigid_tree_substeps steps the rigid tree; set rigid_tree = true with it")
    rigid_gyro = tuple(_take(rf, "rigid_tree_gyroscopic", list, f"{f} [references]", []))
    rules = [g for g in GYROSCOPIC if g != "explicit"]
    if any(g not in rules for g in rigid_gyro) or len(set(rigid_gyro)) != len(rigid_gyro):
        raise StudyError(f"{f} [references]: rigid_tree_gyroscopic lists distinct rules of {rules}, got {list(rigid_gyro)}")
    if rigid_gyro and not rigid_tree:
        raise StudyError(f"{f} [references]: rigid_tree_gyroscopic steps the rigid tree; set rigid_tree = true with it")
    rigid_momentum = _take(rf, "rigid_tree_momentum", bool, f"{f} [references]", False)
    if rigid_momentum and not (rigid_tree and joints):
        raise StudyError(f"{f} [references]: rigid_tree_momentum projects the rigid tree onto its joints; set "
                         "rigid_tree = true and joints = true with it")
    rigid_coordinates = _take(rf, "rigid_tree_coordinates", bool, f"{f} [references]", False)
    if rigid_coordinates and not (rigid_tree and joints):
        raise StudyError(f"{f} [references]: rigid_tree_coordinates steps the rigid tree in its joint coordinates; "
                         "set rigid_tree = true and joints = true with it")
    rigid_soft = _take(rf, "rigid_tree_soft", bool, f"{f} [references]", False)
    if rigid_soft and not rigid_tree:
        raise StudyError(f"{f} [references]: rigid_tree_soft gives the rigid tree MuJoCo's soft contact; set "
                         "rigid_tree = true with it")

    rs = _take(doc, "resolution", dict, f, {})
    where = f"{f} [resolution]"
    _unknown(rs, {"model", "refine", "seeds"}, where)
    rlabel = _take(rs, "model", str, where, "mdgs")
    row = next((m for m in models if m.label == rlabel), None)  # a [[models]] row: its model and settings
    rmodel, rsettings = (row.name, row.settings) if row is not None else (rlabel, ())
    if rs and rmodel not in MODELS:
        raise StudyError(f"{where}: model {rlabel!r} is neither a model of the registry nor the label of a "
                         f"[[models]] row; rows: {', '.join(m.label for m in models)}")
    if rs and not MODELS[rmodel].learned:
        raise StudyError(f"{where}: {rmodel!r} is a reference; the resolution study trains a learned model")
    refine = _ints(rs, "refine", where, (), lo=1)
    return StudyConfig(name=name, path=str(path.resolve()), preset=preset, trajectories=trajectories, seeds=seeds, device=device,
                       long_frames=long_frames, long_trajectories=long_traj, failure_factor=failure,
                       sensitivity=sens, sensitivity_seeds=sens_seeds, budget=budget, scenes=tuple(scenes),
                       models=tuple(models), mujoco_dt_factors=dts, motor_twist=motors, joint_twist=joints,
                       rigid_tree=rigid_tree, rigid_tree_trapezoidal=rigid_trap,
                       rigid_tree_push_out=rigid_push, rigid_tree_substeps=rigid_sub,
                       rigid_tree_gyroscopic=rigid_gyro,
                       rigid_tree_momentum=rigid_momentum, rigid_tree_coordinates=rigid_coordinates,
                       rigid_tree_soft=rigid_soft,
                       resolution_model=rmodel, resolution_label=rlabel, resolution_settings=rsettings,
                       resolution_refine=refine, resolution_seeds=_ints(rs, "seeds", where, (0,)))

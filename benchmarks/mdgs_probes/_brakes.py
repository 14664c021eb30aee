"""What the Cubli probes share (brake_trajectories.py, cube_vs_wheels.py): the test split, the references and
trained runs named on the command line, the frame of t = 40 and which trajectories brake before it."""
import numpy as np

from mdgs.data.split import load_split
from mdgs.evaluate.metrics import frame_of
from mdgs.models import MODELS
from mdgs.runs import load_run


def split_models_and_brakes(argv: list[str]):
    """``argv`` = ``[DATA_FOLDER, LABEL=RUN_FOLDER, ...]`` -> ``(test split, {label: model}, frame of t = 40,
    [T] bool: a command above 5 N m before t = 40)``; the models are constant twist, constant twist + motors +
    joints, the rigid tree + joints and each run, evaluated with the weights its selection rule kept."""
    d = load_split(argv[0] + "/test.h5")
    ct = MODELS["constant-twist"]
    models = {"constant twist": ct(ct.Config()),
              "constant twist + motors + joints": ct(ct.Config(motors=True, joints=True)),
              "rigid tree + joints": ct(ct.Config(dynamics=True, joints=True))}
    for arg in argv[1:]:
        label, _, path = arg.partition("=")
        models[label] = load_run(path, "cpu")[0]
    t = frame_of(40, d.x.shape[1])
    return d, models, t, np.abs(d.ctrl[:, :t]).max((1, 2)) > 5.0

"""Does an MDGS run stay stable over 1100 frames, epoch by epoch, and can a validation rollout tell?

    python benchmarks/mdgs_probes/stability_by_epoch.py DATA LONG_TEST LONG_VALID SEED EPOCHS [key=value ...]

``DATA``: a study's dataset folder of the scene (train/valid/test.h5; e.g. small-select's
``OUT/data/hinge_slide_free``); ``LONG_TEST``: its long test set (``OUT/data/<scene>-long``);
``LONG_VALID``: the validation trajectories run for as many frames (``OUT/data/<scene>-valid1100``, or
``mdgs generate ... --split valid --frames 1100 --n-traj 10``). Trains MDGS (``key=value``: model
settings, e.g. ``actuation=prior``) at the small studies' recipe (batch 32, 512 validation pairs), one
epoch at a time, and after each epoch prints one JSON line: test position MSE at t = 40 and t = 110
(10^-3 m^2, mean over the trajectories that reached it), how many of the long test trajectories
never leave the failure threshold (the study's Stability table), and three rollout scores
(:func:`mdgs.evaluate.rollout.rollout_score`, m^2): on the validation split (what ``select =
"rollout"`` reads), on the long validation trajectories (what ``select_frames = 1100`` reads) and on
the long test set (what neither rule may read: the quantity the rules try to predict). Ends with the
epoch each rule keeps over the first 5 epochs (the studies' budget) and over all, and the
correlation over epochs of each validation score with the long test score. About 20 s per epoch on
the user scene (one thread). docs/mdgs-experiments.md ("Stable on one epoch, not on the next") quotes it.
"""
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

from mdgs.cli.train import parse_settings
from mdgs.data.split import load_split
from mdgs.evaluate.physics import hinge_anchors
from mdgs.evaluate.rollout import rollout_score
from mdgs.models import MODELS
from mdgs.runs import load_run
from mdgs.study.runner import _evaluate_set
from mdgs.train import TrainConfig, train

torch.set_num_threads(1)
data, long_test, long_valid = (Path(a) for a in sys.argv[1:4])
seed, epochs = int(sys.argv[4]), int(sys.argv[5])
kw = parse_settings(MODELS["mdgs"].Config, sys.argv[6:])
test, va = load_split(data / "test.h5"), load_split(data / "valid.h5")
lt, lv = load_split(long_test / "test.h5"), load_split(long_valid / "valid.h5")
anchors = hinge_anchors(test.mj_model())
dev = torch.device("cpu")


def mean_e3(values):
    ok = [v for v in values if v is not None]
    return round(1e3 * float(np.mean(ok)), 3) if ok else None


rows = []
with tempfile.TemporaryDirectory() as tmp:
    run = Path(tmp) / "run"
    for ep in range(1, epochs + 1):
        train(TrainConfig(data=str(data), out=str(run), model_name="mdgs", epochs=ep, batch_size=32, seed=seed,
                          device="cpu", valid_max_pairs=512, model=MODELS["mdgs"].Config(**kw)))
        model = load_run(run, dev)[0]
        r = _evaluate_set(model, test, dev, 1.0, anchors, False)
        long = _evaluate_set(model, lt, dev, 1.0, anchors, True)
        row = {"seed": seed, **kw, "epoch": ep, "t40": mean_e3(r["pos_mse_t40"]), "t110": mean_e3(r["pos_mse_t110"]),
               "stable": sum(t is None for t in long["time_to_failure"]), "of": len(long["time_to_failure"]),
               "score_valid": rollout_score(model, va, dev), "score_long_valid": rollout_score(model, lv, dev),
               "score_long_test": rollout_score(model, lt, dev)}
        rows.append(row)
        print(json.dumps(row), flush=True)
    shutil.rmtree(run, ignore_errors=True)
for n in sorted({min(5, epochs), epochs}):
    for key in ("score_valid", "score_long_valid"):
        pick = min(rows[:n], key=lambda x: x[key])
        print(f"first {n} epochs, lowest {key}: epoch {pick['epoch']}: t40 {pick['t40']}, t110 {pick['t110']}, "
              f"stable {pick['stable']}/{pick['of']}")
for key in ("score_valid", "score_long_valid"):
    c = np.corrcoef([x[key] for x in rows], [x["score_long_test"] for x in rows])[0, 1]
    print(f"correlation over epochs of {key} with score_long_test: {c:.2f}")

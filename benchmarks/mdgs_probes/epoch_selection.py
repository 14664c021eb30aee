"""Which epoch's weights roll out best, and can the validation split tell?

    python benchmarks/mdgs_probes/epoch_selection.py DATA_FOLDER OUT_DIR SEED EPOCHS [MODEL] [key=value ...]
    python benchmarks/mdgs_probes/epoch_selection.py --summary OUT_DIR/epoch_selection.jsonl [EARLY]

Trains ``MODEL`` (default mdgs) on ``DATA_FOLDER`` at the small study's recipe (batch 32, the model's
own rate and noise, 512 validation pairs), one epoch at a time (the run resumes), keeps every
epoch's weights, and rolls each out over the validation and the test split. Per epoch it prints the
one-step validation error the scheduler sees, the validation rollout score (position MSE averaged
over all frames and trajectories, each frame's error capped at the failure threshold, so a
diverged trajectory counts as failed, never as a large number), and the test MSE at t = 40 / 110
(mean over the trajectories not diverged, and how many). Then the test figures of three rules:
the last epoch (what every run of the studies uses), the epoch with the best one-step validation
error, and the epoch with the best validation rollout score. Appends one JSON line per run to
``OUT_DIR/epoch_selection.jsonl``. ``--summary`` prints, per data folder, the mean over seeds of
the test t = 40 / t = 110 under each rule (``EARLY``, default 5: also the rules restricted to the
first EARLY epochs, the studies' budget) and the correlation over epochs of each validation
figure with the test rollout score. docs/mdgs-experiments.md quotes it.
"""
import json
import os
import shutil
import sys

import numpy as np
import torch

from mdgs.cli.train import parse_settings
from mdgs.data.split import load_split
from mdgs.evaluate.rollout import divergence_threshold, rollout
from mdgs.models import MODELS
from mdgs.runs import load_run
from mdgs.train import TrainConfig, train

torch.set_num_threads(1)


def summary(path, early=5):
    runs = [json.loads(x) for x in open(path) if x.strip()]
    by = {}
    for r in runs:
        by.setdefault((os.path.basename(os.path.normpath(r["data"])), r["model"], json.dumps(r["settings"])), []).append(r)
    for (scene, model, settings), rs in by.items():
        print(f"{scene} {model} {settings}: seeds {sorted(r['seed'] for r in rs)}, epochs {len(rs[0]['rows'])}")
        rules = {f"last of {early}": lambda rows: rows[early - 1],
                 f"best valid rollout of {early}": lambda rows: min(rows[:early], key=lambda e: e["valid_rollout"]),
                 "last": lambda rows: rows[-1],
                 "best one-step valid": lambda rows: min(rows, key=lambda e: e["valid_one_step"]),
                 "best valid rollout": lambda rows: min(rows, key=lambda e: e["valid_rollout"])}
        for name, rule in rules.items():
            picked = [rule(r["rows"]) for r in rs]

            def ms(key, picked=picked):
                v = [p[key] for p in picked]
                if any(x is None for x in v):
                    return "failed"
                return f"{1e3 * np.mean(v):.3g} +- {1e3 * np.std(v, ddof=1) if len(v) > 1 else 0:.2g}"
            print(f"  {name:28s} epochs {[p['epoch'] for p in picked]}: t40 {ms('test_t40')}, t110 {ms('test_t110')}"
                  f" ({sum(p['test_t110_n'] for p in picked)}/{10 * len(picked)} reach t110)")
        for key in ("valid_one_step", "valid_rollout"):
            c = [np.corrcoef([x[key] for x in r["rows"]], [x["test_rollout"] for x in r["rows"]])[0, 1] for r in rs]
            print(f"  correlation over epochs of {key} with the test rollout score: {np.round(c, 2).tolist()}")
        ratio = [max(x["test_t110"] or np.inf for x in r["rows"]) / min(x["test_t110"] or np.inf for x in r["rows"]) for r in rs]
        fall = [r["rows"][0]["valid_one_step"] / min(x["valid_one_step"] for x in r["rows"]) for r in rs]
        print(f"  one-step validation error falls {np.round(fall, 1).tolist()}x; test t110 max/min over epochs "
              f"{np.round(ratio, 1).tolist()}")


if sys.argv[1] == "--summary":
    summary(sys.argv[2], int(sys.argv[3]) if len(sys.argv) > 3 else 5)
    sys.exit(0)
data, out, seed, epochs = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
model_name = sys.argv[5] if len(sys.argv) > 5 and "=" not in sys.argv[5] else "mdgs"
kw = parse_settings(MODELS[model_name].Config, [a for a in sys.argv[5:] if "=" in a])  # as `mdgs train --set`
scene = os.path.basename(os.path.normpath(data))
run = os.path.join(out, "runs", f"{model_name}-{scene}-s{seed}" + "".join(f"-{k}{v}" for k, v in kw.items()))
valid, test = load_split(os.path.join(data, "valid.h5")), load_split(os.path.join(data, "test.h5"))
cap = divergence_threshold(valid) / 100.0  # the studies' failure threshold (failure_factor 1)


def score(d):
    """Validation rollout score: mean over trajectories and frames of the position MSE, capped at ``cap``."""
    r = rollout(load_run(run, "cpu")[0], d, "cpu")
    e = np.where(np.isfinite(r.pos_mse), np.minimum(r.pos_mse, cap), cap)
    at = {t: (float(np.nanmean(np.where(np.isfinite(r.pos_mse[:, t - 1]), r.pos_mse[:, t - 1], np.nan)))
              if np.isfinite(r.pos_mse[:, t - 1]).any() else None, int(np.isfinite(r.pos_mse[:, t - 1]).sum()))
          for t in (40, 110)}
    return float(e.mean()), at


rows = []
for ep in range(1, epochs + 1):
    train(TrainConfig(data=data, out=run, model_name=model_name, epochs=ep, batch_size=32, seed=seed, device="cpu",
                      valid_max_pairs=512, model=MODELS[model_name].Config(**kw)))
    shutil.copy(os.path.join(run, "checkpoint.pt"), os.path.join(run, f"epoch{ep}.pt"))
    one = json.load(open(os.path.join(run, "metrics.json")))[-1]["valid_mse"]
    vs, _ = score(valid)
    ts, at = score(test)
    rows.append({"epoch": ep, "valid_one_step": one, "valid_rollout": vs, "test_rollout": ts,
                 "test_t40": at[40][0], "test_t40_n": at[40][1], "test_t110": at[110][0], "test_t110_n": at[110][1]})
    print(f"epoch {ep:3d}: valid one-step {one:.4f}, valid rollout {vs * 1e3:.3f}, test rollout {ts * 1e3:.3f}, "
          f"test t40 {at[40][0] * 1e3 if at[40][0] is not None else float('nan'):.3f} ({at[40][1]}), "
          f"t110 {at[110][0] * 1e3 if at[110][0] is not None else float('nan'):.3f} ({at[110][1]})  [1e-3 m^2]",
          flush=True)

pick = {"last": rows[-1], "best one-step valid": min(rows, key=lambda r: r["valid_one_step"]),
        "best valid rollout": min(rows, key=lambda r: r["valid_rollout"])}
for k, r in pick.items():
    print(f"{k:22s} epoch {r['epoch']:3d}: test t40 {r['test_t40']}, t110 {r['test_t110']} ({r['test_t110_n']})")
with open(os.path.join(out, "epoch_selection.jsonl"), "a") as f:
    f.write(json.dumps({"data": data, "model": model_name, "seed": seed, "settings": kw, "rows": rows,
                        "picks": {k: r["epoch"] for k, r in pick.items()}}) + "\n")

"""Would the weights a run started from have been kept under ``select = "rollout-or-start"``? For each
trained run: the validation rollout score of its starting weights (rebuilt as training built them:
:func:`mdgs.train.loop.starting_model`, same seed and config) against the best epoch's recorded score
(docs/mdgs-experiments.md, "Keeping the start"; the study studies/mdgs-select-start.toml runs the rule
for MDGS; this asks whether it could change any peer's row).

    python benchmarks/mdgs_probes/start_scores.py [LABEL=]RUN_FOLDER ...

Each RUN_FOLDER is a finished run of ``select = "rollout"`` or ``"rollout-or-start"`` (a study's
``runs/<cell>``) whose ``config.json`` names the data it trained on. Prints, per run, both scores
(m^2: position MSE over every frame of every validation trajectory, capped at the failure threshold)
and which the rule keeps; where the checkpoint recorded the start's score itself (runs of
``rollout-or-start``), the rebuilt start must reproduce it, which checks the rebuilding.
"""
import sys
from pathlib import Path

import torch

from mdgs.data.split import load_split
from mdgs.evaluate.rollout import rollout_score
from mdgs.runs import model_config, read_checkpoint
from mdgs.train.loop import starting_model

torch.set_num_threads(1)
print(f"{'run':40s} {'start':>10s} {'best epoch':>10s} {'epoch':>6s}  kept")
for arg in sys.argv[1:]:
    label, _, path = arg.rpartition("=")
    state = read_checkpoint(Path(path) / "checkpoint.pt", "cpu")
    hist = [h for h in state["history"] if "valid_rollout" in h]
    if not hist:
        print(f"{label or path:40s} trained with select = {state['config'].get('select', 'last')!r}: no rollout scores")
        continue
    data = Path(state["config"]["data"])
    cls, mcfg = model_config(state)
    start = starting_model(cls, mcfg, load_split(data / "train.h5"), state["config"]["seed"])
    s0 = rollout_score(start, load_split(data / "valid.h5"), "cpu")
    best = min(hist, key=lambda h: h["valid_rollout"])
    check = ""
    if state.get("start_rollout") is not None:
        check = f"  (recorded start {state['start_rollout']:.4g}: {'same' if abs(s0 - state['start_rollout']) <= 1e-6 * s0 else 'DIFFERS'})"
    print(f"{label or path:40s} {s0:10.4g} {best['valid_rollout']:10.4g} {best['epoch']:6d}  "
          f"{'start' if s0 <= best['valid_rollout'] else 'epoch'}{check}")

"""What the rigid-tree probes share (push_out.py, substeps.py): one reference rolled out on a split, as a line."""
import numpy as np

from mdgs.evaluate import evaluate_reference
from mdgs.models import MODELS


def tree_row(d, **settings) -> tuple[str, object]:
    """The "constant-twist" reference with ``settings`` rolled out on split ``d`` -> (``"t=40 ... (median ...)  t=110
    ... (median ...)  diverged k/n"``, the rollout): position MSE in 10^-3 m^2, mean and median over the
    trajectories that did not diverge."""
    ct = MODELS["constant-twist"]
    rep, r = evaluate_reference(ct(ct.Config(**settings)), d, "cpu")
    t110 = rep["mse_t110"] * 1e3 if rep["mse_t110"] is not None else float("nan")
    return (f"t=40 {rep['mse_t40'] * 1e3:8.4g} (median {np.nanmedian(r.pos_mse[:, 39]) * 1e3:7.3g})  "
            f"t=110 {t110:8.4g} (median {np.nanmedian(r.pos_mse[:, -1]) * 1e3:7.3g})  "
            f"diverged {rep['diverged']}/{d.x.shape[0]}"), r

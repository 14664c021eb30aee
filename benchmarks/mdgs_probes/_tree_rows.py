"""What the rigid-tree probes share (push_out.py, substeps.py, gyroscopic.py): one reference rolled out on a split, as
a line; a scene's mechanical energy from its nodes."""
import numpy as np
import torch

from mdgs.actuation import drives_of
from mdgs.evaluate import evaluate_reference
from mdgs.graphs import SceneGraph
from mdgs.models import MODELS
from mdgs.rigid import twist
from mdgs.structure import kabsch


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


def energy_of(d, keep=None):
    """``energy(x, v)`` for split ``d``'s scene: of the first trajectory of node positions and velocities ``x, v``
    [B, N, 3] (float64), the sum over the moving bodies (the objects ``keep``, when given) of
    ``M |v_c|^2 / 2 + w . I w / 2 + M g z_c`` (J), with the MJCF's masses, inertias and gravity and each body's pose
    and twist fitted to its nodes; conserved in free flight, so what a rollout gains is its integrator's error."""
    sc = SceneGraph.from_static(d.static, has_contact=d.has_contact)
    dr = drives_of(d.mj_model(), d.static["node_body"], d.static["node_centroid"])
    g = float(np.linalg.norm(dr.gravity))

    def energy(x, v) -> float:
        R, t = kabsch(sc.ref_shape.double(), x, sc.obj, sc.n_obj)
        tw = twist(x, v, sc.obj, sc.n_obj, sc.mass.double())
        e = 0.0
        for s in np.flatnonzero(~np.asarray(dr.fixed, bool)) if keep is None else keep:
            inertia = R[0, s] @ torch.as_tensor(dr.inertia[s]) @ R[0, s].T
            com = R[0, s] @ torch.as_tensor(dr.com[s]) + t[0, s]
            w = tw.omega[0, s]
            vcom = tw.vc[0, s] + torch.linalg.cross(w, com - tw.c[0, s])
            e += 0.5 * dr.mass[s] * float(vcom @ vcom) + 0.5 * float(w @ inertia @ w) + dr.mass[s] * g * float(com[2])
        return e

    return energy


def free_flight(d, tr: int, frames: int = 120, every: int = 20, **settings) -> list[float]:
    """The energy (:func:`energy_of`, J) every ``every`` frames of trajectory ``tr`` of split ``d`` in free flight:
    its starting state lifted 10 m, no controls, stepped ``frames`` frames by the "constant-twist" reference
    with ``settings`` (the rigid tree's)."""
    from mdgs.models.base import State

    ct = MODELS["constant-twist"]
    m = ct.from_data(d, ct.Config(**settings))
    m.bind(d)
    energy = energy_of(d)
    mov = torch.as_tensor(~np.asarray(d.static["node_static"], bool)).view(1, -1, 1)
    x0 = torch.as_tensor(d.x[tr:tr + 1, 0]).double()
    x = torch.where(mov, x0 + torch.tensor([0, 0, 10.0]).double(), x0)
    v = torch.as_tensor(d.v[tr:tr + 1, 0]).double()
    u = torch.zeros(1, d.ctrl.shape[-1], dtype=torch.float64)
    es = []
    for f in range(frames + 1):
        if f % every == 0:
            es.append(energy(x, v))
        if f < frames:
            s = m.step(State(x, v), u)
            x, v = s.x, s.v
    return es

"""Physical consistency of rolled-out node trajectories: energy error, rigidity and joint separation.

All take node positions / velocities ``[T, F, N, 3]`` (m, m/s) of a rollout and the split's
static description, and return per-trajectory, per-frame curves ``[T, F]``:

- :func:`energy_error`: ``|E_pred - E_true|`` (J), with ``E = sum_i m_i (|v_i|^2 / 2 - g . x_i)``
  over the moving element nodes (point-mass energy of the element cloud, the quantity the
  node states carry);
- :func:`rigidity_violation`: mean over the face-adjacency pairs (i, j) of one body of
  ``| |x_i - x_j| - |r_i - r_j| |`` (m), ``r`` the nodes in the body frame;
- :func:`joint_separation`: the largest distance (m) over hinge and ball joints between the
  joint anchor carried by the child body and the same anchor carried by the parent body, each
  body placed by the best rigid fit (Kabsch) of its reference nodes to its predicted nodes.
  Joints whose child or parent (other than the world) has fewer than 3 nodes are skipped.
"""

from __future__ import annotations

import numpy as np
import torch

from mdgs.structure import kabsch

__all__ = ["energy_error", "rigidity_violation", "joint_separation", "hinge_anchors"]


def _energy(x: np.ndarray, v: np.ndarray, m: np.ndarray, g: np.ndarray) -> np.ndarray:
    return np.einsum("n,tfn->tf", m, 0.5 * (v**2).sum(-1) - x @ g)


def energy_error(x, v, x_true, v_true, static: dict, gravity) -> np.ndarray:
    """``|E_pred - E_true|`` [T, F] in J over moving nodes (see the module docstring)."""
    mv = ~np.asarray(static["node_static"], bool)
    m = np.asarray(static["node_mass"], float)[mv]
    g = np.asarray(gravity, float)
    return np.abs(_energy(x[:, :, mv], v[:, :, mv], m, g) - _energy(x_true[:, :, mv], v_true[:, :, mv], m, g))


def rigidity_violation(x, static: dict) -> np.ndarray:
    """Mean bond-length error [T, F] (m) over the face-adjacency pairs of the moving bodies."""
    adj = np.asarray(static["adjacency"], int).reshape(-1, 2)
    mv = ~np.asarray(static["node_static"], bool)
    adj = adj[mv[adj[:, 0]] & mv[adj[:, 1]]]
    if not len(adj):
        return np.zeros(x.shape[:2])
    r = np.asarray(static["node_centroid"], float)
    ref = np.linalg.norm(r[adj[:, 0]] - r[adj[:, 1]], axis=-1)
    cur = np.linalg.norm(x[:, :, adj[:, 0]] - x[:, :, adj[:, 1]], axis=-1)
    return np.abs(cur - ref).mean(-1)


def hinge_anchors(model) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """``(child body, parent body, anchor in child frame, anchor in parent frame)`` of every hinge/ball joint
    of a ``mujoco.MjModel`` (or MJCF text)."""
    import mujoco

    m = mujoco.MjModel.from_xml_string(model) if isinstance(model, str) else model
    out = []
    for j in range(m.njnt):
        if int(m.jnt_type[j]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_BALL)):
            continue
        b = int(m.jnt_bodyid[j])
        a_child = np.array(m.jnt_pos[j], float)
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, m.body_quat[b])
        a_parent = np.array(m.body_pos[b], float) + R.reshape(3, 3) @ a_child
        out.append((b, int(m.body_parentid[b]), a_child, a_parent))
    return out


def joint_separation(x, static: dict, anchors) -> np.ndarray:
    """Largest anchor separation [T, F] (m) over the measurable hinge/ball joints (0 if none)."""
    T, F = x.shape[:2]
    if not anchors:
        return np.zeros((T, F))
    body = np.asarray(static["node_body"], int)
    ref = torch.as_tensor(np.asarray(static["node_centroid"], float))
    counts = np.bincount(body, minlength=int(body.max()) + 1)
    keep = [(c, p, ac, ap) for c, p, ac, ap in anchors if counts[c] >= 3 and (p == 0 or counts[p] >= 3)]
    if not keep:
        return np.zeros((T, F))
    seg = torch.as_tensor(body)
    R, t = kabsch(ref, torch.as_tensor(x.reshape(T * F, -1, 3), dtype=torch.float64), seg, int(body.max()) + 1)
    R, t = R.numpy(), t.numpy()
    sep = np.zeros((T * F, len(keep)))
    for k, (c, p, ac, ap) in enumerate(keep):
        from_child = np.einsum("bij,j->bi", R[:, c], ac) + t[:, c]
        from_parent = ap if p == 0 else np.einsum("bij,j->bi", R[:, p], ap) + t[:, p]
        sep[:, k] = np.linalg.norm(from_child - from_parent, axis=-1)
    return sep.max(-1).reshape(T, F)

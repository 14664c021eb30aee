"""How a network's per-node output becomes the next state: one function per integrator.

Each takes the state at t (``x``, ``v`` [B, N, 3]), the network's output ``out = [g_x || g_v]``
[B, N, 6] in units of ``dx_scale`` (m) and ``dv_scale`` (m/s), the frame interval ``dt`` (s),
and the scene (object of each node, element masses), and returns ``x', v'`` [B, N, 3].
docs/ambiguities.md says why MDGS defaults to :func:`rigid` where Eq. (9) is silent.
"""

from __future__ import annotations

import torch

from mdgs.graphs import SceneGraph
from mdgs.rigid import advance, project, twist
from mdgs.structure import segment_mean

__all__ = ["INTEGRATORS", "rigid", "twist_space", "euler", "direct"]


def rigid(x, v, out, scene: SceneGraph, dt: float, dx_scale: float, dv_scale: float, trapezoidal: bool = False,
          **_) -> tuple:
    """Rigid step: ``dv_scale g_v`` is a velocity increment whose rigid part (:func:`mdgs.rigid.project`)
    updates each object's twist; nodes move with the exact rigid motion of the new twist over ``dt``
    (:func:`mdgs.rigid.advance`; ``trapezoidal``: of the mean of the old and new twist), plus the rigid
    part of ``dx_scale g_x`` as a position correction."""
    seg, n, mass = scene.obj.to(x.device), scene.n_obj, scene.mass.to(x.device)
    tw = twist(x, v, seg, n, mass)
    dvc, dw = project(dv_scale * out[..., 3:], x, tw, seg, n, mass)
    dc, dth = project(dx_scale * out[..., :3], x, tw, seg, n, mass)
    return advance(x, tw, tw.vc + dvc, tw.omega + dw, dt, seg, dc, dth, trapezoidal=trapezoidal)


def twist_space(x, v, out, scene: SceneGraph, dt: float, dvc_scale: float, dw_scale: float, **_) -> tuple:
    """Twist-space step: the mass-weighted means over each object of ``dw_scale g_x`` and ``dvc_scale g_v``
    are its angular and linear velocity increments; nodes move rigidly with the mean of the old and new
    twist (trapezoidal rule, exact for a constant acceleration)."""
    seg, n, mass = scene.obj.to(x.device), scene.n_obj, scene.mass.to(x.device)
    tw = twist(x, v, seg, n, mass)
    w = mass.to(torch.float64)
    dw = segment_mean(dw_scale * out[..., :3].to(torch.float64), seg, n, w)
    dvc = segment_mean(dvc_scale * out[..., 3:].to(torch.float64), seg, n, w)
    return advance(x, tw, tw.vc + dvc, tw.omega + dw, dt, seg, trapezoidal=True)


def euler(x, v, out, scene: SceneGraph, dt: float, dx_scale: float, dv_scale: float, **_) -> tuple:
    """Semi-implicit Euler per node: ``v' = v + dv_scale g_v``, ``x' = x + dt v' + dx_scale g_x``."""
    v_next = v + dv_scale * out[..., 3:]
    return x + dx_scale * out[..., :3] + dt * v_next, v_next


def direct(x, v, out, scene: SceneGraph, dt: float, dx_scale: float, dv_scale: float, **_) -> tuple:
    """The paper's literal Eq. (9): ``v' = v + dv_scale g_v``, ``x' = x + dx_scale g_x``."""
    return x + dx_scale * out[..., :3], v + dv_scale * out[..., 3:]


#: Integrator name (``--integrator``) -> function.
INTEGRATORS = {"rigid": rigid, "twist": twist_space, "euler": euler, "direct": direct}

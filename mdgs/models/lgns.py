"""LGNS: a Lagrangian graph network (Bhattoo, Ranu & Krishnan, NeurIPS 2022) on the element nodes of rigid bodies.

The model learns a Lagrangian of the moving element nodes (Cartesian ``q`` [n, 3], float64),

    L(q, qd) = sum_i m_i |qd_i|^2 / 2  -  sum_i V_i(q_i)  -  sum_(i,j) V_ij(|q_i - q_j|),

every term a small MLP ``[in, 10, 1]`` with SquarePlus activations
(:mod:`mdgs.models.mechanics`), and obtains accelerations by automatic differentiation of
the constrained Euler-Lagrange equations (:func:`~mdgs.models.mechanics.lagrangian_acceleration`):

    M = d2L/dqd2,  M qdd = dL/dq - (d2L/dqd dq) qd + Y + J^T lambda,  J qdd = -Jdot qd,

with ``Y`` the learned non-conservative forces and ``Phi(q) = 0`` the holonomic constraints
of the scene's rigid bodies and joints. Integration: velocity Verlet at the data's frame
interval (``substeps`` per frame); ``Y`` and the controls are evaluated at the step's start
and at its predicted end (``qd + qdd h``), so the step stays explicit with velocity-dependent forces.

Deviations from the original, each for a stated reason (also in docs/peers/lgns.md):

1. Particles are element centroids of rigid bodies (our data), not point masses; a body is
   held rigid by holonomic constraints (distances between 2-4 anchor nodes, the other nodes
   fixed affine combinations of the anchors: a minimal, independent set), as Bhattoo et al.
   hold the bars of their chains rigid with distance constraints.
2. Joints (hinge, slide, ball, weld) are holonomic constraints between nodes of the two
   bodies, read from the scene's MJCF; where a body's nodes lie on one line its roll is not
   visible and the joint is written only in part (the model reports the extra degrees of
   freedom in ``constraint_info``).
3. Non-conservative forces: Bhattoo et al. learn a drag term; here the learned node force
   also sees positions (floor contact and friction act on nodes) and actuation directions,
   and a contact-edge force acts between nodes of different objects. A Lagrangian cannot
   hold contact, friction, damping or motor torques, so leaving them out would make every
   scene with a floor or an actuator unlearnable.
4. Masses are learned per node from the node's static properties (positive, softplus), which
   keeps ``M`` positive definite; a singular ``M`` (the original falls back to the pseudo-inverse)
   would be solved with a small ridge (:func:`~mdgs.models.mechanics.solve_multipliers`' rule) but is not reached.
5. The edge potential acts on joint edges only (each body's node nearest a joint and its
   parent's): edges inside a rigid body have constant length, so their potential is constant.
6. Loss: node accelerations (as the original), here the recorded frames' finite difference.
7. The MDGS paper's structural constraint module is applied to rollout positions, as the
   paper did for every baseline.
"""

from __future__ import annotations

import torch

from mdgs.models.base import State
from mdgs.models.energy import EnergyConfig, EnergyPeer
from mdgs.models.mechanics import lagrangian_acceleration, velocity_verlet

__all__ = ["LGNS"]


class LGNS(EnergyPeer):
    """Lagrangian graph network peer (module docstring); registry name ``lgns``."""

    name = "lgns"
    Config = EnergyConfig
    summary = "LGNS (Bhattoo et al. 2022): learned Lagrangian, constrained Euler-Lagrange by autodiff, velocity Verlet"

    def lagrangian(self, b: dict):
        """``L(q, qd)`` of one sample -> scalar (closure over the current parameters)."""
        k = self.node_properties(b)
        m = self.mass(k[b["mov"]])

        def L(q, qd):
            return 0.5 * (m[:, None] * qd * qd).sum() - self.potential(b, k, q)
        return L

    def acceleration(self, b: dict, q: torch.Tensor, qd: torch.Tensor, ctrl: torch.Tensor) -> torch.Tensor:
        with torch.enable_grad():
            force = self.moving_forces(b, q, qd, ctrl)
            return lagrangian_acceleration(self.lagrangian(b), self.jac(b), q, qd, force)

    def step(self, state: State, ctrl: torch.Tensor) -> State:
        """Velocity Verlet over one frame (``substeps`` steps of ``dt / substeps``)."""
        b = self.bound(state.x.device)
        mov = b["mov"]
        q, qd = state.x.double()[:, mov], state.v.double()[:, mov]
        h = self.config.dt / self.config.substeps
        for _ in range(self.config.substeps):
            q, qd = velocity_verlet(lambda q_, v_: self.acceleration(b, q_, v_, ctrl).detach(), q, qd, h)
        x = self.finish(b, q.detach(), state.x)
        v = torch.zeros_like(x).index_copy_(1, mov, qd.detach())
        return State(x, v)

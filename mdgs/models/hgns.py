"""HGNS: a Hamiltonian graph network (Bishnoi et al. 2023) on the element nodes of rigid bodies.

The model learns a Hamiltonian of the moving element nodes (Cartesian ``q``, momenta ``p``, float64),

    H(q, p) = sum_i |p_i|^2 / (2 m_i)  +  sum_i V_i(q_i)  +  sum_(i,j) V_ij(|q_i - q_j|),

from the same small SquarePlus MLPs as LGNS (:mod:`mdgs.models.mechanics`), and its
equations of motion ``z' = J grad H`` with constraint multipliers by automatic
differentiation (:func:`~mdgs.models.mechanics.hamiltonian_derivatives`):

    qd = dH/dp,  pd = -dH/dq + Y + J_Phi^T lambda,  with d2 Phi/dt2 = 0.

Integrator: classical fixed-step Runge-Kutta 4 on ``z = (q, p)`` at the data's frame
interval (``substeps`` per frame); the authors integrate ``z'`` with an ODE solver, and a
fixed step keeps the cost of a frame fixed and equal across rollouts. Momenta enter as
``p_i = m_i v_i`` (the Legendre transform of the learned kinetic energy) and are carried
in the state (``extra["p"]``) between frames.

Deviations from the original: as LGNS (:mod:`mdgs.models.lgns`, items 1-7; docs/peers/hgns.md),
and the loss: the acceleration ``qdd = H_pp pd + H_pq qd`` against the recorded one, since
the recorded data hold velocities, not the learned model's momenta (``pd`` against
``m (v_{t+1} - v_t) / dt`` would depend on the learned masses and can be shrunk by them).
"""

from __future__ import annotations

import torch

from mdgs.models.base import State
from mdgs.models.energy import EnergyConfig, EnergyPeer
from mdgs.models.mechanics import hamiltonian_derivatives, rk4

__all__ = ["HGNS"]


class HGNS(EnergyPeer):
    """Hamiltonian graph network peer (module docstring); registry name ``hgns``."""

    name = "hgns"
    Config = EnergyConfig
    summary = "HGNS (Bishnoi et al. 2023): learned Hamiltonian, constrained z' = J grad H by autodiff, RK4"

    def masses(self, b: dict) -> torch.Tensor:
        """Learned masses of the moving nodes [n], kg."""
        return self.mass(self.node_properties(b)[b["mov"]])

    def hamiltonian(self, b: dict):
        """``H(q, p)`` of one sample -> scalar (closure over the current parameters)."""
        k = self.node_properties(b)
        m = self.mass(k[b["mov"]])

        def H(q, p):
            return 0.5 * (p * p / m[:, None]).sum() + self.potential(b, k, q)
        return H

    def derivatives(self, b: dict, q: torch.Tensor, p: torch.Tensor, ctrl: torch.Tensor):
        """``(qd, pd, qdd)`` [B, n, 3] at ``(q, p)`` under controls ``ctrl``."""
        with torch.enable_grad():
            qd = p / self.masses(b)[:, None]
            force = self.moving_forces(b, q, qd, ctrl)
            return hamiltonian_derivatives(self.hamiltonian(b), self.jac(b), q, p, force)

    def acceleration(self, b: dict, q: torch.Tensor, qd: torch.Tensor, ctrl: torch.Tensor) -> torch.Tensor:
        p = qd * self.masses(b)[:, None]
        return self.derivatives(b, q, p, ctrl)[2]

    def initial_state(self, split, traj, frame) -> State:
        s = super().initial_state(split, traj, frame)
        b = self.bound(s.x.device)
        with torch.no_grad():
            p = torch.zeros_like(s.v).index_copy_(1, b["mov"], s.v[:, b["mov"]] * self.masses(b)[:, None])
        s.extra = {"p": p}
        return s

    def step(self, state: State, ctrl: torch.Tensor) -> State:
        """RK4 on ``(q, p)`` over one frame (``substeps`` steps of ``dt / substeps``)."""
        b = self.bound(state.x.device)
        mov = b["mov"]
        q = state.x.double()[:, mov]
        if "p" in state.extra:
            p = state.extra["p"].double()[:, mov]
        else:
            p = state.v.double()[:, mov] * self.masses(b).detach()[:, None]
        h = self.config.dt / self.config.substeps

        def f(q_, p_):
            qd, pd, _ = self.derivatives(b, q_, p_, ctrl)
            return qd.detach(), pd.detach()
        for _ in range(self.config.substeps):
            q, p = rk4(f, q, p, h)
        x = self.finish(b, q, state.x)
        with torch.no_grad():
            qd = p / self.masses(b)[:, None]
        v = torch.zeros_like(x).index_copy_(1, mov, qd)
        pf = torch.zeros_like(x).index_copy_(1, mov, p)
        return State(x, v, {"p": pf})

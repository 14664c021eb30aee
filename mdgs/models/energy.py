"""The Simulator side shared by LGNS and HGNS: configuration, normalisation, scene binding, forces, loss.

:class:`EnergyPeer` holds everything the two energy-based peers do alike (their physics lives
in :mod:`mdgs.models.mechanics`); :class:`~mdgs.models.lgns.LGNS` adds the Lagrangian and
velocity Verlet, :class:`~mdgs.models.hgns.HGNS` the Hamiltonian and RK4.

Shared choices (each also in docs/peers/lgns.md and docs/peers/hgns.md):

- coordinates: the moving element nodes in Cartesian coordinates, float64 throughout;
  static world nodes are fixed and enter only the edge potential and contact;
- constraints: rigidity of every body and its joint to the parent, holonomic, with
  Lagrange multipliers (:func:`mdgs.models.mechanics.build_constraints`);
- loss: MSE of the predicted node accelerations against the recorded ones, the target of
  Lagrangian/Hamiltonian networks (Cranmer et al. 2020; Bhattoo et al. 2022); the data hold
  no instantaneous accelerations, so the target is the frame's finite difference
  ``(v_{t+1} - v_t) / frame_dt``, scaled by its training std;
- no training noise (the authors train on clean trajectories; the MDGS paper sets noise for MDGS only);
- optimiser: Adam lr 1e-3 (Bhattoo et al.; MDGS B.2 uses the same), with the registry's
  ReduceLROnPlateau (patience 3, factor 0.8) kept so that all peers share one schedule rule;
- structural constraint module (MDGS Appendix B.1.3) on rollout positions, since the MDGS
  paper fitted it to every baseline ("Experimental Settings"); ``structure=False`` turns it off.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np
import torch

from mdgs.data.split import SplitData
from mdgs.graphs import SceneGraph, batch_edges, contact_edges, dense_contacts
from mdgs.models.base import Batch, ModelError, Simulator
from mdgs.models.mechanics import (
    EdgePotential,
    ExternalForces,
    NodeMass,
    NodePotential,
    build_constraints,
)
from mdgs.structure import align_to_reference

__all__ = ["EnergyConfig", "EnergyPeer", "N_PROPERTIES", "DENSE_CONTACT_MAX_PAIRS"]

#: Static node properties k_i: mass, volume, tau, object type one-hot (3) (as MDGS's k_i).
N_PROPERTIES = 6

#: Scenes with at most this many contact candidate pairs (ordered node pairs of different objects, not both
#: static) evaluate the contact force on every candidate, masked (:meth:`EnergyPeer.external_forces`): a fixed
#: shape, so the step compiles as one graph. The bound keeps the masked pairs' work and memory small (at batch 256,
#: 4096 pairs hold 1M rows of contact features); the small study's scenes have 252-1024
#: (docs/results/mdgs-probes/energy_one_graph.txt).
DENSE_CONTACT_MAX_PAIRS = 4096


@dataclass(frozen=True)
class EnergyConfig:
    """Hyperparameters shared by LGNS and HGNS; every default documented.

    Attributes
    ----------
    hidden : width of every MLP's hidden layer (baselines.md, after Bhattoo et al.: ``[in, 10, 1]``).
    depth : hidden layers per MLP (1: ``[in, hidden, out]``).
    substeps : integrator steps per data frame (1: the frame interval, as the authors integrate
        at the data's timestep).
    structure : structural constraint module (MDGS B.1.3) on rollout positions (paper: on for baselines).
    constraints : write rigid bodies and joints as holonomic constraints (False: free particles,
        for ablation only).
    contact : learn the contact-edge force; set from the data (a scene that can have no contact has none).
    control_dim : actuators; set from the data.
    dt : frame interval, s; set from the data.
    a_scale : m/s^2, std of the training accelerations (loss scale); set from the data.
    m_scale : kg, mean moving node mass (mass MLP output scale); set from the data.
    f_scale : N, ``m_scale * a_scale`` (force MLP output scale); set from the data.
    e_scale : J, ``f_scale * length`` (potential MLP output scale); set from the data.
    length : m, std of the moving node positions (edge potential length unit); set from the data.
    v_std : m/s, std of the moving node velocities (input scale); set from the data.
    Values left at 0 are filled by :meth:`EnergyPeer.resolve_config` from the training split.
    """

    hidden: int = 10
    depth: int = 1
    substeps: int = 1
    structure: bool = True
    constraints: bool = True
    contact: bool = True
    control_dim: int = 0
    dt: float = 0.0
    a_scale: float = 0.0
    m_scale: float = 0.0
    f_scale: float = 0.0
    e_scale: float = 0.0
    length: float = 0.0
    v_std: float = 0.0

    def __post_init__(self):
        for k in ("hidden", "depth", "substeps"):
            if int(getattr(self, k)) < 1:
                raise ValueError(f"{k} must be a positive integer, got {getattr(self, k)!r}")


def _accelerations(d: SplitData) -> np.ndarray:
    mv = d.moving
    return ((d.v[:, 1:] - d.v[:, :-1]) / d.frame_dt)[:, :, mv]


class EnergyPeer(Simulator):
    """Base of :class:`~mdgs.models.lgns.LGNS` and :class:`~mdgs.models.hgns.HGNS` (module docstring)."""

    Config = EnergyConfig

    def __init__(self, config: EnergyConfig = EnergyConfig()):
        super().__init__(config)
        c = config
        dk = N_PROPERTIES
        self.mass = NodeMass(dk, c.m_scale or 1.0, c.hidden, c.depth)
        self.node_potential = NodePotential(dk, c.e_scale or 1.0, c.hidden, c.depth)
        self.edge_potential = EdgePotential(dk, c.e_scale or 1.0, c.length or 1.0, c.hidden, c.depth)
        self.forces = ExternalForces(dk, c.f_scale or 1.0, c.contact, c.hidden, c.depth)
        self.register_buffer("x_mean", torch.zeros(3, dtype=torch.float64))
        self.register_buffer("x_std", torch.ones((), dtype=torch.float64))
        self.register_buffer("k_mean", torch.zeros(dk, dtype=torch.float64))
        self.register_buffer("k_std", torch.ones(dk, dtype=torch.float64))
        self.double()
        self._bound: dict = {}
        self.constraint_info: dict = {}

    # --- construction ------------------------------------------------------------------------
    @classmethod
    def resolve_config(cls, config: EnergyConfig, d: SplitData) -> EnergyConfig:
        """Fill ``dt``, ``contact``, ``control_dim`` and the scales left at 0 from the training split."""
        c = config
        mv = d.moving
        if not mv.any():
            raise ModelError(f"{d.path} has no moving nodes; there is nothing for {cls.name} to simulate")
        a = _accelerations(d)
        mass = float(np.asarray(d.static["node_mass"], float)[mv].mean())
        a_s = float(max(a.std(), 1e-9))
        length = float(max(d.x[:, :, mv].std(), 1e-6))
        kw = {"dt": c.dt or float(d.frame_dt), "contact": bool(d.has_contact) and c.contact,
              "control_dim": int(d.ctrl.shape[-1])}
        kw["a_scale"] = c.a_scale or a_s
        kw["m_scale"] = c.m_scale or max(mass, 1e-9)
        kw["f_scale"] = c.f_scale or kw["m_scale"] * kw["a_scale"]
        kw["length"] = c.length or length
        kw["e_scale"] = c.e_scale or kw["f_scale"] * kw["length"]
        kw["v_std"] = c.v_std or float(max(d.v[:, :, mv].std(), 1e-9))
        return replace(c, **kw)

    def fit(self, d: SplitData) -> None:
        """Position mean/std of the moving nodes and node-property mean/std, training split only."""
        mv = d.moving
        xs = d.x[:, :, mv].reshape(-1, 3).astype(np.float64)
        self.x_mean.copy_(torch.from_numpy(xs.mean(0)))
        self.x_std.copy_(torch.tensor(max(float(xs.std()), 1e-9)))
        k = SceneGraph.from_static(d.static, has_contact=d.has_contact).properties().double()
        self.k_mean.copy_(k.mean(0))
        self.k_std.copy_(k.std(0).clamp_min(1e-8))

    def bind(self, split: SplitData) -> None:
        """Build the scene's constraints, joint edges and control map (cached per scene)."""
        c = self.config
        if int(split.ctrl.shape[-1]) != c.control_dim:
            raise ModelError(f"{split.path} has {split.ctrl.shape[-1]} actuators but the model was built for "
                             f"{c.control_dim}; use data of the scene it was trained on")
        super().bind(split)
        scene = SceneGraph.from_static(split.static, has_contact=split.has_contact)
        cs, info = build_constraints(split)
        if not c.constraints:
            cs = cs.subset([])
        self.constraint_info = {k: v for k, v in info.items() if k != "xref"}
        st = np.asarray(split.static["node_static"], bool)
        a, p = np.asarray(split.static["body_anchor_node"]), np.asarray(split.static["body_parent_anchor_node"])
        ok = (a >= 0) & (p >= 0)
        edges = np.stack([a[ok], p[ok]], 1) if ok.any() else np.zeros((0, 2), int)
        edges = edges[~(st[edges[:, 0]] & st[edges[:, 1]])] if len(edges) else edges
        self._host = {"scene": scene, "cs": cs, "xref": torch.from_numpy(info["xref"]),
                      "mov": torch.from_numpy(np.where(~st)[0]), "static": torch.from_numpy(st),
                      "edges": torch.as_tensor(edges, dtype=torch.long).reshape(-1, 2),
                      "pairs": torch.stack(torch.nonzero(scene.contact_candidates("cpu"), as_tuple=True)),
                      "sign": torch.from_numpy(np.asarray(split.control_sign, np.float64))}
        self._bound = {}

    def bound(self, dev) -> dict:
        """The bound scene's tensors on ``dev`` (cached)."""
        if not getattr(self, "_host", None):
            raise ModelError("the model is not bound to a scene; call bind(split) first")
        key = str(dev)
        if key not in self._bound:
            h = self._host
            self._bound[key] = {"scene": h["scene"].to(dev), "cs": h["cs"].to(dev), "xref": h["xref"].to(dev),
                                "mov": h["mov"].to(dev), "static": h["static"].to(dev),
                                "edges": h["edges"].to(dev), "pairs": h["pairs"].to(dev), "sign": h["sign"].to(dev)}
        return self._bound[key]

    def config_dict(self) -> dict:
        return asdict(self.config)

    # --- shared pieces -----------------------------------------------------------------------------
    def node_properties(self, b: dict) -> torch.Tensor:
        """Normalised ``k_i`` [N, 6] (float64)."""
        return (b["scene"].properties().double() - self.k_mean) / self.k_std

    def full_positions(self, b: dict, q: torch.Tensor) -> torch.Tensor:
        """Moving-node coordinates ``q`` [..., n, 3] -> all nodes [..., N, 3] (static nodes at the reference)."""
        return b["xref"].expand(*q.shape[:-2], -1, -1).index_copy(-2, b["mov"], q)

    def potential(self, b: dict, k: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        """``V(q)`` of one sample (``q`` [n, 3]) -> scalar, J: node and joint-edge MLPs."""
        x = self.full_positions(b, q)
        xn = (q - self.x_mean) / self.x_std
        return self.node_potential(xn, k[b["mov"]]) + self.edge_potential(x, k, b["edges"])

    def phi(self, b: dict):
        """``Phi(q)`` (``q`` [..., n, 3]) -> [..., m]."""
        cs = b["cs"]
        return lambda q: cs(self.full_positions(b, q))

    def jac(self, b: dict):
        """``(J, Jdot qd)`` of the batch (``q``, ``qd`` [B, n, 3]), closed form."""
        cs = b["cs"]
        return lambda q, qd: cs.jacobian(self.full_positions(b, q), b["mov"], qd)

    def actuation_features(self, b: dict, x: torch.Tensor, ctrl: torch.Tensor) -> torch.Tensor:
        """Per-node actuation directions [B, N, 3] (:class:`~mdgs.models.mechanics.ExternalForces`)."""
        B, N, _ = x.shape
        cs = b["cs"]
        if ctrl.shape[-1] == 0 or cs.act_axis.numel() == 0:
            return x.new_zeros(B, N, 3)
        P = cs.attachments(x)
        has = cs.act_axis >= 0
        A = P[:, cs.act_anchor.clamp_min(0)]  # [B, nu, 3]
        a = P[:, cs.act_axis.clamp_min(0)]
        rot = torch.linalg.cross(a[:, :, None].expand(-1, -1, N, -1), x[:, None] - A[:, :, None], dim=-1)
        g = torch.where(cs.act_slide[None, :, None, None], a[:, :, None].expand(-1, -1, N, -1),
                        rot / self.config.length)
        g = g * has[None, :, None, None]
        w = ctrl.to(x.dtype)[:, :, None] * b["sign"][None]  # [B, nu, N]
        return torch.einsum("bkn,bkni->bni", w, g)

    def external_forces(self, b: dict, x: torch.Tensor, v: torch.Tensor, ctrl: torch.Tensor) -> torch.Tensor:
        """Learned non-conservative forces on all nodes [B, N, 3] at full positions ``x``, velocities ``v``.

        Contact: where the scene has at most :data:`DENSE_CONTACT_MAX_PAIRS` candidate pairs (nodes of different
        objects, not both static), the contact MLP acts on every candidate pair and a mask keeps those closer than
        the contact radius (:func:`mdgs.graphs.dense_contacts`, the rule of :func:`mdgs.graphs.contact_edges`), so
        the step has no data-dependent shape and compiles as one graph; on the paper's scenes most candidates are in
        contact (small Cubli test frames: 733 of 1024 on average, rotational-center 480 of 858), on the small study's
        user scene few (10 of 252; docs/results/mdgs-probes/energy_one_graph.txt). A larger scene takes the edge list
        of the pairs in contact (:meth:`_contact_edge_list`), eagerly."""
        c = self.config
        scene = b["scene"]
        k = self.node_properties(b)
        edges = mask = None
        if c.contact and scene.has_contact:
            pairs = b["pairs"]
            if pairs.shape[1] <= DENSE_CONTACT_MAX_PAIRS:
                B, N, _ = x.shape
                near = dense_contacts(x.detach(), scene.obj, scene.contact_radius,
                                      candidates=scene.contact_candidates(x.device))  # [B, N, N]
                mask = near[:, pairs[0], pairs[1]].reshape(-1)
                edges = batch_edges(pairs, N, B)
            else:
                edges = self._contact_edge_list(x.detach(), scene)
        vn = v / c.v_std
        xn = (x - self.x_mean) / self.x_std
        return self.forces(vn, xn, k, self.actuation_features(b, x, ctrl), edges, x, v, scene.contact_radius, c.v_std,
                           mask)

    # eager inside a compiled step: the contact edges change in number from step to step, and each new number would
    # compile the code after them anew (dynamo's shapes are static here, mdgs.models.compile_step)
    @staticmethod
    @torch.compiler.disable
    def _contact_edge_list(x: torch.Tensor, scene: SceneGraph) -> torch.Tensor:
        """The contact edges [2, E] of positions ``x`` [B, N, 3] (:func:`mdgs.graphs.contact_edges`)."""
        return contact_edges(x, scene.obj, scene.contact_radius, scene.static)

    def moving_forces(self, b: dict, q: torch.Tensor, qd: torch.Tensor, ctrl: torch.Tensor) -> torch.Tensor:
        """:meth:`external_forces` at moving coordinates, restricted to the moving nodes [B, n, 3]."""
        x = self.full_positions(b, q)
        v = torch.zeros_like(x).index_copy_(1, b["mov"], qd)
        return self.external_forces(b, x, v, ctrl)[:, b["mov"]]

    def finish(self, b: dict, q: torch.Tensor, x_in: torch.Tensor) -> torch.Tensor:
        """Full positions of the new frame (static nodes stay where ``x_in`` has them), with the
        structural constraint module if configured."""
        x = self.full_positions(b, q)
        if self.config.structure:
            scene = b["scene"]
            moving = ~b["static"]
            x = align_to_reference(x, scene.ref_shape.to(x.device), scene.obj, scene.n_obj, mask=moving)
        return torch.where((~b["static"]).view(1, -1, 1), x, x_in.to(x.dtype))

    # --- training ----------------------------------------------------------------------------------
    def acceleration(self, b: dict, q: torch.Tensor, qd: torch.Tensor, ctrl: torch.Tensor) -> torch.Tensor:
        """Node accelerations [B, n, 3] at moving coordinates (model-specific)."""
        raise NotImplementedError

    def _split_batch(self, batch: Batch):
        b = self.bound(batch.x.device)
        mov = b["mov"]
        q, qd = batch.x.double()[:, mov], batch.v.double()[:, mov]
        target = (batch.v_next.double()[:, mov] - qd) / self.config.dt
        return b, q, qd, target

    def losses(self, batch: Batch) -> dict[str, torch.Tensor]:
        """``mse``: mean squared node-acceleration error over moving nodes, in units of ``a_scale``."""
        b, q, qd, target = self._split_batch(batch)
        acc = self.acceleration(b, q, qd, batch.ctrl)
        return {"mse": (((acc - target) / self.config.a_scale) ** 2).mean()}

    def validation_error(self, batch: Batch) -> torch.Tensor:
        with torch.enable_grad():
            return self.losses(batch)["mse"].detach()

    def initial_state(self, split: SplitData, traj: np.ndarray, frame: int):
        s = super().initial_state(split, traj, frame)
        s.x, s.v = s.x.double(), s.v.double()
        return s

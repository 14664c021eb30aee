"""The MDGS simulator (Sections 3.2-3.3, Appendix B.2): force networks, global gatherer, state network.

One step, for a batch of ``B`` graphs of one scene with ``N`` nodes:

    z_i        = [x_i || v_i || k_i]                          node features (Section 3.1)
    F~         = g^F~(G~, Z)                                   non-contact forces, object graph (Eq. 4)
    Z-         = g^Z-(G- u G~, Z)                              global features, union graph (Eq. 5)
    F-         = g^F-(G-, [Z || Z-]),  0 off contact edges     contact forces, contact graph (Eq. 6)
    F          = F- + F~                                       (Eq. 7)
    z'_i       = [z_i || lambda F_i]                           (Eq. 8)
    Z^(t+1)    = g(G~, Z')                                     state, object graph (Eq. 9)

followed by the structural constraint module (Appendix B.1.3, :mod:`mdgs.structure`).
Every GNN is a GCN (Kipf & Welling 2017) with 3 layers, hidden 200, ReLU (Appendix B.2).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from mdgs.graphs import Propagator, SceneGraph, contact_edges, gcn_norm
from mdgs.rigid import advance, project, twist
from mdgs.structure import align_to_reference, segment_mean

__all__ = ["ModelConfig", "VARIANTS", "INTEGRATORS", "GCN", "Prediction", "MDGS"]

#: Variants of Table 1: the full method, no Kane constraint, single-speed constraint.
VARIANTS = ("mdgs", "mdgs-nc", "mdgs-sc")
#: How the state network's output becomes the next state (see ModelConfig.integrator).
INTEGRATORS = ("rigid", "twist", "euler", "direct")


@dataclass(frozen=True)
class ModelConfig:
    """Hyperparameters of :class:`MDGS`; every default is documented here.

    Attributes
    ----------
    variant : "mdgs" (L_mse + L_cst over speeds x, y, z), "mdgs-nc" (no L_cst),
        "mdgs-sc" (L_cst along the single speed x).
    structure : apply the structural constraint module (B.1.3) in training and rollout.
    hidden : GCN hidden width (B.2: 200).
    layers : GCN layers (B.2: 3).
    global_dim : width of the global features Z- of Eq. (5) (= hidden).
    control_dim : per-node, per-frame inputs appended to k_i (actuator controls), 0 if none.
    lam : lambda of Eq. (8); ``None`` -> ``1 / force_scale`` (forces enter at O(1)).
    force_scale : N; force networks output ``force_scale * GCN(.)``.
    dx_scale, dv_scale : m and m/s; g outputs ``[dx / dx_scale, dv / dv_scale]``.
    bound : "paper" (Eq. 12) or "corrected" (kane's corrected statement) for L_cst.
    integrator : how g's output ``[g_x || g_v]`` becomes ``Z^(t+1)`` (docs/ambiguities.md):
        "rigid" (default): ``dv_scale * g_v`` is a velocity increment whose rigid part
        (:func:`mdgs.rigid.project`) updates each object's twist, and nodes move with the
        exact rigid motion of the new twist over ``dt`` (:func:`mdgs.rigid.advance`), plus the
        rigid part of ``dx_scale * g_x`` as a position correction;
        "twist": g's outputs are read in twist space: the mass-weighted means over each object of
        ``dw_scale * g_x`` and ``dvc_scale * g_v`` are its angular and linear velocity increments,
        and nodes move rigidly with the mean of the old and new twist (trapezoidal rule);
        "euler": ``v' = v + dv_scale g_v``, ``x' = x + dt v' + dx_scale g_x`` per node;
        "direct": ``v' = v + dv_scale g_v``, ``x' = x + dx_scale g_x`` (the paper's literal Eq. 9).
    dvc_scale, dw_scale : m/s and rad/s, output scales of the "twist" integrator (spread of the
        objects' velocity and angular velocity increments in the training data).
    dt : frame interval, s (used by "rigid", "twist" and "euler"); ``mdgs train`` sets it from the data.
    cst_weight : weight of L_cst in the total loss (paper: summed, i.e. 1).
    dense_max_nodes : object graphs up to this many nodes propagate densely.
    """

    variant: str = "mdgs"
    structure: bool = True
    hidden: int = 200
    layers: int = 3
    global_dim: int = 200
    control_dim: int = 0
    lam: float | None = None
    force_scale: float = 1.0
    dx_scale: float = 1.0
    dv_scale: float = 1.0
    bound: str = "paper"
    integrator: str = "rigid"
    dvc_scale: float = 1.0
    dw_scale: float = 1.0
    dt: float = 0.0
    cst_weight: float = 1.0
    dense_max_nodes: int = 256

    def __post_init__(self):
        if self.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {', '.join(VARIANTS)}, got {self.variant!r}")
        if self.bound not in ("paper", "corrected"):
            raise ValueError(f"bound must be 'paper' or 'corrected', got {self.bound!r}")
        if self.integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {', '.join(INTEGRATORS)}, got {self.integrator!r}")

    def to_dict(self) -> dict:
        return asdict(self)


#: Static node properties k_i: mass, volume, tau, object type one-hot (3).
N_PROPERTIES = 6


class GCN(nn.Module):
    """``H^{l+1} = ReLU(A_hat H^l W^l + b^l)``, no activation after the last layer (Kipf & Welling 2017)."""

    def __init__(self, d_in: int, hidden: int, d_out: int, layers: int = 3):
        super().__init__()
        dims = [d_in] + [hidden] * (layers - 1) + [d_out]
        self.lins = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:], strict=True))

    def forward(self, prop: Propagator, h: torch.Tensor) -> torch.Tensor:
        """``h`` [B, N, d_in] -> [B, N, d_out]."""
        for k, lin in enumerate(self.lins):
            # propagate on the narrower side of the linear map (fewer features to gather)
            if lin.in_features <= lin.out_features:
                h = lin(prop(h))
            else:
                h = prop(h @ lin.weight.T) + lin.bias
            if k < len(self.lins) - 1:
                h = torch.relu(h)
        return h


@dataclass
class Prediction:
    """Output of one :class:`MDGS` step (shapes ``[B, N, 3]``; forces in N).

    x, v : predicted positions (m) and velocities (m/s) at t+1.
    force : F of Eq. (7); force_noncontact : F~ (Eq. 4); force_contact : F- (Eq. 6).
    contact_edges : [2, E] batched contact edges used (empty without a contact branch).
    """

    x: torch.Tensor
    v: torch.Tensor
    force: torch.Tensor
    force_noncontact: torch.Tensor
    force_contact: torch.Tensor
    contact_edges: torch.Tensor


class MDGS(nn.Module):
    """The MDGS simulator for the scenes described by a :class:`~mdgs.graphs.SceneGraph`.

    Parameters
    ----------
    config : ModelConfig
    contact : build the contact branch (g^Z-, g^F-); a scene that can have no contact has none.
    """

    def __init__(self, config: ModelConfig = ModelConfig(), contact: bool = True):
        super().__init__()
        c = config
        self.config = c
        self.contact = contact
        d_z = 3 + 3 + N_PROPERTIES + c.control_dim
        self.d_z = d_z
        self.force_noncontact = GCN(d_z, c.hidden, 3, c.layers)  # g^F~
        if contact:
            self.global_gather = GCN(d_z, c.hidden, c.global_dim, c.layers)  # g^Z-
            self.force_contact = GCN(d_z + c.global_dim, c.hidden, 3, c.layers)  # g^F-
        self.state = GCN(d_z + 3, c.hidden, 6, c.layers)  # g
        # input normalisation of z (set from training data by set_normalization)
        self.register_buffer("z_mean", torch.zeros(d_z))
        self.register_buffer("z_std", torch.ones(d_z))

    def force_parameters(self):
        """Parameters of the force networks g^F~, g^F- (and g^Z-, which feeds only g^F-)."""
        mods = [self.force_noncontact] + ([self.global_gather, self.force_contact] if self.contact else [])
        return [p for m in mods for p in m.parameters()]

    def set_normalization(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        """Set the per-feature mean and std of ``z`` (``[d_z]``); std is floored at 1e-8."""
        self.z_mean.copy_(torch.as_tensor(mean, dtype=self.z_mean.dtype))
        self.z_std.copy_(torch.as_tensor(std, dtype=self.z_std.dtype).clamp_min(1e-8))

    def node_features(self, scene: SceneGraph, x: torch.Tensor, v: torch.Tensor,
                      control: torch.Tensor | None = None) -> torch.Tensor:
        """Raw ``z = [x || v || k]`` -> [B, N, d_z]; ``control`` [B, N, control_dim] joins ``k``."""
        B, N, _ = x.shape
        k = scene.properties().to(x.device, x.dtype).expand(B, N, -1)
        parts = [x, v, k]
        if self.config.control_dim:
            if control is None:
                raise ValueError(f"this model expects control inputs of width {self.config.control_dim}")
            parts.append(control.to(x.dtype))
        return torch.cat(parts, dim=-1)

    def forward(self, scene: SceneGraph, x: torch.Tensor, v: torch.Tensor,
                control: torch.Tensor | None = None) -> Prediction:
        """One step ``Z^(t) -> Z^(t+1)``.

        Parameters
        ----------
        scene : static graph of the scene (on the same device).
        x, v : [B, N, 3] centroid positions (m) and velocities (m/s) at t.
        control : [B, N, control_dim] or None.
        """
        c = self.config
        B, N, _ = x.shape
        dev, dt = x.device, x.dtype
        z = (self.node_features(scene, x, v, control) - self.z_mean) / self.z_std
        obj_prop = scene.object_graph.propagator(B, dev, dt)
        f_nc = c.force_scale * self.force_noncontact(obj_prop, z)  # Eq. (4)
        if self.contact and scene.has_contact:
            ce = contact_edges(x.detach(), scene.obj, scene.contact_radius, scene.static)
            z_glob = self.global_gather(scene.object_graph.union(ce, B, dev, dt), z)  # Eq. (5)
            con_prop = Propagator(csr=gcn_norm(ce, B * N, dt, dev))
            f_c = c.force_scale * self.force_contact(con_prop, torch.cat([z, z_glob], -1))  # Eq. (6)
            touched = torch.zeros(B * N, dtype=torch.bool, device=dev)
            touched[ce[0]] = True
            f_c = f_c * touched.view(B, N, 1)  # zero off contact edges
        else:
            ce = torch.zeros(2, 0, dtype=torch.long, device=dev)
            f_c = torch.zeros_like(f_nc)
        f = f_c + f_nc  # Eq. (7)
        lam = c.lam if c.lam is not None else 1.0 / c.force_scale
        out = self.state(obj_prop, torch.cat([z, lam * f], -1))  # Eqs. (8)-(9)
        x_next, v_next = self.integrate(scene, x, v, out)
        moving = ~scene.static.to(dev)
        if c.structure:
            x_next = align_to_reference(x_next, scene.ref_shape.to(dev), scene.obj.to(dev), scene.n_obj, mask=moving)
        # static elements never move
        m = moving.view(1, N, 1)
        x_next = torch.where(m, x_next, x)
        v_next = torch.where(m, v_next, torch.zeros_like(v_next))
        return Prediction(x_next, v_next, f, f_nc, f_c, ce)

    def integrate(self, scene: SceneGraph, x: torch.Tensor, v: torch.Tensor,
                  out: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``Z^(t+1)`` from the state network's output ``out = [g_x || g_v]`` [B, N, 6] (see ``integrator``)."""
        c = self.config
        if c.integrator == "rigid":
            seg, n, mass = scene.obj.to(x.device), scene.n_obj, scene.mass.to(x.device)
            tw = twist(x, v, seg, n, mass)
            dvc, dw = project(c.dv_scale * out[..., 3:], x, tw, seg, n, mass)
            dc, dth = project(c.dx_scale * out[..., :3], x, tw, seg, n, mass)
            return advance(x, tw, tw.vc + dvc, tw.omega + dw, c.dt, seg, dc, dth)
        if c.integrator == "twist":
            seg, n, mass = scene.obj.to(x.device), scene.n_obj, scene.mass.to(x.device)
            tw = twist(x, v, seg, n, mass)
            w = mass.to(torch.float64)
            dw = segment_mean(c.dw_scale * out[..., :3].to(torch.float64), seg, n, w)
            dvc = segment_mean(c.dvc_scale * out[..., 3:].to(torch.float64), seg, n, w)
            return advance(x, tw, tw.vc + dvc, tw.omega + dw, c.dt, seg, trapezoidal=True)
        v_next = v + c.dv_scale * out[..., 3:]
        x_next = x + c.dx_scale * out[..., :3]
        if c.integrator == "euler":  # semi-implicit Euler per node
            x_next = x_next + c.dt * v_next
        return x_next, v_next

    @torch.no_grad()
    def rollout(self, scene: SceneGraph, x0: torch.Tensor, v0: torch.Tensor, steps: int,
                control: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Autoregressive rollout: ``x0, v0`` [B, N, 3] -> positions and velocities [B, steps, N, 3].

        ``control`` [B, steps, N, control_dim] or None.
        """
        xs, vs = [], []
        x, v = x0, v0
        for t in range(steps):
            p = self(scene, x, v, None if control is None else control[:, t])
            x, v = p.x, p.v
            xs.append(x)
            vs.append(v)
        return torch.stack(xs, 1), torch.stack(vs, 1)

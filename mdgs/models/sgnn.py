"""SGNN, the subequivariant hierarchical graph network of Han et al. (NeurIPS 2022), as a peer of MDGS.

Han, Huang, Xu, Chen, Li, Liu (2022), "Learning physical dynamics with subequivariant graph
neural networks"; reference code hanjq17/SGNN (``Physion/models/SGNN.py``). Rebuilt here in our
own code against the :class:`~mdgs.models.base.Simulator` contract. docs/peers/sgnn.md lists
every setting and every deviation with its reason.

One step for a batch of ``B`` graphs of one scene (``N`` nodes in ``S`` rigid objects):

    v_i   = (x_i(t) - x_i(t-1)) / dt                     input velocity: finite difference
    f_i   = [x_i - xbar_o, v_i - vbar_o, v_i]            particle vectors [3, 3]; xbar_o, vbar_o: object means
    s_i   = W1 [mean_{j in o} e_j || e_j],  e = W0 k      particle scalars (k: node properties, controls)
    1. inter-object stage: message passing on the radius graph between nodes of different objects
       (edge vector x_i - x_j), read out per edge, mean-pooled onto object pairs
    2. object stage: message passing between objects that touch, object vectors
       [vbar_o, g_hat * phi_o(s_o)] (the gravity direction as an extra vector channel)
    3. intra-object stage: message passing on the pairs of nodes of one object, node vectors
       [object vectors || f_i || g_hat * phi_p(s_i)]; the first output vector is v_i(t+1)
    x_i(t+1) = x_i(t) + dt v_i(t+1)

Every stage is ONE subequivariant layer applied ``p_step`` (4) times with shared weights. A
layer (:class:`SubequivariantLayer`) only ever sees the vectors through the Gram matrix
``Z^T Z`` of the vectors it combines (flattened, L2-normalised), and outputs vectors as linear
combinations ``Z W`` of them with weights ``W`` from an MLP of those invariants: the map is
O(3)-equivariant, and adding the gravity direction ``g_hat`` as one more vector channel keeps
it equivariant exactly under the rotations and reflections that fix ``g_hat``
(subequivariance). Positions enter only relative to an object mean or another node, so the
model is translation equivariant. Scenes without gravity (``space-*``) get no gravity channel
and the model is fully E(3)-equivariant.

Training (reference code ``Physion/train_new.py``): MSE of the next velocity (in units of the
training split's velocity scale), Adam lr 1e-4, ReduceLROnPlateau (factor 0.8, patience 3)
on the validation loss, noise 3e-4 on the input velocity (:meth:`SGNN.perturb`). The MDGS
paper's Appendix B sets no SGNN-specific setting; it says the paper integrated its structural
constraint module (the rigid snap below) into the baselines.

Rigid snap (``rigid_snap``; registry ``sgnn-snap``): at rollout time each moving object's
predicted nodes are replaced by the best rigid motion of its reference shape (Kabsch,
:func:`mdgs.structure.align_to_reference`) and the velocity becomes ``(x_snapped - x) / dt``,
as the reference code's evaluation does (``--ransac_on_pred 1``, which fits the previous
frame's shape instead of the reference shape). It is never applied in training or to the
one-step validation loss, so ``sgnn`` and ``sgnn-snap`` train to identical weights for the
same seed; only the rollouts differ.

Deviations from the reference code (reasons in docs/peers/sgnn.md): element nodes of rigid
bodies as particles; actuator controls as extra node scalars (+ctrl on the driven body,
-ctrl on its parent, as MDGS); static world nodes as a static object; object scalars by mean
pooling (the paper) instead of the code's sum x 1e-3; intra-object pairs from the reference
shape (fixed for a rigid body) plus the face adjacency; cut-off radius = the scene's contact
radius (the one MDGS uses); inputs scaled by one length and one speed (isotropic, so the
symmetry survives); no floor indicator feature (the floor is in the graph as static nodes).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from mdgs.data.split import SplitData
from mdgs.graphs import SceneGraph, batch_edges, contact_edges, object_edges
from mdgs.models.base import Batch, ModelError, Simulator, State
from mdgs.structure import align_to_reference

__all__ = ["SGNNConfig", "SGNN", "SGNNSnap", "SubequivariantLayer", "SubequivariantNetwork",
           "gravity_direction"]


@dataclass(frozen=True)
class SGNNConfig:
    """Hyperparameters of :class:`SGNN`; every default is documented here.

    Attributes
    ----------
    rigid_snap : replace each object's predicted nodes by the best rigid motion of its
        reference shape at rollout time (evaluation only; registry ``sgnn-snap`` sets it).
    hidden : width of every scalar feature and MLP hidden layer (reference code: 200).
    p_step : iterations of the one shared layer of each stage (reference code: 4; n_layer 1).
    radius : cut-off of the radius graphs, m; 0 -> the scene's contact radius
        (:attr:`mdgs.graphs.SceneGraph.contact_radius`, twice the largest element radius).
        Set from the data by :meth:`SGNN.resolve_config`.
    gravity : "auto" (the scene's gravity from its MJCF), "none" (no gravity channel: fully
        E(3)-equivariant), or a direction "gx,gy,gz"; resolved to "none" or a unit vector.
    noise : std of the training noise on the input velocity, m/s (reference code: 3e-4).
        As in the reference code it is split over the velocity steps of the input window
        (two: frames t-1 -> t and t -> t+1) and drawn for the one input step only, so the
        input velocity is perturbed by ``noise / sqrt(2)`` per component (:meth:`SGNN.perturb`).
    noise_per_node : False (reference code): one noise vector per scene, shared by all moving
        nodes; True: one per node (as GNS, whose recipe the reference code follows).
    noise_correction : False (reference code): the target stays the clean next velocity;
        True: the target is corrected so that the noisy input lands on the true next
        position (GNS-style).
    weight_decay : Adam weight decay (1e-8, docs/peers/sgnn.md).
    control_dim : actuators (per-node control scalars); set from the data.
    dt : frame interval, s; set from the data.
    vel_scale : m/s, speed unit of inputs and loss (rms component of the training split's
        finite-difference velocities of moving nodes); set from the data.
    """

    rigid_snap: bool = False
    hidden: int = 200
    p_step: int = 4
    radius: float = 0.0
    gravity: str = "auto"
    noise: float = 3e-4
    noise_per_node: bool = False
    noise_correction: bool = False
    weight_decay: float = 1e-8
    control_dim: int = 0
    dt: float = 0.0
    vel_scale: float = 0.0

    def __post_init__(self):
        try:
            noise = 0.0 if str(self.noise).strip().lower() == "none" else float(self.noise)
        except ValueError:
            noise = -1.0
        if not (math.isfinite(noise) and noise >= 0):
            raise ValueError(f"noise must be a non-negative number (m/s) or none, got {self.noise!r}")
        object.__setattr__(self, "noise", noise)
        if self.hidden < 1 or self.p_step < 1:
            raise ValueError(f"hidden and p_step must be at least 1, got {self.hidden} and {self.p_step}")
        if self.radius < 0:
            raise ValueError(f"radius must be at least 0 (0: the scene's contact radius), got {self.radius}")
        _parse_gravity(self.gravity)

    def to_dict(self) -> dict:
        return asdict(self)


def _parse_gravity(text: str) -> np.ndarray | None:
    """``"auto"`` -> None (unresolved), ``"none"`` -> zeros, ``"gx,gy,gz"`` -> that vector; ValueError else."""
    t = str(text).strip().lower()
    if t == "auto":
        return None
    if t == "none":
        return np.zeros(3)
    try:
        g = np.array([float(p) for p in t.split(",")])
    except ValueError:
        g = np.zeros(0)
    if g.shape != (3,) or not np.isfinite(g).all():
        raise ValueError(f"gravity must be auto, none or a direction gx,gy,gz, got {text!r}")
    return g


def gravity_direction(d: SplitData) -> str:
    """The scene's gravity direction from its MJCF as ``"gx,gy,gz"`` (unit vector), or ``"none"``."""
    import mujoco

    g = np.asarray(mujoco.MjModel.from_xml_string(d.mjcf).opt.gravity, float)
    n = float(np.linalg.norm(g))
    return "none" if n == 0.0 else ",".join(repr(float(c)) for c in g / n)


# --- the subequivariant layer -----------------------------------------------------------------------


def _mlp(d_in: int, hidden: int, d_out: int) -> nn.Sequential:
    """Two hidden SiLU layers (the reference code's BaseMLP)."""
    return nn.Sequential(nn.Linear(d_in, hidden), nn.SiLU(), nn.Linear(hidden, hidden), nn.SiLU(),
                         nn.Linear(hidden, d_out))


def _invariants(z: torch.Tensor) -> torch.Tensor:
    """Flattened Gram matrix ``Z^T Z`` of vectors ``z`` [M, 3, K], L2-normalised -> [M, K*K] (O(3)-invariant)."""
    g = z.transpose(-1, -2) @ z
    return F.normalize(g.reshape(z.shape[0], -1), p=2.0, dim=-1)


def _mean_at(src: torch.Tensor, index: torch.Tensor, n: int) -> torch.Tensor:
    """Mean of the rows of ``src`` [M, ...] falling on each of ``n`` targets ``index`` [M]; 0 where none."""
    out = src.new_zeros((n, *src.shape[1:])).index_add_(0, index, src)
    cnt = src.new_zeros(n).index_add_(0, index, src.new_ones(index.shape[0]))
    return out / cnt.clamp_min(1.0).view(n, *([1] * (src.dim() - 1)))


class SubequivariantLayer(nn.Module):
    """One message-passing layer on vector features ``f`` [n, 3, F] and scalars ``s`` [n, H].

    Message of edge (i, j), received by i (= ``edges[0]``): with ``Z = [f_i, f_j, e_ij]`` [3, K]
    (K = 2F + Fe) and ``u = [inv(Z), s_i, s_j, e^s_ij]``, ``phi(u) = (W [K, F], m^s)`` and the
    vector message is ``Z W``. Node update: ``Y = [f_i, mean_j Z W]`` [3, 2F],
    ``psi([inv(Y), s_i, mean_j m^s]) = (W' [2F, F], s'_i)``, ``f'_i = Y W'``. ``inv`` is
    :func:`_invariants`. With ``readout`` the layer returns the edge messages instead
    (``out_f`` vectors and H scalars per edge).
    """

    def __init__(self, f_dim: int, s_dim: int, ef_dim: int, es_dim: int, hidden: int, out_f: int | None = None):
        super().__init__()
        self.f_dim, self.s_dim = f_dim, s_dim
        k = 2 * f_dim + ef_dim
        self.k = k
        self.out_f = f_dim if out_f is None else out_f
        self.message = _mlp(k * k + 2 * s_dim + es_dim, hidden, k * self.out_f + s_dim)
        self.readout = out_f is not None
        if not self.readout:
            self.update = _mlp(4 * f_dim * f_dim + 2 * s_dim, hidden, 2 * f_dim * f_dim + s_dim)

    def messages(self, f, s, edges, ef=None, es=None) -> tuple[torch.Tensor, torch.Tensor]:
        """Vector [M, 3, out_f] and scalar [M, H] messages of the edges ``edges`` [2, M]."""
        i, j = edges
        z = torch.cat([f[i], f[j]] + ([ef] if ef is not None else []), dim=-1)  # [M, 3, K]
        u = torch.cat([_invariants(z), s[i], s[j]] + ([es] if es is not None else []), dim=-1)
        c = self.message(u)
        w = c[:, :self.k * self.out_f].reshape(-1, self.k, self.out_f)
        return z @ w, c[:, self.k * self.out_f:]

    def forward(self, f, s, edges, ef=None, es=None) -> tuple[torch.Tensor, torch.Tensor]:
        n = f.shape[0]
        if edges.shape[1]:
            mf, ms = self.messages(f, s, edges, ef, es)
            if self.readout:
                return mf, ms
            af, as_ = _mean_at(mf, edges[0], n), _mean_at(ms, edges[0], n)
        else:
            if self.readout:
                return f.new_zeros(0, 3, self.out_f), s.new_zeros(0, self.s_dim)
            af, as_ = torch.zeros_like(f), torch.zeros_like(s)
        y = torch.cat([f, af], dim=-1)  # [n, 3, 2F]
        c = self.update(torch.cat([_invariants(y), s, as_], dim=-1))
        w = c[:, :2 * self.f_dim * self.f_dim].reshape(n, 2 * self.f_dim, self.f_dim)
        return y @ w, c[:, 2 * self.f_dim * self.f_dim:]


class SubequivariantNetwork(nn.Module):
    """ONE :class:`SubequivariantLayer` applied ``p_step`` times (shared weights), optionally
    followed by an edge readout layer (the inter-object stage)."""

    def __init__(self, f_dim, s_dim, ef_dim, es_dim, hidden, p_step, edge_readout: int | None = None):
        super().__init__()
        self.p_step = p_step
        self.layer = SubequivariantLayer(f_dim, s_dim, ef_dim, es_dim, hidden)
        self.readout = (SubequivariantLayer(f_dim, s_dim, ef_dim, es_dim, hidden, out_f=edge_readout)
                        if edge_readout else None)

    def forward(self, f, s, edges, ef=None, es=None):
        for _ in range(self.p_step):
            f, s = self.layer(f, s, edges, ef, es)
        if self.readout is not None:
            return self.readout(f, s, edges, ef, es)
        return f, s


# --- the model --------------------------------------------------------------------------------------

#: Static node scalars: mass, volume, tau, object type one-hot (3) (:meth:`SceneGraph.properties`).
N_PROPERTIES = 6


class SGNN(Simulator):
    """SGNN without the rigid snap (module docstring); registry name ``sgnn``."""

    name = "sgnn"
    Config = SGNNConfig
    summary = "SGNN (Han et al. 2022): subequivariant particle-object hierarchy, predicts velocity; no rigid snap"
    default_lr = 1e-4

    def __init__(self, config: SGNNConfig = SGNNConfig()):
        super().__init__(config)
        c = config
        self.history = 1  # the input velocity is the finite difference of frames t-1 and t
        g = _parse_gravity(c.gravity)
        self.has_gravity = g is not None and bool(np.linalg.norm(g) > 0)
        gd = g / np.linalg.norm(g) if self.has_gravity else np.zeros(3)
        self.register_buffer("g_hat", torch.tensor(gd, dtype=torch.float32))
        h, d_k = c.hidden, N_PROPERTIES + c.control_dim
        ng = int(self.has_gravity)
        self.embed = nn.Linear(d_k, h)
        self.embed_particle = nn.Linear(2 * h, h)
        self.embed_object = nn.Linear(2 * h, h)
        # stage 1: particle vectors [x - xbar, v - vbar, v], edge vector x_i - x_j; edge readout of 2 vectors
        self.inter = SubequivariantNetwork(3, h, 1, 0, h, c.p_step, edge_readout=2)
        # stage 2: object vectors [vbar (, gravity)], edge vectors/scalars pooled from stage 1
        self.objects = SubequivariantNetwork(1 + ng, h, 2, h, h, c.p_step)
        # stage 3: [object vectors, particle vectors (, gravity)], edge vector x_i - x_j
        self.particles = SubequivariantNetwork(1 + ng + 3 + ng, h, 1, 0, h, c.p_step)
        if self.has_gravity:
            self.gravity_object = nn.Sequential(nn.Linear(h, h), nn.SiLU(), nn.Linear(h, 1))
            self.gravity_particle = nn.Sequential(nn.Linear(h, h), nn.SiLU(), nn.Linear(h, 1))
        self.register_buffer("k_mean", torch.zeros(d_k))
        self.register_buffer("k_std", torch.ones(d_k))
        self._scene: SceneGraph | None = None
        self._scenes: dict = {}
        self._sign: torch.Tensor | None = None
        self._intra: torch.Tensor | None = None

    # --- construction ---------------------------------------------------------------------------------
    @classmethod
    def resolve_config(cls, config: SGNNConfig, d: SplitData) -> SGNNConfig:
        """Set ``control_dim``, ``dt``, ``radius`` (if 0), ``gravity`` (if auto), ``vel_scale`` (if 0) from ``d``."""
        kw = {"control_dim": int(d.ctrl.shape[-1])}
        if config.dt <= 0:
            kw["dt"] = float(d.frame_dt)
        if config.radius <= 0:
            kw["radius"] = SceneGraph.from_static(d.static, has_contact=d.has_contact).contact_radius
        if config.gravity.strip().lower() == "auto":
            kw["gravity"] = gravity_direction(d)
        if config.vel_scale <= 0:
            dt = kw.get("dt", config.dt)
            fd = (d.x[:, 1:] - d.x[:, :-1])[:, :, d.moving] / dt
            kw["vel_scale"] = float(max(np.sqrt(np.mean(fd.astype(np.float64) ** 2)), 1e-9))
        return replace(config, **kw)

    def fit(self, d: SplitData) -> None:
        """Mean and std of the node scalars (properties, controls) over 256 random training frames."""
        n = d.x.shape[0] * d.x.shape[1]
        idx = np.random.default_rng(0).choice(n, size=min(256, n), replace=False)
        c = torch.tensor(d.control.reshape(-1, *d.control.shape[2:])[idx])
        scene = SceneGraph.from_static(d.static, has_contact=d.has_contact)
        k = self._scalars(scene, c).reshape(-1, self.k_mean.shape[0])
        self.k_mean.copy_(k.mean(0))
        self.k_std.copy_(k.std(0).clamp_min(1e-8))

    def bind(self, split: SplitData) -> None:
        """Use the static graph and control map of ``split`` (same node and actuator counts as trained)."""
        if int(split.ctrl.shape[-1]) != self.config.control_dim:
            raise ModelError(f"{split.path} has {split.ctrl.shape[-1]} actuators but the model was built for "
                             f"{self.config.control_dim}; use data of the scene it was trained on")
        super().bind(split)
        sc = SceneGraph.from_static(split.static, has_contact=split.has_contact)
        self._scene, self._scenes = sc, {}
        self._sign = torch.from_numpy(np.asarray(split.control_sign, np.float32))
        self._intra = self.intra_edges(sc, split.static["adjacency"], self.config.radius)

    @staticmethod
    def intra_edges(sc: SceneGraph, adjacency, radius: float) -> torch.Tensor:
        """Pairs (both directions) of distinct moving nodes of one object closer than ``radius`` in the
        reference shape, united with the face adjacency -> [2, E]. Fixed for a rigid body."""
        ref = sc.ref_shape
        same = (sc.obj[:, None] == sc.obj[None, :]) & ~torch.eye(sc.num_nodes, dtype=torch.bool)
        moving = ~sc.static
        near = torch.cdist(ref, ref, compute_mode="donot_use_mm_for_euclid_dist") < radius
        adj = torch.zeros_like(same)
        fe = object_edges(adjacency, sc.num_nodes)
        adj[fe[0], fe[1]] = True
        keep = same & (near | adj) & moving[:, None] & moving[None, :]
        return torch.stack(torch.nonzero(keep, as_tuple=True))

    def _scene_on(self, dev) -> tuple[SceneGraph, torch.Tensor]:
        if self._scene is None:
            raise ModelError("the model is not bound to a scene; call bind(split) first")
        key = str(dev)
        if key not in self._scenes:
            self._scenes[key] = (self._scene.to(dev), self._intra.to(dev))
        return self._scenes[key]

    def node_controls(self, ctrl: torch.Tensor) -> torch.Tensor:
        """Controls [B, nu] -> per-node control scalars [B, N, nu] (+ on the driven body, - on its parent)."""
        return ctrl.to(torch.float32)[:, None, :] * self._sign.to(ctrl.device).T[None]

    def _scalars(self, scene: SceneGraph, control: torch.Tensor) -> torch.Tensor:
        """Raw node scalars [B, N, 6 + nu]: properties and control scalars (all rotation-invariant)."""
        B, N = control.shape[:2]
        k = scene.properties().to(control.device, control.dtype).expand(B, N, -1)
        return torch.cat([k, control], dim=-1)

    # --- the network ------------------------------------------------------------------------------------
    def velocity(self, x: torch.Tensor, v: torch.Tensor, ctrl: torch.Tensor) -> torch.Tensor:
        """Next velocity [B, N, 3] (m/s) from positions ``x`` (m) and velocities ``v`` (m/s) [B, N, 3] at t
        and controls ``ctrl`` [B, nu]; static nodes get 0."""
        c = self.config
        sc, intra = self._scene_on(x.device)
        B, N, _ = x.shape
        S, dt = sc.n_obj, x.dtype
        L, V = c.radius, c.vel_scale
        dev = x.device
        obj = (sc.obj[None, :] + S * torch.arange(B, device=dev)[:, None]).reshape(-1)  # batched object ids
        xf, vf = x.reshape(B * N, 3) / L, v.reshape(B * N, 3) / V
        k = (self._scalars(sc, self.node_controls(ctrl).to(dt)) - self.k_mean.to(dt)) / self.k_std.to(dt)
        e = self.embed(k.reshape(B * N, -1))
        x_o, v_o, s_o = _mean_at(xf, obj, B * S), _mean_at(vf, obj, B * S), _mean_at(e, obj, B * S)
        f_p = torch.stack([xf - x_o[obj], vf - v_o[obj], vf], dim=-1)  # [BN, 3, 3]
        s_p = self.embed_particle(torch.cat([s_o[obj], e], dim=-1))
        # 1. inter-object stage on the radius graph between objects
        inter = contact_edges(x.detach(), sc.obj, c.radius, sc.static)
        ef = (xf[inter[0]] - xf[inter[1]]).unsqueeze(-1)
        mf, ms = self.inter(f_p, s_p, inter, ef)  # [M, 3, 2], [M, H]
        # 2. object stage between objects joined by at least one inter-object edge
        key = obj[inter[0]] * (B * S) + obj[inter[1]]
        pairs, where = torch.unique(key, return_inverse=True)
        oe = torch.stack([pairs // (B * S), pairs % (B * S)])
        f_o = [v_o]
        if self.has_gravity:
            f_o.append(self.g_hat.to(dt) * self.gravity_object(s_o))
        f_o, s_o = self.objects(torch.stack(f_o, -1), s_o, oe, _mean_at(mf, where, pairs.shape[0]),
                                _mean_at(ms, where, pairs.shape[0]))
        # 3. intra-object stage: object -> particle
        f_q = torch.cat([f_o[obj], f_p], dim=-1)
        s_q = self.embed_object(torch.cat([s_o[obj], s_p], dim=-1))
        if self.has_gravity:
            f_q = torch.cat([f_q, (self.g_hat.to(dt) * self.gravity_particle(s_q)).unsqueeze(-1)], dim=-1)
        ie = batch_edges(intra, N, B)
        f_q, _ = self.particles(f_q, s_q, ie, (xf[ie[0]] - xf[ie[1]]).unsqueeze(-1))
        v_next = (V * f_q[:, :, 0]).reshape(B, N, 3)
        return torch.where(sc.static.view(1, N, 1), torch.zeros_like(v_next), v_next)

    # --- the Simulator contract -----------------------------------------------------------------------
    def initial_state(self, split: SplitData, traj: np.ndarray, frame: int) -> State:
        """Positions at ``frame`` and the finite-difference velocity of frames ``frame - 1 -> frame``."""
        if frame < 1:
            raise ValueError("SGNN needs the frame before the first one it steps from (frame >= 1)")
        dev = self.device
        x0 = torch.from_numpy(split.x[traj, frame - 1]).to(dev)
        x1 = torch.from_numpy(split.x[traj, frame]).to(dev)
        return State(x1, (x1 - x0) / self.config.dt)

    def step(self, state: State, ctrl: torch.Tensor) -> State:
        """``x' = x + dt v'``; with ``rigid_snap`` each moving object snapped rigid and ``v' = (x' - x) / dt``."""
        c = self.config
        x = state.x
        v_next = self.velocity(x, state.v, ctrl)
        x_next = x + c.dt * v_next
        if c.rigid_snap:
            sc, _ = self._scene_on(x.device)
            x_next = align_to_reference(x_next, sc.ref_shape, sc.obj, sc.n_obj, mask=~sc.static)
            v_next = (x_next - x) / c.dt
        return State(x_next, v_next)

    def _targets(self, batch: Batch) -> tuple[torch.Tensor, torch.Tensor]:
        """Input velocity (x_t - x_{t-1}) / dt and target velocity (x_{t+1} - x_t) / dt, [B, N, 3]."""
        dt = self.config.dt
        return (batch.x - batch.x_past[:, -1]) / dt, (batch.x_next - batch.x) / dt

    def losses(self, batch: Batch) -> dict[str, torch.Tensor]:
        """``mse``: mean squared error of the next velocity over moving nodes, in units of ``vel_scale``."""
        sc, _ = self._scene_on(batch.x.device)
        v_in, v_target = self._targets(batch)
        v_pred = self.velocity(batch.x, v_in, batch.ctrl)
        err = ((v_pred - v_target) / self.config.vel_scale)[:, ~sc.static]
        return {"mse": err.pow(2).mean()}

    def perturb(self, batch: Batch, gen: torch.Generator) -> Batch:
        """The reference code's noise: a random-walk velocity noise over the window's velocity steps.

        With one input velocity (frames t-1 -> t) the window has two velocity steps, so the
        per-step std is ``noise / sqrt(2)`` and only the input step is perturbed: ``v~_t = v_t + n``,
        and the input frame moves with it, ``x~_t = x_{t-1} + dt v~_t = x_t + dt n`` (moving nodes).
        Target: the reference code keeps the clean next velocity ``(x_{t+1} - x_t) / dt``; here
        ``x_next`` is shifted by the same ``dt n`` so that ``(x_next - x~_t) / dt`` is exactly that.
        With ``noise_correction`` ``x_next`` stays, so the target ``(x_{t+1} - x~_t) / dt`` brings the
        noisy input onto the true next position. ``n``: one vector per scene (reference code)
        or per node (``noise_per_node``).
        """
        c = self.config
        if c.noise == 0:
            return batch
        sc, _ = self._scene_on(batch.x.device)
        B, N, _ = batch.x.shape
        shape = (B, N, 3) if c.noise_per_node else (B, 1, 3)
        n = c.noise / math.sqrt(2.0) * torch.randn(shape, generator=gen, device=batch.x.device, dtype=batch.x.dtype)
        shift = c.dt * n * (~sc.static).view(1, N, 1).to(batch.x.dtype)
        x_next = batch.x_next if c.noise_correction else batch.x_next + shift
        return replace(batch, x=batch.x + shift, x_next=x_next)

    def optimizer(self, lr: float):
        """Adam (betas 0.9/0.999, weight decay ``weight_decay``) and ReduceLROnPlateau (factor 0.8,
        patience 3) on the validation loss once per epoch, as the reference code."""
        opt = torch.optim.Adam(self.parameters(), lr=lr, betas=(0.9, 0.999), weight_decay=self.config.weight_decay)
        return opt, torch.optim.lr_scheduler.ReduceLROnPlateau(opt, mode="min", factor=0.8, patience=3), "epoch"


@dataclass(frozen=True)
class _SnapConfig(SGNNConfig):
    """:class:`SGNNConfig` with ``rigid_snap = True``."""

    rigid_snap: bool = True


class SGNNSnap(SGNN):
    """SGNN with the evaluation-time rigid snap (registry ``sgnn-snap``); trains exactly as ``sgnn``."""

    name = "sgnn-snap"
    Config = _SnapConfig
    trains_as = "sgnn"
    summary = "SGNN with the rigid snap at rollout (Kabsch of each object's reference shape onto the prediction)"

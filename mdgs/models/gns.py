"""GNS, the Graph Network-based Simulator of Sanchez-Gonzalez et al. (ICML 2020), as a peer of MDGS.

Rebuilt on our own code after the paper and its reference implementation (deepmind-research
``learning_to_simulate``); the particles are the scene's element nodes. One step, for a batch
of ``B`` graphs with ``N`` nodes and the positions ``x^{t-H} .. x^t`` (``H = 5``):

    u^k        = x^{k} - x^{k-1},  k = t-H+1 .. t          H velocities (m per frame)
    node_i     = [(u_i^k - mu_u) / s_u for the H velocities || clip(d_i^p / R, -1, 1) per floor plane p
                  || ctrl features || type embedding (16)]
    edges      = {(j -> i) : |x_i^t - x_j^t| < R}  (self-edges included)
    edge_ji    = [(x_j^t - x_i^t) / R || |x_j^t - x_i^t| / R]
    encode     : node MLP, edge MLP -> latent 128 (LayerNorm)
    process    : 10 interaction networks with UNSHARED weights and residuals:
                 m_ji = f_e([e_ji, h_j, h_i]);  e'_ji = e_ji + m_ji;  h'_i = h_i + f_h([h_i, sum_j m_ji])
    decode     : MLP -> normalised acceleration a~;  a = s_a a~ + mu_a            (m per frame^2)
    integrate  : u^{t+1} = u^t + a,  x^{t+1} = x^t + u^{t+1}   (semi-implicit Euler, dt = 1 frame)

Every MLP has 2 hidden layers of 128 with ReLU and a LayerNorm on its output, except the
decoder's. Training: MSE between predicted and target normalised accelerations, summed over
x, y, z and averaged over moving nodes; random-walk noise on the input velocity sequence
(:meth:`GNS.perturb`) with the noise-corrected target; statistics ``s_u = sqrt(std(u)^2 +
sigma^2)``, ``s_a = sqrt(std(a)^2 + sigma^2)`` from the training split only; Adam with the
learning rate decaying exponentially from the trainer's ``lr`` (GNS: 1e-4) to 1e-6 by 0.1 per
5e6 steps, stepped after every optimiser step.

With ``prior = "tree"`` (not in the original; a comparison row for MDGS's "dynamics" prior, which no peer had)
GNS corrects the scene's rigid tree instead of its constant-velocity guess: where the original moves every node by
``x^t + u^t`` and adds the decoded acceleration, the tree's state after the frame ``(x_p, v_p)``
(:func:`mdgs.tree.tree_step`, the same call and settings as MDGS's prior) takes that place,

    x^{t+1} = x_p + a,   v^{t+1} = v_p + a / dt                                  (a in m, per frame^2 x 1 frame^2)

(the velocity changes by the acceleration over the frame, as in GNS's own semi-implicit Euler), so the state carries
the node velocities the tree needs (``State.v``: recorded at the first frame, then ``v^{t+1}``), the target is the
tree's residual ``x^{t+1} - x_p`` and its statistics are the residual's on the training split. GNS's own features,
network, loss, noise and schedule are unchanged, and GNS still reads nothing of what the tree did. The noisy last
velocity reaches the tree as ``v + (n^t - n^{t-1}) / dt``, and the noise-corrected target must be the true next
position (``noise_target = "position"``): the tree places each body rigidly, so it carries only the rigid part of
the input's noise, and the original's target, shifted by every node's noise, would ask GNS to put the rest back.

Deviations from the original, and why (also in docs/peers/gns.md):

- Particles are element centroids of rigid bodies, not a dense particle sampling; the node
  type (embedding of width 16) is the rigid body (object) the element belongs to, world
  geometry being one more object. Static world elements are the original's kinematic
  particles: in the graph, never moved, never noised, not in the loss.
- The connectivity radius ``R`` is ``radius_factor`` (1.5) times the largest distance from a
  moving element to its nearest element of the same body in the first training frame (the
  coarsest element spacing), so every element is linked to its nearest sibling and to
  contact partners before they touch; the original picks R per dataset by hand.
- Boundaries: the original clips the distances to the axis-aligned domain walls. Our scenes
  have no box domain; the boundary features are the signed distances to the world's planes
  (the floor) along their normals, clipped to [-1, 1] after division by R. A scene without a
  plane (free-floating robots) has no boundary feature; world obstacles (walls, blocks) are
  static element nodes in the radius graph instead, as obstacles are in the original's
  datasets with boundary particles.
- Actuator controls (absent in the original) enter as node inputs: actuator k's control,
  divided by its training std, is +1x on the nodes of the body it drives and -1x on its parent
  body's nodes (the reaction; MDGS's control map, :func:`mdgs.data.split.control_map`).
- Units: positions in metres, velocity per frame (m per frame), so the original's ``dt = 1``
  update holds; the noise std (6.7e-4) is read in metres. ``State.v`` (for metrics only) is
  the backward difference ``(x^{t+1} - x^t) / frame_dt``: GNS has no other velocity.
- The noise-corrected target of the original shifts the true next position by the noise of
  the last input position, so the target acceleration restores the true next *velocity*
  exactly (``noise_target = "velocity"``, default); ``noise_target = "position"`` corrects
  that shift too, so the target lands on the true next position.
- ``structure = True`` snaps every body's predicted nodes to its reference shape after each
  rollout step (the MDGS paper says it added its structural module to the baselines for its
  tables); off by default, the original has no such step. Training is unaffected.
- Batch size is the trainer's (``mdgs train --batch-size``, default 32; the original uses 2),
  and the decay schedule keeps the original's per-step time constant, so short runs stay
  near the initial rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch
from torch import nn

from mdgs.actuation import DriveSet, check_contact, drives_of, warn_unseen
from mdgs.data.split import SplitData
from mdgs.graphs import SceneGraph, radius_edges
from mdgs.joints import JointSet, joints_of
from mdgs.models.base import Batch, ModelError, Simulator, State, batch_of
from mdgs.structure import align_to_reference
from mdgs.tree import check_joint_velocities, tree_step

__all__ = ["GNSConfig", "GNS", "MLP", "element_spacing", "world_planes", "random_walk_noise"]

#: How the target of a noisy input is corrected (see :meth:`GNS.perturb`).
NOISE_TARGETS = ("velocity", "position")

#: What GNS's acceleration corrects (module docstring): its own constant-velocity guess, or the rigid tree's state.
PRIORS = ("none", "tree")


@dataclass(frozen=True)
class GNSConfig:
    """Hyperparameters of :class:`GNS`; every default is documented here.

    Attributes
    ----------
    latent : width of node and edge latents (GNS: 128).
    hidden : width of the hidden layers of every MLP (GNS: 128).
    mlp_layers : hidden layers per MLP (GNS: 2).
    steps : message-passing steps, each with its own weights (GNS: 10, unshared).
    history : velocities given to the model, from ``history + 1`` positions (GNS: 5).
    type_embedding : width of the learned node-type embedding (GNS: 16).
    radius : connectivity radius R, m; 0 -> ``radius_factor`` x :func:`element_spacing` of the
        training split.
    radius_factor : R as a multiple of the coarsest element spacing (1.5: face neighbours and
        face diagonals of a cube of 2x2x2 elements, not its body diagonal).
    noise_std : std of the random-walk noise on the input velocities at the last step, m per
        frame (GNS: 6.7e-4; the MDGS paper's Appendix B sets no GNS noise). 0 disables it.
    noise_target : "velocity" (the original: the target restores the true next velocity; the
        next position is the true one shifted by the last input's noise) or "position" (the
        target lands on the true next position).
    lr_final : learning rate the exponential decay tends to (GNS: 1e-6).
    lr_decay : factor of the decay over ``lr_decay_steps`` steps (GNS: 0.1 per 5e6 steps).
    lr_decay_steps : optimiser steps of one ``lr_decay`` factor.
    structure : snap each body to its reference shape after every rollout step (the MDGS
        paper's baseline setting; off in the original GNS).
    prior : "none" (the original: the acceleration corrects ``x^t + u^t``) or "tree" (it corrects the scene's
        rigid tree after the frame; module docstring). The four settings below are the tree's, as MDGS's
        ``prior_substeps``, ``trapezoidal``, ``prior_contact`` and ``joint_velocities`` set its prior (the
        defaults are mdgs-soft-8's MDGS row); the tree always keeps the scene's joints, without push-out and
        with the gyroscopic terms at each substep's start.
    prior_substeps : substeps of the tree per frame.
    prior_trapezoidal : velocity Verlet (with "coordinates") or the mean twist, instead of semi-implicit Euler.
    prior_contact : the tree's contact model, "soft" (MuJoCo's) or "rigid" (:data:`mdgs.actuation.CONTACT_MODELS`).
    prior_joint_velocities : how the tree keeps its joints (:data:`mdgs.tree.JOINT_VELOCITIES`).
    n_types : node types (bodies with elements); set from the data.
    n_planes : world planes giving boundary features; set from the data.
    control_dim : actuators; set from the data.
    dt : frame interval, s (for ``State.v``); set from the data.
    """

    latent: int = 128
    hidden: int = 128
    mlp_layers: int = 2
    steps: int = 10
    history: int = 5
    type_embedding: int = 16
    radius: float = 0.0
    radius_factor: float = 1.5
    noise_std: float = 6.7e-4
    noise_target: str = "velocity"
    lr_final: float = 1e-6
    lr_decay: float = 0.1
    lr_decay_steps: float = 5e6
    structure: bool = False
    prior: str = "none"
    prior_substeps: int = 8
    prior_trapezoidal: bool = True
    prior_contact: str = "soft"
    prior_joint_velocities: str = "coordinates"
    n_types: int = 0
    n_planes: int = 0
    control_dim: int = 0
    dt: float = 0.0

    def __post_init__(self):
        if self.noise_target not in NOISE_TARGETS:
            raise ValueError(f"noise_target must be one of {', '.join(NOISE_TARGETS)}, got {self.noise_target!r}")
        for name in ("latent", "hidden", "steps", "history", "type_embedding"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)!r}")
        if self.mlp_layers < 0:
            raise ValueError(f"mlp_layers must be at least 0, got {self.mlp_layers!r}")
        if not (self.radius >= 0 and self.radius_factor > 0 and self.noise_std >= 0):
            raise ValueError("radius and noise_std must be >= 0 and radius_factor > 0, got "
                             f"{self.radius!r}, {self.noise_std!r}, {self.radius_factor!r}")
        if not (0 < self.lr_decay <= 1 and self.lr_decay_steps > 0 and self.lr_final >= 0):
            raise ValueError("lr_decay must be in (0, 1], lr_decay_steps > 0 and lr_final >= 0")
        if self.prior not in PRIORS:
            raise ValueError(f"prior must be one of {', '.join(map(repr, PRIORS))}, got {self.prior!r}")
        n = self.prior_substeps
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"prior_substeps must be a positive integer, got {n!r}")
        if not isinstance(self.prior_trapezoidal, bool):
            raise ValueError(f"prior_trapezoidal must be true or false, got {self.prior_trapezoidal!r}")
        check_contact(self.prior_contact)
        check_joint_velocities(self.prior_joint_velocities)
        if self.prior == "tree" and self.noise_std > 0 and self.noise_target != "position":
            raise ValueError("prior = \"tree\" needs noise_target = \"position\" (or noise_std = 0): the rigid tree "
                             "carries only the rigid part of each body's input noise to its positions, so the "
                             "\"velocity\" target, shifted by every node's noise, would train GNS to put the rest back")


class MLP(nn.Sequential):
    """``layers`` hidden layers of ``hidden`` with ReLU, a linear output, and a LayerNorm on it if ``norm``."""

    def __init__(self, d_in: int, hidden: int, d_out: int, layers: int = 2, norm: bool = True):
        dims = [d_in] + [hidden] * layers
        mods: list[nn.Module] = []
        for a, b in zip(dims[:-1], dims[1:], strict=True):
            mods += [nn.Linear(a, b), nn.ReLU()]
        mods.append(nn.Linear(dims[-1], d_out))
        if norm:
            mods.append(nn.LayerNorm(d_out))
        super().__init__(*mods)


class _Interaction(nn.Module):
    """One interaction network (Battaglia et al. 2016) with residual node and edge updates."""

    def __init__(self, latent: int, hidden: int, layers: int):
        super().__init__()
        self.edge = MLP(3 * latent, hidden, latent, layers)
        self.node = MLP(2 * latent, hidden, latent, layers)

    def forward(self, h: torch.Tensor, e: torch.Tensor, snd: torch.Tensor, rcv: torch.Tensor):
        """``h`` [M, L] nodes, ``e`` [E, L] edges from ``snd`` to ``rcv`` -> updated ``(h, e)``."""
        de = self.edge(torch.cat([e, h[snd], h[rcv]], -1))
        agg = torch.zeros_like(h).index_add_(0, rcv, de)
        return h + self.node(torch.cat([h, agg], -1)), e + de


def element_spacing(d: SplitData) -> float:
    """The coarsest element spacing of a scene, m: the largest distance from a moving node to the
    nearest node of its own body (first frame of the first trajectory).

    Bodies of one element have no sibling; when no moving node has one, the largest distance
    from a moving node to its nearest other node is used; for a lone node, twice its radius ``tau``.
    """
    x = np.asarray(d.x[0, 0], np.float64)
    body = np.asarray(d.static["node_body"])
    mv = d.moving
    if len(x) < 2 or not mv.any():
        return float(2.0 * max(np.asarray(d.static["node_tau"], float).max(initial=0.0), 1e-3))
    dist = np.linalg.norm(x[:, None] - x[None], axis=-1)
    np.fill_diagonal(dist, np.inf)
    same = np.where(body[:, None] == body[None], dist, np.inf).min(1)[mv]
    same = same[np.isfinite(same)]
    return float(same.max() if same.size else dist.min(1)[mv].max())


def world_planes(mjcf: str) -> tuple[np.ndarray, np.ndarray]:
    """Planes of the world body (floors): points ``[P, 3]`` and unit normals ``[P, 3]``, m."""
    import mujoco

    m = mujoco.MjModel.from_xml_string(mjcf)
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    g = [i for i in range(m.ngeom) if m.geom_type[i] == mujoco.mjtGeom.mjGEOM_PLANE and m.geom_bodyid[i] == 0]
    pts = np.array([d.geom_xpos[i] for i in g], np.float64).reshape(-1, 3)
    nrm = np.array([d.geom_xmat[i].reshape(3, 3)[:, 2] for i in g], np.float64).reshape(-1, 3)
    return pts, nrm


def random_walk_noise(shape: tuple[int, int, int, int], std_last: float, gen: torch.Generator,
                      device) -> torch.Tensor:
    """Position noise ``[B, H + 1, N, 3]`` of a random walk on the ``H`` velocities of ``H + 1`` positions.

    Each velocity gets independent noise of std ``std_last / sqrt(H)``, accumulated over time,
    so the last velocity's noise has std ``std_last``; the oldest position is not perturbed
    and position ``k`` carries the sum of the first ``k`` velocity noises (GNS, Section 4.2).
    """
    B, H1, N, D = shape
    H = H1 - 1
    dv = torch.randn((B, H, N, D), generator=gen, device=device) * (std_last / math.sqrt(H))
    return torch.cat([torch.zeros((B, 1, N, D), device=device), torch.cumsum(dv, dim=1)], dim=1)


class GNS(Simulator):
    """GNS of Sanchez-Gonzalez et al. 2020 (module docstring); registry name ``gns``."""

    name = "gns"
    Config = GNSConfig
    summary = "GNS: encode-process-decode, 10 unshared interaction steps, 5-velocity history, radius graph"
    default_lr = 1e-4

    def __init__(self, config: GNSConfig = GNSConfig()):
        super().__init__(config)
        c = config
        self.history = int(c.history)
        d_node = 3 * c.history + c.n_planes + c.control_dim + c.type_embedding
        self.embed = nn.Embedding(max(c.n_types, 1), c.type_embedding)
        self.node_encoder = MLP(d_node, c.hidden, c.latent, c.mlp_layers)
        self.edge_encoder = MLP(4, c.hidden, c.latent, c.mlp_layers)
        self.processor = nn.ModuleList(_Interaction(c.latent, c.hidden, c.mlp_layers) for _ in range(c.steps))
        self.decoder = MLP(c.latent, c.hidden, 3, c.mlp_layers, norm=False)
        # statistics (fit on the training split): velocity and acceleration per axis, control std
        for k in ("vel_mean", "acc_mean"):
            self.register_buffer(k, torch.zeros(3))
        for k in ("vel_std", "acc_std"):
            self.register_buffer(k, torch.ones(3))
        self.register_buffer("ctrl_std", torch.ones(c.control_dim))
        self._scene: SceneGraph | None = None
        self._cache: dict = {}
        self._drives, self._joints = DriveSet(), JointSet()

    # --- construction ------------------------------------------------------------------------
    @classmethod
    def resolve_config(cls, config: GNSConfig, d: SplitData) -> GNSConfig:
        """Set ``n_types``, ``n_planes``, ``control_dim``, ``dt`` and (if 0) ``radius`` from the training split."""
        cls._check_frames(d, config.history)
        scene = SceneGraph.from_static(d.static, has_contact=d.has_contact)
        kw = {"n_types": int(scene.n_obj), "n_planes": int(len(world_planes(d.mjcf)[0])),
              "control_dim": int(d.ctrl.shape[-1]), "dt": float(d.frame_dt)}
        if config.radius <= 0:
            kw["radius"] = float(config.radius_factor * element_spacing(d))
        return replace(config, **kw)

    @staticmethod
    def _check_frames(d: SplitData, history: int) -> None:
        if d.x.shape[1] < history + 2:
            raise ModelError(f"{d.path} has {d.x.shape[1]} frames per trajectory but GNS needs at least "
                             f"{history + 2} ({history + 1} given, one to predict); generate longer trajectories")

    def fit(self, d: SplitData) -> None:
        """Per-axis mean and std of the moving nodes' velocities and accelerations (per frame) over the
        training split, the noise folded into the stds; std of each actuator's control. With the tree
        prior the accelerations are its residuals ``x^{t+1} - x_p`` (:meth:`_tree_residuals`)."""
        x = d.x[:, :, d.moving].astype(np.float64)
        u = np.diff(x, axis=1).reshape(-1, 3)
        a = np.diff(x, n=2, axis=1).reshape(-1, 3) if self.config.prior == "none" else self._tree_residuals(d)
        s2 = self.config.noise_std ** 2
        f = lambda z: torch.as_tensor(z, dtype=torch.float32)  # noqa: E731
        if len(u):
            self.vel_mean.copy_(f(u.mean(0)))
            self.vel_std.copy_(f(np.sqrt(u.var(0) + s2)).clamp_min(1e-8))
        if len(a):
            self.acc_mean.copy_(f(a.mean(0)))
            self.acc_std.copy_(f(np.sqrt(a.var(0) + s2)).clamp_min(1e-8))
        if self.config.control_dim:
            sd = d.ctrl.reshape(-1, d.ctrl.shape[-1]).astype(np.float64).std(0)
            self.ctrl_std.copy_(f(np.where(sd > 0, sd, 1.0)))

    def _tree_residuals(self, d: SplitData) -> np.ndarray:
        """What the decoder must add to the tree prior on every training pair with a full history:
        ``x^{t+1} - x_p`` of the moving nodes, m (per frame^2 x 1 frame^2), ``[P * N_moving, 3]``."""
        pairs = d.pairs(self.history)
        out = []
        with torch.no_grad():
            for i in range(0, len(pairs), 256):
                b = batch_of(d, pairs[i:i + 256], "cpu", self.history)
                out.append((b.x_next - self._tree(b.x, b.v, b.ctrl)[0])[:, d.moving].double().numpy())
        return np.concatenate(out).reshape(-1, 3)

    def _tree(self, x: torch.Tensor, v: torch.Tensor, ctrl: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The rigid tree's node positions and velocities ``[B, N, 3]`` after the frame from ``x, v`` (no gradient;
        static nodes kept, their velocity zero): :func:`mdgs.tree.tree_step` with the ``prior_*`` settings."""
        c = self.config
        sc = self._on(x.device)
        s = sc["scene"]
        with torch.no_grad():
            xp, vp = tree_step(x.detach(), v.detach(), ctrl, self._drives, s.ref_shape, s.obj, s.n_obj, s.mass, c.dt,
                               c.prior_substeps, c.prior_trapezoidal, False, self._joints, "explicit",
                               c.prior_joint_velocities, c.prior_contact)
        m = sc["moving"].view(1, -1, 1)
        return torch.where(m, xp, x.detach()), torch.where(m, vp, torch.zeros_like(vp))

    @property
    def scalar_loops(self) -> bool:
        """With ``prior = "tree"`` the step runs the rigid tree's forward dynamics (:attr:`Simulator.scalar_loops`)."""
        return self.config.prior == "tree"

    def bind(self, split: SplitData) -> None:
        """Use the scene of ``split``: its bodies (node types), floor planes and control map."""
        c = self.config
        self._check_frames(split, c.history)
        scene = SceneGraph.from_static(split.static, has_contact=split.has_contact)
        pts, nrm = world_planes(split.mjcf)
        if (int(split.ctrl.shape[-1]), scene.n_obj, len(pts)) != (c.control_dim, c.n_types, c.n_planes):
            raise ModelError(f"{split.path} has {split.ctrl.shape[-1]} actuators, {scene.n_obj} bodies and "
                             f"{len(pts)} floor planes but the model was built for {c.control_dim}, {c.n_types} "
                             f"and {c.n_planes}; use data of the scene it was trained on")
        super().bind(split)
        self._scene = scene
        self._planes = (torch.as_tensor(pts, dtype=torch.float32), torch.as_tensor(nrm, dtype=torch.float32))
        self._sign = torch.as_tensor(np.asarray(split.control_sign, np.float32))
        self._cache = {}
        if c.prior == "tree":
            mj = split.mj_model()
            self._drives = drives_of(mj, split.static["node_body"], split.static["node_centroid"])
            self._joints = joints_of(mj, split.static["node_body"], split.static["node_centroid"])
            warn_unseen(self._drives, "GNS's tree prior")

    def _on(self, dev) -> dict:
        """The bound scene's tensors on ``dev`` (cached)."""
        if self._scene is None:
            raise ModelError("the model is not bound to a scene; call bind(split) first")
        key = str(dev)
        if key not in self._cache:
            sc = self._scene
            self._cache[key] = {"type": sc.obj.to(dev), "moving": (~sc.static).to(dev), "scene": sc.to(dev),
                                "plane_p": self._planes[0].to(dev), "plane_n": self._planes[1].to(dev),
                                "sign": self._sign.to(dev)}
        return self._cache[key]

    # --- the network ---------------------------------------------------------------------------
    def forward(self, xs: torch.Tensor, ctrl: torch.Tensor) -> torch.Tensor:
        """Normalised accelerations ``[B, N, 3]`` from positions ``xs`` [B, H+1, N, 3] (oldest first, m)
        and actuator controls ``ctrl`` [B, nu]."""
        c = self.config
        B, H1, N, _ = xs.shape
        if H1 != c.history + 1:
            raise ValueError(f"GNS expects {c.history + 1} positions per node, got {H1}")
        sc = self._on(xs.device)
        x = xs[:, -1]
        u = (xs[:, 1:] - xs[:, :-1] - self.vel_mean) / self.vel_std  # [B, H, N, 3]
        parts = [u.permute(0, 2, 1, 3).reshape(B, N, 3 * c.history)]
        if c.n_planes:
            pp, pn = sc["plane_p"].to(x.dtype), sc["plane_n"].to(x.dtype)
            dist = torch.einsum("bnpk,pk->bnp", x[:, :, None, :] - pp, pn)
            parts.append(torch.clamp(dist / c.radius, -1.0, 1.0))
        if c.control_dim:
            parts.append((ctrl.to(x.dtype) / self.ctrl_std)[:, None, :] * sc["sign"].T[None].to(x.dtype))
        parts.append(self.embed(sc["type"]).expand(B, N, -1))
        h = self.node_encoder(torch.cat(parts, -1)).reshape(B * N, -1)
        snd, rcv = radius_edges(x.detach(), c.radius)
        flat = x.reshape(B * N, 3)
        rel = (flat[snd] - flat[rcv]) / c.radius
        e = self.edge_encoder(torch.cat([rel, rel.norm(dim=-1, keepdim=True)], -1))
        for block in self.processor:
            h, e = block(h, e, snd, rcv)
        return self.decoder(h).reshape(B, N, 3)

    def acceleration(self, a_norm: torch.Tensor) -> torch.Tensor:
        """Normalised -> physical acceleration, m per frame^2."""
        return a_norm * self.acc_std + self.acc_mean

    def target(self, xs: torch.Tensor, x_next: torch.Tensor, tree: tuple | None = None) -> torch.Tensor:
        """The normalised acceleration that :meth:`integrate` turns into ``x_next`` from ``xs`` (inverse Euler), or
        with the tree prior ``tree`` (:meth:`_tree`) the tree's residual ``x_next - x_p``."""
        if tree is not None:
            a = x_next - tree[0]
        else:  # differences of neighbouring positions first: exact in float32 (Sterbenz), as GNS computes them
            a = (x_next - xs[:, -1]) - (xs[:, -1] - xs[:, -2])
        return (a - self.acc_mean) / self.acc_std

    def integrate(self, xs: torch.Tensor, a_norm: torch.Tensor, tree: tuple | None = None) -> torch.Tensor:
        """Semi-implicit Euler in frame units: ``u' = (x^t - x^{t-1}) + a``, ``x' = x^t + u'``, or with the tree
        prior ``tree`` ``x' = x_p + a``; static nodes stay."""
        x = xs[:, -1]
        a = self.acceleration(a_norm)
        x_next = tree[0] + a if tree is not None else x + (x - xs[:, -2]) + a
        return torch.where(self._on(x.device)["moving"].view(1, -1, 1), x_next, x)

    # --- the Simulator contract ------------------------------------------------------------------
    def initial_state(self, split: SplitData, traj: np.ndarray, frame: int) -> State:
        """Frame ``frame`` with ``extra["x_past"]`` = frames ``frame - history .. frame - 1`` [B, H, N, 3]."""
        H = self.history
        if frame < H:
            raise ModelError(f"GNS starts from frame {H} or later (it reads {H} past frames), not from frame {frame}")
        base = super().initial_state(split, traj, frame)
        past = torch.from_numpy(split.x[np.asarray(traj)[:, None], np.arange(frame - H, frame)]).to(self.device)
        return State(base.x, base.v, {"x_past": past})

    def step(self, state: State, ctrl: torch.Tensor) -> State:
        """One frame; ``State.v`` is the backward difference, or with the tree prior ``v_p + a / dt`` (the velocity
        the next frame's tree starts from)."""
        xs = torch.cat([state.extra["x_past"], state.x[:, None]], 1)
        tree = self._tree(state.x, state.v, ctrl) if self.config.prior == "tree" else None
        x_next = self.integrate(xs, self(xs, ctrl), tree)
        sc = self._on(x_next.device)
        if tree is not None:
            v_next = tree[1] + (x_next - tree[0]) / self.config.dt
        if self.config.structure:
            s = sc["scene"]
            x_next = align_to_reference(x_next, s.ref_shape, s.obj, s.n_obj, mask=sc["moving"])
        if tree is None:
            v_next = (x_next - state.x) / self.config.dt
        return State(x_next, v_next, {"x_past": xs[:, 1:]})

    def _positions(self, batch: Batch) -> torch.Tensor:
        if batch.x_past is None or batch.x_past.shape[1] != self.history:
            raise ValueError(f"GNS needs batches with {self.history} past frames (batch_of(..., history={self.history}))")
        return torch.cat([batch.x_past, batch.x[:, None]], 1)

    def losses(self, batch: Batch) -> dict[str, torch.Tensor]:
        """``mse``: squared error of the normalised acceleration, summed over x, y, z, mean over moving nodes."""
        xs = self._positions(batch)
        tree = self._tree(batch.x, batch.v, batch.ctrl) if self.config.prior == "tree" else None
        err = ((self(xs, batch.ctrl) - self.target(xs, batch.x_next, tree)) ** 2).sum(-1)  # [B, N]
        mv = self._on(xs.device)["moving"]
        return {"mse": err[:, mv].mean()}

    def perturb(self, batch: Batch, gen: torch.Generator) -> Batch:
        """Random-walk noise on the input velocities of the moving nodes (:func:`random_walk_noise`,
        ``noise_std`` at the last velocity), with the noise-corrected target.

        ``noise_target = "velocity"`` (GNS): the target next position is shifted by the last input
        position's noise, so the target acceleration restores the true next velocity
        ``x^{t+1} - x^t``; ``"position"``: the target stays the true next position. With the tree prior the
        velocity the tree reads takes the last input velocity's noise, ``(n^t - n^{t-1}) / dt``.
        """
        c = self.config
        if c.noise_std == 0:
            return batch
        xs = self._positions(batch)
        n = random_walk_noise(tuple(xs.shape), c.noise_std, gen, xs.device)
        n = n * self._on(xs.device)["moving"].view(1, 1, -1, 1)
        xs = xs + n
        x_next = batch.x_next + n[:, -1] if c.noise_target == "velocity" else batch.x_next
        v = batch.v + (n[:, -1] - n[:, -2]) / c.dt if c.prior == "tree" else batch.v
        return replace(batch, x=xs[:, -1], v=v, x_past=xs[:, :-1], x_next=x_next)

    def optimizer(self, lr: float):
        """Adam (lr) with ``lr_k = lr_final + (lr - lr_final) * lr_decay^(k / lr_decay_steps)`` after step ``k``
        (``when = "step"``; GNS: 1e-4 -> 1e-6, 0.1 per 5e6 steps)."""
        c = self.config
        opt = torch.optim.Adam(self.parameters(), lr=lr)
        lo = min(c.lr_final, lr)

        def factor(k: int) -> float:
            return (lo + (lr - lo) * c.lr_decay ** (k / c.lr_decay_steps)) / lr

        return opt, torch.optim.lr_scheduler.LambdaLR(opt, factor), "step"

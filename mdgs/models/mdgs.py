"""The MDGS simulator (Sections 3.2-3.4, Appendix B) and its variants mdgs-nc and mdgs-sc.

One step, for a batch of ``B`` graphs of one scene with ``N`` nodes:

    z_i        = [x_i || v_i || k_i]                          node features (Section 3.1)
    F~         = g^F~(G~, Z)                                   non-contact forces, object graph (Eq. 4)
    Z-         = g^Z-(G- u G~, Z)                              global features, union graph (Eq. 5)
    F-         = g^F-(G-, [Z || Z-]),  0 off contact edges     contact forces, contact graph (Eq. 6)
    F          = F- + F~                                       (Eq. 7)
    z'_i       = [z_i || lambda F_i]                           (Eq. 8)
    Z^(t+1)    = g(G~, Z')                                     state, object graph (Eq. 9)

followed by an integrator (:mod:`mdgs.models.integrators`) and the structural constraint
module (Appendix B.1.3, :mod:`mdgs.structure`). Every GNN is a GCN (Kipf & Welling 2017) with
3 layers, hidden 200, ReLU (Appendix B.2). Training (Section 3.4, Appendix B.2): L_mse (Eq. 10)
plus the Kane constraint L_cst (Eqs. 11-15) summed; Adam (lr 1e-3) with ReduceLROnPlateau
(patience 3, factor 0.8); training noise on the input frame (:func:`noise_sigmas`).

Actuated scenes: each actuator's control ``ctrl_k`` (actuator units) enters the node features
of the body it drives (+ctrl_k) and of that body's parent (-ctrl_k, the reaction), one channel
per actuator (:func:`mdgs.data.split.control_map`; docs/ambiguities.md).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import NamedTuple

import numpy as np
import torch

from mdgs.actuation import (
    DriveSet,
    actuation_forces,
    check_contact,
    coupled_motor_accelerations,
    drives_of,
    gyroscopic_weight,
    motor_accelerations,
    push_out,
    warn_unseen,
)
from mdgs.data.split import SplitData
from mdgs.graphs import (
    Propagator,
    SceneGraph,
    contact_edges,
    dense_contacts,
    gcn_norm,
    gcn_norm_adjacency,
)
from mdgs.joints import JointSet, joints_of, project_joints
from mdgs.losses import constraint_loss, huber_loss, mse_loss, pair_mse, speeds_of
from mdgs.models.base import Batch, ModelError, Simulator, State, batch_of
from mdgs.models.integrators import INTEGRATORS
from mdgs.models.layers import GCN, weights_folded
from mdgs.rigid import advance, perturb, project, twist
from mdgs.structure import align_with_pose
from mdgs.tree import check_joint_velocities, tree_step, warn_unprojected

__all__ = ["MDGSConfig", "ModelConfig", "VARIANTS", "Prediction", "MDGS", "MDGSNoConstraint",
           "MDGSSingleSpeed", "noise_sigmas", "CUBLI_NOISE", "INCREMENT_NOISE"]

#: Variants of Table 1: the full method, no Kane constraint, single-speed constraint.
VARIANTS = ("mdgs", "mdgs-nc", "mdgs-sc")
#: Training noise of Appendix B.2: absolute sigma (m, m/s) for Cubli scenes.
CUBLI_NOISE = 4e-4
#: Smallest per-object scale, as a fraction of the global one (``object_scales``): a body that hardly
#: moves in the training split (a cube at rest) would otherwise get a scale that magnifies any
#: output noise on it a thousandfold. The small study's bodies all lie above it (0.097-1.4).
OBJECT_SCALE_FLOOR = 0.05
#: Where g's output scales come from (``scales``): the increments' std, or the priors' robust residual.
SCALES = ("increments", "residual")
#: Training pairs the "residual" scales are measured on (a fixed, evenly spaced subset).
RESIDUAL_PAIRS = 2048
#: Least "residual" scale, as a fraction of the increments' scale of the same quantity and object: where the
#: tree is exact on most frames (the user scene's bodies at rest: a median residual of 1e-8 m/s, float32
#: round-off) the median alone would ask g for a precision its float32 output does not have. The Cubli's
#: residual scales lie above it (2-4e-4 of the increments').
RESIDUAL_FLOOR = 1e-4
#: And at this many times the float32 round-off of the quantity itself (machine epsilon times the RMS
#: position or velocity of the split's moving nodes): a residual below it is round-off in the data.
ROUNDOFF_FACTOR = 10
#: What MDGS knows of a scene's motors (``actuation``, :mod:`mdgs.actuation`).
ACTUATION = ("none", "force", "step", "prior", "coupled", "dynamics")
#: Node features z_i (``features``): the paper's [x || v || k], or "local" (module docstring).
FEATURES = ("paper", "local")
#: The one-step loss (``loss``): Eq. (10), its Huber form, or each pair relative to doing nothing.
LOSSES = ("mse", "huber", "relative")
#: Training noise of Appendix B.2 for the other scenes, as a fraction of the per-step increment std.
INCREMENT_NOISE = 0.06


@dataclass(frozen=True)
class MDGSConfig:
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
    contact : build the contact branch (g^Z-, g^F-); set from the data (a scene that can have
        no contact has none).
    lam : lambda of Eq. (8); ``None`` -> ``1 / force_scale`` (forces enter at O(1)).
    force_scale : N; force networks output ``force_scale * GCN(.)``.
    dx_scale, dv_scale : m and m/s; g outputs ``[dx / dx_scale, dv / dv_scale]``.
    bound : "paper" (Eq. 12) or "corrected" (kane's corrected statement) for L_cst.
    integrator : how g's output ``[g_x || g_v]`` becomes ``Z^(t+1)``, a key of
        :data:`mdgs.models.integrators.INTEGRATORS`: "rigid" (default), "twist", "euler",
        "direct" (the paper's literal Eq. 9); see docs/ambiguities.md.
    dvc_scale, dw_scale : m/s and rad/s, output scales of the "twist" integrator (spread of the
        objects' velocity and angular velocity increments in the training data).
    dvc_scales, dw_scales : per object, the same (``object_scales`` with the "twist" integrator: each
        object's own spread of its increments, as ``dv_scales`` for the rigid integrator, floored at
        ``OBJECT_SCALE_FLOOR`` of the global one); empty otherwise.
    dt : frame interval, s (used by "rigid", "twist" and "euler"); set from the data.
    cst_weight : weight of L_cst in the total loss (paper: summed, i.e. 1).
    dense_max_nodes : object graphs (and contact graphs) up to this many nodes propagate densely:
        one [N, N] (or [B, N, N]) block instead of sparse edge lists; the same numbers.
    noise : training noise spec, "auto" (B.2: ``abs:4e-4`` for Cubli scenes, ``inc:0.06``
        otherwise), ``abs:S``, ``inc:F``, ``obj:F`` or ``none`` (:func:`noise_sigmas`).
    noise_sigma_x, noise_sigma_v : m and m/s, the resolved noise (set from the data; -1: unset).
    noise_sigma_xs, noise_sigma_vs : per object (``obj:F``), m and m/s; empty otherwise.
    zero_init : start g's last layer at zero, so the untrained model is the constant-twist
        reference (rigid integrator) and training moves it away only where that lowers the loss.
    joints : project every simulated step (rollout, one-step validation; not the training
        pass) onto the scene's MJCF joints (:mod:`mdgs.joints`), so hinged bodies stay hinged.
        Projecting inside training with a straight-through gradient was measured worse than
        training without it (docs/mdgs-experiments.md).
    object_scales : scale g's outputs and L_mse per object (``dx_scales``, ``dv_scales``: each
        object's own spread of the rigid integrator's targets, floored at ``OBJECT_SCALE_FLOOR`` = 5 %
        of the global spread) instead of one global ``dx_scale``, ``dv_scale``, so that a slow body (a cube)
        weighs as much as a fast one (its flywheels). With the "twist" integrator also g's outputs per
        object (``dvc_scales``, ``dw_scales``), so that a cube's turn is not read on its flywheels' scale.
        "euler" and "direct" use the global scales whatever this says.
    The three defaults above are not the paper's (it has none of them): each was measured with 3
    seeds (``studies/mdgs-ablation.toml``, docs/mdgs-experiments.md); ``False`` for all three
    gives the paper's method.
    actuation : what MDGS knows of the scene's motors (:mod:`mdgs.actuation`): "none" (the paper:
        the controls only as per-node input features), "force" (the motors' loads on free bodies
        join the force set F of Eq. 7, so the state network g and L_cst see them), "prior" (the
        velocity change over ``dt`` of each motor's joint with its parent held,
        :func:`mdgs.actuation.motor_accelerations`, is added to g's increment, so g learns only
        what the recoil, contacts and coupling add; F as in the paper), "step" (both), "coupled"
        (as "prior" with the motors' response of the whole tree, the parents recoiling,
        :func:`mdgs.actuation.coupled_motor_accelerations`), "dynamics" (as "prior" with the whole
        tree's forward dynamics: motors, gravity, velocity terms, range limits and contact with the
        world's surfaces with friction at box corners and cylinder rims, the same function given the velocities; g learns what that one-step-per-frame
        rigid tree misses, and the "rigid tree" reference is what it simulates untrained).
    gravity_prior : add the scene's gravity over ``dt`` (``g dt``, MJCF ``opt.gravity``) to the
        velocity increment of every moving node, as ``actuation = "prior"`` adds the motors' response,
        so g learns what contacts and joints add to free fall instead of free fall itself. The
        untrained model then falls through floors (a resting body's support is left to g to learn).
    pushforward : 0 (the paper: one-step L_mse); K > 0 adds a second L_mse term, on the step
        taken from the model's own state after K simulated steps (rollout steps, joint projection
        included, without gradient) against the true frame t + K + 1: the pushforward trick of
        Brandstetter et al. (2022), so the network also learns from the states its rollouts reach.
    unroll : 0 (the paper: one-step L_mse); K > 0 trains on a K + 1 step rollout from the true frame
        t *with* gradient through it (backpropagation through time, as in solver-in-the-loop
        training, Um et al. 2020): each step starts from the previous step's output, projected
        onto the joints as a rollout step is (straight through: the projection's gradient is taken
        as the identity, as the structural constraint's is, since the Kabsch SVD's own gradient is
        unbounded for symmetric bodies), and L_mse is the mean of the K + 1 one-step terms
        against frames t + 1 .. t + K + 1. A training pass costs K + 1 network passes. Not
        combined with ``pushforward``.
    features : the node features z_i: "paper" ([x || v || k], Section 3.1) or "local" (no absolute
        horizontal position: ``[x_i - c || x_i,z || v_i || w || k]`` with ``c``, ``w`` the centroid and
        angular velocity of the node's object, so a model that has seen a motion in one place knows it
        in another, and a body's spin is an input rather than a pattern across its nodes).
    self_weight : give every GCN layer a separate weight on each node's own features
        (:class:`mdgs.models.layers.GCN`); the paper's GCN only averages over a node's neighbourhood.
    trapezoidal : with the "rigid" integrator, move each body over the frame with the mean of its old and
        new twist (exact for a constant acceleration) instead of the new one; g's position target is
        then the residual of that motion. With ``actuation = "dynamics"`` the untrained model is the
        "rigid tree + joints, trapezoidal" reference.
    loss : the one-step term: "mse" (Eq. 10), "huber" (:func:`mdgs.losses.huber_loss`, delta 1 in the
        scaled units) or "relative" (each pair's Eq. 10 divided by that of the zero output on the same
        pair, i.e. of constant twist plus the priors, plus the batch's median of it: every frame weighs
        alike however large its own increment, so the rare brake and impact frames that hold most of
        Eq. 10 cannot buy their fit with errors on the common quiet frames).
    prior_input : g also reads what the priors (``actuation``, ``gravity_prior``) do this frame, their velocity
        increment in g's own velocity units, beside ``[z || lam f]``.
    fade : 0 (off) or F > 0: g's output is multiplied by ``exp(-(e / F)^2)``, ``e`` how far (in standard
        deviations of the training split) the state's normalised features lie outside the range they had
        there, so that g's correction fades where it was never trained and the priors alone move the bodies.
    push_out : with ``actuation = "dynamics"``, move each simulated step's bodies out of the world's surfaces,
        their twists kept (:func:`mdgs.actuation.push_out`; straight through inside ``unroll``, as the joints'
        projection): a rigid tree's held corners stop at the acceleration level and sink a little at every
        impact, never pushed back.
    prior_substeps : with ``actuation = "dynamics"`` and the "rigid" integrator, 1 (the prior is the tree's
        velocity change over the frame, which g's output joins before the frame's one rigid step) or N > 1: the
        prior is the rigid tree's own state after the frame in N substeps (:func:`mdgs.tree.tree_step`, with
        ``trapezoidal``, ``push_out`` and the joints as set here), and g's output corrects that state: its
        velocity part changes each object's twist, moving it by the change times dt/2 (trapezoidal) or dt,
        its position part moves it rigidly. Untrained, MDGS is then the "rigid tree + joints, N substeps"
        reference.
    gyroscopic : with ``actuation = "dynamics"``, when in each of the rigid tree's steps the gyroscopic terms
        act (:data:`mdgs.actuation.GYROSCOPIC`): "explicit" at its start, "implicit" at its end or "midpoint"
        halfway, linearised, so that a rotor spun fast on a light carrier does not gain energy.
    joint_velocities : with ``prior_substeps`` above 1 and ``joints``, how the prior's rigid tree projects its twists
        onto the joints after each substep (:data:`mdgs.tree.JOINT_VELOCITIES`): "parent" (each child takes its
        parent's twist across the joint), "momentum" (the least kinetic-energy change, impulses at the joints) or
        "coordinates" (the tree stepped in its joint coordinates, nothing projected; velocity Verlet with
        ``trapezoidal``).
    prior_contact : with ``actuation = "dynamics"``, the prior's contact model (:data:`mdgs.actuation.CONTACT_MODELS`):
        "rigid" (a held corner stops within the step) or "soft" (MuJoCo's soft contact; with ``push_out = false``,
        which would undo its depth).
    scales : where the scales left at 1.0 (``dx_scale``, ``dv_scale`` and, with ``object_scales``, the
        per-object ones) come from: "increments" (the std of the frame's increments under the integrator,
        as without priors g predicts them) or "residual" (what g must add to its zero output, that is to
        the priors, on the training split: per object ``1.4826 median |r|`` over the components of the
        moving nodes' residuals ``r``, a robust spread, floored as ``object_scales`` floors, at
        ``RESIDUAL_FLOOR`` = 1e-4 of the increments' scale and at ``ROUNDOFF_FACTOR`` = 10 times the float32
        round-off of the split's positions or velocities). With a
        rigid-tree prior the common residual is a thousandth of the increments and the rare impacts
        hold its std, so under "increments" g's output must be precise to 1e-3 of its range on the
        quiet frames (docs/mdgs-experiments.md, "Output scales from the prior's residual").
    Scales left at 1.0, ``control_dim``, ``contact``, ``dt`` and the sigmas are filled from the
    training split by :meth:`MDGS.resolve_config`.
    """

    variant: str = "mdgs"
    structure: bool = True
    hidden: int = 200
    layers: int = 3
    global_dim: int = 200
    control_dim: int = 0
    contact: bool = True
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
    actuation: str = "none"
    gravity_prior: bool = False
    pushforward: int = 0
    unroll: int = 0
    features: str = "paper"
    self_weight: bool = False
    trapezoidal: bool = False
    loss: str = "mse"
    prior_input: bool = False
    fade: float = 0.0
    push_out: bool = False
    prior_substeps: int = 1
    gyroscopic: str = "explicit"
    joint_velocities: str = "parent"
    prior_contact: str = "rigid"
    scales: str = "increments"
    noise: str = "auto"
    noise_sigma_x: float = -1.0
    noise_sigma_v: float = -1.0
    noise_sigma_xs: tuple[float, ...] = ()
    noise_sigma_vs: tuple[float, ...] = ()
    zero_init: bool = True
    joints: bool = True
    object_scales: bool = True
    dx_scales: tuple[float, ...] = ()
    dv_scales: tuple[float, ...] = ()
    dvc_scales: tuple[float, ...] = ()
    dw_scales: tuple[float, ...] = ()

    def __post_init__(self):
        for name in ("hidden", "layers", "global_dim"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if isinstance(self.dense_max_nodes, bool) or not isinstance(self.dense_max_nodes, int) or self.dense_max_nodes < 0:
            raise ValueError(f"dense_max_nodes must be an integer of at least 0, got {self.dense_max_nodes!r}")
        for name in ("force_scale", "dx_scale", "dv_scale", "dvc_scale", "dw_scale"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if not (isinstance(self.cst_weight, int | float) and math.isfinite(self.cst_weight) and self.cst_weight >= 0):
            raise ValueError(f"cst_weight must be a number of at least 0, got {self.cst_weight!r}")
        if self.lam is not None and not (isinstance(self.lam, int | float) and math.isfinite(self.lam) and self.lam > 0):
            raise ValueError(f"lam must be a positive number or None, got {self.lam!r}")
        if not (isinstance(self.dt, int | float) and math.isfinite(self.dt) and self.dt >= 0):
            raise ValueError(f"dt must be a number of at least 0 (s), got {self.dt!r}")
        if self.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {', '.join(VARIANTS)}, got {self.variant!r}")
        if self.bound not in ("paper", "corrected"):
            raise ValueError(f"bound must be 'paper' or 'corrected', got {self.bound!r}")
        if self.integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {', '.join(INTEGRATORS)}, got {self.integrator!r}")
        if isinstance(self.pushforward, bool) or not isinstance(self.pushforward, int) or self.pushforward < 0:
            raise ValueError(f"pushforward must be an integer of at least 0, got {self.pushforward!r}")
        if isinstance(self.unroll, bool) or not isinstance(self.unroll, int) or self.unroll < 0:
            raise ValueError(f"unroll must be an integer of at least 0, got {self.unroll!r}")
        if self.unroll and self.pushforward:
            raise ValueError("pushforward and unroll are two kinds of multi-step training: set one of them, not both")
        if self.actuation not in ACTUATION:
            raise ValueError(f"actuation must be one of {', '.join(ACTUATION)}, got {self.actuation!r}")
        if self.features not in FEATURES:
            raise ValueError(f"features must be one of {', '.join(FEATURES)}, got {self.features!r}")
        if self.loss not in LOSSES:
            raise ValueError(f"loss must be one of {', '.join(LOSSES)}, got {self.loss!r}")
        if not isinstance(self.gravity_prior, bool):
            raise ValueError(f"gravity_prior must be true or false, got {self.gravity_prior!r}")
        if not isinstance(self.self_weight, bool):
            raise ValueError(f"self_weight must be true or false, got {self.self_weight!r}")
        if not isinstance(self.trapezoidal, bool):
            raise ValueError(f"trapezoidal must be true or false, got {self.trapezoidal!r}")
        if isinstance(self.fade, bool) or not (isinstance(self.fade, int | float) and math.isfinite(self.fade)
                                               and self.fade >= 0):
            raise ValueError(f"fade must be a number of at least 0 (standard deviations; 0: off), got {self.fade!r}")
        if not isinstance(self.prior_input, bool):
            raise ValueError(f"prior_input must be true or false, got {self.prior_input!r}")
        if self.prior_input and self.actuation == "none" and not self.gravity_prior:
            raise ValueError("prior_input = true needs a prior for g to read: set actuation (e.g. \"dynamics\") "
                             "or gravity_prior = true")
        if self.scales not in SCALES:
            raise ValueError(f"scales must be one of {', '.join(SCALES)}, got {self.scales!r}")
        if self.scales == "residual" and self.integrator == "twist":
            raise ValueError("scales = 'residual' measures g's position and velocity outputs; the 'twist' integrator "
                             "has twist outputs: use scales = 'increments' with it")
        if not isinstance(self.push_out, bool):
            raise ValueError(f"push_out must be true or false, got {self.push_out!r}")
        if self.push_out and self.actuation != "dynamics":
            raise ValueError("push_out moves the rigid tree out of the world's surfaces, which only the \"dynamics\" "
                             "prior knows; set actuation = \"dynamics\" with it")
        if isinstance(self.prior_substeps, bool) or not isinstance(self.prior_substeps, int) or self.prior_substeps < 1:
            raise ValueError(f"prior_substeps must be a positive integer, got {self.prior_substeps!r}")
        if self.prior_substeps > 1 and (self.actuation != "dynamics" or self.integrator != "rigid"):
            raise ValueError("prior_substeps > 1 steps the rigid tree of the \"dynamics\" prior, whose end state the "
                             "\"rigid\" integrator corrects; set actuation = \"dynamics\" and integrator = \"rigid\"")
        gyroscopic_weight(self.gyroscopic)  # a rule it does not know raises, naming the rules
        check_joint_velocities(self.joint_velocities)
        if self.joint_velocities != "parent" and not (self.prior_substeps > 1 and self.joints):
            raise ValueError("joint_velocities sets how the prior's rigid tree keeps its joints; "
                             "set actuation = \"dynamics\", prior_substeps above 1 and joints = true with it")
        check_contact(self.prior_contact, self.push_out)
        if self.prior_contact != "rigid" and self.actuation != "dynamics":
            raise ValueError("prior_contact sets the contact model of the \"dynamics\" prior's rigid tree; set actuation = "
                             "\"dynamics\" with it")
        if self.gyroscopic != "explicit" and self.actuation != "dynamics":
            raise ValueError("gyroscopic sets how the rigid tree of the \"dynamics\" prior steps; set actuation = "
                             "\"dynamics\" with it")
        if self.gravity_prior and self.actuation == "dynamics":
            raise ValueError("actuation = \"dynamics\" already adds gravity; set gravity_prior = false with it")

    def to_dict(self) -> dict:
        return asdict(self)

    #: What a setting meant in checkpoints written before it existed (:func:`mdgs.runs.load_model`
    #: uses these for keys a checkpoint lacks, not today's defaults, so an old run is evaluated as
    #: it was trained).
    ABSENT = {"joints": False, "object_scales": False, "zero_init": False, "actuation": "none"}


#: The name the configuration had before the model registry.
ModelConfig = MDGSConfig

#: Static node properties k_i: mass, volume, tau, object type one-hot (3).
N_PROPERTIES = 6


class PriorState(NamedTuple):
    """The rigid tree's node positions and velocities [B, N, 3] after the frame (``prior_substeps`` > 1): a prior
    that g's output corrects instead of joining (:meth:`MDGS._integrate`)."""

    x: torch.Tensor
    v: torch.Tensor


def _increment(priors: list, v: torch.Tensor) -> torch.Tensor:
    """The priors' node velocity increment over the frame [B, N, 3] (a :class:`PriorState`'s: its velocities less ``v``)."""
    return sum(p.v - v.detach() if isinstance(p, PriorState) else p for p in priors)


@dataclass
class Prediction:
    """Output of one network pass (shapes ``[B, N, 3]``; forces in N).

    x, v : predicted positions (m) and velocities (m/s) at t+1.
    force : F of Eq. (7); force_noncontact : F~ (Eq. 4); force_contact : F- (Eq. 6).
    contact_edges : [2, E] batched contact edges used (empty without a contact branch); on the
        dense path built from ``contact_mask`` [B, N, N] when first read, so a rollout step (which
        never reads it) has no data-dependent ``nonzero`` (a host sync, and a graph break for
        ``torch.compile``).
    priors : the priors' velocity increments this pass added (:meth:`MDGS._priors`; no gradient), which
        the relative loss's zero-output step reuses instead of solving the forward dynamics again.
    """

    x: torch.Tensor
    v: torch.Tensor
    force: torch.Tensor
    force_noncontact: torch.Tensor
    force_contact: torch.Tensor
    edges: torch.Tensor | None = None
    contact_mask: torch.Tensor | None = None
    priors: list | None = None

    @property
    def contact_edges(self) -> torch.Tensor:
        if self.edges is None:
            b, i, j = self.contact_mask.nonzero(as_tuple=True)
            n = self.contact_mask.shape[1]
            self.edges = torch.stack([b * n + i, b * n + j])
        return self.edges


def noise_sigmas(spec: str, d: SplitData) -> tuple:
    """Noise std ``(sigma_x [m], sigma_v [m/s])`` of the spec ``auto``, ``abs:S``, ``inc:F``, ``obj:F`` or ``none``.

    What is perturbed: the *input* frame only (:meth:`MDGS.perturb`); the targets
    ``x_{t+1}, v_{t+1}`` stay clean, so the model learns to pull a perturbed state back onto the
    true trajectory (the noise-corrected target of Sanchez-Gonzalez et al. 2020 for a one-frame
    input). ``inc:F`` sets each sigma to F times the std of the per-step increments
    ``x_{t+1} - x_t`` (resp. ``v_{t+1} - v_t``) of the training set: the scale the model
    predicts, so the noise never swamps one step. The paper's "0.06 times the standard
    deviation" names no quantity; a fraction of the states' own spread (metres for positions)
    is larger than a whole step and was found to make the one-step target unlearnable. Cubli
    scenes use the paper's absolute 4e-4 (m and m/s). ``obj:F`` is ``inc:F`` per object: each
    object's sigmas are F times its own increments' std, returned as two tuples (one entry per
    object of :class:`~mdgs.graphs.SceneGraph`, 0 for static ones), so that a fast flywheel and
    a slow cube are each perturbed at the scale of their own motion.
    """
    s = spec.strip().lower()
    if s == "auto":
        s = f"abs:{CUBLI_NOISE}" if str(d.attrs.get("family", "")) == "cubli" else f"inc:{INCREMENT_NOISE}"
    if s == "none":
        return 0.0, 0.0
    kind, _, val = s.partition(":")
    try:
        f = float(val)
    except ValueError:
        f = -1.0
    if kind not in ("abs", "inc", "obj") or not np.isfinite(f) or f < 0:
        raise ModelError(f"--noise {spec!r} is not understood; use auto, none, abs:SIGMA (m, m/s), inc:FRACTION "
                         "or obj:FRACTION")
    if kind == "abs":
        return f, f
    dx, dv = _increments(d)
    if kind == "inc":
        return f * float(dx.std()), f * float(dv.std())
    scene = SceneGraph.from_static(d.static, has_contact=d.has_contact)
    om = np.asarray(scene.obj)[d.moving]
    sx, sv = [0.0] * scene.n_obj, [0.0] * scene.n_obj
    for o in np.unique(om):
        sx[o], sv[o] = f * float(dx[:, :, om == o].std()), f * float(dv[:, :, om == o].std())
    return tuple(sx), tuple(sv)


def _increments(d: SplitData) -> tuple[np.ndarray, np.ndarray]:
    mv = d.moving
    return (d.x[:, 1:] - d.x[:, :-1])[:, :, mv], (d.v[:, 1:] - d.v[:, :-1])[:, :, mv]


def _rigid_increments(d: SplitData, scene: SceneGraph, dt: float, trapezoidal: bool = False,
                      max_pairs: int = 4096) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What the rigid integrators' g predicts, on (up to ``max_pairs``) training pairs.

    Returns the node velocity increments of the rigid twist change ``(v_c' - v_c) + (w' - w) x r_i``
    and the position residual ``x' - advance(x, twist', dt)``, both [P, N_moving, 3], and the
    moving objects' increments ``v_c' - v_c`` and ``w' - w`` [P, S_moving, 3].
    """
    pairs = d.pairs()
    if len(pairs) > max_pairs:
        pairs = pairs[np.linspace(0, len(pairs) - 1, max_pairs).astype(int)]
    t, f = pairs[:, 0], pairs[:, 1]
    x0, v0 = torch.from_numpy(d.x[t, f]).double(), torch.from_numpy(d.v[t, f]).double()
    x1, v1 = torch.from_numpy(d.x[t, f + 1]).double(), torch.from_numpy(d.v[t, f + 1]).double()
    seg, n, mass = scene.obj, scene.n_obj, scene.mass
    a, b = twist(x0, v0, seg, n, mass), twist(x1, v1, seg, n, mass)
    r = x0 - a.c[:, seg]
    dv = (b.vc - a.vc)[:, seg] + torch.linalg.cross((b.omega - a.omega)[:, seg], r, dim=-1)
    xr, _ = advance(x0, a, b.vc, b.omega, dt, seg, trapezoidal=trapezoidal)
    mv = d.moving
    objs = np.unique(np.asarray(seg)[mv])
    return (dv[:, mv].numpy(), (x1 - xr)[:, mv].numpy(), (b.vc - a.vc)[:, objs].numpy(),
            (b.omega - a.omega)[:, objs].numpy())


class MDGS(Simulator):
    """The MDGS simulator (module docstring); registry name ``mdgs`` (and ``mdgs-nc``, ``mdgs-sc``)."""

    name = "mdgs"
    Config = MDGSConfig
    #: 1: joints, object_scales and zero_init on by default (issue 14).
    revision = 1
    summary = "MDGS: GCN force networks + state network, Kane constraint L_cst over speeds x, y, z"

    def __init__(self, config: MDGSConfig = MDGSConfig()):
        super().__init__(config)
        c = config
        d_z = (3 if c.features == "paper" else 7) + 3 + N_PROPERTIES + c.control_dim
        self.d_z = d_z
        self.contact = c.contact
        sw = c.self_weight
        self.force_noncontact = GCN(d_z, c.hidden, 3, c.layers, sw)  # g^F~
        if c.contact:
            self.global_gather = GCN(d_z, c.hidden, c.global_dim, c.layers, sw)  # g^Z-
            self.force_contact = GCN(d_z + c.global_dim, c.hidden, 3, c.layers, sw)  # g^F-
        self.state = GCN(d_z + 3 + (3 if c.prior_input else 0), c.hidden, 6, c.layers, sw)  # g
        if c.zero_init:  # start as the constant-twist reference: g outputs 0 until trained
            self.state.zero_output()
        # input normalisation of z (set from training data by fit / set_normalization)
        self.register_buffer("z_mean", torch.zeros(d_z))
        self.register_buffer("z_std", torch.ones(d_z))
        if c.fade:  # the range of the normalised features over the training split (set by fit)
            self.register_buffer("z_lo", torch.full((d_z,), -math.inf))
            self.register_buffer("z_hi", torch.full((d_z,), math.inf))
        self._scene: SceneGraph | None = None
        self._scenes: dict = {}
        self._sign: torch.Tensor | None = None
        self._joints = JointSet()
        self._drives = DriveSet()
        self._gravity: torch.Tensor | None = None
        self.future = int(max(config.pushforward, config.unroll))
        self._fold_cache: tuple | None = None  # (weight versions, products) of _folded_weights

    # --- construction ------------------------------------------------------------------------
    @classmethod
    def resolve_config(cls, config: MDGSConfig, d: SplitData) -> MDGSConfig:
        """Fill scales left at 1.0 from the training data; set ``control_dim``, ``contact``, ``dt``, sigmas.

        ``dx_scale``, ``dv_scale``: std of what g predicts under the chosen integrator (position
        residual and velocity increment), or with ``scales = "residual"`` the robust spread of what g must
        add to the priors (:meth:`_residual_scales`); ``force_scale``: mean ``|M dv / dt|`` of an element.
        """
        cfg = config
        dx, dv = _increments(d)
        mass = np.asarray(d.static["node_mass"])[d.moving]
        kw = {"control_dim": int(d.ctrl.shape[-1]), "contact": bool(d.has_contact)}
        if cfg.dt <= 0.0:
            kw["dt"] = float(d.frame_dt)
        dt = kw.get("dt", cfg.dt)
        f_scale = float(max(np.abs(mass[None, None, :, None] * dv / d.frame_dt).mean(), 1e-9))
        scene = SceneGraph.from_static(d.static, has_contact=d.has_contact)
        if cfg.integrator == "euler":  # the learned position term is the residual x' - x - dt v'
            xs, vs = d.x[..., d.moving, :], d.v[..., d.moving, :]
            dx = (xs[:, 1:] - xs[:, :-1] - dt * vs[:, 1:]).reshape(-1, 3)
        elif cfg.integrator in ("rigid", "twist"):
            dv, dx, dvc, dw = _rigid_increments(d, scene, dt, trapezoidal=cfg.integrator == "twist" or cfg.trapezoidal)
            if cfg.integrator == "twist":
                if cfg.dvc_scale == 1.0:
                    kw["dvc_scale"] = float(max(dvc.std(), 1e-12))
                if cfg.dw_scale == 1.0:
                    kw["dw_scale"] = float(max(dw.std(), 1e-12))
        # twist: g has no position output; a velocity error weighs like the position error it makes
        # over half a frame. Otherwise: the spread of g's position target.
        dx_auto = dt / 2 * float(dv.std()) if cfg.integrator == "twist" else float(dx.std())
        n_obj = scene.n_obj
        for name in ("dx_scales", "dv_scales", "dvc_scales", "dw_scales"):
            given = getattr(cfg, name)
            if given and len(given) != n_obj:
                raise ModelError(f"--set {name}: {len(given)} values given, but the scene has {n_obj} objects "
                                 f"(one value per object, in the order of the scene's bodies with elements, the "
                                 f"world's first when it has elements)")
        if cfg.object_scales and cfg.integrator in ("rigid", "twist") and not (cfg.dx_scales and cfg.dv_scales):
            # per object: each object's own spread, floored
            om = np.asarray(scene.obj)[d.moving]
            gx, gv = max(float(dx.std()), 1e-12), max(float(dv.std()), 1e-12)
            sx, sv = [1.0] * scene.n_obj, [1.0] * scene.n_obj
            for o in np.unique(om):
                sv[o] = max(float(dv[:, om == o].std()), OBJECT_SCALE_FLOOR * gv)
                # twist: no position output; a velocity error weighs like the position error of half a frame
                sx[o] = (dt / 2 * sv[o] if cfg.integrator == "twist"
                         else max(float(dx[:, om == o].std()), OBJECT_SCALE_FLOOR * gx))
            kw["dx_scales"], kw["dv_scales"] = cfg.dx_scales or tuple(sx), cfg.dv_scales or tuple(sv)  # given ones kept
            if cfg.integrator == "twist":  # g's outputs per object: its own twist increments' spread
                svc, sw = [1.0] * scene.n_obj, [1.0] * scene.n_obj
                gvc, gw = max(float(dvc.std()), 1e-12), max(float(dw.std()), 1e-12)
                for k, o in enumerate(np.unique(om)):  # dvc, dw: [P, S_moving, 3] in this order
                    svc[o] = max(float(dvc[:, k].std()), OBJECT_SCALE_FLOOR * gvc)
                    sw[o] = max(float(dw[:, k].std()), OBJECT_SCALE_FLOOR * gw)
                kw["dvc_scales"], kw["dw_scales"] = tuple(svc), tuple(sw)
        if cfg.dx_scale == 1.0:
            kw["dx_scale"] = max(dx_auto, 1e-12)
        if cfg.dv_scale == 1.0:
            kw["dv_scale"] = float(max(dv.std(), 1e-12))
        if cfg.force_scale == 1.0:  # typical |M dv / dt| of an element, N
            kw["force_scale"] = f_scale
        if cfg.scales == "residual":  # the values not given, measured on the priors' residual
            res = cls._residual_scales(replace(cfg, **kw), d, scene)
            given = {"dx_scale": cfg.dx_scale != 1.0, "dv_scale": cfg.dv_scale != 1.0,
                     "dx_scales": bool(cfg.dx_scales), "dv_scales": bool(cfg.dv_scales)}
            kw.update({k: val for k, val in res.items() if not given[k]})
        sx, sv = noise_sigmas(cfg.noise, d)
        if isinstance(sx, tuple):  # per object
            kw["noise_sigma_x"], kw["noise_sigma_v"], kw["noise_sigma_xs"], kw["noise_sigma_vs"] = 0.0, 0.0, sx, sv
        else:
            kw["noise_sigma_x"], kw["noise_sigma_v"] = sx, sv
        return replace(cfg, **kw)

    @classmethod
    def _residual_scales(cls, cfg: MDGSConfig, d: SplitData, scene: SceneGraph) -> dict:
        """The ``scales = "residual"`` values: ``dx_scale``, ``dv_scale`` and, with ``object_scales``, per object,
        from what g must add to its zero output on ``RESIDUAL_PAIRS`` evenly spaced training pairs: ``1.4826
        median |r|`` over the components of the moving nodes' residuals ``r``, at least ``ROUNDOFF_FACTOR`` times
        the float32 round-off of the quantity, then at least ``RESIDUAL_FLOOR`` times the increments' scale
        that ``cfg`` holds."""
        model = cls(cfg)
        model.bind(d)
        pairs = d.pairs(model.history)
        pairs = pairs[np.linspace(0, len(pairs) - 1, min(RESIDUAL_PAIRS, len(pairs))).astype(int)]
        rx, rv = [], []
        with torch.no_grad():
            for i in range(0, len(pairs), 256):
                b = batch_of(d, pairs[i:i + 256], "cpu", model.history)
                x0, v0 = model._zero_step(scene, b.x, b.v, model._priors(scene, b.x, b.v, b.ctrl))
                rx.append((b.x_next - x0)[:, d.moving].double().numpy())
                rv.append((b.v_next - v0)[:, d.moving].double().numpy())
        rx, rv = np.concatenate(rx), np.concatenate(rv)  # [P, N_moving, 3]
        eps = float(np.finfo(np.float32).eps)
        fx, fv = (ROUNDOFF_FACTOR * eps * float(np.sqrt((q[:, :, d.moving] ** 2).sum(-1).mean())) for q in (d.x, d.v))
        spread = lambda r, floor: max(1.4826 * float(np.median(np.abs(r))), floor, 1e-12)  # noqa: E731
        gx, gv = spread(rx, fx), spread(rv, fv)
        kw = {"dx_scale": max(gx, RESIDUAL_FLOOR * cfg.dx_scale), "dv_scale": max(gv, RESIDUAL_FLOOR * cfg.dv_scale)}
        if cfg.object_scales:
            om = np.asarray(scene.obj)[d.moving]
            sx, sv = [1.0] * scene.n_obj, [1.0] * scene.n_obj
            for o in np.unique(om):
                sx[o] = max(spread(rx[:, om == o], fx), OBJECT_SCALE_FLOOR * gx)
                sv[o] = max(spread(rv[:, om == o], fv), OBJECT_SCALE_FLOOR * gv)
            if len(cfg.dx_scales) == scene.n_obj:  # the increments' per-object scales (the rigid integrators)
                sx = [max(a, RESIDUAL_FLOOR * b) for a, b in zip(sx, cfg.dx_scales, strict=True)]
                sv = [max(a, RESIDUAL_FLOOR * b) for a, b in zip(sv, cfg.dv_scales, strict=True)]
            kw["dx_scales"], kw["dv_scales"] = tuple(sx), tuple(sv)
        return kw

    def fit(self, d: SplitData) -> None:
        """Mean and std of the raw node features z over 256 random training frames."""
        n = d.x.shape[0] * d.x.shape[1]
        idx = np.random.default_rng(0).choice(n, size=min(256, n), replace=False)
        x = torch.tensor(d.x.reshape(n, *d.x.shape[2:])[idx])
        v = torch.tensor(d.v.reshape(n, *d.v.shape[2:])[idx])
        c = torch.tensor(d.control.reshape(n, *d.control.shape[2:])[idx])  # n, not -1: nu may be 0
        scene = SceneGraph.from_static(d.static, has_contact=d.has_contact)
        z = self.node_features(scene, x, v, c).reshape(-1, self.d_z)
        self.set_normalization(z.mean(0), z.std(0))
        if self.config.fade:  # every training frame's range, in chunks
            lo, hi = self.z_lo.clone().fill_(math.inf), self.z_hi.clone().fill_(-math.inf)
            xs, vs = d.x.reshape(n, *d.x.shape[2:]), d.v.reshape(n, *d.v.shape[2:])
            cs = d.control.reshape(n, *d.control.shape[2:])
            for i in range(0, n, 1024):
                zi = (self.node_features(scene, torch.tensor(xs[i:i + 1024]), torch.tensor(vs[i:i + 1024]),
                                         torch.tensor(cs[i:i + 1024])) - self.z_mean) / self.z_std
                lo = torch.minimum(lo, zi.amin(dim=(0, 1)))
                hi = torch.maximum(hi, zi.amax(dim=(0, 1)))
            self.z_lo.copy_(lo)
            self.z_hi.copy_(hi)

    @property
    def scalar_loops(self) -> bool:
        """With ``actuation = "dynamics"`` the step runs the rigid tree's forward dynamics (:attr:`Simulator.scalar_loops`)."""
        return self.config.actuation == "dynamics"

    def bind(self, split: SplitData) -> None:
        """Use the static graph and control map of ``split`` (same node and actuator counts)."""
        if int(split.ctrl.shape[-1]) != self.config.control_dim:
            raise ModelError(f"{split.path} has {split.ctrl.shape[-1]} actuators but the model was built for "
                             f"{self.config.control_dim}; use data of the scene it was trained on")
        super().bind(split)
        self._scene = SceneGraph.from_static(split.static, has_contact=split.has_contact)
        self._scenes = {}
        self._sign = torch.from_numpy(np.asarray(split.control_sign, np.float32))
        self._joints = (joints_of(split.mj_model(), split.static["node_body"], split.static["node_centroid"])
                        if self.config.joints else JointSet())
        self._drives = (drives_of(split.mj_model(), split.static["node_body"], split.static["node_centroid"])
                        if self.config.actuation != "none" else DriveSet())
        if self.config.actuation == "dynamics":
            warn_unseen(self._drives, "MDGS's \"dynamics\" prior")
            if self.config.prior_substeps > 1:
                warn_unprojected(self._drives, self.config.joints, "MDGS's \"dynamics\" prior")
        self._gravity = (torch.tensor(np.asarray(split.mj_model().opt.gravity, float), dtype=torch.float32)
                         if self.config.gravity_prior else None)

    def scene_on(self, dev) -> SceneGraph:
        """The bound scene graph on ``dev`` (cached)."""
        if self._scene is None:
            raise ModelError("the model is not bound to a scene; call bind(split) first")
        key = str(dev)
        if key not in self._scenes:
            self._scenes[key] = self._scene.to(dev)
        return self._scenes[key]

    def scales(self, scene: SceneGraph, dev) -> tuple:
        """``(dx_scale, dv_scale)``: floats, or with ``object_scales`` per-node ``[N, 1]`` tensors (m, m/s)."""
        c = self.config
        return self._per_node(scene, dev, "scales", (c.dx_scales, c.dv_scales), (c.dx_scale, c.dv_scale))

    def twist_scales(self, scene: SceneGraph, dev) -> tuple:
        """``(dvc_scale, dw_scale)`` of the "twist" integrator: floats, or with ``object_scales`` per-node
        ``[N, 1]`` tensors (m/s, rad/s; each node carries its object's)."""
        c = self.config
        return self._per_node(scene, dev, "twist_scales", (c.dvc_scales, c.dw_scales), (c.dvc_scale, c.dw_scale))

    def _per_node(self, scene: SceneGraph, dev, name: str, per_object: tuple, whole: tuple) -> tuple:
        """``per_object`` (tuples of one scale per object) as per-node ``[N, 1]`` tensors on ``dev`` (cached
        under ``name``), or ``whole`` (the global floats) without ``object_scales`` or per-object values."""
        if not (self.config.object_scales and per_object[0]):
            return whole
        key = (name, str(dev))
        if key not in self._scenes:
            obj = scene.obj.to(dev)
            self._scenes[key] = tuple(torch.tensor(s, dtype=torch.float32, device=dev)[obj].unsqueeze(-1)
                                      for s in per_object)
        return self._scenes[key]

    def node_controls(self, ctrl: torch.Tensor) -> torch.Tensor:
        """Actuator controls [B, nu] -> per-node control features [B, N, nu] (+ on the driven body, - on its parent)."""
        key = ("sign", str(ctrl.device))  # once per device: a host-to-device copy every step would also stop
        if key not in self._scenes:        # the step from being captured as a CUDA graph
            self._scenes[key] = self._sign.to(ctrl.device)
        sign = self._scenes[key]
        return ctrl.to(torch.float32)[:, None, :] * sign.T[None]

    def set_normalization(self, mean: torch.Tensor, std: torch.Tensor) -> None:
        """Set the per-feature mean and std of ``z`` (``[d_z]``).

        A feature with no spread in the data (std at most 1e-6 of its magnitude, at least 1e-6
        absolute: below float32 resolution; e.g. the out-of-plane velocity of a planar model) is
        centred but not scaled (std 1): dividing by a floored std would blow the training noise
        and any rollout drift in it up by 1/std (issue 15, item 13).
        """
        mean = torch.as_tensor(mean, dtype=self.z_mean.dtype)
        std = torch.as_tensor(std, dtype=self.z_std.dtype)
        flat = std <= 1e-6 * mean.abs().clamp_min(1.0)
        self.z_mean.copy_(mean)
        self.z_std.copy_(torch.where(flat, torch.ones_like(std), std))

    def force_parameters(self):
        """Parameters of the force networks g^F~, g^F- (and g^Z-, which feeds only g^F-)."""
        mods = [self.force_noncontact] + ([self.global_gather, self.force_contact] if self.contact else [])
        return [p for m in mods for p in m.parameters()]

    # --- the network ---------------------------------------------------------------------------
    def node_features(self, scene: SceneGraph, x: torch.Tensor, v: torch.Tensor,
                      control: torch.Tensor | None = None) -> torch.Tensor:
        """Raw ``z = [x || v || k]`` (``features="local"``: ``[x - c || x_z || v || w || k]``) -> [B, N, d_z];
        ``control`` [B, N, control_dim] joins ``k``."""
        B, N, _ = x.shape
        k = scene.properties().to(x.device, x.dtype).expand(B, N, -1)
        if self.config.features == "local":  # no absolute horizontal position; the object's spin made explicit
            seg = scene.obj.to(x.device)
            tw = twist(x, v, seg, scene.n_obj, scene.mass.to(x.device))
            parts = [x - tw.c[:, seg].to(x.dtype), x[..., 2:], v, tw.omega[:, seg].to(x.dtype), k]
        else:
            parts = [x, v, k]
        if self.config.control_dim:
            if control is None:
                raise ValueError(f"this model expects control inputs of width {self.config.control_dim}")
            parts.append(control.to(x.dtype))
        return torch.cat(parts, dim=-1)

    def forward(self, scene: SceneGraph, x: torch.Tensor, v: torch.Tensor,
                control: torch.Tensor | None = None, simulate: bool = False,
                ctrl: torch.Tensor | None = None) -> Prediction:
        """One step ``Z^(t) -> Z^(t+1)`` on ``scene`` (same device).

        x, v : [B, N, 3] centroid positions (m) and velocities (m/s) at t.
        control : [B, N, control_dim] per-node control features, or None.
        simulate : a simulation step (rollout, one-step validation) rather than a training pass:
            with ``joints`` the prediction is projected onto the scene's joints.
        ctrl : [B, nu] the raw controls, for ``actuation`` (the motors' known loads); None: no loads.
        """
        c = self.config
        B, N, _ = x.shape
        dev, dt = x.device, x.dtype
        z = (self.node_features(scene, x, v, control) - self.z_mean) / self.z_std
        obj_prop = scene.object_graph.propagator(B, dev, dt)
        f_nc = c.force_scale * self.force_noncontact(obj_prop, z)  # Eq. (4)
        if self.contact and scene.has_contact and N <= c.dense_max_nodes:  # one [B, N, N] block per graph
            a_c = dense_contacts(x.detach(), scene.obj, scene.contact_radius,
                                 candidates=scene.contact_candidates(dev))
            union = Propagator(dense=gcn_norm_adjacency(a_c | scene.object_graph.adjacency(dev), dt))
            con_prop = Propagator(dense=gcn_norm_adjacency(a_c, dt))
            if weights_folded() and not c.self_weight:
                f_c = c.force_scale * self._contact_forces_folded(union, con_prop, z)  # Eqs. (5)-(6)
            else:
                z_glob = self.global_gather(union, z)  # Eq. (5)
                f_c = c.force_scale * self.force_contact(con_prop, torch.cat([z, z_glob], -1))  # Eq. (6)
            f_c = f_c * a_c.any(-1, keepdim=True)  # zero off contact edges
            ce, mask = None, a_c  # the edge list only if read (Prediction.contact_edges)
        elif self.contact and scene.has_contact:
            ce, mask = contact_edges(x.detach(), scene.obj, scene.contact_radius, scene.static), None
            z_glob = self.global_gather(scene.object_graph.union(ce, B, dev, dt), z)  # Eq. (5)
            con_prop = Propagator(csr=gcn_norm(ce, B * N, dt, dev))
            f_c = c.force_scale * self.force_contact(con_prop, torch.cat([z, z_glob], -1))  # Eq. (6)
            touched = torch.zeros(B * N, dtype=torch.bool, device=dev)
            touched[ce[0]] = True
            f_c = f_c * touched.view(B, N, 1)  # zero off contact edges
        else:
            ce, mask = torch.zeros(2, 0, dtype=torch.long, device=dev), None
            f_c = torch.zeros_like(f_nc)
        f = f_c + f_nc  # Eq. (7)
        if self._drives and ctrl is not None and c.actuation in ("force", "step"):  # motors' known loads join F
            f = f + actuation_forces(x.detach(), ctrl, self._drives, scene.ref_shape.to(dev), scene.obj.to(dev), scene.n_obj,
                                     scene.mass.to(dev))
        lam = c.lam if c.lam is not None else 1.0 / c.force_scale
        priors = self._priors(scene, x, v, ctrl)
        g_in = [z, lam * f]
        if c.prior_input:  # what the priors do this frame, in g's own velocity units
            sv = self.scales(scene, dev)[1]
            g_in.append((_increment(priors, v) / sv).expand(B, N, 3).to(z.dtype) if priors else torch.zeros_like(f))
        out = self.state(obj_prop, torch.cat(g_in, -1))  # Eqs. (8)-(9)
        if c.fade:  # fade g's correction where the state leaves the training data's range
            e = torch.maximum(z - self.z_hi, self.z_lo - z).clamp_min(0.0).amax(dim=(-2, -1))  # [B]
            out = out * torch.exp(-(e / c.fade) ** 2).view(B, 1, 1)
        x_next, v_next, pose = self._integrate(scene, x, v, out, priors)
        moving = scene.moving(dev)
        if simulate and c.push_out:  # out of the world's surfaces, twists kept (before the joints, as the rigid tree)
            x_next, v_next = push_out(x_next, v_next, self._drives, scene.ref_shape.to(dev), scene.obj.to(dev),
                                      scene.n_obj, scene.mass.to(dev))
            pose = None  # the structure's placement moved: the joints fit their own
        if simulate and c.joints and self._joints:  # on the structure's placement (pose), not a second fit
            x_next, v_next = project_joints(x_next, v_next, self._joints, scene.ref_shape.to(dev), scene.obj.to(dev),
                                            scene.n_obj, scene.mass.to(dev), pose)
        # static elements never move
        m = moving.view(1, N, 1)
        x_next = torch.where(m, x_next, x)
        v_next = torch.where(m, v_next, torch.zeros_like(v_next))
        return Prediction(x_next, v_next, f, f_nc, f_c, ce, mask, priors)

    def _contact_forces_folded(self, union: Propagator, con_prop: Propagator, z: torch.Tensor) -> torch.Tensor:
        """``g^F-([z || g^Z-(z)])`` of Eqs. (5)-(6) [B, N, 3] with g^Z-'s last layer folded into g^F-'s first.

        No activation separates them: g^Z-'s output is ``Z- = A_u h W3^T + b3`` (``h`` [B, N, hidden] its last
        hidden features, ``A_u`` the union graph) and g^F-'s first layer maps ``[z || Z-] W1^T = z W1z^T +
        Z- W1g^T``, so that layer is ``A_c (z W1z^T + A_u h (W1g W3)^T + (W1g b3)^T) + b1``: one
        ``[hidden, hidden]`` product per step fewer (:meth:`_folded_weights`). The same function as the
        unfolded path up to float round-off (tests/test_model.py); used inside
        :func:`~mdgs.models.layers.folded_weights` (the ahead-of-time compiled step).
        """
        gz, fc = self.global_gather, self.force_contact
        w1z, wf, bf = self._folded_weights()
        h = gz(union, z, last=len(gz.lins) - 1)  # g^Z-'s input to its last layer
        h1 = con_prop(z @ w1z.T + union(h @ wf.T) + bf) + fc.lins[0].bias
        if len(fc.lins) > 1:
            h1 = torch.relu(h1)
        return fc(con_prop, h1, first=1)

    def _folded_weights(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(W1z, W1g W3, W1g b3)`` of :meth:`_contact_forces_folded`: [hidden, d_z], [hidden, hidden of g^Z-],
        [hidden]. Traced, the products are part of the graph (AOTInductor folds them into constants);
        eagerly they are cached until a weight changes (its version counter)."""
        w3, b3 = self.global_gather.lins[-1].weight, self.global_gather.lins[-1].bias
        w1 = self.force_contact.lins[0].weight  # [hidden, d_z + global_dim]
        compiling = torch.compiler.is_compiling()
        key = tuple((id(p), p._version) for p in (w3, b3, w1)) if not compiling else None
        if key is not None and self._fold_cache is not None and self._fold_cache[0] == key:
            return self._fold_cache[1]
        w1g = w1[:, self.d_z:]
        out = (w1[:, :self.d_z], w1g @ w3, w1g @ b3)
        if key is not None:
            self._fold_cache = (key, out)
        return out

    # --- the Simulator contract ------------------------------------------------------------------
    def step(self, state: State, ctrl: torch.Tensor) -> State:
        p = self(self.scene_on(state.x.device), state.x, state.v, self.node_controls(ctrl), simulate=True, ctrl=ctrl)
        return State(p.x, p.v)

    def losses(self, batch: Batch) -> dict[str, torch.Tensor]:
        """``mse``: Eq. (10) on scaled ``[x || v]``; ``cst``: Eqs. (13)-(15) (zero for mdgs-nc)."""
        cfg = self.config
        scene = self.scene_on(batch.x.device)
        moving = ~scene.static
        p = self(scene, batch.x, batch.v, self.node_controls(batch.ctrl), ctrl=batch.ctrl)
        scales = self.scales(scene, batch.x.device)
        l_mse = self._one_step_loss(scene, batch.x, batch.v, batch.ctrl, p, batch.x_next, batch.v_next, moving,
                                    scales)  # Eq. (10)
        if cfg.pushforward:  # from the model's own state after K rollout steps (no gradient), one trained step
            with torch.no_grad():
                s = self(scene, batch.x, batch.v, self.node_controls(batch.ctrl), simulate=True, ctrl=batch.ctrl)
                x, v = s.x, s.v
                for k in range(cfg.pushforward - 1):
                    c = batch.ctrl_future[:, k]
                    s = self(scene, x, v, self.node_controls(c), simulate=True, ctrl=c)
                    x, v = s.x, s.v
            c = batch.ctrl_future[:, cfg.pushforward - 1]
            q = self(scene, x, v, self.node_controls(c), ctrl=c)
            l_mse = l_mse + self._one_step_loss(scene, x, v, c, q, batch.x_future[:, -1], batch.v_future[:, -1],
                                                moving, scales)
        if cfg.unroll:  # a (K + 1)-step rollout with gradient through it, every step scored
            terms = [l_mse]
            x, v = p.x, p.v
            for k in range(cfg.unroll):
                if (cfg.joints and self._joints) or cfg.push_out:  # the state a rollout step would hand on,
                    with torch.no_grad():  # straight through (the Kabsch SVD's gradient is unbounded for symmetric bodies)
                        xp, vp = x, v
                        if cfg.push_out:
                            xp, vp = push_out(xp, vp, self._drives, scene.ref_shape.to(x.device), scene.obj.to(x.device),
                                              scene.n_obj, scene.mass.to(x.device))
                        if cfg.joints and self._joints:
                            xp, vp = project_joints(xp, vp, self._joints, scene.ref_shape.to(x.device),
                                                    scene.obj.to(x.device), scene.n_obj, scene.mass.to(x.device))
                    x, v = x + (xp - x).detach(), v + (vp - v).detach()
                c = batch.ctrl_future[:, k]
                q = self(scene, x, v, self.node_controls(c), ctrl=c)
                terms.append(self._one_step_loss(scene, x, v, c, q, batch.x_future[:, k], batch.v_future[:, k],
                                                 moving, scales))
                x, v = q.x, q.v
            l_mse = torch.stack(terms).mean()
        l_cst = constraint_loss(p.force, batch.x, batch.v, p.x, p.v, scene.mass, scene.tau, scene.obj, scene.n_obj,
                                cfg.dt, moving=moving, bound=cfg.bound, speeds=speeds_of(cfg.variant),
                                scale=cfg.force_scale * int(moving.sum()))  # Eqs. (13)-(15)
        return {"mse": l_mse, "cst": l_cst}

    def _one_step_loss(self, scene: SceneGraph, x, v, ctrl, p: Prediction, x_true, v_true, moving, scales):
        """The one-step term of the loss (``loss``) of prediction ``p`` from ``x, v`` [B, N, 3] against the truth."""
        kind = self.config.loss
        if kind == "mse":
            return mse_loss(p.x, p.v, x_true, v_true, moving, *scales)
        if kind == "huber":
            return huber_loss(p.x, p.v, x_true, v_true, moving, *scales)
        with torch.no_grad():  # the zero output's error on each pair (the priors are p's: the same state)
            x0, v0 = self._zero_step(scene, x, v, p.priors)
            r = pair_mse(x0, v0, x_true, v_true, moving, *scales)
        return (pair_mse(p.x, p.v, x_true, v_true, moving, *scales) / (r + r.median().clamp_min(1e-12))).mean()

    def _priors(self, scene: SceneGraph, x, v, ctrl) -> list:
        """The priors' node velocity increments over ``dt``, each [B, N, 3] or [N, 3]: the motors' joint
        response or the whole tree's forward dynamics (``actuation``; none without ``ctrl``) and gravity
        (``gravity_prior``)."""
        c = self.config
        dev = x.device
        priors = []
        if c.actuation == "dynamics" and ctrl is not None and c.prior_substeps > 1:  # the tree's state after dt
            seg, mass, ref = scene.obj.to(dev), scene.mass.to(dev), scene.ref_shape.to(dev)
            xp, vp = tree_step(x.detach(), v.detach(), ctrl, self._drives, ref, seg, scene.n_obj, mass, c.dt,
                               c.prior_substeps, c.trapezoidal, c.push_out, self._joints if c.joints else None,
                               c.gyroscopic, c.joint_velocities, c.prior_contact)
            m = scene.moving(dev).view(1, -1, 1)
            priors.append(PriorState(torch.where(m, xp, x.detach()), torch.where(m, vp, torch.zeros_like(vp))))
        elif c.actuation == "dynamics" and ctrl is not None:  # the whole tree's forward dynamics over dt
            seg, mass = scene.obj.to(dev), scene.mass.to(dev)
            priors.append(c.dt * coupled_motor_accelerations(x.detach(), ctrl, self._drives, scene.ref_shape.to(dev),
                                                             seg, scene.n_obj, v=v.detach(), mass=mass, dt=c.dt,
                                                             gyroscopic=c.gyroscopic, contact=c.prior_contact))
        elif self._drives and ctrl is not None and c.actuation in ("step", "prior", "coupled"):
            # the pose enters without gradient (its Kabsch SVD has none for symmetric bodies; only an
            # unrolled training step, whose x carries one, would differentiate it)
            response = coupled_motor_accelerations if c.actuation == "coupled" else motor_accelerations
            priors.append(c.dt * response(x.detach(), ctrl, self._drives, scene.ref_shape.to(dev),
                                          scene.obj.to(dev), scene.n_obj))
        if self._gravity is not None:  # free fall over dt on every moving node
            key = ("gravity", str(dev))
            if key not in self._scenes:
                self._scenes[key] = self._gravity.to(dev)
            dv_g = (c.dt * self._scenes[key]) * scene.moving(dev).unsqueeze(-1).to(x.dtype)  # [N, 3]
            priors.append(dv_g)
        return priors

    def _integrate(self, scene: SceneGraph, x, v, out, priors: list) -> tuple:
        """``x', v'`` [B, N, 3] from g's output ``out`` [B, N, 6]: plus the ``priors``' velocity increments
        (:meth:`_priors`), through the integrator, then the structural constraint module; and the objects'
        placement ``(R, t)`` that module fitted (None without it)."""
        c = self.config
        dev = x.device
        sx, sv = self.scales(scene, dev)
        svc, sw = self.twist_scales(scene, dev)
        if priors and isinstance(priors[0], PriorState):  # g corrects the rigid tree's state after the frame
            seg, mass = scene.obj.to(dev), scene.mass.to(dev)
            xp, vp = priors[0]
            tw = twist(xp, vp, seg, scene.n_obj, mass)
            dvc, dw = project(sv * out[..., 3:], xp, tw, seg, scene.n_obj, mass)
            dc, dth = project(sx * out[..., :3], xp, tw, seg, scene.n_obj, mass)
            h = c.dt / 2 if c.trapezoidal else c.dt  # a twist change over the frame moves the body by h times it
            x1, v1 = advance(xp, tw, tw.vc + dvc, tw.omega + dw, 0.0, seg, dc + h * dvc, dth + h * dw)
        elif priors and c.integrator == "twist":  # g reads twist increments: add the priors' rigid part
            seg, mass = scene.obj.to(dev), scene.mass.to(dev)
            tw = twist(x.detach(), v.detach(), seg, scene.n_obj, mass)
            dvc_p, dw_p = project(sum(priors).expand_as(x), x.detach(), tw, seg, scene.n_obj, mass)  # [B, S, 3]
            out = out + torch.cat([dw_p[:, seg].to(out.dtype) / sw, dvc_p[:, seg].to(out.dtype) / svc], -1)
        elif priors:
            for p in priors:  # one at a time, as before the twist integrator took them
                out = out + torch.cat([torch.zeros_like(p), p / sv], -1)
        if not (priors and isinstance(priors[0], PriorState)):
            x1, v1 = INTEGRATORS[c.integrator](x, v, out, scene, dt=c.dt, dx_scale=sx, dv_scale=sv,
                                               trapezoidal=c.trapezoidal, dvc_scale=svc, dw_scale=sw)
        pose = None
        if c.structure:
            x1, *pose = align_with_pose(x1, scene.ref_shape.to(dev), scene.obj.to(dev), scene.n_obj,
                                        mask=scene.moving(dev))
        return x1, v1, pose

    def _zero_step(self, scene: SceneGraph, x, v, priors: list) -> tuple:
        """``x', v'`` of the state network's output zero (constant twist plus ``priors``, the velocity
        increments :meth:`_priors` gives for ``x, v``; no joint projection)."""
        return self._integrate(scene, x, v, torch.zeros(*x.shape[:-1], 6, dtype=x.dtype, device=x.device), priors)[:2]

    def loss_weights(self) -> dict[str, float]:
        return {"mse": 1.0, "cst": self.config.cst_weight}  # Section 3.4: summed

    def validation_error(self, batch: Batch) -> torch.Tensor:
        """One-step L_mse (Eq. 10, scaled by the model's dx/dv scales, moving nodes)."""
        scene = self.scene_on(batch.x.device)
        p = self(scene, batch.x, batch.v, self.node_controls(batch.ctrl), simulate=True, ctrl=batch.ctrl)
        return mse_loss(p.x, p.v, batch.x_next, batch.v_next, ~scene.static, *self.scales(scene, batch.x.device))

    def perturb(self, batch: Batch, gen: torch.Generator) -> Batch:
        """Training noise (B.2) on the input frame's moving nodes; targets stay clean (:func:`noise_sigmas`).

        With the rigid integrators each object is moved and re-twisted rigidly by the rigid part
        of the noise (rigid rollouts make rigid errors); otherwise every node independently.
        """
        cfg = self.config
        scene = self.scene_on(batch.x.device)
        mv = (~scene.static).view(1, -1, 1).to(torch.float32)
        x, v = batch.x, batch.v
        if cfg.noise_sigma_xs:  # per object
            obj = scene.obj.to(x.device)
            ax, av = (torch.tensor(s, dtype=torch.float32, device=x.device)[obj].view(1, -1, 1)
                      for s in (cfg.noise_sigma_xs, cfg.noise_sigma_vs))
        else:
            ax, av = cfg.noise_sigma_x, cfg.noise_sigma_v
        nx = ax * mv * torch.randn(x.shape, generator=gen, device=x.device)
        nv = av * mv * torch.randn(v.shape, generator=gen, device=v.device)
        if cfg.integrator in ("rigid", "twist"):
            xn, vn = perturb(x, v, nx, nv, scene.obj, scene.n_obj, scene.mass)
            x, v = torch.where(mv > 0, xn, x), torch.where(mv > 0, vn, v)
        else:
            x, v = x + nx, v + nv
        return replace(batch, x=x, v=v)


@dataclass(frozen=True)
class _NCConfig(MDGSConfig):
    """:class:`MDGSConfig` with ``variant = "mdgs-nc"`` (no Kane constraint)."""

    variant: str = "mdgs-nc"


@dataclass(frozen=True)
class _SCConfig(MDGSConfig):
    """:class:`MDGSConfig` with ``variant = "mdgs-sc"`` (constraint along the single speed x)."""

    variant: str = "mdgs-sc"


class MDGSNoConstraint(MDGS):
    """MDGS without the Kane constraint (Table 1, "MDGS-NC")."""

    name = "mdgs-nc"
    Config = _NCConfig
    summary = "MDGS without L_cst (ablation)"


class MDGSSingleSpeed(MDGS):
    """MDGS with L_cst along the single speed x (Table 1, "MDGS-SC")."""

    name = "mdgs-sc"
    Config = _SCConfig
    summary = "MDGS with L_cst along the single speed x (ablation)"

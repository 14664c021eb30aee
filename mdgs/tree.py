"""The rigid tree stepped over a frame: the forward dynamics of :mod:`mdgs.actuation` integrated in substeps.

One substep of length ``h = dt / n`` from node positions and velocities ``x, v`` [B, N, 3]: every object's
twist (:func:`mdgs.rigid.twist`) changes by the rigid part of the whole tree's accelerations times ``h``
(:func:`mdgs.actuation.coupled_motor_accelerations` given the velocities, ``h`` as its frame), the objects
move rigidly by the new twist or, ``trapezoidal``, by the mean of the old and the new one
(:func:`mdgs.rigid.advance`); then, optionally, out of the world's surfaces (:func:`mdgs.actuation.push_out`)
and onto the joints (:func:`mdgs.joints.project_joints`). Or, ``joint_velocities = "coordinates"``, the substep
is taken in the tree's joint coordinates, so that nothing needs projecting (:func:`tree_step`). The controls are
held over the frame, as MuJoCo holds them over its steps. It is the "rigid tree" reference of
:mod:`mdgs.models.references` and, with ``prior_substeps``, the state MDGS's "dynamics" prior hands its network to
correct (:class:`mdgs.models.mdgs.MDGSConfig`). A fast rotor turns a radian or more in a 10 ms frame; one step per
frame then gains energy where a few do not (docs/mdgs-experiments.md, "Substeps, friction and push-out").
"""

from __future__ import annotations

import torch

from mdgs.actuation import (
    DriveSet,
    Pose,
    check_contact,
    coupled_motor_accelerations,
    pose_of,
    project_velocities,
    push_out,
)
from mdgs.joints import JointSet, project_joints
from mdgs.rigid import advance, project, rotation_matrix, twist

__all__ = ["JOINT_VELOCITIES", "check_joint_velocities", "tree_step", "warn_unprojected"]

#: How :func:`tree_step` keeps the joints: it projects the twists onto them, "parent" (each child takes its parent's
#: twist across the joint, :func:`mdgs.joints.project_joints`) or "momentum" (the least kinetic-energy change,
#: impulses at the joints: :func:`mdgs.actuation.project_velocities`); or it steps in the joints' coordinates,
#: "coordinates" (the bodies placed by the tree's kinematics: :func:`tree_step`).
JOINT_VELOCITIES = ("parent", "momentum", "coordinates")


def check_joint_velocities(rule: str) -> None:
    """Raise ``ValueError`` naming the rules when ``rule`` is not one of ``JOINT_VELOCITIES`` (the configs of the
    rigid tree and of MDGS check theirs with it)."""
    if rule not in JOINT_VELOCITIES:
        raise ValueError(f"joint_velocities must be one of {', '.join(map(repr, JOINT_VELOCITIES))}, got {rule!r}")


def tree_step(x: torch.Tensor, v: torch.Tensor, ctrl: torch.Tensor, drives: DriveSet, ref: torch.Tensor,
              seg: torch.Tensor, n_obj: int, mass: torch.Tensor, dt: float, substeps: int = 1,
              trapezoidal: bool = False, pushed_out: bool = False,
              joints: JointSet | None = None, gyroscopic: str = "explicit",
              joint_velocities: str = "parent", contact: str = "rigid") -> tuple[torch.Tensor, torch.Tensor]:
    """``x', v'`` [B, N, 3] of the rigid tree after ``dt`` in ``substeps`` equal substeps (module docstring).

    ``ctrl`` [B, nu]; ``ref`` [N, 3] the nodes in their bodies' frames (:attr:`mdgs.graphs.SceneGraph.ref_shape`),
    ``seg`` [N] their objects, ``mass`` [N]; ``pushed_out``: out of the surfaces after every substep;
    ``joints``: projected onto them after every substep; ``gyroscopic``: when in each substep the gyroscopic
    terms act (:data:`mdgs.actuation.GYROSCOPIC`); ``joint_velocities``: with ``joints``, the projected twists are
    the parent's across each joint ("parent", :func:`mdgs.joints.project_joints`) or the least kinetic-energy
    change that keeps the joints' momentum ("momentum", :func:`mdgs.actuation.project_velocities`); ``contact``: the
    contact model (:data:`mdgs.actuation.CONTACT_MODELS`; "soft" without ``pushed_out``). Static nodes
    are moved like any other: the caller keeps them in place.

    ``joint_velocities = "coordinates"`` steps the tree in its joint coordinates instead (:func:`_coordinates_step`):
    the generalised velocities ``u`` (each root's twist, each jointed child's rate across its joint) change by the
    rigid part of the accelerations ``h a`` read as joint rates, and each root moves rigidly by its twist, each child
    with its parent and about (along) its joint by its rate, so that the joints hold by construction and no projection
    follows. With ``trapezoidal`` this is velocity Verlet, ``q' = q + h u + h^2 a(q, u) / 2`` and
    ``u' = u + h (a(q, u) + a(q', u + h a)) / 2`` (the end's accelerations taken at the predicted velocities and
    reused as the next substep's start: ``substeps + 1`` solves a frame), which keeps a swinging pendulum's energy
    where the trapezoidal step of the bodies' twists gains it; without, semi-implicit Euler in joint coordinates,
    MuJoCo's own integrator, each root stepped at its frame's origin as MuJoCo's free joint is
    (docs/mdgs-experiments.md, "Stepping in the joints' coordinates"). Joints that :mod:`mdgs.joints` leaves alone
    (``joints.skipped``) and free joints make their child a root; ``pushed_out`` moves still project the joints after
    the push (:func:`mdgs.joints.project_joints`), as the push keeps them only to first order."""
    check_joint_velocities(joint_velocities)
    check_contact(contact, pushed_out)
    if joint_velocities == "coordinates":
        return _coordinates_step(x, v, ctrl, drives, ref, seg, n_obj, mass, dt, substeps, trapezoidal, pushed_out,
                                 joints, gyroscopic, contact)
    h = dt / substeps
    pose = None  # the objects' poses and twists at x, v, fitted once per state
    warm = {}  # each solve starts from the contact rows' states the one before settled on
    for _ in range(substeps):
        if pose is None:
            pose = pose_of(x, v, ref, seg, n_obj, mass)
        tw = pose.tw
        acc = coupled_motor_accelerations(x, ctrl, drives, ref, seg, n_obj, v=v, mass=mass, dt=h, gyroscopic=gyroscopic,
                                          pose=pose, contact=contact, warm=warm)
        dvc, dw = project(acc * h, x, tw, seg, n_obj, mass)
        x, v = advance(x, tw, tw.vc + dvc, tw.omega + dw, h, seg, trapezoidal=trapezoidal)
        pose = None
        if pushed_out:
            pose = pose_of(x, v, ref, seg, n_obj, mass)
            xp, vp = push_out(x, v, drives, ref, seg, n_obj, mass, pose=pose)
            if xp is not x or vp is not v:  # moved: the next substep fits its pose again
                x, v, pose = xp, vp, None
        if joints:  # on the pose fitted for the push-out, where that left x, v as they were
            xj, vj = project_joints(x, v, joints, ref, seg, n_obj, mass, pose)
            if joint_velocities == "momentum":
                vj = project_velocities(xj, v, drives, ref, seg, n_obj, mass, x_from=x, dt=h)
            x, v, pose = xj, vj, None
    return x, v


def warn_unprojected(drives: DriveSet, projected: bool, who: str) -> None:
    """Warn (``UserWarning``) that ``who`` steps the tree without the joints' projection where the scene has
    joints: the forward dynamics holds them through their accelerations only, so their positions drift, and a
    hinge whose child spins at hundreds of rad/s is left within frames (the tiny Cubli's flywheel,
    tests/test_dynamics.py). Nothing when ``projected`` or without joints."""
    if not projected and any(lk.kind != "free" for lk in drives.links):
        import warnings

        warnings.warn(f"{who} steps the rigid tree without projecting it onto the joints: they drift, and a fast "
                      "rotor leaves its hinge within frames; set joints = true (the reference "
                      "constant-twist:dynamics+joints, MDGS's default)", UserWarning, stacklevel=2)


def _links_in_coordinates(drives: DriveSet, joints: JointSet | None) -> list:
    """The links that :func:`_coordinates_step` steps in joint coordinates, parents first: those of ``drives`` whose
    child is one of ``joints``' children (a hinge, slide, ball or weld that :mod:`mdgs.joints` can pose)."""
    children = {j.child for j in joints.joints} if joints else set()
    return [lk for lk in drives.links if lk.kind != "free" and lk.child in children]


def _parent_pose(R: torch.Tensor, t: torch.Tensor, p: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Object ``p``'s pose ``R [B, 3, 3], t [B, 3]`` of the poses ``R [B, S, 3, 3], t [B, S, 3]`` (-1: the world)."""
    if p >= 0:
        return R[:, p], t[:, p]
    return torch.eye(3, dtype=R.dtype, device=R.device).expand(R.shape[0], 3, 3), t.new_zeros(t.shape[0], 3)


def _across(R: torch.Tensor, t: torch.Tensor, w: torch.Tensor, vo: torch.Tensor, lk, drives: DriveSet) -> tuple:
    """What link ``lk``'s child is measured against: its parent's rotation ``R_p`` [B, 3, 3], angular velocity ``w_p``
    and velocity field at the origin ``vo_p`` [B, 3] (zero for the world), the joint's axis ``n`` and anchor ``A``
    [B, 3] in the world, of the poses ``R, t`` and the field ``v(y) = vo + w x y`` of each object [B, S, 3]."""
    p = lk.parent
    Rp, tp = _parent_pose(R, t, p)
    wp, vop = (w[:, p], vo[:, p]) if p >= 0 else (w.new_zeros(w.shape[0], 3), w.new_zeros(w.shape[0], 3))
    return (Rp, wp, vop, Rp @ drives.const(lk.axis, R.device), Rp @ drives.const(lk.anchor, R.device) + tp)


def _joint_rates(R: torch.Tensor, t: torch.Tensor, c: torch.Tensor, vc: torch.Tensor, w: torch.Tensor, links: list,
                 drives: DriveSet) -> dict:
    """The generalised velocities of twists ``(vc, w)`` [B, S, 3] (the velocity at the points ``c`` [B, S, 3], the
    angular velocity) at the poses ``R, t``: ``{"vc": vc, "w": w}`` for the roots and, for each link's child, its
    rate across the joint: a hinge's ``n . (w_c - w_p)`` [B], a slide's ``n . (v_c(A) - v_p(A))`` [B] at the anchor
    ``A`` (``n``, ``A`` fixed in the parent), a ball's ``R_p^T (w_c - w_p)`` [B, 3] in the parent's frame (a weld has
    none). Linear in the twists, so it reads the increments ``(h a, h alpha)`` as the rates' increments ``h qdd``
    (for hinges and slides the axis's own turn adds nothing to ``qdd`` while the joint holds)."""
    out = {"vc": vc, "w": w}
    vo = vc - torch.linalg.cross(w, c, dim=-1)  # the velocity field v(y) = vo + w x y
    for lk in links:
        k = lk.child
        Rp, wp, vop, n, A = _across(R, t, w, vo, lk, drives)
        if lk.kind == "hinge":
            out[k] = (n * (w[:, k] - wp)).sum(-1)
        elif lk.kind == "slide":
            out[k] = (n * (vo[:, k] - vop + torch.linalg.cross(w[:, k] - wp, A, dim=-1))).sum(-1)
        elif lk.kind == "ball":
            out[k] = (Rp.transpose(-1, -2) @ (w[:, k] - wp).unsqueeze(-1)).squeeze(-1)
    return out


def _place(R: torch.Tensor, t: torch.Tensor, c: torch.Tensor, u: dict, h: float, links: list, drives: DriveSet
           ) -> tuple[torch.Tensor, torch.Tensor]:
    """The poses ``R', t'`` after ``h`` at the generalised velocities ``u`` (:func:`_joint_rates`): each root turned
    by ``h w`` about its point ``c`` moved by ``h vc`` (:func:`mdgs.rigid.advance`'s motion), the world's objects
    kept, then, parents first, each child's pose in its parent's frame turned about the joint's axis by ``h`` times
    its rate about the anchor (hinge; a ball by ``h`` times its rate vector), moved along the axis (slide) or kept
    (weld), and carried by the parent's new pose."""
    fixed = drives.const(drives.fixed, R.device, torch.bool)
    S = R.shape[1]
    Q = rotation_matrix(h * u["w"])
    Rn = torch.where(fixed.view(1, S, 1, 1), R, Q @ R)
    tn = torch.where(fixed.view(1, S, 1), t, c + h * u["vc"] + (Q @ (t - c).unsqueeze(-1)).squeeze(-1))
    for lk in links:
        k, p = lk.child, lk.parent
        Rp, tp = _parent_pose(R, t, p)
        Rp2, tp2 = _parent_pose(Rn, tn, p)
        a, anchor = drives.const(lk.axis, R.device), drives.const(lk.anchor, R.device)
        Rrel = Rp.transpose(-1, -2) @ R[:, k]
        trel = (Rp.transpose(-1, -2) @ (t[:, k] - tp).unsqueeze(-1)).squeeze(-1)
        if lk.kind in ("hinge", "ball"):
            Qr = rotation_matrix(h * (u[k].unsqueeze(-1) * a if lk.kind == "hinge" else u[k]))
            Rrel, trel = Qr @ Rrel, anchor + (Qr @ (trel - anchor).unsqueeze(-1)).squeeze(-1)
        elif lk.kind == "slide":
            trel = trel + h * u[k].unsqueeze(-1) * a
        Rn[:, k] = Rp2 @ Rrel
        tn[:, k] = (Rp2 @ trel.unsqueeze(-1)).squeeze(-1) + tp2
    return Rn, tn


def _node_velocities(R: torch.Tensor, t: torch.Tensor, c: torch.Tensor, u: dict, links: list, drives: DriveSet,
                     x: torch.Tensor, seg: torch.Tensor) -> torch.Tensor:
    """Node velocities [B, N, 3] at the nodes ``x`` of the poses ``R, t`` from the generalised velocities ``u``
    (:func:`_joint_rates`; the roots' twists about their points ``c``): parents first, a hinge's child turns with its
    parent's angular velocity plus its rate about the axis through the anchor, a ball's likewise by its rate vector,
    a slide's child moves with its parent plus its rate along the axis, a weld's with its parent."""
    fixed = drives.const(drives.fixed, R.device, torch.bool).view(1, -1, 1)
    w = torch.where(fixed, 0.0, u["w"])  # new tensors: the children's rows are written below
    vo = torch.where(fixed, 0.0, u["vc"] - torch.linalg.cross(u["w"], c, dim=-1))
    for lk in links:
        k = lk.child
        Rp, wp, vop, n, A = _across(R, t, w, vo, lk, drives)
        if lk.kind in ("hinge", "ball"):
            wk = wp + (u[k].unsqueeze(-1) * n if lk.kind == "hinge" else (Rp @ u[k].unsqueeze(-1)).squeeze(-1))
            vok = vop + torch.linalg.cross(wp - wk, A, dim=-1)
        elif lk.kind == "slide":
            wk, vok = wp, vop + u[k].unsqueeze(-1) * n
        else:
            wk, vok = wp, vop
        w[:, k], vo[:, k] = wk, vok
    return vo[:, seg] + torch.linalg.cross(w[:, seg], x, dim=-1)


def _coordinates_step(x: torch.Tensor, v: torch.Tensor, ctrl: torch.Tensor, drives: DriveSet, ref: torch.Tensor,
                      seg: torch.Tensor, n_obj: int, mass: torch.Tensor, dt: float, substeps: int, trapezoidal: bool,
                      pushed_out: bool, joints: JointSet | None, gyroscopic: str,
                      contact: str = "rigid") -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`tree_step` in joint coordinates (its docstring: velocity Verlet with ``trapezoidal``, else
    semi-implicit Euler); float64 inside, ``x', v'`` [B, N, 3] in ``x``'s dtype."""
    f64, dev = torch.float64, x.device
    h = dt / substeps
    links = _links_in_coordinates(drives, joints)
    refd, seg = ref.to(dev, f64), seg.to(dev)
    xd, vd = x.to(f64), v.to(f64)
    if pushed_out and joints and not torch.compiler.is_compiling():
        # the joints' groups (data-dependent shapes) built now, eagerly: only a push calls their projection below,
        # and a compiled step, which cannot branch on the data, always does, reading the groups an eager step built
        joints.tensors(seg, ref, mass, n_obj, dev)

    def root_point(pose) -> torch.Tensor:
        """The point [B, S, 3] whose velocity is a root's generalised velocity: under semi-implicit Euler the frame's
        origin, as MuJoCo's free joint has it (its ``qvel`` the origin's velocity and the angular velocity, the
        origin moved by the one and the frame turned about it by the other), so that at MuJoCo's timestep the step
        is MuJoCo's; under Verlet the nodes' mass centre."""
        return pose.tw.c if trapezoidal else pose.t

    warm = {}  # each solve starts from the contact rows' states the one before settled on

    def increments(xd: torch.Tensor, vd: torch.Tensor, pose) -> dict:  # h qdd at (xd, vd), generalised
        acc = coupled_motor_accelerations(xd, ctrl, drives, ref, seg, n_obj, v=vd, mass=mass, dt=h,
                                          gyroscopic=gyroscopic, pose=pose, contact=contact, warm=warm)
        dvc, dw = project(acc * h, xd, pose.tw, seg, n_obj, mass)
        du = _joint_rates(pose.R, pose.t, pose.tw.c, dvc, dw, links, drives)
        if not trapezoidal:  # the origin's acceleration, its centripetal part about the mass centre included
            off, w = pose.t - pose.tw.c, pose.tw.omega
            du["vc"] = dvc + torch.linalg.cross(dw, off, dim=-1) + h * torch.linalg.cross(
                w, torch.linalg.cross(w, off, dim=-1), dim=-1)
        return du

    pose = pose_of(xd, vd, ref, seg, n_obj, mass)
    du = increments(xd, vd, pose)
    for k in range(substeps):
        R, t, tw = pose
        P = root_point(pose)
        u = _joint_rates(R, t, P, tw.vc + torch.linalg.cross(tw.omega, P - tw.c, dim=-1), tw.omega, links, drives)
        u_end = {key: u[key] + du[key] for key in u}  # semi-implicit Euler's, Verlet's prediction
        u_move = {key: u[key] + 0.5 * du[key] for key in u} if trapezoidal else u_end
        Rn, tn = _place(R, t, P, u_move, h, links, drives)
        xd = (Rn[:, seg] @ refd.unsqueeze(-1)).squeeze(-1) + tn[:, seg]
        vd = _node_velocities(Rn, tn, P + h * u_move["vc"], u_end, links, drives, xd, seg)
        if pushed_out:
            xp, vp = push_out(xd, vd, drives, ref, seg, n_obj, mass)
            if xp is not xd or vp is not vd:  # the push keeps the joints to first order: put them back
                xd, vd = (a.to(f64) for a in (project_joints(xp, vp, joints, ref, seg, n_obj, mass) if joints
                                              else (xp, vp)))
            pose = pose_of(xd, vd, ref, seg, n_obj, mass)
        else:  # the nodes are the placed poses' (xd = Rn ref + tn): those are their fit, to round-off
            pose = Pose(Rn, tn, twist(xd, vd, seg, n_obj, mass.to(dev)))
        if trapezoidal or k < substeps - 1:
            du_end = increments(xd, vd, pose)
        if trapezoidal:  # u' = u + (h a + h a') / 2: the prediction, less half of h a, plus half of h a'
            R, t, tw = pose
            u_pred = _joint_rates(R, t, tw.c, tw.vc, tw.omega, links, drives)
            u_new = {key: u_pred[key] + 0.5 * (du_end[key] - du[key]) for key in u_pred}
            vd = _node_velocities(R, t, tw.c, u_new, links, drives, xd, seg)
            pose = Pose(R, t, twist(xd, vd, seg, n_obj, mass.to(dev)))  # the nodes have not moved: keep their fit
        if k < substeps - 1:
            du = du_end
    return xd.to(x.dtype), vd.to(v.dtype)


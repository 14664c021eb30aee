"""The rigid tree stepped over a frame: the forward dynamics of :mod:`mdgs.actuation` integrated in substeps.

One substep of length ``h = dt / n`` from node positions and velocities ``x, v`` [B, N, 3]: every object's
twist (:func:`mdgs.rigid.twist`) changes by the rigid part of the whole tree's accelerations times ``h``
(:func:`mdgs.actuation.coupled_motor_accelerations` given the velocities, ``h`` as its frame), the objects
move rigidly by the new twist or, ``trapezoidal``, by the mean of the old and the new one
(:func:`mdgs.rigid.advance`); then, optionally, out of the world's surfaces (:func:`mdgs.actuation.push_out`)
and onto the joints (:func:`mdgs.joints.project_joints`). The controls are held over the frame, as MuJoCo
holds them over its steps. It is the "rigid tree" reference of :mod:`mdgs.models.references` and, with
``prior_substeps``, the state MDGS's "dynamics" prior hands its network to correct
(:class:`mdgs.models.mdgs.MDGSConfig`). A fast rotor turns a radian or more in a 10 ms frame; one step per
frame then gains energy where a few do not (docs/mdgs-experiments.md, "Substeps, friction and push-out").
"""

from __future__ import annotations

import torch

from mdgs.actuation import (
    DriveSet,
    coupled_motor_accelerations,
    pose_of,
    project_velocities,
    push_out,
)
from mdgs.joints import JointSet, project_joints
from mdgs.rigid import advance, project

__all__ = ["JOINT_VELOCITIES", "check_joint_velocities", "tree_step", "warn_unprojected"]

#: How :func:`tree_step` projects the twists onto the joints: "parent" (each child takes its parent's twist
#: across the joint, :func:`mdgs.joints.project_joints`) or "momentum" (the least kinetic-energy change,
#: impulses at the joints: :func:`mdgs.actuation.project_velocities`).
JOINT_VELOCITIES = ("parent", "momentum")


def check_joint_velocities(rule: str) -> None:
    """Raise ``ValueError`` naming the rules when ``rule`` is not one of ``JOINT_VELOCITIES`` (the configs of the
    rigid tree and of MDGS check theirs with it)."""
    if rule not in JOINT_VELOCITIES:
        raise ValueError(f"joint_velocities must be one of {', '.join(map(repr, JOINT_VELOCITIES))}, got {rule!r}")


def tree_step(x: torch.Tensor, v: torch.Tensor, ctrl: torch.Tensor, drives: DriveSet, ref: torch.Tensor,
              seg: torch.Tensor, n_obj: int, mass: torch.Tensor, dt: float, substeps: int = 1,
              trapezoidal: bool = False, pushed_out: bool = False,
              joints: JointSet | None = None, gyroscopic: str = "explicit",
              joint_velocities: str = "parent") -> tuple[torch.Tensor, torch.Tensor]:
    """``x', v'`` [B, N, 3] of the rigid tree after ``dt`` in ``substeps`` equal substeps (module docstring).

    ``ctrl`` [B, nu]; ``ref`` [N, 3] the nodes in their bodies' frames (:attr:`mdgs.graphs.SceneGraph.ref_shape`),
    ``seg`` [N] their objects, ``mass`` [N]; ``pushed_out``: out of the surfaces after every substep;
    ``joints``: projected onto them after every substep; ``gyroscopic``: when in each substep the gyroscopic
    terms act (:data:`mdgs.actuation.GYROSCOPIC`); ``joint_velocities``: with ``joints``, the projected twists are
    the parent's across each joint ("parent", :func:`mdgs.joints.project_joints`) or the least kinetic-energy
    change that keeps the joints' momentum ("momentum", :func:`mdgs.actuation.project_velocities`). Static nodes
    are moved like any other: the caller keeps them in place."""
    check_joint_velocities(joint_velocities)
    h = dt / substeps
    pose = None  # the objects' poses and twists at x, v, fitted once per state
    for _ in range(substeps):
        if pose is None:
            pose = pose_of(x, v, ref, seg, n_obj, mass)
        tw = pose.tw
        acc = coupled_motor_accelerations(x, ctrl, drives, ref, seg, n_obj, v=v, mass=mass, dt=h, gyroscopic=gyroscopic,
                                          pose=pose)
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

"""What compiling the rigid tree's forward dynamics buys on this machine: eager against ``torch.compile``.

    python benchmarks/compiled_dynamics.py [--scene cubli-triple] [--batch 16] [--substeps 4]

One run, one torch thread, untrained weights, a ``tiny`` dataset of the scene
(:func:`bench_models.tiny_splits`). For the rigid-tree reference (constant twist with the whole tree's
forward dynamics, trapezoidal, projected onto the joints as every study row of it is: without the projection
the tiny Cubli's fast flywheel leaves its hinge within ten frames, and a diverging rollout is not a step
worth timing) and MDGS on that prior (``actuation = "dynamics"``, its joints projected by default), ms per frame for
one trajectory and per trajectory-frame at ``--batch`` trajectories, eager and compiled with inductor
(:func:`mdgs.evaluate.cost.compiled_cost`; compile seconds outside the timings), or ahead of time (``--modes none
aot``), and how far the first test trajectory's rollout with the step as timed lies from the eager one (``max
|dx|``). Compiled, the forward
dynamics solves with a slot for every contact candidate and runs every pass
(:func:`mdgs.actuation.coupled_motor_accelerations`), so that its shapes do not follow the state: cheaper
for one trajectory (no graph breaks), dearer in a batch (larger systems than the eager step's; with the soft contact
every candidate enters the products, but the solves keep the tree's size). ``--substeps N`` (N > 1) measures the tree and MDGS
in N substeps with push-out instead (``studies/mdgs-substeps.toml``'s settings), whose compiled graph holds
every substep's active-set passes: its compiling takes minutes. ``--joint-velocities coordinates`` steps that tree
in its joint coordinates by velocity Verlet (``studies/mdgs-coordinates.toml``'s rows), one solve a frame more.
``--contact rigid soft`` measures the substepped tree and MDGS with each contact model in turn, side by side in one
run (soft: MuJoCo's soft contact without push-out, ``studies/mdgs-soft.toml``'s rows).

``--models gns`` adds GNS correcting the same tree (``prior = "tree"``, ``studies/gns-soft-8.toml``'s no-noise row;
its tree has no push-out, so only with soft contact or one step a frame).

``--loops vector scalar`` measures each compiled row with the step's loops written both ways for the CPU
(:data:`mdgs.models.base.LOOPS`; default ``model``: as the model chooses, :attr:`~mdgs.models.Simulator.scalar_loops`),
and ``--models plain`` adds MDGS alone (no prior, the registry's defaults), whose step is its network's;
``--models twist`` the constant-twist references without the tree's dynamics (plain, + joints, + motors + joints).

``--stack on off`` measures each ahead-of-time row with its buffers allowed on the stack and without
(:data:`mdgs.models.base.AOT_STACK_ALLOCATION`; default ``on``, as :func:`mdgs.models.compile_step` compiles).

``--device cuda`` measures on the GPU instead, where ``--modes none cudagraphs`` compares the eager step with
the step replayed as a CUDA graph (:func:`mdgs.models.compile_step`); ``--models tree`` or ``mdgs`` measures one
of the two; ``--batch 1`` times (and compiles) one trajectory only.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import torch
from bench_models import tiny_splits

from mdgs.evaluate.cost import compiled_cost
from mdgs.evaluate.rollout import rollout
from mdgs.models import MODELS, base
from mdgs.models.base import LOOPS
from mdgs.tree import JOINT_VELOCITIES


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="cubli-triple")
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--substeps", type=int, default=1, help="N > 1: N substeps with push-out")
    ap.add_argument("--device", default="cpu", help="cpu, or cuda")
    ap.add_argument("--modes", nargs="*", default=["none", "inductor"], choices=("none", "inductor", "aot", "cudagraphs"),
                    help="how the step runs: none (eager), inductor (torch.compile), aot (AOTInductor), cudagraphs (CUDA only)")
    ap.add_argument("--models", nargs="*", default=["tree", "mdgs"], choices=("tree", "mdgs", "gns", "plain", "twist"))
    ap.add_argument("--loops", nargs="*", default=["model"], choices=("model", *LOOPS),
                    help="how compiled steps write their loops for the CPU (model: as the model chooses)")
    ap.add_argument("--joint-velocities", default="parent", choices=JOINT_VELOCITIES,
                    help="with --substeps N > 1: how the tree keeps its joints (coordinates: stepped in them, Verlet)")
    ap.add_argument("--contact", nargs="*", default=["rigid"], choices=("rigid", "soft"),
                    help="with --substeps N > 1: the contact models to measure in turn (soft: without push-out)")
    ap.add_argument("--stack", nargs="*", default=["on"], choices=("on", "off"),
                    help="aot rows: intermediate buffers allowed on the stack (on) or not (off)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    dev = torch.device(args.device)
    tr, te = tiny_splits(args.scene)
    ct, md, gn = MODELS["constant-twist"], MODELS["mdgs"], MODELS["gns"]
    if args.joint_velocities != "parent" and args.substeps == 1:
        ap.error("--joint-velocities needs --substeps above 1 (the studies' rows step the tree so)")
    if args.contact != ["rigid"] and args.substeps == 1:
        ap.error("--contact needs --substeps above 1 (the studies' rows step the tree so)")
    if "gns" in args.models and args.substeps > 1 and "rigid" in args.contact:
        ap.error("--models gns with --substeps above 1 needs --contact soft (GNS's tree has no push-out)")
    builds = []
    for contact in args.contact:
        sub = {} if args.substeps == 1 else {"push_out": contact == "rigid", "joint_velocities": args.joint_velocities}
        tag = "" if args.substeps == 1 else f", {args.substeps} sub." + (
            "" if args.joint_velocities == "parent" else f", {args.joint_velocities}") + (
            ", soft" if contact == "soft" else "")
        builds += [(k, label, build) for k, label, build in (
            ("tree", f"rigid tree + joints, trap.{tag}", lambda sub=sub, contact=contact: ct.from_data(te, ct.Config(
                dynamics=True, joints=True, trapezoidal=True, substeps=args.substeps, contact=contact, **sub))),
            ("mdgs", f"mdgs + dynamics prior{tag}", lambda sub=sub, contact=contact: md.from_data(tr, md.Config(
                actuation="dynamics", trapezoidal=True, prior_substeps=args.substeps, prior_contact=contact, **sub))),
            ("gns", f"gns + tree prior{tag}", lambda contact=contact: gn.from_data(tr, gn.Config(
                prior="tree", prior_substeps=args.substeps, prior_trapezoidal=True, prior_contact=contact,
                prior_joint_velocities=args.joint_velocities, noise_std=0.0))))
            if k in args.models]
    if "plain" in args.models:
        builds.append(("plain", "mdgs alone (no prior)", lambda: md.from_data(tr, md.Config())))
    if "twist" in args.models:  # the references without the tree's dynamics: a body's twist, motors, joints
        builds += [("twist", label, lambda kw=kw: ct.from_data(te, ct.Config(**kw))) for label, kw in (
            ("constant twist", {}), ("constant twist + joints", {"joints": True}),
            ("constant twist + motors + joints", {"motors": True, "joints": True}))]
    where = "CPU, 1 torch thread" if dev.type == "cpu" else f"{torch.cuda.get_device_name(dev)}, torch {torch.__version__}"
    print(f"scene {args.scene}: {tr.x.shape[2]} nodes, {where}")
    print(f"{'model':52s}{'step':>10s}{'loops':>8s}{'stack':>7s}{'ms/f b1':>10s}{f'ms/tf b{args.batch}':>13s}{'compile s':>11s}{'max |dx| m':>12s}")
    one = dataclasses.replace(te, **{k: getattr(te, k)[:1] for k in ("x", "v", "ctrl", "qpos", "qvel", "act")
                                     if getattr(te, k) is not None})  # the first test trajectory
    for _, label, build in builds:
        runs = [(m, lp, st) for m in args.modes for lp in (args.loops if m in ("inductor", "aot") else ["model"])
                for st in (args.stack if m == "aot" else ["-"])]
        for mode, loops, stack in runs:
            base.AOT_STACK_ALLOCATION = stack != "off"
            model = build().to(dev)
            eager = rollout(model, one, dev).x
            r = compiled_cost(model, te, mode, batched=args.batch, loops=None if loops == "model" else loops)
            dx = float(np.abs(rollout(model, one, dev).x - eager).max())  # the step as timed, one trajectory
            way = "-" if r["compiled"] not in ("inductor", "aot") or dev.type != "cpu" else (
                loops if loops != "model" else ("scalar" if model.scalar_loops else "vector"))
            print(f"{label:52s}{r['compiled']:>10s}{way:>8s}{stack if r['compiled'] == 'aot' else '-':>7s}{r['single']['ms_per_frame']:>10.3f}"
                  f"{r['batched']['ms_per_trajectory_frame']:>13.3f}{r['compile_seconds']:>11.0f}{dx:>12.2g}"
                  + (f"  ({r['note']})" if r["note"] else ""), flush=True)
    print("step: none = eager, inductor = torch.compile, aot = AOTInductor, cudagraphs = replayed as a CUDA graph; loops: how "
          "the compiled step's loops are written for the CPU (vector or scalar; - for the eager step); stack: an aot step's "
          "buffers allowed on the stack (on) or not (off); ms/f b1: ms per frame, one "
          "trajectory; ms/tf bN: ms per trajectory-frame at batch N; max |dx|: the largest difference of the rollout of "
          "the first test trajectory with the step as timed from the eager one (float32 positions)")


if __name__ == "__main__":
    main()

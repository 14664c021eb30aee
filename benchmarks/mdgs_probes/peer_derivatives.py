"""LGNS's and HGNS's second derivatives by forward mode over reverse mode or by reverse mode twice: cost and equality.

    python benchmarks/mdgs_probes/peer_derivatives.py [--batches 1 4] [--repeats 7]

One run, one torch thread, this CPU, untrained peers (seed 0) on a ``tiny`` Cubli dataset (the cost of a step does not
depend on training). The energy peers obtain ``M = d2L/dqd2`` and the mixed term ``(d2L/dqd dq) qd`` (LGNS; HGNS's
``d2H/dp2`` and ``(d2H/dp dq) qd``) by automatic differentiation. Two ways, side by side:

- ``forward``: ``jacfwd`` over ``jacrev`` for the Hessian and a ``jvp`` for the mixed term (the peers' code before
  reverse mode replaced it; kept here as the reference);
- ``reverse``: ``jacrev`` over ``jacrev`` for both, the mixed term as a matrix-vector product
  (:func:`mdgs.models.mechanics.lagrangian_acceleration`, :func:`~mdgs.models.mechanics.hamiltonian_derivatives`).

Printed per peer and way: ms per eager rollout step at each batch, ms per compiled step at batch 1
(:func:`mdgs.models.compile_step` ``"inductor"``, or why it does not compile), ms per training step (losses of 32
pairs and their backward pass), and against ``forward``: the largest difference of the step's positions and of the
loss gradient (relative to its largest entry). Medians of ``--repeats`` timings.
"""
from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

import numpy as np
import torch
from torch.func import jacfwd, jacrev, jvp, vmap

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_models import median_time, tiny_splits  # noqa: E402

import mdgs.models.hgns as hgns  # noqa: E402
import mdgs.models.lgns as lgns  # noqa: E402
import mdgs.models.mechanics as mech  # noqa: E402
from mdgs.evaluate.cost import quiet_compiler  # noqa: E402
from mdgs.models import MODELS, batch_of, compile_step  # noqa: E402


def lagrangian_acceleration_forward(L, jac, q, qd, force):
    """:func:`mdgs.models.mechanics.lagrangian_acceleration` with ``jacfwd`` over ``jacrev`` and a ``jvp``."""
    B, n, _ = q.shape
    D = 3 * n
    dLdv = jacrev(L, argnums=1)

    def one(q1, qd1):
        gq = jacrev(L, argnums=0)(q1, qd1)
        M = jacfwd(dLdv, argnums=1)(q1, qd1).reshape(D, D)
        mixed = jvp(lambda z: dLdv(z, qd1), (q1,), (qd1,))[1]
        return (gq - mixed).reshape(D), M

    f, M = vmap(one)(q, qd)
    J, Jdqd = jac(q, qd)
    f = f + force.reshape(B, D)
    sol = mech._solve(M, torch.cat([f.unsqueeze(-1), J.transpose(1, 2)], -1))
    Minv_f, Minv_JT = sol[..., 0], sol[..., 1:]
    if J.shape[1]:
        lam = mech.solve_multipliers(Minv_JT, J, -Jdqd - (J @ Minv_f.unsqueeze(-1))[..., 0])
        Minv_f = Minv_f + (Minv_JT @ lam.unsqueeze(-1))[..., 0]
    return Minv_f.view(B, n, 3)


def hamiltonian_derivatives_forward(H, jac, q, p, force):
    """:func:`mdgs.models.mechanics.hamiltonian_derivatives` with ``jacfwd`` over ``jacrev`` and a ``jvp``."""
    B, n, _ = q.shape
    D = 3 * n
    dHdp = jacrev(H, argnums=1)

    def one(q1, p1):
        Hq = jacrev(H, argnums=0)(q1, p1)
        qd1 = dHdp(q1, p1)
        Hpp = jacfwd(dHdp, argnums=1)(q1, p1).reshape(D, D)
        mixed = jvp(lambda z: dHdp(z, p1), (q1,), (qd1,))[1]
        return qd1.reshape(D), Hq.reshape(D), Hpp, mixed.reshape(D)

    qd, Hq, Hpp, mixed = vmap(one)(q, p)
    J, Jdqd = jac(q, qd.view(B, n, 3))
    base = -Hq + force.reshape(B, D)
    if J.shape[1]:
        rhs = -Jdqd - (J @ (mixed + (Hpp @ base.unsqueeze(-1))[..., 0]).unsqueeze(-1))[..., 0]
        lam = mech.solve_multipliers(Hpp @ J.transpose(1, 2), J, rhs)
        pd = base + (J.transpose(1, 2) @ lam.unsqueeze(-1))[..., 0]
    else:
        pd = base
    qdd = (Hpp @ pd.unsqueeze(-1))[..., 0] + mixed
    return qd.view(B, n, 3), pd.view(B, n, 3), qdd.view(B, n, 3)


@contextlib.contextmanager
def way(name: str):
    """Within this block the peers differentiate the ``name``d way ("forward" or "reverse")."""
    before = lgns.lagrangian_acceleration, hgns.hamiltonian_derivatives
    if name == "forward":
        lgns.lagrangian_acceleration, hgns.hamiltonian_derivatives = (lagrangian_acceleration_forward,
                                                                      hamiltonian_derivatives_forward)
    try:
        yield
    finally:
        lgns.lagrangian_acceleration, hgns.hamiltonian_derivatives = before


def median_ms(fn, repeats: int) -> float:
    """Median milliseconds of ``fn()`` over ``repeats`` calls after one warm-up call."""
    return 1e3 * median_time(fn, repeats, warmup=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--batches", nargs="*", type=int, default=[1, 4])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    torch.set_num_threads(1)
    tr, te = tiny_splits("cubli-triple")
    print(f"tiny cubli-triple: {tr.x.shape[2]} nodes; one torch thread; medians of {args.repeats}; untrained, seed 0")
    print(f"{'peer':6s}{'way':9s}" + "".join(f"{'step b' + str(b):>10s}" for b in args.batches)
          + f"{'compiled b1':>13s}{'train b32':>11s}{'max |dx| m':>12s}{'grad diff':>11s}")
    for name in ("lgns", "hgns"):
        ref = {}
        for w in ("forward", "reverse"):
            with way(w):
                torch.manual_seed(0)
                m = MODELS[name].from_data(tr, MODELS[name].Config())
                m.bind(te)
                steps = []
                for b in args.batches:
                    st = m.initial_state(te, np.zeros(b, dtype=int), m.history)
                    ctrl = torch.as_tensor(te.ctrl[np.zeros(b, dtype=int), m.history])
                    with torch.no_grad():
                        steps.append(median_ms(lambda m=m, st=st, ctrl=ctrl: m.step(st, ctrl), args.repeats))
                        x = m.step(st, ctrl).x
                pairs = tr.pairs(m.history)
                batch = batch_of(tr, pairs[np.linspace(0, len(pairs) - 1, 32).astype(int)], m.device, m.history)
                m.train()

                def train_step(m=m, batch=batch):
                    m.zero_grad()
                    sum(wt * m.losses(batch)[k] for k, wt in m.loss_weights().items()).backward()

                train = median_ms(train_step, args.repeats)
                grad = torch.cat([p.grad.flatten() for p in m.parameters() if p.grad is not None])
                m.eval()
                st = m.initial_state(te, np.zeros(1, dtype=int), m.history)
                ctrl = torch.as_tensor(te.ctrl[[0], m.history])
                try:
                    torch._dynamo.reset()  # nothing left over from the other way's attempt
                    compile_step(m, "inductor")
                    with torch.no_grad(), quiet_compiler():
                        m.step(st, ctrl)  # the first step of a binding runs eagerly
                        m.step(st, ctrl)  # compiles
                        compiled = f"{median_ms(lambda m=m, st=st, ctrl=ctrl: m.step(st, ctrl), args.repeats):.2f}"
                except Exception as e:  # noqa: BLE001 - dynamo's and inductor's many failure types: say which
                    compiled = "fails"
                    print(f"  {name} {w}: does not compile ({type(e).__name__}: {str(e).splitlines()[0][:100]})")
                if w == "forward":
                    ref = {"x": x, "grad": grad}
                dx = float((x - ref["x"]).abs().max())
                dg = float((grad - ref["grad"]).abs().max() / ref["grad"].abs().max())
                print(f"{name:6s}{w:9s}" + "".join(f"{s:>10.2f}" for s in steps)
                      + f"{compiled:>13s}{train:>11.1f}{dx:>12.1e}{dg:>11.1e}", flush=True)
    print("step bN: ms per eager rollout step of N trajectories; compiled b1: ms per step compiled by inductor; "
          "train b32: ms per training step (losses and backward, 32 pairs); max |dx|, grad diff: against forward")


if __name__ == "__main__":
    main()

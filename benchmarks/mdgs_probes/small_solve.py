"""What the soft contact's eight passes cost compiled ahead of time, solved by the library's LU or by fused elimination.

    python benchmarks/mdgs_probes/small_solve.py

One run, one torch thread, this CPU. The loop of :func:`mdgs.actuation._unilateral_solve`'s passes (a system of the
tree's degrees of freedom ``n`` a pass: ``G^T M G + (Ju G)^T W (Ju G)``, then which of the ``U`` rows push) on random
systems of the study scenes' sizes (the Cubli: n = 9, U = 96 pyramid edges and limits; rotational-center: n = 8,
U = 680), exported and compiled by AOTInductor twice: each pass solving with ``torch.linalg.solve_ex`` (which
AOTInductor, having no C shim for it, calls through its proxy executor) and with
:func:`mdgs.actuation._solve_unpivoted` (elimination in ``n`` fused steps). Printed: microseconds for the eight passes
(median of 5 timings of 2000 calls each), their ratio, the compile seconds and the largest difference of the two
solutions.
"""
import tempfile
import time

import torch

from mdgs.actuation import SOFT_CONTACT_PASSES, _solve_unpivoted

torch.set_num_threads(1)
f64 = torch.float64


class Passes(torch.nn.Module):
    """The passes' loop as in :func:`mdgs.actuation._unilateral_solve`, solving with ``solve``."""

    def __init__(self, solve):
        super().__init__()
        self.solve = solve

    def forward(self, Mr, fr, JG, gap, Ru, held):
        JGT, active = JG.transpose(-1, -2), held
        for _ in range(SOFT_CONTACT_PASSES):
            W = active.to(f64) / Ru
            y = self.solve(Mr + JGT @ (W.unsqueeze(-1) * JG), fr + (JGT @ (W * gap).unsqueeze(-1)).squeeze(-1))
            active = held & ((JG @ y.unsqueeze(-1)).squeeze(-1) < gap)
        return y, active


def library(K, b):
    return torch.linalg.solve_ex(K, b)[0]


def timed(module, args) -> tuple[float, float, tuple]:
    """Median microseconds a call of ``module`` compiled ahead of time, the compile seconds, its outputs."""
    folder = tempfile.mkdtemp(prefix="mdgs-small-solve-")
    t0 = time.perf_counter()
    program = torch.export.export(module, args, strict=False)
    run = torch._inductor.aoti_load_package(torch._inductor.aoti_compile_and_package(
        program, package_path=f"{folder}/passes.pt2")).loader.boxed_run
    seconds = time.perf_counter() - t0
    for _ in range(200):
        out = run(list(args))
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(2000):
            run(list(args))
        times.append((time.perf_counter() - t0) / 2000 * 1e6)
    return sorted(times)[2], seconds, out


print("# python benchmarks/mdgs_probes/small_solve.py")
print(f"{'sizes':32s}{'library us':>12s}{'fused us':>10s}{'ratio':>7s}{'compile s':>11s}{'max |dy|':>10s}")
for name, n, U in (("cubli-triple", 9, 96), ("rotational-center", 8, 680)):
    g = torch.Generator().manual_seed(0)
    L = torch.randn(1, n, n, generator=g, dtype=f64)
    args = (L @ L.transpose(-1, -2) + n * torch.eye(n, dtype=f64), torch.randn(1, n, generator=g, dtype=f64),
            torch.randn(1, U, n, generator=g, dtype=f64), torch.randn(1, U, generator=g, dtype=f64),
            torch.rand(1, U, generator=g, dtype=f64) + 0.1, torch.rand(1, U, generator=g) < 0.5)
    lib, lib_s, lib_out = timed(Passes(library), args)
    fused, fused_s, fused_out = timed(Passes(_solve_unpivoted), args)
    dy = float((lib_out[0] - fused_out[0]).abs().max())
    print(f"{f'{name} (n {n}, U {U})':32s}{lib:>12.1f}{fused:>10.1f}{lib / fused:>7.2f}{lib_s + fused_s:>11.0f}{dy:>10.1e}",
          flush=True)
print("library us, fused us: one call of the eight passes; ratio: library over fused; compile s: both packages")

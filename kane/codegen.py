"""Generated numeric functions from the sympy expressions that the checks verify.

One source for each formula: the constraint loss of :mod:`mdgs` evaluates the function that
:func:`to_torch` generates from the same sympy expression that :mod:`kane.claims` checks.
Torch is imported only when a torch function is generated, so ``kane`` imports without it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import sympy as sp
from sympy.printing.numpy import NumPyPrinter

__all__ = ["to_numpy", "to_torch", "to_casadi"]


def _max_args(printer, expr, fn: str, zero_fn: str) -> str:
    args = list(expr.args)
    if len(args) == 2 and sp.S.Zero in args:
        other = args[1] if args[0] == 0 else args[0]
        return f"{zero_fn}({printer._print(other)})"
    out = printer._print(args[0])
    for a in args[1:]:
        out = f"{fn}({out}, {printer._print(a)})"
    return out


class _NumPyPrinter(NumPyPrinter):
    """NumPy printer with an element-wise ``Max`` (``numpy.maximum``)."""

    def _print_Max(self, expr):  # noqa: N802 (sympy naming)
        return _max_args(self, expr, "numpy.maximum", "(lambda _x: numpy.maximum(_x, 0))")


def _torch_printer_cls():
    from sympy.printing.pytorch import TorchPrinter

    class _TorchPrinter(TorchPrinter):
        """Torch printer with ``Max(0, x) -> torch.relu(x)`` (sympy prints ``torch.max(0, x)``, which fails)."""

        def _print_Max(self, expr):  # noqa: N802
            return _max_args(self, expr, "torch.maximum", "torch.relu")

        def _print_Rational(self, expr):  # noqa: N802
            return f"({expr.p}/{expr.q})"

    return _TorchPrinter


def to_numpy(args: Sequence[sp.Symbol], expr: sp.Expr) -> Callable:
    """``f(*arrays)`` evaluating ``expr`` element-wise with numpy broadcasting."""
    import numpy

    return sp.lambdify(list(args), expr, modules=[{"numpy": numpy}, "numpy"], printer=_NumPyPrinter)


def to_torch(args: Sequence[sp.Symbol], expr: sp.Expr) -> Callable:
    """``f(*tensors)`` evaluating ``expr`` element-wise in torch (differentiable, any device)."""
    import torch

    printer = _torch_printer_cls()({"fully_qualified_modules": True})
    return sp.lambdify(list(args), expr, modules=[{"torch": torch}], printer=printer)


def to_casadi(args: Sequence[sp.Symbol], expr: sp.Expr) -> Callable:
    """``f(*casadi_symbols_or_floats)`` building the CasADi graph of ``expr``."""
    import casadi

    mapping = {
        "Max": lambda *a: _fold(casadi.fmax, a),
        "Min": lambda *a: _fold(casadi.fmin, a),
        "Abs": casadi.fabs,
        "sqrt": casadi.sqrt,
        "sin": casadi.sin,
        "cos": casadi.cos,
    }
    return sp.lambdify(list(args), expr, modules=[mapping, casadi])


def _fold(fn, args):
    out = args[0]
    for a in args[1:]:
        out = fn(out, a)
    return out

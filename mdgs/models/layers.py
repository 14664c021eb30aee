"""Network blocks shared by the models: the GCN of Kipf & Welling (2017) on a scene's propagator."""

from __future__ import annotations

import contextlib

import torch
from torch import nn

from mdgs.graphs import Propagator

__all__ = ["GCN", "folded_weights", "weights_folded"]

_FOLDED = False  # set by folded_weights(); read by weights_folded()


@contextlib.contextmanager
def folded_weights():
    """Within this block (and without gradients) a model may compute a step with products of weights
    that are computed once, so it skips a matrix product per step that only weights feed (MDGS:
    Eqs. (5)-(6) with g^Z-'s last layer folded into g^F-'s first). ``compile_step(model, "aot")``
    traces the step inside it, and AOTInductor's runtime constant folding computes the products when
    the package loads; eagerly a model caches them until its weights change (benchmarks count the
    compiled step's FLOPs this way)."""
    global _FOLDED
    before, _FOLDED = _FOLDED, True
    try:
        yield
    finally:
        _FOLDED = before


def weights_folded() -> bool:
    """Whether the step now computed may use folded weight products (:func:`folded_weights`): inside
    that block and without gradients, never in training."""
    return _FOLDED and not torch.is_grad_enabled()


class GCN(nn.Module):
    """``H^{l+1} = ReLU(A_hat H^l W^l + b^l)``, no activation after the last layer (Kipf & Welling 2017).

    ``self_weight``: ``H^{l+1} = ReLU(A_hat H^l W^l + H^l S^l + b^l)``, a separate weight on each
    node's own features (as GraphSAGE, Hamilton et al. 2017), so a layer can tell a node from the
    average of its neighbourhood instead of only smoothing over it.
    """

    def __init__(self, d_in: int, hidden: int, d_out: int, layers: int = 3, self_weight: bool = False):
        super().__init__()
        dims = [d_in] + [hidden] * (layers - 1) + [d_out]
        self.lins = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:], strict=True))
        self.selfs = (nn.ModuleList(nn.Linear(a, b, bias=False) for a, b in zip(dims[:-1], dims[1:], strict=True))
                      if self_weight else None)

    def forward(self, prop: Propagator, h: torch.Tensor, first: int = 0, last: int | None = None) -> torch.Tensor:
        """``h`` [B, N, d_in] -> [B, N, d_out]; with ``first``/``last`` only the layers ``first..last-1``
        (``h`` the input of layer ``first``, the output that of layer ``last-1``, after its ReLU if it
        has one)."""
        n = len(self.lins)
        for k in range(first, n if last is None else last):
            lin = self.lins[k]
            own = self.selfs[k](h) if self.selfs is not None else None
            # propagate on the narrower side of the linear map (fewer features to gather)
            if lin.in_features <= lin.out_features:
                h = lin(prop(h))
            else:
                h = prop(h @ lin.weight.T) + lin.bias
            if own is not None:
                h = h + own
            if k < n - 1:
                h = torch.relu(h)
        return h

    def zero_output(self) -> None:
        """Make the last layer output zero (every weight and bias of it)."""
        nn.init.zeros_(self.lins[-1].weight)
        nn.init.zeros_(self.lins[-1].bias)
        if self.selfs is not None:
            nn.init.zeros_(self.selfs[-1].weight)

"""Network blocks shared by the models: the GCN of Kipf & Welling (2017) on a scene's propagator."""

from __future__ import annotations

import torch
from torch import nn

from mdgs.graphs import Propagator

__all__ = ["GCN"]


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

    def forward(self, prop: Propagator, h: torch.Tensor) -> torch.Tensor:
        """``h`` [B, N, d_in] -> [B, N, d_out]."""
        for k, lin in enumerate(self.lins):
            own = self.selfs[k](h) if self.selfs is not None else None
            # propagate on the narrower side of the linear map (fewer features to gather)
            if lin.in_features <= lin.out_features:
                h = lin(prop(h))
            else:
                h = prop(h @ lin.weight.T) + lin.bias
            if own is not None:
                h = h + own
            if k < len(self.lins) - 1:
                h = torch.relu(h)
        return h

    def zero_output(self) -> None:
        """Make the last layer output zero (every weight and bias of it)."""
        nn.init.zeros_(self.lins[-1].weight)
        nn.init.zeros_(self.lins[-1].bias)
        if self.selfs is not None:
            nn.init.zeros_(self.selfs[-1].weight)

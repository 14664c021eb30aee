"""Multi-process training under ``torchrun`` (torch.distributed): the only module that touches it.

``torchrun --standalone --nproc_per_node N -m mdgs.cli train ...`` starts N ranks. Each rank
builds the same global batch of ``batch_size`` training pairs (the same seeded permutation on
every rank), applies the model's noise to the global batch (the same generator on every rank,
so the noise of a pair does not depend on how many ranks there are), keeps its own contiguous
``batch_size / N`` rows (DistributedSampler semantics: each rank computes on its part), and
``DistributedDataParallel`` averages the gradients. Since every model's losses are means over
the batch's graphs, N ranks take the same optimiser steps as one process with the same global
batch, up to float summation order. Only rank 0 writes the run folder; the others wait at a
barrier. Backend: ``nccl`` on CUDA, ``gloo`` on CPU.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn

__all__ = ["Dist", "setup", "teardown"]


@dataclass(frozen=True)
class Dist:
    """This process's place in the job: ``rank`` of ``world`` (1 when not under torchrun)."""

    rank: int = 0
    world: int = 1

    @property
    def enabled(self) -> bool:
        return self.world > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def rows(self, n: int) -> slice:
        """This rank's contiguous rows of a global batch of ``n`` (``n`` divisible by ``world``)."""
        k = n // self.world
        return slice(self.rank * k, (self.rank + 1) * k)

    def barrier(self) -> None:
        if self.enabled:
            dist.barrier()

    def mean(self, values: dict[str, float]) -> dict[str, float]:
        """Mean of each value over the ranks (for logs: the global batch's loss)."""
        if not self.enabled or not values:
            return values
        t = torch.tensor(list(values.values()), dtype=torch.float64)
        dist.all_reduce(t)
        return dict(zip(values, (t / self.world).tolist(), strict=True))

    def wrap(self, module: nn.Module, device: torch.device) -> nn.Module:
        """``DistributedDataParallel(module)`` when distributed, else ``module``."""
        if not self.enabled:
            return module
        ids = [device.index or 0] if device.type == "cuda" else None
        # some models leave parameters out of a batch's loss (e.g. a contact network when no
        # contact happens in it): DDP must not wait for their gradients
        return nn.parallel.DistributedDataParallel(module, device_ids=ids, find_unused_parameters=True)


def setup(device: str) -> tuple[Dist, str]:
    """Join the torchrun job if there is one -> (Dist, device name for this rank)."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return Dist(), device
    rank = int(os.environ["RANK"])
    cuda = torch.cuda.is_available() and device in ("auto", "cuda")
    if cuda:
        local = int(os.environ.get("LOCAL_RANK", "0"))
        torch.cuda.set_device(local)
        device = f"cuda:{local}"
    elif device == "auto":
        device = "cpu"
    if not dist.is_initialized():
        dist.init_process_group("nccl" if cuda else "gloo")
    return Dist(rank, world), device


def teardown(d: Dist) -> None:
    if d.enabled and dist.is_initialized():
        dist.barrier()
        dist.destroy_process_group()

"""torchrun / DDP helpers: one process per device, rank 0 writes, metrics reduced by sum.

`torchrun --nproc-per-node N -m segmin.train.cli --config ...` sets RANK, WORLD_SIZE, LOCAL_RANK and
MASTER_ADDR/PORT; `init_distributed` reads them. Backend: nccl with CUDA, gloo on CPU.
Without those variables everything runs as a single process (rank 0 of 1).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol

import torch
import torch.distributed as dist
from torch.utils.data import Sampler


@dataclass(frozen=True)
class DistInfo:
    """This process's place in the torchrun group (rank 0 of 1 without torchrun) and its device."""

    rank: int
    world_size: int
    local_rank: int
    device: torch.device

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1


def pick_device(spec: str, local_rank: int = 0) -> torch.device:
    """ "auto" -> cuda:<local_rank> when CUDA is available, else cpu."""
    if spec == "auto":
        return torch.device(f"cuda:{local_rank}") if torch.cuda.is_available() else torch.device("cpu")
    device = torch.device(spec)
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"device={spec!r}: CUDA is not available")
        if device.index is None:
            device = torch.device(f"cuda:{local_rank}")
    return device


def init_distributed(device_spec: str = "auto") -> DistInfo:
    """Join the torchrun process group if the environment says so; pick this rank's device."""
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local_rank = int(os.environ.get("LOCAL_RANK", str(rank)))
    device = pick_device(device_spec, local_rank)
    if world_size > 1 and not dist.is_initialized():
        if device.type == "cuda":
            torch.cuda.set_device(device)
        dist.init_process_group(backend="nccl" if device.type == "cuda" else "gloo", rank=rank, world_size=world_size)
    return DistInfo(rank, world_size, local_rank, device)


def cleanup() -> None:
    """Leave the process group, if one was joined, so the next run in this process can join anew."""
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


def barrier() -> None:
    """Wait for every rank (no-op alone), so no rank starts the next epoch while rank 0 still writes."""
    if dist.is_available() and dist.is_initialized():
        dist.barrier()


def all_reduce_sum(tensor: torch.Tensor) -> torch.Tensor:
    """Sum `tensor` in place over the DDP ranks (a no-op without a process group): metrics are sums."""
    if dist.is_available() and dist.is_initialized():
        dist.all_reduce(tensor)
    return tensor


class SizedSampler(Protocol):
    """A sampler that knows its length (torch's `Sampler` does not declare `__len__`)."""

    def __iter__(self) -> Iterator[int]: ...

    def __len__(self) -> int: ...


class EpochSampler(Sampler):
    """Yields `(epoch, index)` so the dataset seeds each sample's augmentation from both.

    Wraps a `DistributedSampler` (seeded order per epoch, a shard per rank). `skip` drops the
    first indices of the epoch: `--resume` after an interrupt continues mid-epoch exactly.
    """

    def __init__(self, base: SizedSampler, epoch: int = 0, skip: int = 0) -> None:
        self.base = base
        self.epoch = epoch
        self.skip = skip

    def set_epoch(self, epoch: int, skip: int = 0) -> None:
        self.epoch, self.skip = epoch, skip
        if hasattr(self.base, "set_epoch"):
            self.base.set_epoch(epoch)

    def __iter__(self) -> Iterator[tuple[int, int]]:
        for i, index in enumerate(self.base):
            if i >= self.skip:
                yield (self.epoch, int(index))

    def __len__(self) -> int:
        return max(0, len(self.base) - self.skip)


class ShardSampler(Sampler):
    """Evaluation shard: rank r takes indices r, r + W, ... (no padding, so sums are exact)."""

    def __init__(self, indices: Sequence[int] | int, rank: int = 0, world_size: int = 1) -> None:
        indices = range(indices) if isinstance(indices, int) else indices
        self.indices = list(indices)[rank::world_size]

    def __iter__(self) -> Iterator[int]:
        return iter(self.indices)

    def __len__(self) -> int:
        return len(self.indices)

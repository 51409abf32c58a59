"""Many processes, one report: shard images across ranks and gather the results in order.

Used by ``torchrun ... -m claravid.eval`` and by training's validation. Without an initialised
process group everything here is the single-process identity, so the same code runs everywhere.
"""

from __future__ import annotations

import atexit
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import torch
import torch.distributed as dist

T = TypeVar("T")


@dataclass(frozen=True)
class DistInfo:
    """This process's place: rank, world size, local rank and the device it computes on."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))

    @property
    def is_main(self) -> bool:
        """Rank 0 logs, writes checkpoints and reports."""
        return self.rank == 0


def init_distributed(device: str | None = None) -> DistInfo:
    """Join the process group that ``torchrun`` describes in the environment (if any).

    NCCL with one GPU per local rank when CUDA is there, gloo on CPU. Without torchrun's
    variables (``WORLD_SIZE`` unset or 1) nothing is initialised.

    Args:
        device: ``"cpu"``, ``"cuda"`` or None (CUDA when available).
    """
    use_cuda = torch.cuda.is_available() if device is None else device.startswith("cuda")
    world = int(os.environ.get("WORLD_SIZE", "1"))
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    if world <= 1:
        dev = torch.device(device or ("cuda" if use_cuda else "cpu"))
        return DistInfo(device=dev)
    if use_cuda:
        torch.cuda.set_device(local_rank)
    if not dist.is_initialized():
        dist.init_process_group("nccl" if use_cuda else "gloo")
        global _OWNED
        _OWNED = True
        # A group left to interpreter shutdown can abort the process ("terminate called
        # without an active exception" from gloo's threads): the console scripts tear it down
        # when their work is done (`shutdown`), and this catches any other exit.
        atexit.register(shutdown)
    dev = torch.device("cuda", local_rank) if use_cuda else torch.device("cpu")
    return DistInfo(dist.get_rank(), dist.get_world_size(), local_rank, dev)


#: Whether `init_distributed` made the process group (a group the caller made is theirs).
_OWNED = False


def shutdown() -> None:
    """Tear down the process group `init_distributed` made, if any (idempotent)."""
    global _OWNED
    if _OWNED and dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()
    _OWNED = False


def current() -> DistInfo:
    """Rank and world size of an initialised group (device left to the caller)."""
    if dist.is_available() and dist.is_initialized():
        return DistInfo(dist.get_rank(), dist.get_world_size())
    return DistInfo()


def shard_indices(n: int, rank: int | None = None, world_size: int | None = None) -> list[int]:
    """This rank's share of ``range(n)``: every ``world_size``-th index from ``rank``.

    Interleaving keeps neighbouring (similar) frames on different ranks, so shards take about
    the same time.
    """
    info = current()
    rank = info.rank if rank is None else rank
    world_size = info.world_size if world_size is None else world_size
    return list(range(rank, n, world_size))


def gather_in_order(items: Sequence[T], indices: Sequence[int]) -> list[T]:
    """Every rank's ``items`` (item i belongs to global index ``indices[i]``), on every rank,
    sorted by global index. Objects travel pickled (``all_gather_object``), fine for per-image
    confusions.
    """
    if len(items) != len(indices):
        raise ValueError(f"{len(items)} items for {len(indices)} indices")
    if not (dist.is_available() and dist.is_initialized()) or dist.get_world_size() == 1:
        return [item for _, item in sorted(zip(indices, items, strict=True), key=_first)]
    parts: list[Any] = [None] * dist.get_world_size()
    dist.all_gather_object(parts, (list(indices), list(items)))
    pairs = [pair for idx, its in parts for pair in zip(idx, its, strict=True)]
    return [item for _, item in sorted(pairs, key=_first)]


def _first(pair: tuple[int, Any]) -> int:
    return pair[0]


def barrier() -> None:
    """Wait for every rank (no-op in a single process)."""
    if dist.is_available() and dist.is_initialized():
        dist.barrier()

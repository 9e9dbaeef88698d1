"""Data-parallel training across processes (torch.distributed), as `torchrun` starts them.

    torchrun --nproc_per_node 2 -m prompose_grasp.perception.train --data DIR --out RUN --batch-size 8

Every process runs the same step loop; each step's global batch (its windows and augmentation, drawn from
`default_rng([seed, step])` as in one process) is collated on every rank and split by rank into equal
contiguous shards; the network's forward and backward, the costly part, run on the shard only. The loss of a
shard is its part of the global batch's loss (`pose_loss(..., denominators=...)`: the masked means divide by
the global batch's valid frame count, the temporal term by its window count), so the sum over ranks is the
one-process loss exactly, and DistributedDataParallel's gradient average (sum / world size) times the world
size is the one-process gradient. What differs from one process is the order of float additions only.

Backend: gloo on the CPU, nccl on CUDA devices (each rank takes `cuda:LOCAL_RANK`). Rank 0 alone writes the
checkpoint and the log; every rank reads the checkpoint to resume.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch

from prompose_grasp.errors import InvalidInputError

__all__ = ["DistributedContext", "current_context", "init_from_env"]


@dataclass(frozen=True)
class DistributedContext:
    """This process's place in the job: rank in [0, world_size); `device` the torch device it trains on."""

    rank: int
    world_size: int
    device: torch.device

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def shard(self, batch_size: int) -> tuple[int, int]:
        """[start, stop) of this rank's rows of a global batch of `batch_size` windows."""
        if batch_size % self.world_size:
            raise InvalidInputError(
                f"batch size {batch_size} does not split into {self.world_size} equal shards; give a "
                "multiple of the process count (--batch-size is the global batch)"
            )
        per = batch_size // self.world_size
        return self.rank * per, (self.rank + 1) * per

    def all_sum(self, values: dict[str, torch.Tensor]) -> dict[str, float]:
        """The sum over ranks of each scalar (one all-reduce for all of them)."""
        keys = sorted(values)
        flat = torch.stack([values[k].detach().reshape(()).to(torch.float64) for k in keys]).to(self.device)
        torch.distributed.all_reduce(flat, op=torch.distributed.ReduceOp.SUM)
        return {k: float(v) for k, v in zip(keys, flat.cpu())}

    def barrier(self) -> None:
        torch.distributed.barrier()


def _launched() -> bool:
    return int(os.environ.get("WORLD_SIZE", "1")) > 1


def init_from_env(device: str | torch.device = "cpu") -> DistributedContext | None:
    """Join the process group `torchrun` describes (RANK, WORLD_SIZE, MASTER_ADDR, MASTER_PORT, LOCAL_RANK in
    the environment); None when this process runs alone. A group already initialised is joined as it is."""
    dist = torch.distributed
    if not dist.is_available():
        if _launched():
            raise InvalidInputError("this torch build has no torch.distributed; run one process")
        return None
    if not dist.is_initialized():
        if not _launched():
            return None
        requested = torch.device(device)
        backend = "nccl" if requested.type == "cuda" else "gloo"
        if backend == "nccl":
            torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))
        dist.init_process_group(backend=backend, init_method="env://")
    return current_context(device)


def current_context(device: str | torch.device = "cpu") -> DistributedContext | None:
    """The context of an initialised process group of more than one process, else None."""
    dist = torch.distributed
    if not (dist.is_available() and dist.is_initialized()) or dist.get_world_size() < 2:
        return None
    requested = torch.device(device)
    if requested.type == "cuda":
        requested = torch.device("cuda", int(os.environ.get("LOCAL_RANK", dist.get_rank())))
    return DistributedContext(dist.get_rank(), dist.get_world_size(), requested)

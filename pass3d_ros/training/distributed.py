"""Data-parallel training under torchrun: the process group, who is who, and the few collectives the trainer uses.

`torchrun --nproc_per_node N -m pass3d_ros.tools.train ...` starts N processes with RANK, WORLD_SIZE and
LOCAL_RANK set; `setup` joins them into one process group (gloo for a CPU device, nccl for CUDA). Without
torchrun (no WORLD_SIZE, or WORLD_SIZE=1) nothing is initialised and every helper is the single-process no-op,
so a plain run is unchanged.
"""

from __future__ import annotations

import datetime
import os
from dataclasses import dataclass
from typing import Any

import torch
import torch.distributed as dist

# Rank 0 validates alone while the others wait in a collective: give it far more than gloo's 30 minutes.
TIMEOUT = datetime.timedelta(hours=4)


@dataclass(frozen=True)
class Dist:
    """This process's place in the run: rank, world size and the torch device it trains on."""

    rank: int = 0
    world: int = 1
    device: str = "cpu"

    @property
    def enabled(self) -> bool:
        """Whether several processes train together."""
        return self.world > 1

    @property
    def main(self) -> bool:
        """Whether this is the process that logs, draws progress bars and writes files."""
        return self.rank == 0


def setup(device: str) -> Dist:
    """Join the torchrun process group when there is one; the device becomes cuda:LOCAL_RANK for CUDA."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return Dist(device=device)
    cuda = device.startswith("cuda")
    if cuda:
        local = int(os.environ.get("LOCAL_RANK", "0"))
        device = f"cuda:{local}"
        torch.cuda.set_device(local)
    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if cuda else "gloo", timeout=TIMEOUT)
    return Dist(rank=dist.get_rank(), world=dist.get_world_size(), device=device)


def shutdown(ctx: Dist) -> None:
    """Leave the process group `setup` joined."""
    if ctx.enabled and dist.is_initialized():
        dist.destroy_process_group()


def all_gather(ctx: Dist, value: Any) -> list[Any]:
    """Every rank's `value` (any picklable object), in rank order."""
    if not ctx.enabled:
        return [value]
    out: list[Any] = [None] * ctx.world
    dist.all_gather_object(out, value)
    return out


def broadcast(ctx: Dist, value: Any) -> Any:
    """Rank 0's `value` on every rank."""
    if not ctx.enabled:
        return value
    box = [value]
    dist.broadcast_object_list(box, src=0)
    return box[0]


def mean(ctx: Dist, value: float) -> float:
    """The mean of `value` over the ranks."""
    if not ctx.enabled:
        return value
    tensor = torch.tensor([value], dtype=torch.float64)
    if ctx.device.startswith("cuda"):
        tensor = tensor.to(ctx.device)
    dist.all_reduce(tensor)
    return float(tensor.item()) / ctx.world


def strip_module_prefix(state_dict: dict[str, Any]) -> dict[str, Any]:
    """A state dict without DistributedDataParallel's `module.` key prefix (unchanged when it has none)."""
    if state_dict and all(k.startswith("module.") for k in state_dict):
        return {k[len("module."):]: v for k, v in state_dict.items()}
    return state_dict


def barrier(ctx: Dist) -> None:
    """Wait until every rank is here."""
    if ctx.enabled:
        dist.barrier()

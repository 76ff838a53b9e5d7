"""Data-parallel training: the process group, who is who, the few collectives the trainer uses, and a worker's life.

`pass3d_train --nproc N` (pass3d_ros.training.launcher) or `torchrun --nproc_per_node N -m pass3d_ros.tools.train
...` starts N processes with RANK, WORLD_SIZE and LOCAL_RANK set; `setup` joins them into one process group (gloo for
a CPU device, nccl for CUDA). Without a launcher (no WORLD_SIZE, or WORLD_SIZE=1) nothing is initialised and every
helper is the single-process no-op, so a plain run is unchanged. A worker's rank, whether it reports and its tie to
its launcher (it dies with it) are pass3d_ros.training.worker's, which needs no torch."""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist

from pass3d_ros.training.worker import die_with_parent, world_size

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


# What gloo's and the TCP store's errors say when the other end of a collective is gone (a plain RuntimeError).
PEER_LOSS_MARKERS = ("Connection closed by peer", "Connection reset by peer", "Broken pipe", "remote worker crashing")


def is_peer_loss(exc: BaseException) -> bool:
    """Whether `exc`, raised in a collective, means another process of the run stopped."""
    if isinstance(exc, dist.DistError):
        return True
    return isinstance(exc, RuntimeError) and any(marker in str(exc) for marker in PEER_LOSS_MARKERS)


def record_error(text: str) -> None:
    """Under torchrun, hand a silent rank's report to torchrun's failure summary (its TORCHELASTIC_ERROR_FILE)."""
    path = os.environ.get("TORCHELASTIC_ERROR_FILE")
    lines = text.strip().splitlines()
    if path and lines:
        with contextlib.suppress(OSError):
            Path(path).write_text(json.dumps({"message": lines[-1], "timestamp": int(time.time())}))


def setup(device: str) -> Dist:
    """Join the launcher's process group when there is one; the device becomes cuda:LOCAL_RANK for CUDA."""
    world = world_size()
    if world <= 1:
        return Dist(device=device)
    die_with_parent()
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

"""Multi-GPU training with DistributedDataParallel when launched by ``torchrun`` (WORLD_SIZE > 1).

Every rank builds the same model from the same seed (DDP also broadcasts rank 0's weights), draws its own
scenes from its own data generator, and averages gradients; only rank 0 writes files and shows progress.
Decisions that end the loop (time budget, Ctrl-C, a non-finite loss) are agreed by all ranks so none waits
forever on the others.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn

from insertnerf_cli.errors import UserError


@dataclass(frozen=True)
class DistContext:
    """Where this process runs: its rank among world_size processes and its device."""

    rank: int
    world_size: int
    device: torch.device

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1


def start(device: torch.device) -> DistContext:
    """Join the process group when torchrun started several processes; a single process otherwise."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistContext(0, 1, device)
    local = int(os.environ.get("LOCAL_RANK", "0"))
    if device.type == "cuda":
        if local >= torch.cuda.device_count():
            raise UserError(f"torchrun started {world} processes but only {torch.cuda.device_count()} GPU(s) are "
                            "visible; lower --nproc_per_node.")
        device = torch.device("cuda", local)
        torch.cuda.set_device(device)
    if not dist.is_initialized():
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo")
    return DistContext(dist.get_rank(), dist.get_world_size(), device)


def stop(ctx: DistContext) -> None:
    if ctx.distributed and dist.is_initialized():
        dist.destroy_process_group()


def wrap(module: nn.Module, ctx: DistContext) -> nn.Module:
    """``module`` wrapped in DistributedDataParallel when several processes train, else itself."""
    if not ctx.distributed:
        return module
    ids = [ctx.device.index] if ctx.device.type == "cuda" else None
    return nn.parallel.DistributedDataParallel(module, device_ids=ids)


def any_rank(flags: list[bool], ctx: DistContext) -> list[bool]:
    """For each flag: True on every rank when it is true on at least one."""
    if not ctx.distributed:
        return list(flags)
    value = torch.tensor([1.0 if f else 0.0 for f in flags], device=ctx.device)
    dist.all_reduce(value, op=dist.ReduceOp.MAX)
    return [bool(v > 0) for v in value.tolist()]


def barrier(ctx: DistContext) -> None:
    if ctx.distributed:
        dist.barrier()

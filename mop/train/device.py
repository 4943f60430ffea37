"""The training device and the DDP process group (torchrun sets WORLD_SIZE, RANK, LOCAL_RANK)."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

import torch
import torch.distributed as dist

from mop.config import TrainConfig
from mop.errors import MopError


def resolve_device(name: str) -> torch.device:
    """'auto' -> cuda when available else cpu; MopError for cuda without CUDA."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise MopError(f"train.device={name!r} but CUDA is not available; use train.device=cpu")
    return torch.device(name)


def init_distributed() -> tuple[int, int]:
    """(rank, world_size), initialising the process group under torchrun."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return 0, 1
    if not dist.is_initialized():
        nccl = torch.cuda.is_available() and os.environ.get("MOP_DDP_BACKEND") != "gloo"
        backend = "nccl" if nccl else "gloo"
        dist.init_process_group(backend)
    return dist.get_rank(), dist.get_world_size()


@contextlib.contextmanager
def distributed_session() -> Iterator[None]:
    """Close the process group (if one was opened inside) before the interpreter exits.

    A rank that leaves it to interpreter finalization can abort (SIGABRT): gloo's worker threads still hold
    tensors whose release needs the interpreter being torn down. So every rank waits for the others (when
    nothing failed) and then destroys the group while Python is whole.
    """
    failed = True
    try:
        yield
        failed = False
    finally:
        if dist.is_available() and dist.is_initialized():
            if not failed:
                dist.barrier()
            dist.destroy_process_group()


def setup_device(cfg: TrainConfig, world: int) -> torch.device:
    """The device of this process (cuda:LOCAL_RANK under DDP), with deterministic algorithms and TF32 set."""
    if cfg.deterministic:
        torch.use_deterministic_algorithms(True)
    device = resolve_device(cfg.device)
    if device.type == "cuda" and world > 1:
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        torch.cuda.set_device(device)
    if device.type == "cuda":
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
    return device

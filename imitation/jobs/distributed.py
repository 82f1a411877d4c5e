"""The processes of a data-parallel job under torchrun (`torchrun --nproc-per-node N -m imitation …`).

torchrun starts N copies of the command with RANK, LOCAL_RANK, WORLD_SIZE, MASTER_ADDR and
MASTER_PORT in their environment. `process_group` joins them through torch.distributed (gloo for
CPU tensors, nccl for CUDA ones) and `ProcessGroup` is what a learner calls: sums, rank 0's
values, every rank's values, and rank 0's checkpoint handed to the others. A failed collective (a
process that died, a timeout) is one line naming this rank; torchrun itself stops the other
processes when one exits with an error.

A single-process run never gets here: `world_size()` reads the environment alone.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import timedelta
from typing import TypeVar

import torch

from imitation.checkpoints import CheckpointData
from imitation.errors import ImitationError

# How long a process waits for the others at any collective, joining included, before it gives
# up with an error: long enough for a rank's share of a large dataset to load before the first
# one, short enough that a lost process does not hold the others for torch's default half hour.
TIMEOUT = timedelta(minutes=15)

T = TypeVar("T")


def world_size() -> int:
    """The processes torchrun started for this job (its WORLD_SIZE; 1 without torchrun)."""
    text = os.environ.get("WORLD_SIZE", "1")
    try:
        size = int(text)
    except ValueError:
        size = 0
    if size < 1:
        raise ImitationError(f"WORLD_SIZE must be a positive whole number (torchrun sets it), got {text!r}")
    return size


class ProcessGroup:
    """This process's view of the job's processes (the learner's `DataParallel`)."""

    def __init__(self, rank: int, world_size: int, device: torch.device) -> None:
        self.rank = rank
        self.world_size = world_size
        self.device = device  # where the backend takes tensors: the CPU for gloo, this rank's GPU for nccl

    def _collective(self, operation: Callable[[], T]) -> T:
        try:
            return operation()
        except RuntimeError as error:  # torch.distributed's errors (DistBackendError, timeouts) derive from it
            detail = (str(error).strip().splitlines() or [type(error).__name__])[0]
            raise ImitationError(
                f"torchrun rank {self.rank}: lost the other processes ({detail}); another rank's error above says why"
            ) from None

    def _on_backend(self, tensor: torch.Tensor, operation: Callable[[torch.Tensor], None]) -> None:
        """`operation` in place on `tensor`, through a copy on the backend's device where it lies elsewhere."""
        if tensor.device == self.device and tensor.is_contiguous():
            self._collective(lambda: operation(tensor))
            return
        staged = tensor.to(self.device).contiguous()
        self._collective(lambda: operation(staged))
        tensor.copy_(staged)

    def all_sum(self, tensor: torch.Tensor) -> None:
        import torch.distributed as dist

        self._on_backend(tensor, lambda t: dist.all_reduce(t, op=dist.ReduceOp.SUM))

    def broadcast(self, tensor: torch.Tensor) -> None:
        import torch.distributed as dist

        self._on_backend(tensor, lambda t: dist.broadcast(t, src=0))

    def all_gather(self, tensor: torch.Tensor) -> torch.Tensor:
        import torch.distributed as dist

        staged = tensor.to(self.device).contiguous()
        gathered = [torch.empty_like(staged) for _ in range(self.world_size)]
        self._collective(lambda: dist.all_gather(gathered, staged))
        return torch.stack(gathered).to(tensor.device)

    def any(self, flag: bool) -> bool:
        """Whether `flag` holds on some process (every process gets the same answer)."""
        votes = torch.tensor([int(flag)], dtype=torch.int64)
        self.all_sum(votes)
        return bool(votes.item())

    def broadcast_checkpoint(self, checkpoint: CheckpointData | None) -> CheckpointData | None:
        """Rank 0's checkpoint (the one it resumes from, or None) on every process: a JSON header
        of the state and the tensors' names, dtypes and shapes, then each tensor. JSON rather than
        torch's pickled objects: nothing a process receives is unpickled."""
        header = b""
        if self.rank == 0:
            described = None
            if checkpoint is not None:
                tensors, state = checkpoint
                described = {
                    "state": state,
                    "tensors": [[name, str(t.dtype).removeprefix("torch."), list(t.shape)] for name, t in tensors.items()],
                }
            header = json.dumps(described).encode()
        size = torch.tensor([len(header)], dtype=torch.int64)
        self.broadcast(size)
        encoded = (
            torch.frombuffer(bytearray(header), dtype=torch.uint8)
            if self.rank == 0
            else torch.empty(int(size), dtype=torch.uint8)
        )
        self.broadcast(encoded)
        described = json.loads(bytes(encoded.numpy()).decode())
        if described is None:
            return None
        received: dict[str, torch.Tensor] = {}
        for name, dtype, shape in described["tensors"]:
            if self.rank == 0:
                assert checkpoint is not None  # rank 0 described it
                tensor = checkpoint[0][name].detach().clone().contiguous()
            else:
                tensor = torch.empty(shape, dtype=getattr(torch, dtype))
            self.broadcast(tensor)
            received[name] = tensor
        return received, described["state"]


@contextmanager
def process_group(device: torch.device) -> Iterator[ProcessGroup]:
    """This process joined to the others torchrun started (see the module docstring), for the block."""
    import torch.distributed as dist

    rank, size = int(os.environ.get("RANK", "0")), world_size()
    if device.type == "cuda":
        torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))
        device = torch.device("cuda", torch.cuda.current_device())
    try:
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo", timeout=TIMEOUT)
    except (RuntimeError, ValueError) as error:
        detail = (str(error).strip().splitlines() or [type(error).__name__])[0]
        raise ImitationError(f"torchrun rank {rank}: cannot join the other {size - 1} process(es) ({detail})") from None
    try:
        yield ProcessGroup(rank, size, device)
    finally:
        dist.destroy_process_group()

"""Checkpoints that let an interrupted training run continue: what trainers save, and how Ctrl-C
stops them at a point where the state is whole.

A checkpoint is a pair (tensors, state): tensors go to a safetensors file, everything else
(counters, logs, optimiser settings, random-generator positions) to JSON; nothing is pickled.
The run directory writes them (`imitation.runs.RunWriter.save_checkpoint`); trainers build and
restore them with the helpers here:

- `prefixed` / `unprefixed`: one part's tensors (a network, a pool of samples) among the rest;
- `optimizer_checkpoint` / `restore_optimizer`: an optimiser's per-parameter tensors and its
  parameter groups;
- `rng_checkpoint` / `restore_rng`: torch's CPU generator and numpy's global one;
- `Checkpointing`: what a trainer is handed: where to save, how often, and what to resume from;
- `StopAtBoundary`: defers Ctrl-C (SIGINT) to the end of the current update or epoch, where the
  trainer saves a checkpoint and raises `TrainingInterrupted`; a second Ctrl-C stops at once;
- `Checkpointable`: a hook with state of its own inside a trainer (GCL's reward learner inside
  PPO), which the trainer saves and restores with its own, in the same checkpoint.

Trainers that checkpoint, and where: PPO after an update (with GCL's reward learner when it is
the rollout hook), BC after an epoch, DAgger after a round, tabular MaxEnt/MCE IRL after an
iteration.
"""

from __future__ import annotations

import json
import signal
import threading
from dataclasses import dataclass
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np
import torch

from imitation.errors import ImitationError

Tensors = dict[str, torch.Tensor]
CheckpointData = tuple[Tensors, dict[str, Any]]


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped training after a checkpoint was saved; the message says how to resume."""


@dataclass
class Checkpointing:
    """`save(tensors, state)` every `every` updates or epochs (None: every tenth of the run) and
    when interrupted; `resume`, when given, is the checkpoint to continue from."""

    save: Callable[[Tensors, dict[str, Any]], None]
    every: int | None = None
    resume: CheckpointData | None = None

    def interval(self, total: int) -> int:
        return self.every if self.every is not None else max(1, total // 10)


class StopAtBoundary:
    """Within the block, Ctrl-C only sets `requested`; the trainer checks it between updates.
    The first Ctrl-C restores the previous handler, so a second one interrupts immediately.
    Outside the main thread (where signal handlers cannot be set) it does nothing."""

    def __init__(self, *, enabled: bool = True) -> None:
        self.requested = False
        self._enabled = enabled
        self._previous: Any = None
        self._active = False

    def _handle(self, signum: int, frame: Any) -> None:
        self.requested = True
        signal.signal(signal.SIGINT, self._previous)

    def __enter__(self) -> StopAtBoundary:
        if self._enabled and threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
            self._active = True
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._active:
            signal.signal(signal.SIGINT, self._previous)


@runtime_checkable
class Checkpointable(Protocol):
    """State a trainer does not own but must save to resume exactly (see the module docstring)."""

    def checkpoint(self) -> CheckpointData: ...

    def restore(self, checkpoint: CheckpointData) -> None: ...


def prefixed(prefix: str, tensors: Tensors) -> Tensors:
    """`tensors` named `prefix.name`, to sit beside other parts' in one checkpoint."""
    return {f"{prefix}.{name}": tensor for name, tensor in tensors.items()}


def unprefixed(prefix: str, tensors: Tensors) -> Tensors:
    """The tensors `prefixed(prefix, ...)` named, under their own names again."""
    return {name.removeprefix(prefix + "."): tensor for name, tensor in tensors.items() if name.startswith(prefix + ".")}


def optimizer_checkpoint(optimizer: torch.optim.Optimizer, prefix: str) -> CheckpointData:
    """An optimiser's state: per-parameter tensors (Adam's step, moments) as `prefix.i.name`,
    parameter groups as JSON."""
    state = optimizer.state_dict()
    tensors = {f"{prefix}.{index}.{name}": value for index, values in state["state"].items() for name, value in values.items()}
    return tensors, {"param_groups": state["param_groups"]}


def restore_optimizer(optimizer: torch.optim.Optimizer, tensors: Tensors, state: dict[str, Any], prefix: str) -> None:
    per_parameter: dict[int, dict[str, torch.Tensor]] = {}
    for key, value in tensors.items():
        if key.startswith(prefix + "."):
            index, name = key[len(prefix) + 1 :].split(".", 1)
            per_parameter.setdefault(int(index), {})[name] = value
    optimizer.load_state_dict({"state": per_parameter, "param_groups": state["param_groups"]})


def rng_checkpoint() -> CheckpointData:
    """The positions of torch's CPU generator and numpy's global generator."""
    kind, keys, position, has_gauss, cached = np.random.get_state()
    tensors = {"rng.torch": torch.get_rng_state(), "rng.numpy": torch.from_numpy(keys.astype(np.int64))}
    return tensors, {"numpy": {"kind": kind, "position": int(position), "has_gauss": int(has_gauss), "cached_gaussian": float(cached)}}


def restore_rng(tensors: Tensors, state: dict[str, Any]) -> None:
    torch.set_rng_state(tensors["rng.torch"])
    numpy = state["numpy"]
    keys = tensors["rng.numpy"].numpy().astype(np.uint32)
    np.random.set_state((numpy["kind"], keys, numpy["position"], numpy["has_gauss"], numpy["cached_gaussian"]))


def checked_counter(value: int, name: str, first: int, last: int) -> int:
    """A counter read from a checkpoint (the next epoch, round, update), which must lie in
    [first, last]: a damaged or edited checkpoint must not make a run loop for ever."""
    if not first <= value <= last:
        raise ImitationError(f"the checkpoint's {name} is {value}, outside {first}..{last} for this run: damaged or edited; start again without --resume")
    return value


def snapshot(tensors: Tensors, state: dict[str, Any]) -> CheckpointData:
    """Copies that later training does not change (state_dict tensors and logs are live)."""
    return {name: tensor.detach().clone() for name, tensor in tensors.items()}, json.loads(json.dumps(state))


def floats(row: dict[str, Any]) -> dict[str, float]:
    """A logged row back from JSON, where non-finite numbers were written as null."""
    return {key: float("nan") if value is None else float(value) for key, value in row.items()}

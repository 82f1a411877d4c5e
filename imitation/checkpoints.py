"""The pieces learners build their checkpoints from, and restore them with.

A checkpoint is a pair (tensors, state): tensors go to a safetensors file, everything else
(counters, optimiser settings, random-generator positions) to JSON; nothing is pickled. Each
learner's `state_dict()` assembles one from these helpers and `load_state_dict()` reads it back;
the training loop (`imitation.jobs.loop`) decides when to save and resume:

- `prefixed` / `unprefixed`: one part's tensors (a network, a pool of samples) among the rest;
- `optimizer_checkpoint` / `restore_optimizer`: an optimiser's per-parameter tensors and its
  parameter groups;
- `rng_checkpoint` / `restore_rng`: torch's CPU generator and numpy's global one;
- `restoring`: turns what a checkpoint that does not fit raises into one line;
- `checked_counter`: a counter read back must lie in the run's range.

A learner uses them through `CheckpointWriter` (its `state_dict()` adds its parts one by one) and
`CheckpointReader` (its `load_state_dict()` reads them back inside `restoring`), which keep the
names every learner shares: "optimizer", "rng" and "seconds".
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import torch

from imitation.errors import ImitationError
from imitation.flat_adam import FlatAdam

Tensors = dict[str, torch.Tensor]
CheckpointData = tuple[Tensors, dict[str, Any]]


@contextmanager
def restoring(what: str) -> Iterator[None]:
    """Around a `load_state_dict`: a checkpoint of another run (edited, damaged, another
    configuration) fails as one line naming `what` kind of run it does not fit."""
    try:
        yield
    except (KeyError, TypeError, ValueError, RuntimeError) as error:
        detail = (str(error).splitlines() or [""])[0]
        raise ImitationError(f"the checkpoint does not fit this {what} run ({type(error).__name__}: {detail})") from None


def prefixed(prefix: str, tensors: Tensors) -> Tensors:
    """`tensors` named `prefix.name`, to sit beside other parts' in one checkpoint."""
    return {f"{prefix}.{name}": tensor for name, tensor in tensors.items()}


def unprefixed(prefix: str, tensors: Tensors) -> Tensors:
    """The tensors `prefixed(prefix, ...)` named, under their own names again."""
    return {name.removeprefix(prefix + "."): tensor for name, tensor in tensors.items() if name.startswith(prefix + ".")}


def optimizer_checkpoint(optimizer: torch.optim.Optimizer | FlatAdam, prefix: str) -> CheckpointData:
    """An optimiser's state: per-parameter tensors (Adam's step, moments) as `prefix.i.name`,
    parameter groups as JSON."""
    state = optimizer.state_dict()
    tensors = {f"{prefix}.{index}.{name}": value for index, values in state["state"].items() for name, value in values.items()}
    return tensors, {"param_groups": state["param_groups"]}


def restore_optimizer(
    optimizer: torch.optim.Optimizer | FlatAdam, tensors: Tensors, state: dict[str, Any], prefix: str
) -> None:
    per_parameter: dict[int, dict[str, torch.Tensor]] = {}
    for key, value in tensors.items():
        if key.startswith(prefix + "."):
            index, name = key[len(prefix) + 1 :].split(".", 1)
            per_parameter.setdefault(int(index), {})[name] = value
    optimizer.load_state_dict({"state": per_parameter, "param_groups": state["param_groups"]})


def rng_checkpoint() -> CheckpointData:
    """The positions of torch's CPU generator and numpy's global generator."""
    state = np.random.get_state(legacy=True)  # the default; numpy's stub types the call without it as the dict form
    assert isinstance(state, tuple)  # the legacy form: the global generator is an MT19937
    kind, keys, position, has_gauss, cached = state
    tensors = {"rng.torch": torch.get_rng_state(), "rng.numpy": torch.from_numpy(keys.astype(np.int64))}
    return tensors, {
        "numpy": {"kind": kind, "position": int(position), "has_gauss": int(has_gauss), "cached_gaussian": float(cached)}
    }


def restore_rng(tensors: Tensors, state: dict[str, Any]) -> None:
    torch.set_rng_state(tensors["rng.torch"])
    numpy = state["numpy"]
    keys = tensors["rng.numpy"].numpy().astype(np.uint32)
    np.random.set_state((numpy["kind"], keys, numpy["position"], numpy["has_gauss"], numpy["cached_gaussian"]))


def checked_counter(value: int, name: str, first: int, last: int) -> int:
    """A counter read from a checkpoint (the next epoch, round, update), which must lie in
    [first, last]: a damaged or edited checkpoint must not make a run loop for ever."""
    if not first <= value <= last:
        raise ImitationError(
            f"the checkpoint's {name} is {value}, outside {first}..{last} for this run: damaged or edited; start again "
            "without --resume"
        )
    return value


def snapshot(tensors: Tensors, state: dict[str, Any]) -> CheckpointData:
    """Copies that later training does not change (state_dict tensors and logs are live)."""
    return {name: tensor.detach().clone() for name, tensor in tensors.items()}, json.loads(json.dumps(state))


def floats(row: dict[str, Any]) -> dict[str, float]:
    """A logged row back from JSON, where non-finite numbers were written as null."""
    return {key: float("nan") if value is None else float(value) for key, value in row.items()}


class TrainingClock:
    """Seconds of training across resumes: those a checkpoint recorded plus this process's,
    counted from `start()` (the first step)."""

    def __init__(self) -> None:
        self.before = 0.0
        self._started: float | None = None

    def start(self) -> None:
        if self._started is None:
            self._started = time.perf_counter()

    @property
    def seconds(self) -> float:
        return self.before + (time.perf_counter() - self._started if self._started is not None else 0.0)


def flat_names(trees: dict[str, Any]) -> Tensors:
    """Trees of tensors as one flat name → tensor map for a checkpoint: a dict leaf `key` of `name` is `name.key`."""
    flat: Tensors = {}
    for name, tree in trees.items():
        if isinstance(tree, dict):
            flat |= prefixed(name, flat_names(tree))
        else:
            flat[name] = tree
    return flat


def tree_of_names(flat: Tensors) -> dict[str, Any]:
    """`flat_names` undone."""
    trees: dict[str, Any] = {}
    for name, tensor in flat.items():
        *path, leaf = name.split(".")
        node = trees
        for key in path:
            node = node.setdefault(key, {})
        node[leaf] = tensor
    return trees


class CheckpointWriter:
    """A learner's checkpoint assembled part by part: networks and tensors under a prefix each,
    optimisers, the random generators, the training clock, and JSON state."""

    def __init__(self, **state: Any) -> None:
        self.tensors: Tensors = {}
        self.state: dict[str, Any] = dict(state)

    def module(self, name: str, tensors: Tensors) -> None:
        """A part's tensors (a state dict), named `name.…`."""
        self.tensors |= prefixed(name, tensors)

    def optimizer(self, optimizer: torch.optim.Optimizer | FlatAdam, name: str = "optimizer") -> None:
        tensors, self.state[name] = optimizer_checkpoint(optimizer, name)
        self.tensors |= tensors

    def rng(self) -> None:
        """torch's CPU generator and numpy's global one, where they are now."""
        tensors, self.state["rng"] = rng_checkpoint()
        self.tensors |= tensors

    def clock(self, clock: TrainingClock) -> None:
        self.state["seconds"] = clock.seconds

    def data(self) -> CheckpointData:
        return self.tensors, self.state


class CheckpointReader:
    """A checkpoint read back part by part (what `CheckpointWriter` wrote), as a context: inside
    it, a checkpoint that does not fit this `what` run fails in one line (`restoring`)."""

    def __init__(self, checkpoint: CheckpointData, what: str) -> None:
        self.tensors, self.state = checkpoint
        self._restoring = restoring(what)

    def __enter__(self) -> CheckpointReader:
        self._restoring.__enter__()
        return self

    def __exit__(self, *exc: Any) -> bool | None:
        return self._restoring.__exit__(*exc)

    def module(self, name: str) -> Tensors:
        """The tensors `CheckpointWriter.module(name, …)` wrote, under their own names."""
        return unprefixed(name, self.tensors)

    def optimizer(self, optimizer: torch.optim.Optimizer | FlatAdam, name: str = "optimizer") -> None:
        restore_optimizer(optimizer, self.tensors, self.state[name], name)

    def rng(self) -> None:
        restore_rng(self.tensors, self.state["rng"])

    def clock(self, clock: TrainingClock) -> None:
        clock.before = float(self.state["seconds"])

    def counter(self, key: str, name: str, first: int, last: int, *, default: int | None = None) -> int:
        """The counter saved as `key` (`default` where a checkpoint may lack it), refused outside
        [first, last] (`checked_counter`)."""
        value = self.state[key] if default is None else self.state.get(key, default)
        return checked_counter(int(value), name, first, last)

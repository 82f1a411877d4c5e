"""Demos → torch: contiguous transition tensors, episode-wise train/validation splits, minibatches.

Typical use::

    dataset = DemoDataset(["cartpole.mcap"])
    train_ids, val_ids = split_episodes(len(dataset), validation_fraction=0.2, seed=0)
    train = transitions_to_torch(load_transitions(dataset, episodes=train_ids), "cuda")
    for batch in MinibatchLoader(train, batch_size=256, seed=0):
        loss = policy_loss(batch.observations, batch.actions)
"""

from __future__ import annotations

import math
import os
import resource
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import torch

from imitation.data.columns import read_transitions
from imitation.data.dataset import DemoDataset
from imitation.data.frame_transform import FrameTransform
from imitation.data.spaces import space_leaves
from imitation.data.types import Episode, Transitions, episodes_to_transitions, first_nonfinite
from imitation.errors import ImitationError
from imitation.tensors import TensorTree, resolve_device, tree_map


@dataclass(frozen=True, kw_only=True)
class TransitionTensors:
    """Transitions as torch tensors on one device; Dict observations/actions are dicts of tensors."""

    observations: TensorTree
    actions: TensorTree
    rewards: torch.Tensor
    next_observations: TensorTree | None
    terminated: torch.Tensor
    truncated: torch.Tensor
    episode_index: torch.Tensor

    def __len__(self) -> int:
        return len(self.rewards)

    @property
    def device(self) -> torch.device:
        return self.rewards.device

    def to(self, device: str | torch.device) -> TransitionTensors:
        device = resolve_device(device)
        return TransitionTensors(**{f.name: tree_map(lambda t: t.to(device), getattr(self, f.name)) for f in fields(self)})

    def select(self, index: torch.Tensor) -> TransitionTensors:
        """The transitions at `index` (a long tensor on this device), as new tensors."""
        if index.device.type == "cpu" and index.dtype in (torch.int64, torch.int32) and index.dim() == 1:
            rows = index.numpy()
            return TransitionTensors(
                **{f.name: tree_map(lambda t: _take_rows(t, rows, index), getattr(self, f.name)) for f in fields(self)}
            )
        return TransitionTensors(**{f.name: tree_map(lambda t: t[index], getattr(self, f.name)) for f in fields(self)})


def _take_rows(tensor: torch.Tensor, rows: np.ndarray, index: torch.Tensor) -> torch.Tensor:
    """`tensor[index]` for a CPU tensor, the same values in a new tensor: numpy's take copies
    each row whole, where torch's advanced indexing of a uint8 image batch goes element by
    element, several times slower (bench/RESULTS.md). The RNG stream and the rows chosen are the
    caller's."""
    if (
        tensor.device.type != "cpu"
        or tensor.requires_grad
        or tensor.dim() == 0
        or tensor.dtype not in _NUMPY_DTYPES
        or tensor.is_conj()
        or tensor.is_neg()
    ):
        return tensor[index]
    return torch.from_numpy(np.take(tensor.numpy(), rows, axis=0))


_NUMPY_DTYPES = {
    torch.bool,
    torch.uint8,
    torch.int8,
    torch.int16,
    torch.int32,
    torch.int64,
    torch.float16,
    torch.float32,
    torch.float64,
    torch.complex64,
    torch.complex128,
}


def transitions_to_torch(transitions: Transitions, device: str | torch.device = "cpu") -> TransitionTensors:
    """Zero-copy on CPU (the tensors share the numpy arrays' memory); one copy to a GPU."""
    target = resolve_device(device)

    def convert(array: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(array)).to(target)

    return TransitionTensors(**{f.name: tree_map(convert, getattr(transitions, f.name)) for f in fields(transitions)})


def load_episodes(
    source: DemoDataset | Sequence[str | os.PathLike] | str | os.PathLike,
    *,
    episodes: Sequence[int] | None = None,
) -> list[Episode]:
    """The chosen episodes (all by default), in ascending order, each chunk read once."""
    dataset = source if isinstance(source, DemoDataset) else DemoDataset(source)
    return _read(dataset, episodes)


def _read(dataset: DemoDataset, episodes: Sequence[int] | None, transform: FrameTransform | None = None) -> list[Episode]:
    try:
        return dataset.read_episodes(episodes, transform=transform)
    except IndexError as error:
        raise ImitationError(str(error)) from None


def load_transitions(
    source: DemoDataset | Sequence[str | os.PathLike] | str | os.PathLike,
    *,
    episodes: Sequence[int] | None = None,
    next_observations: bool = True,
    finite: bool = True,
    too_large: str = "train on fewer demo files, or on a machine with more memory",
    transform: FrameTransform | None = None,
    progress: Callable[[int], None] | None = None,
) -> Transitions:
    """All transitions of the chosen episodes as one contiguous numpy batch.

    Leave out `next_observations` when the learner does not need s': it is a second copy of
    the observations. With `finite` (the default), NaN or ±inf anywhere in the observations,
    actions or rewards is an ImitationError naming the file, episode and step (see
    `check_finite`). A batch larger than the memory available is refused before it is
    allocated, the error ending in `too_large` (what the caller's user can do about it).

    With `transform`, every frame of the observations' image leaves is cropped and resized as
    it is decoded (`FrameTransform`), so that no more than a frame is held at its stored size.
    `progress(n)` is told of observations loaded (each episode's steps and its final
    observation), possibly from other threads."""
    dataset = source if isinstance(source, DemoDataset) else DemoDataset(source)
    indices = sorted(set(int(k) for k in episodes)) if episodes is not None else list(range(len(dataset)))
    if indices and not 0 <= indices[0] <= indices[-1] < len(dataset):
        raise ImitationError(f"episode indices must lie in [0, {len(dataset)}), got {indices[0]}..{indices[-1]}")
    all_facts = dataset.episodes
    steps = sum(all_facts[k].length for k in indices)
    if steps == 0:
        raise ImitationError("no transitions to load: the demos hold no steps")
    _check_memory(dataset, steps, len(indices), next_observations=next_observations, too_large=too_large, transform=transform)
    transitions = read_transitions(
        dataset, indices, next_observations=next_observations, transform=transform, progress=progress
    )
    if transitions is None and transform is not None:
        transitions = episodes_to_transitions(
            list(_transformed_episodes(dataset, indices, transform, progress)), indices, next_observations=next_observations
        )
    elif transitions is None:
        transitions = episodes_to_transitions(_read(dataset, indices), indices, next_observations=next_observations)
        if progress is not None:
            progress(steps + len(indices))
    if finite:
        check_finite(transitions, dataset)
    return transitions


def human_steps(dataset: DemoDataset, episodes: Sequence[int], *, unrecorded: bool | None = None) -> np.ndarray:
    """Per transition of `episodes`, in `load_transitions`' order: whether a person (the expert)
    drove it, from the episodes' intervention channels. An episode without them counts as
    `unrecorded` throughout (True for demos the expert recorded alone); None makes it an error."""
    indices = sorted(set(int(k) for k in episodes))
    masks = []
    for k, episode in zip(indices, _read(dataset, indices)):
        if episode.interventions is not None:
            masks.append(episode.interventions.human)
        elif unrecorded is None:
            file, local = dataset.locate(k)
            raise ImitationError(
                f"{file.path}: episode {local} does not record who drove it (no /intervention channels); "
                "only the rounds of DAgger write them"
            )
        else:
            masks.append(np.full(len(episode), unrecorded))
    return np.concatenate(masks) if masks else np.zeros(0, dtype=bool)


def select_human_steps(
    transitions: TransitionTensors, dataset: DemoDataset, episodes: Sequence[int], *, unrecorded: bool | None = None
) -> TransitionTensors:
    """Of `transitions` (episodes `episodes` as `load_transitions` gave them), those a person drove
    (see `human_steps`)."""
    return transitions.select(torch.from_numpy(np.flatnonzero(human_steps(dataset, episodes, unrecorded=unrecorded))))


def _transformed_episodes(
    dataset: DemoDataset, indices: Sequence[int], transform: FrameTransform, progress: Callable[[int], None] | None
) -> Iterator[Episode]:
    """Episodes `indices`, read one at a time, their frames transformed as they are decoded."""
    for k in indices:
        (episode,) = _read(dataset, [k], transform)
        yield episode
        if progress is not None:
            progress(len(episode) + 1)


def _check_memory(
    dataset: DemoDataset,
    steps: int,
    episodes: int,
    *,
    next_observations: bool,
    too_large: str,
    transform: FrameTransform | None = None,
) -> None:
    """Refuse, before allocating, a load that cannot fit in the memory this machine has free:
    one line naming the size, instead of an out-of-memory kill or traceback midway. With
    `transform` the observations are counted at their transformed size."""
    space = dataset.observation_space
    observation_row = (
        transform.row_bytes(space)
        if transform is not None
        else sum(dtype.itemsize * math.prod(shape) for _, dtype, shape in space_leaves(space))
    )
    action_row = sum(dtype.itemsize * math.prod(shape) for _, dtype, shape in space_leaves(dataset.action_space))
    # observations and final rows, s' if asked for, actions, rewards, the two flags, episode indices
    needed = (
        (steps + episodes) * observation_row
        + (steps * observation_row if next_observations else 0)
        + steps * (action_row + 8 + 2 + 8)
    )
    available = available_memory()
    if available is not None and needed > available:
        raise ImitationError(
            f"{dataset.files[0].path}: loading {steps} transitions ({len(dataset.files)} file(s)) needs {needed / 2**30:.1f} "
            f"GiB of memory and {available / 2**30:.1f} GiB is available; {too_large}"
        )


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux's MemAvailable, bounded by what an
    address-space limit, if one is set, leaves beyond the address space this process already
    maps); None where it cannot be told."""
    found = _proc_kilobytes("/proc/meminfo", "MemAvailable:")
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        found.append(max(0, soft - sum(_proc_kilobytes("/proc/self/status", "VmSize:"))))
    return min(found) if found else None


def _proc_kilobytes(path: str, key: str) -> list[int]:
    """The bytes of the "`key` N kB" lines of a /proc file (none where it cannot be read)."""
    try:
        with open(path) as stream:
            return [int(line.split()[1]) * 1024 for line in stream if line.startswith(key)]
    except (OSError, ValueError, IndexError):
        return []


def check_finite(transitions: Transitions, dataset: DemoDataset) -> None:
    """One vectorised pass over every float field; the first NaN or ±inf is reported with its
    file, episode (within that file) and step, so a learner never trains on it."""
    candidates = []
    for what, tree, shift in (
        ("observation", transitions.observations, 0),
        ("action", transitions.actions, 0),
        ("reward", transitions.rewards, 0),
        ("observation", transitions.next_observations, 1),  # s' of transition t is observation t + 1
    ):
        if tree is not None and (found := first_nonfinite(tree, what)) is not None:
            candidates.append((found[0], shift, found[1], found[2]))
    if not candidates:
        return
    row, shift, name, value = min(candidates)
    episode = int(transitions.episode_index[row])
    raise _nonfinite_error(
        dataset, episode, row - int(np.searchsorted(transitions.episode_index, episode)) + shift, name, value
    )


def check_episodes_finite(episodes: Sequence[Episode], dataset: DemoDataset, indices: Sequence[int] | None = None) -> None:
    """`check_finite` for whole episodes (dataset-wide `indices`, all by default): one
    vectorised pass per episode and field."""
    for k, episode in zip(range(len(episodes)) if indices is None else indices, episodes):
        for what, tree in (("observation", episode.observations), ("action", episode.actions), ("reward", episode.rewards)):
            if (found := first_nonfinite(tree, what)) is not None:
                raise _nonfinite_error(dataset, int(k), *found)


def _nonfinite_error(dataset: DemoDataset, episode: int, step: int, name: str, value: float) -> ImitationError:
    """The error for a NaN or ±inf at dataset-wide `episode`, named by its file and place there."""
    demo, local = dataset.locate(episode)
    return ImitationError(
        f"{demo.path}: episode {local}, step {step}: the {name} is {value}; "
        "learners need finite observations, actions and rewards (fix the source and write the file again)"
    )


def split_episodes(num_episodes: int, *, validation_fraction: float, seed: int) -> tuple[list[int], list[int]]:
    """Shuffle episode indices with `seed` and split them: whole episodes go to one side only,
    so validation measures generalisation to unseen trajectories, not to neighbouring steps.
    At least one episode stays in training; validation gets round(fraction·n) episodes."""
    if not 0.0 <= validation_fraction < 1.0:
        raise ImitationError(f"validation fraction must be in [0, 1), got {validation_fraction}")
    order = np.random.default_rng(seed).permutation(num_episodes)
    num_validation = min(int(round(validation_fraction * num_episodes)), max(num_episodes - 1, 0))
    return sorted(order[num_validation:].tolist()), sorted(order[:num_validation].tolist())


def split_episode_tails(transitions: Transitions, *, validation_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices of training and validation transitions for data with too few episodes to hold
    whole ones out (one long recording): the last round(fraction·T) steps of each episode are
    validation. The held-out block is contiguous, so only its first step neighbours training
    data; each episode keeps at least one training step."""
    if not 0.0 <= validation_fraction < 1.0:
        raise ImitationError(f"validation fraction must be in [0, 1), got {validation_fraction}")
    starts = np.flatnonzero(np.diff(transitions.episode_index, prepend=transitions.episode_index[:1] - 1) != 0)
    ends = np.append(starts[1:], len(transitions))
    validation = np.zeros(len(transitions), dtype=bool)
    for start, end in zip(starts, ends):
        held = min(int(round(validation_fraction * (end - start))), end - start - 1)
        validation[end - held : end] = held > 0
    return np.flatnonzero(~validation), np.flatnonzero(validation)


class MinibatchLoader:
    """Minibatches of transitions, reshuffled every epoch from a seeded generator.

    An epoch is one pass over the data, or as many passes (each in its own order) as it takes to
    reach `min_samples` samples; or, with `steps`, exactly that many full batches, from as many
    passes as they take (the last one cut short): the processes of a data-parallel run must all
    take the same number of steps on shares of different sizes. Indexing happens on the tensors'
    device, so once the data is on a GPU no batch crosses the bus. `gather(rows)` makes a batch of
    the rows drawn (default: those transitions; `imitation.data.windows` gathers windows).
    """

    def __init__(
        self,
        data: TransitionTensors,
        *,
        batch_size: int,
        shuffle: bool = True,
        seed: int = 0,
        drop_last: bool = False,
        min_samples: int = 0,
        steps: int | None = None,
        gather: Callable[[torch.Tensor], Any] | None = None,
    ) -> None:
        if batch_size < 1:
            raise ImitationError(f"batch size must be positive, got {batch_size}")
        self.data = data
        self.batch_size = batch_size
        self.shuffle = shuffle
        self.drop_last = drop_last
        self.steps = steps
        self.gather = gather or data.select
        wanted = min_samples if steps is None else steps * batch_size
        self.passes = max(1, -(-wanted // max(1, len(data))))
        self._generator = torch.Generator(device="cpu").manual_seed(seed)

    def generator_state(self) -> torch.Tensor:
        """Where the shuffling generator is (for checkpoints)."""
        return self._generator.get_state()

    def set_generator_state(self, state: torch.Tensor) -> None:
        self._generator.set_state(state)

    def __len__(self) -> int:
        if self.steps is not None:
            return self.steps
        full, rest = divmod(self.passes * len(self.data), self.batch_size)
        return full if self.drop_last or rest == 0 else full + 1

    def __iter__(self) -> Iterator[Any]:
        return self.batches()

    def batches(self, skip: int = 0) -> Iterator[Any]:
        """An epoch's batches, the first `skip` of them left out (an epoch resumed midway: the
        order is drawn as for the whole epoch, and the batches left out are never gathered)."""
        count = len(self.data)
        if self.shuffle:
            order = torch.cat([torch.randperm(count, generator=self._generator) for _ in range(self.passes)]).to(
                self.data.device
            )
        else:
            order = torch.arange(count, device=self.data.device).repeat(self.passes)
        if self.steps is not None:
            order = order[: self.steps * self.batch_size]
        for start in range(skip * self.batch_size, len(order), self.batch_size):
            index = order[start : start + self.batch_size]
            if self.drop_last and len(index) < self.batch_size:
                break
            yield self.gather(index)


__all__ = [
    "MinibatchLoader",
    "TransitionTensors",
    "load_episodes",
    "load_transitions",
    "split_episode_tails",
    "split_episodes",
    "transitions_to_torch",
]

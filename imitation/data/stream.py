"""Streaming minibatches for datasets larger than memory: decoded episodes pass through a shuffle
buffer bounded in bytes, and batches are drawn from it while worker threads decode ahead.

Each epoch (seeded, reproducible):

1. the chosen episodes are put in a random order (one permutation per pass);
2. `workers` threads decode them in that order (Pillow and zlib release the GIL), as far ahead as
   the memory budget allows;
3. a producer thread copies decoded rows into a preallocated buffer of half the budget — image
   leaves already stacked with their episode's previous frames (`stack_frames`' semantics, so no
   stack crosses an episode boundary) — and draws each minibatch uniformly from the rows buffered,
   which mixes many episodes in every batch;
4. the learner takes ready batches from a short queue and only waits when decoding falls behind
   (`wait_seconds` counts it).

With a `window` (a sequence policy's), each buffered row is a window of its episode instead of one
transition: the n observations up to the row and the H actions from it, padded at the episode's
edges with their masks (`imitation.data.windows`), gathered when the episode enters the buffer,
so that a window never crosses episodes and batches are `WindowBatch`es.

Memory held at once (`peak_bytes`): the buffer plus the decoded episodes waiting for it stays
within `memory` plus one episode (the last admitted may overshoot), counted at the size the
learner takes its frames (`transform`). The content of every batch
depends on the seed alone, never on thread timing: episodes enter the buffer in permutation
order, and rows are drawn from a numpy generator seeded from the epoch's torch generator.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections import deque
from collections.abc import Generator, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import closing
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from imitation.data.dataset import DemoDataset
from imitation.data.frame_transform import FrameTransform
from imitation.data.loader import TransitionTensors, check_episodes_finite, transitions_to_torch
from imitation.data.spaces import LeafPath, space_leaves
from imitation.data.types import Transitions, episodes_to_transitions, tree_from_leaves, tree_leaves
from imitation.data.windows import WindowBatch, WindowSpec, window_index
from imitation.envs.pixels import frame_stack_index
from imitation.errors import ImitationError
from imitation.tensors import tree_map

_QUEUE_BATCHES = 4  # batches assembled ahead of the learner: enough to hide a slow refill
_POLL_SECONDS = 0.1  # how often a blocked producer checks whether the consumer has gone


@dataclass(frozen=True)
class _Leaf:
    """One array of a buffered row: which field and leaf it is, its row shape and dtype, and
    which of the episode's rows it gathers (`_Gathers`: "frames", "history", "chunk"; None for
    the row itself; a pad mask is taken whole from the episode's windows)."""

    field: str
    path: LeafPath
    shape: tuple[int, ...]
    dtype: np.dtype
    gathers: str | None = None

    @property
    def row_bytes(self) -> int:
        return self.dtype.itemsize * math.prod(self.shape)

    @property
    def decoded_row_bytes(self) -> int:
        """What one decoded transition holds of this leaf (a gathered row's one entry; a mask nothing)."""
        if self.field in _PAD_FIELDS:
            return 0
        return self.dtype.itemsize * math.prod(self.shape[1:]) if self.gathers else self.row_bytes


_PAD_FIELDS = ("observation_pad", "action_pad")


@dataclass(frozen=True)
class _Gathers:
    """An episode's rows per buffered row: its frame stacks, or its windows' observation and action rows and pads."""

    frames: np.ndarray
    history: np.ndarray | None = None
    chunk: np.ndarray | None = None
    observation_pad: np.ndarray | None = None
    action_pad: np.ndarray | None = None

    def rows(self, start: int, stop: int) -> _Gathers:
        def part(value: np.ndarray | None) -> np.ndarray | None:
            return None if value is None else value[start:stop]

        return _Gathers(
            self.frames[start:stop], part(self.history), part(self.chunk), part(self.observation_pad), part(self.action_pad)
        )


class StreamingLoader:
    """Shuffled minibatches (CPU `TransitionTensors`, no next observations; `WindowBatch`es with
    a `window`) of `episodes` of `dataset`, decoded on the fly within a `memory` budget in bytes
    (see the module docstring).

    `frames` > 1 stacks the top-level image leaves `image_keys` as `stack_frames` does. An epoch
    passes over the data as often as it takes to reach `min_samples` samples, each pass in its own
    order. Without `shuffle`, episodes and rows come in ascending order and the buffer holds one
    batch. NaN or ±inf in an episode is an ImitationError naming its file, episode and step.
    With `transform`, each frame is cropped and resized as it is decoded, and the budget counts
    the frames at that size."""

    def __init__(
        self,
        dataset: DemoDataset,
        episodes: Sequence[int],
        *,
        batch_size: int,
        memory: int,
        frames: int = 1,
        image_keys: Sequence[str] = (),
        shuffle: bool = True,
        seed: int = 0,
        workers: int = 2,
        min_samples: int = 0,
        transform: FrameTransform | None = None,
        window: WindowSpec | None = None,
    ) -> None:
        if batch_size < 1:
            raise ImitationError(f"batch size must be positive, got {batch_size}")
        if window is not None and frames > 1:
            raise ImitationError("a stream gathers windows of observations or stacks of frames, not both")
        self.dataset = dataset
        self.episodes = sorted(set(int(k) for k in episodes))
        if self.episodes and not 0 <= self.episodes[0] <= self.episodes[-1] < len(dataset):
            raise ImitationError(
                f"episode indices must lie in [0, {len(dataset)}), got {self.episodes[0]}..{self.episodes[-1]}"
            )
        facts = dataset.episodes
        self._lengths = {k: facts[k].length for k in self.episodes}
        self.transitions = sum(self._lengths.values())
        self.batch_size, self.memory, self.frames, self.shuffle, self.workers = batch_size, memory, frames, shuffle, workers
        self.image_keys = list(image_keys)
        self.transform, self.window = transform, window
        observation_space = transform.space(dataset.observation_space) if transform is not None else dataset.observation_space
        self._leaves = _buffer_leaves(observation_space, dataset.action_space, frames, set(image_keys), window)
        self.row_bytes = sum(leaf.row_bytes for leaf in self._leaves)
        # Decoded, ungathered: what a waiting episode holds per row (counted for its T + 1 observations).
        self._decoded_row_bytes = sum(leaf.decoded_row_bytes for leaf in self._leaves)
        self.capacity = batch_size if not shuffle else (memory // 2) // self.row_bytes
        if self.capacity < batch_size:
            needed = math.ceil(2 * batch_size * self.row_bytes / 2**20)
            raise ImitationError(
                f"a streaming memory of {memory / 2**20:.0f} MB buffers fewer rows than one batch of {batch_size} "
                f"({self.row_bytes} bytes a row); give at least {needed} MB"
            )
        self.passes = max(1, -(-min_samples // max(1, self.transitions)))
        self._generator = torch.Generator(device="cpu").manual_seed(seed)
        self.peak_bytes = 0  # the most bytes of decoded transitions held at once, over all epochs
        self.wait_seconds = 0.0  # time the consumer spent waiting for a batch, over all epochs

    def in_order(self) -> StreamingLoader:
        """The same episodes, one pass in ascending order as single transitions, within the same
        budget (for statistics)."""
        return StreamingLoader(
            self.dataset,
            self.episodes,
            batch_size=self.batch_size,
            memory=self.memory,
            frames=self.frames,
            image_keys=self.image_keys,
            shuffle=False,
            workers=self.workers,
            transform=self.transform,
        )

    def generator_state(self) -> torch.Tensor:
        """Where the epoch generator is (for checkpoints): it decides every later epoch's batches."""
        return self._generator.get_state()

    def set_generator_state(self, state: torch.Tensor) -> None:
        self._generator.set_state(state)

    def __len__(self) -> int:
        return -(-self.passes * self.transitions // self.batch_size)

    def __iter__(self) -> Iterator[TransitionTensors | WindowBatch]:
        return self.batches()

    def batches(self, skip: int = 0) -> Iterator[TransitionTensors | WindowBatch]:
        """An epoch's batches, the first `skip` of them decoded and left out (an epoch resumed
        midway: the buffer's draws depend on every batch before)."""
        with closing(self._epoch()) as epoch:  # a consumer that stops early stops the producer at once
            for index, batch in enumerate(epoch):
                if index >= skip:
                    yield batch

    def _epoch(self) -> Generator[TransitionTensors | WindowBatch, None, None]:
        if self.shuffle:
            order = [
                self.episodes[i]
                for _ in range(self.passes)
                for i in torch.randperm(len(self.episodes), generator=self._generator)
            ]
        else:
            order = self.episodes * self.passes
        seed = int(torch.randint(2**62, (1,), generator=self._generator)) if self.shuffle else 0
        batches: queue.Queue[TransitionTensors | WindowBatch | BaseException | None] = queue.Queue(_QUEUE_BATCHES)
        stop = threading.Event()
        producer = threading.Thread(target=self._produce, args=(order, seed, batches, stop), daemon=True)
        producer.start()
        try:
            while True:
                started = time.perf_counter()
                item = batches.get()
                self.wait_seconds += time.perf_counter() - started
                if item is None:
                    return
                if isinstance(item, BaseException):
                    raise item
                yield item
        finally:
            stop.set()  # a consumer that stops early (an exception, a break) releases the producer
            producer.join()

    # -- the producer thread -----------------------------------------------------------------

    def _produce(self, order: list[int], seed: int, out: queue.Queue, stop: threading.Event) -> None:
        """Fill the buffer from decoded episodes and put batches on `out`; None at the end, or the error."""
        pool = ThreadPoolExecutor(self.workers, thread_name_prefix="stream-decode")
        try:
            self._fill_and_draw(order, np.random.default_rng(seed), pool, out, stop)
            self._put(out, None, stop)
        except BaseException as error:  # handed to the consumer, which raises it in its own thread
            self._put(out, error, stop)
        finally:
            pool.shutdown(cancel_futures=True)  # a consumer that stopped early wants no more decoding

    def _fill_and_draw(
        self, order: list[int], rng: np.random.Generator, pool: ThreadPoolExecutor, out: queue.Queue, stop: threading.Event
    ) -> None:
        buffer = {leaf: np.empty((self.capacity, *leaf.shape), dtype=leaf.dtype) for leaf in self._leaves}
        buffer_bytes = self.capacity * self.row_bytes
        waiting: deque[tuple[Future[Transitions], int]] = deque()  # decoding or decoded, in order
        waiting_bytes = 0
        upcoming = iter(order)
        exhausted = False
        current: Transitions | None = None  # the episode being copied into the buffer
        current_bytes, copied, filled = 0, 0, 0
        gathers = self._gathers(0)  # the rows of `current` each buffered row takes
        while not stop.is_set():
            # Decode ahead while the budget allows; always at least the next episode.
            while not exhausted and (not waiting or buffer_bytes + current_bytes + waiting_bytes < self.memory):
                k = next(upcoming, None)
                if k is None:
                    exhausted = True
                    break
                size = (self._lengths[k] + 1) * self._decoded_row_bytes
                waiting.append((pool.submit(self._decode, k), size))
                waiting_bytes += size
            self.peak_bytes = max(self.peak_bytes, buffer_bytes + current_bytes + waiting_bytes)
            # Copy rows into the buffer until it is full or no episode is left.
            while filled < self.capacity:
                if current is None or copied == len(current):
                    if not waiting:
                        break
                    future, current_bytes = waiting.popleft()
                    waiting_bytes -= current_bytes
                    current, copied = future.result(), 0
                    gathers = self._gathers(len(current))
                count = min(len(current) - copied, self.capacity - filled)
                self._copy(current, gathers.rows(copied, copied + count), buffer, filled)
                copied, filled = copied + count, filled + count
                if copied == len(current):
                    current, current_bytes = None, 0
            if filled == 0:
                return
            if filled < self.capacity and (waiting or not exhausted):
                continue  # more episodes to come: draw only from a full buffer
            if self.shuffle:
                taken = rng.choice(filled, min(self.batch_size, filled), replace=False)
            else:
                taken = np.arange(filled)
            rows = {leaf: array[taken] for leaf, array in buffer.items()}
            batch = _tensors(rows) if self.window is None else _windows(rows)
            filled = _remove(buffer, taken, filled)
            self._put(out, batch, stop)

    def _decode(self, k: int) -> Transitions:
        """Episode k as one contiguous block of its T transitions (a worker thread's job), its
        frames transformed if the loader has a transform."""
        (episode,) = self.dataset.read_episodes([k], transform=self.transform)
        check_episodes_finite([episode], self.dataset, [k])
        return episodes_to_transitions([episode], [k], next_observations=False)

    def _gathers(self, length: int) -> _Gathers:
        """The rows each of an episode's `length` rows gathers: its frames, or its window's."""
        stacks = frame_stack_index(np.zeros(length, dtype=np.int64), self.frames)
        if self.window is None:
            return _Gathers(stacks)
        index = window_index(np.zeros(length, dtype=np.int64), self.window)
        return _Gathers(stacks, index.observation_rows, index.action_rows, index.observation_pad, index.action_pad)

    def _copy(self, source: Transitions, gathers: _Gathers, buffer: dict[_Leaf, np.ndarray], at: int) -> None:
        """Rows `gathers.frames[:, -1]` of `source` into buffer rows from `at`, each leaf gathering what it holds."""
        rows = gathers.frames[:, -1]
        end = at + len(rows)
        for leaf, array in buffer.items():
            if leaf.field in _PAD_FIELDS:
                array[at:end] = getattr(gathers, leaf.field)
                continue
            tree = getattr(source, leaf.field)
            values = dict(tree_leaves(tree))[leaf.path] if isinstance(tree, dict) else tree
            array[at:end] = values[rows] if leaf.gathers is None else values[getattr(gathers, leaf.gathers)]

    @staticmethod
    def _put(out: queue.Queue, item: object, stop: threading.Event) -> None:
        while not stop.is_set():
            try:
                out.put(item, timeout=_POLL_SECONDS)
                return
            except queue.Full:
                continue


def _buffer_leaves(
    observation_space: gym.Space, action_space: gym.Space, frames: int, image_keys: set[str], window: WindowSpec | None
) -> list[_Leaf]:
    """The arrays of one buffered row: observations (image leaves stacked), actions, rewards, flags,
    episode; with a `window`, the window's observations and actions and their pad masks."""
    if window is not None:
        observations = [
            _Leaf("observations", path, (window.observations, *shape), np.dtype(dtype), "history")
            for path, dtype, shape in space_leaves(observation_space)
        ]
        actions = [
            _Leaf("actions", path, (window.actions, *shape), np.dtype(dtype), "chunk")
            for path, dtype, shape in space_leaves(action_space)
        ]
        masks = [
            _Leaf("observation_pad", (), (window.observations,), np.dtype(bool)),
            _Leaf("action_pad", (), (window.actions,), np.dtype(bool)),
        ]
        return observations + actions + masks
    leaves = []
    for path, dtype, shape in space_leaves(observation_space):
        stacked = frames > 1 and ("" if not path else path[0]) in image_keys and len(path) <= 1
        leaves.append(
            _Leaf("observations", path, (frames, *shape) if stacked else shape, np.dtype(dtype), "frames" if stacked else None)
        )
    leaves += [_Leaf("actions", path, shape, np.dtype(dtype)) for path, dtype, shape in space_leaves(action_space)]
    leaves += [
        _Leaf("rewards", (), (), np.dtype(np.float64)),
        _Leaf("terminated", (), (), np.dtype(bool)),
        _Leaf("truncated", (), (), np.dtype(bool)),
        _Leaf("episode_index", (), (), np.dtype(np.int64)),
    ]
    return leaves


def _remove(buffer: dict[_Leaf, np.ndarray], taken: np.ndarray, filled: int) -> int:
    """Drop rows `taken` from the first `filled` buffer rows, moving the last rows into the holes
    (order within the buffer does not matter: draws are uniform); the number of rows left."""
    left = filled - len(taken)
    holes = taken[taken < left]
    movers = np.setdiff1d(np.arange(left, filled), taken, assume_unique=True)
    for array in buffer.values():
        array[holes] = array[movers]
    return left


def _field(rows: dict[_Leaf, np.ndarray], field: str) -> Any:
    """One field of gathered buffer rows, as the tree of its leaves."""
    return tree_from_leaves({leaf.path: array for leaf, array in rows.items() if leaf.field == field})


def _tensors(rows: dict[_Leaf, np.ndarray]) -> TransitionTensors:
    """Gathered buffer rows as CPU tensors (sharing the gathered arrays' memory)."""
    fields = ("observations", "actions", "rewards", "terminated", "truncated", "episode_index")
    return transitions_to_torch(Transitions(next_observations=None, **{field: _field(rows, field) for field in fields}))


def _windows(rows: dict[_Leaf, np.ndarray]) -> WindowBatch:
    """Gathered buffered windows as CPU tensors (sharing the gathered arrays' memory)."""
    return WindowBatch(
        observations=tree_map(torch.from_numpy, _field(rows, "observations")),
        observation_pad=torch.from_numpy(_field(rows, "observation_pad")),
        actions=torch.from_numpy(_field(rows, "actions")),
        action_pad=torch.from_numpy(_field(rows, "action_pad")),
    )


__all__ = ["StreamingLoader"]

"""Bulk loading: demo files straight into flat transition arrays.

`load_transitions` asks this module first. Each chunk is decompressed into its decoding thread's
own reusable buffer (faulted in once, warm in cache) and every block's rows are copied from there
to their place in the output arrays: no buffer holds the whole decompressed file and no
per-episode arrays are built, which halves the memory a load touches (in a fresh process,
touching new memory is much of the cost). Chunks decode on a thread pool; zstd and CRC-32
release the GIL.

A block's place follows from its message alone: its episode is the one whose time range holds
the block's log time, and its first row is (log_time − t_start)/dt, which is how DemoWriter
stamps the blocks of a recording without its own timestamps. An image channel's message is one
frame, placed the same way and decoded straight into its row. Files with their own timestamps
(a `/time` channel), and any file whose blocks do not tile every episode exactly (a frame that
does not decode included), return None: the caller then takes the general path, which also
reports damage with its own messages.
"""

from __future__ import annotations

import bisect
import contextlib
import math
import mmap
import struct
import threading
from collections import defaultdict
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from imitation.data.frame_transform import FrameTransform
from imitation.data.mcap.format import EPISODE_TOPIC, REWARD_FIELD, TIME_FIELD, Field, fields_for
from imitation.data.mcap.images import decode_frame, is_image_leaf
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.records import ChunkRef, Damage, chunk_header, chunk_records, decode_chunk
from imitation.data.types import Transitions, tree_from_leaves

if TYPE_CHECKING:
    from imitation.data.dataset import DemoDataset


# Below this an array comes from numpy's allocator as usual.
_LARGE_BYTES = 32 * 1024 * 1024


def large_empty(shape: tuple[int, ...], dtype: np.dtype | type) -> np.ndarray:
    """np.empty for the big arrays of a load (image columns, batches of frames): at 32 MiB or
    more, memory of its own mapping marked for transparent huge pages, so filling it costs one
    page fault per 2 MiB instead of per 4 KiB (on a VM with THP "madvise", about a tenth of the CPU
    time to fill: bench/RESULTS.md), where numpy's own huge-page hint does not take effect. The
    array behaves as any other (writable, C-contiguous; the mapping is freed with its last
    reference); elsewhere it is np.empty."""
    dtype = np.dtype(dtype)
    size = math.prod(shape) * dtype.itemsize
    if size < _LARGE_BYTES or not hasattr(mmap, "MADV_HUGEPAGE") or dtype.hasobject:
        return np.empty(shape, dtype)
    try:
        memory = mmap.mmap(-1, size, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    except (OSError, OverflowError, ValueError):
        return np.empty(shape, dtype)  # numpy then reports a failed allocation its own way
    with contextlib.suppress(OSError):  # huge pages off or unsupported: an ordinary mapping
        memory.madvise(mmap.MADV_HUGEPAGE)
    return np.frombuffer(memory, dtype=dtype).reshape(shape)


class _NotTiled(Exception):
    """The file's blocks cannot be placed by their log times: use the general path."""


class _ContentBuffers(threading.local):
    """Each decoding thread's reusable buffer for one chunk's decompressed records: it stays
    in cache and is faulted in once, where a fresh buffer per chunk would be faulted in anew."""

    def __init__(self) -> None:
        self.buffer = np.empty(0, dtype=np.uint8)

    def get(self, size: int) -> memoryview:
        if len(self.buffer) < size:
            self.buffer = np.empty(size, dtype=np.uint8)
        return memoryview(self.buffer)[:size]


@dataclass
class _Column:
    """One output array and, for observations, the episodes' final rows (which have no transition).
    An image column may hold its frames transformed (`FrameTransform`): its rows are then of
    another shape than the field's."""

    field: Field
    out: np.ndarray  # (N, *shape)
    final: np.ndarray | None  # (E, *shape), observations only
    transform: FrameTransform | None = None

    @property
    def row_nbytes(self) -> int:
        return self.field.row_nbytes if self.transform is None else self.out.dtype.itemsize * math.prod(self.out.shape[1:])

    def place(self, data: memoryview, episode: int, start: int, length: int, first_row: int) -> None:
        """A block holding rows [first_row, ...) of output episode `episode`, whose `length`
        transitions start at flat row `start`."""
        row_nbytes = self.row_nbytes
        rows = len(data) // row_nbytes
        in_out = max(0, min(first_row + rows, length) - first_row)
        if first_row + rows > length + (self.final is not None):
            raise _NotTiled(f"{self.field.topic}: a block runs past its episode's end")
        self._put(self.out[start + first_row : start + first_row + in_out], data[: in_out * row_nbytes])
        if in_out < rows:
            assert self.final is not None
            self._put(self.final[episode : episode + 1], data[in_out * row_nbytes :])

    def _put(self, target: np.ndarray, data: memoryview) -> None:
        if target.dtype == self.field.dtype:
            memoryview(target.reshape(-1).view(np.uint8))[:] = data
        else:
            target[...] = np.frombuffer(data, dtype=self.field.dtype).reshape(target.shape)


@dataclass(frozen=True)
class _FilePlan:
    """Where one file's wanted episodes go in the output."""

    file: DemoFile
    ordinal_of: dict[int, int]  # file episode index → output episode ordinal
    chunks: list[ChunkRef]


def read_transitions(
    dataset: DemoDataset,
    indices: Sequence[int],
    *,
    next_observations: bool,
    transform: FrameTransform | None = None,
    progress: Callable[[int], None] | None = None,
) -> Transitions | None:
    """Episodes `indices` (dataset-wide, ascending) as one Transitions batch, or None when the
    files need the general path (own timestamps, blocks not placeable by log time, damage).

    With `transform`, each frame of an image channel is cropped and resized as it is decoded,
    into an output array of the transformed size (the files' frames are never held whole).
    `progress(steps)` is told, from the decoding threads, the observations of each chunk as it is
    placed (the steps and each episode's final observation)."""
    fields = fields_for(dataset.observation_space, dataset.action_space)
    observation_fields = [f for f in fields if f.kind == "observation"]
    action_fields = [f for f in fields if f.kind == "action"]
    plans = _plan(dataset, indices)
    if plans is None or any(f.row_nbytes == 0 for f in observation_fields + action_fields):
        return None
    transformed = {f.topic for f in observation_fields if transform is not None and is_image_leaf(f.dtype, f.shape)}
    facts = [f.file.episodes[k] for f in plans for k in f.ordinal_of]
    lengths = np.array([episode.length for episode in facts], dtype=np.int64)
    total = int(lengths.sum())
    if 8 * total > sum(c.uncompressed_size for plan in plans for c in plan.chunks):
        return None  # more steps than the chunks hold 8-byte rewards for: a damaged index, for the general path to report
    starts = np.cumsum(lengths) - lengths

    def shape(f: Field) -> tuple[int, ...]:
        return transform.shape(f.shape) if transform is not None and f.topic in transformed else f.shape

    columns = {
        f.topic: _Column(
            f,
            large_empty((total, *shape(f)), f.native_dtype),
            np.empty((len(facts), *shape(f)), f.native_dtype),
            transform if f.topic in transformed else None,
        )
        for f in observation_fields
    }
    columns |= {f.topic: _Column(f, large_empty((total, *f.shape), f.native_dtype), None) for f in action_fields}
    columns[REWARD_FIELD.topic] = _Column(REWARD_FIELD, np.empty(total, REWARD_FIELD.native_dtype), None)
    pieces: dict[tuple[str, int], list[tuple[int, int]]] = defaultdict(list)
    try:
        for plan in plans:
            for placed in _fill_file(plan, columns, starts, lengths, progress):
                for topic, ordinal, first_row, rows in placed:
                    pieces[topic, ordinal].append((first_row, rows))
    except (_NotTiled, Damage, ValueError, struct.error):
        return None
    for column in columns.values():
        expected = lengths + (column.final is not None)
        if not all(_tiles(pieces.get((column.field.topic, j), []), int(expected[j])) for j in range(len(facts))):
            return None

    def tree(fields: list[Field]) -> Any:
        return tree_from_leaves({f.path: columns[f.topic].out for f in fields})

    ends = starts + lengths
    terminated = np.zeros(total, dtype=bool)
    truncated = np.zeros(total, dtype=bool)
    nonempty = lengths > 0
    terminated[ends[nonempty] - 1] = [episode.terminated for episode, keep in zip(facts, nonempty) if keep]
    truncated[ends[nonempty] - 1] = [episode.truncated for episode, keep in zip(facts, nonempty) if keep]
    return Transitions(
        observations=tree(observation_fields),
        actions=tree(action_fields),
        rewards=columns[REWARD_FIELD.topic].out,
        next_observations=_next_observations(observation_fields, columns, ends, nonempty) if next_observations else None,
        terminated=terminated,
        truncated=truncated,
        episode_index=np.repeat(np.asarray(indices, dtype=np.int64), lengths),
    )


def _plan(dataset: DemoDataset, indices: Sequence[int]) -> list[_FilePlan] | None:
    plans: list[_FilePlan] = []
    offset = 0
    chosen = list(indices)
    ordinal = 0
    for file in dataset.files:
        if TIME_FIELD.topic in file.channels:
            return None
        local = [k - offset for k in chosen if offset <= k < offset + len(file)]
        offset += len(file)
        if not local:
            continue
        ordinal_of = {k: ordinal + i for i, k in enumerate(local)}
        ordinal += len(local)
        needed = {chunk.offset: chunk for k in local for chunk in file.chunks_of(file.episodes[k])}
        plans.append(_FilePlan(file, ordinal_of, sorted(needed.values(), key=lambda c: (c.start_time, c.offset))))
    return plans


def _fill_file(
    plan: _FilePlan,
    columns: dict[str, _Column],
    starts: np.ndarray,
    lengths: np.ndarray,
    progress: Callable[[int], None] | None = None,
) -> list[list[tuple[str, int, int, int]]]:
    file = plan.file
    dt_ns = round(file.dt * 1e9)
    if dt_ns <= 0:
        raise _NotTiled("no time step")
    topic_of = {channel_id: (f.topic if f is not None else EPISODE_TOPIC) for channel_id, f in file.channel_fields.items()}
    codec_of: dict[int, str] = {}
    coded: set[str] = set()
    for channel_id, f in file.channel_fields.items():
        if f is not None and f.codec is not None and f.topic in columns:
            if (f.dtype, f.shape) != (columns[f.topic].field.dtype, columns[f.topic].field.shape):
                raise _NotTiled(f"{f.topic}: the image channel's layout differs from the space's")
            codec_of[channel_id] = f.codec
            coded.add(f.topic)
    if any(column.transform is not None and topic not in coded for topic, column in columns.items()):
        raise _NotTiled("frames stored as blocks of rows: the general path transforms them episode by episode")
    t_starts = [facts.t_start_ns for facts in file.episodes]
    counted = next(topic for topic, column in columns.items() if column.final is not None)  # the steps of one observation

    def fill_chunk(chunk: ChunkRef) -> list[tuple[str, int, int, int]]:
        record = memoryview(source.read(chunk.offset, chunk.length))
        content = decode_chunk(record, buffers.get(chunk_header(record).uncompressed_size))
        placed: list[tuple[str, int, int, int]] = []
        for channel_id, log_time, data in chunk_records(content, lambda channel: None):
            if channel_id not in topic_of:
                raise _NotTiled(f"message on unknown channel id {channel_id}")
            column = columns.get(topic_of[channel_id])
            k = bisect.bisect_right(t_starts, log_time) - 1
            ordinal = plan.ordinal_of.get(k)
            if column is None or ordinal is None:
                continue
            if channel_id in codec_of:
                frame = decode_frame(codec_of[channel_id], column.field.shape, data)
                data = memoryview(column.transform(frame) if column.transform is not None else frame).cast("B")
            first_row, misaligned = divmod(log_time - t_starts[k], dt_ns)
            rows, partial = divmod(len(data), column.row_nbytes)
            if misaligned or partial or log_time > file.episodes[k].t_end_ns:
                raise _NotTiled(f"{column.field.topic}: block at {log_time} ns is not placed by its time")
            column.place(data, ordinal, int(starts[ordinal]), int(lengths[ordinal]), first_row)
            placed.append((column.field.topic, ordinal, first_row, rows))
        if progress is not None:
            progress(sum(rows for topic, _, _, rows in placed if topic == counted))
        return placed

    buffers = _ContentBuffers()
    with (
        file.byte_source() as source,
        ThreadPoolExecutor(max_workers=min(len(plan.chunks), source.parallel_reads, 8) or 1) as pool,
    ):
        return list(pool.map(fill_chunk, plan.chunks))


def _tiles(pieces: list[tuple[int, int]], expected: int) -> bool:
    """Whether the (first row, rows) pieces cover [0, expected) exactly once."""
    position = 0
    for first_row, rows in sorted(pieces):
        if first_row != position:
            return False
        position += rows
    return position == expected


def _next_observations(fields: list[Field], columns: dict[str, _Column], ends: np.ndarray, nonempty: np.ndarray) -> Any:
    """s' of every transition: the next row, except at an episode's end, where it is the final observation."""
    leaves = {}
    for f in fields:
        column = columns[f.topic]
        assert column.final is not None
        following = large_empty(column.out.shape, column.out.dtype)
        following[:-1] = column.out[1:]
        following[ends[nonempty] - 1] = column.final[nonempty]
        leaves[f.path] = following
    return tree_from_leaves(leaves)

"""Data-parallel shares of a dataset by chunks: which episodes each of N processes reads, so that no
two processes read the same MCAP chunk.

An episode's messages lie in a run of its file's chunks (`DemoFile.chunks_of`), and a chunk may
hold the ends of several episodes. Episodes linked by a shared chunk, directly or through others,
form a *unit*: reading any of them reads chunks the others need. Units are disjoint in chunks (and
never cross files: a chunk belongs to one file), so a process given whole units reads chunks no
other one reads.

The deal is longest-processing-time first: units in decreasing order of counted transitions, each
to the process with the fewest so far (ties: the lower rank; equal units: file order), which
balances the shares to within the largest unit. Units with no counted transition (validation
episodes alone) are then dealt the same way by their own transitions. The plan depends on the files
and the counted episodes alone, so every process computes the same one without talking.
"""

from __future__ import annotations

import heapq
from collections.abc import Collection
from dataclasses import dataclass

from imitation.data.dataset import DemoDataset
from imitation.errors import ImitationError

ChunkId = tuple[int, int]  # (file index in the dataset, byte offset of the chunk record)


@dataclass(frozen=True)
class Unit:
    """Episodes (dataset-wide indices, ascending) linked by shared chunks, and those chunks."""

    episodes: list[int]
    chunks: list[ChunkId]


@dataclass(frozen=True)
class Share:
    """What one process reads: its episodes (dataset-wide, ascending), the chunks they lie in, and
    the transitions of its counted episodes."""

    episodes: list[int]
    chunks: list[ChunkId]
    transitions: int


def chunk_units(dataset: DemoDataset) -> list[Unit]:
    """The dataset's episodes grouped into units (see the module docstring), in file order."""
    units: list[Unit] = []
    first = 0
    for file_index, file in enumerate(dataset.files):
        chunks_of = [[chunk.offset for chunk in file.chunks_of(facts)] for facts in file.episodes]
        for episodes in _linked(chunks_of):
            chunks = sorted({offset for local in episodes for offset in chunks_of[local]})
            units.append(Unit([first + local for local in episodes], [(file_index, offset) for offset in chunks]))
        first += len(file)
    return units


def _linked(chunks_of: list[list[int]]) -> list[list[int]]:
    """Episodes (by position in `chunks_of`, their chunks' offsets) grouped by shared chunks,
    transitively: union-find over the offsets; each group ascending, groups by first episode."""
    parent: dict[int, int] = {}

    def root(offset: int) -> int:
        while parent[offset] != offset:
            parent[offset] = parent[parent[offset]]
            offset = parent[offset]
        return offset

    for offsets in chunks_of:
        for offset in offsets:
            parent.setdefault(offset, offset)
        for offset in offsets[1:]:
            parent[root(offset)] = root(offsets[0])
    groups: dict[int, list[int]] = {}
    for episode, offsets in enumerate(chunks_of):
        # An episode with no chunk (nothing to read) is a group of its own, keyed apart from offsets.
        groups.setdefault(root(offsets[0]) if offsets else -1 - episode, []).append(episode)
    return sorted(groups.values(), key=lambda episodes: episodes[0])


def plan_shares(dataset: DemoDataset, processes: int, *, counted: Collection[int] | None = None) -> list[Share]:
    """Each of `processes` processes' share of `dataset`, by rank, balancing the transitions of
    the `counted` episodes (the training ones; all by default). Every process must get some
    counted transition: fewer units that hold one than processes is an ImitationError."""
    lengths = [facts.length for facts in dataset.episodes]
    counted_set = set(range(len(lengths))) if counted is None else set(counted)
    units = chunk_units(dataset)
    weights = [sum(lengths[k] for k in unit.episodes if k in counted_set) for unit in units]
    training = [i for i, weight in enumerate(weights) if weight > 0]
    if len(training) < processes:
        raise ImitationError(
            f"torchrun: {processes} processes, but the training episodes lie in {len(training)} group(s) of chunks "
            f"(episodes that share a chunk are read by one process); run at most {len(training)} processes"
        )
    owner = _deal(training, weights, processes)
    rest = [i for i, weight in enumerate(weights) if weight == 0]
    owner |= _deal(rest, [sum(lengths[k] for k in unit.episodes) for unit in units], processes)
    shares = []
    for rank in range(processes):
        mine = [units[i] for i in sorted(i for i, r in owner.items() if r == rank)]
        shares.append(
            Share(
                episodes=sorted(k for unit in mine for k in unit.episodes),
                chunks=sorted(chunk for unit in mine for chunk in unit.chunks),
                transitions=sum(weights[i] for i, r in owner.items() if r == rank),
            )
        )
    return shares


def _deal(indices: list[int], weights: list[int], processes: int) -> dict[int, int]:
    """Units `indices` to ranks, heaviest first, each to the least loaded rank: {unit: rank}."""
    loads = [(0, rank) for rank in range(processes)]
    owner = {}
    for i in sorted(indices, key=lambda i: (-weights[i], i)):
        load, rank = heapq.heappop(loads)
        owner[i] = rank
        heapq.heappush(loads, (load + weights[i], rank))
    return owner


__all__ = ["Share", "Unit", "chunk_units", "plan_shares"]

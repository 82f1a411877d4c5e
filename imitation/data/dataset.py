"""Datasets of several demo files: `DemoDataset` reads shards or DAgger rounds of one
environment as one sequence of episodes."""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence

import numpy as np

from imitation.data.mcap.format import EpisodeFacts
from imitation.data.mcap.images import FrameMap
from imitation.data.mcap.reader import DemoFile
from imitation.data.spaces import spaces_equal
from imitation.data.types import Episode
from imitation.errors import DemoFileError, ImitationError


class DemoDataset:
    """Several demo files of one environment as one dataset of episodes (shards, DAgger rounds).

    Indexing is global: episodes of the first file come first. Every file must share the env id
    and the observation and action spaces; a mismatch names the file.
    """

    def __init__(self, paths: Sequence[str | os.PathLike] | str | os.PathLike, *, salvage: bool = False) -> None:
        if isinstance(paths, (str, os.PathLike)):
            paths = [paths]
        if not paths:
            raise ImitationError("no demo files given")
        self.files = [DemoFile(path, salvage=salvage) for path in paths]
        first = self.files[0]
        for other in self.files[1:]:
            if other.env_id != first.env_id:
                raise DemoFileError(f"{other.path}: env id {other.env_id!r} differs from {first.path}'s {first.env_id!r}")
            for name in ("observation_space", "action_space"):
                if not spaces_equal(getattr(other, name), getattr(first, name)):
                    raise DemoFileError(f"{other.path}: {name.replace('_', ' ')} differs from {first.path}'s")
        self.env_id = first.env_id
        self.observation_space = first.observation_space
        self.action_space = first.action_space
        self._offsets = np.cumsum([0] + [len(f) for f in self.files])

    def __len__(self) -> int:
        return int(self._offsets[-1])

    @property
    def episodes(self) -> list[EpisodeFacts]:
        return [facts for f in self.files for facts in f.episodes]

    @property
    def num_transitions(self) -> int:
        return sum(f.num_transitions for f in self.files)

    def locate(self, k: int) -> tuple[DemoFile, int]:
        """The file that holds dataset-wide episode k, and k's index within that file."""
        file_index = int(np.searchsorted(self._offsets, k, side="right")) - 1
        return self.files[file_index], k - int(self._offsets[file_index])

    def __getitem__(self, k: int) -> Episode:
        if not -len(self) <= k < len(self):
            raise IndexError(f"episode {k} out of range (the dataset holds {len(self)})")
        k %= len(self)
        file_index = int(np.searchsorted(self._offsets, k, side="right")) - 1
        return self.files[file_index][k - int(self._offsets[file_index])]

    def __iter__(self) -> Iterator[Episode]:
        for f in self.files:
            yield from f

    def read_episodes(self, indices: Sequence[int] | None = None, *, transform: FrameMap | None = None) -> list[Episode]:
        """Episodes `indices` (dataset-wide; all by default) in ascending order, each chunk read
        once; with `transform`, their frames as it makes them, each as it is decoded."""
        if indices is None:
            return [episode for f in self.files for episode in f.read_episodes(transform=transform)]
        chosen = sorted(set(int(k) for k in indices))
        if chosen and not 0 <= chosen[0] <= chosen[-1] < len(self):
            raise IndexError(f"episode indices must lie in [0, {len(self)}), got {chosen[0]}..{chosen[-1]}")
        episodes: list[Episode] = []
        for file_index, f in enumerate(self.files):
            start, end = int(self._offsets[file_index]), int(self._offsets[file_index + 1])
            local = [k - start for k in chosen if start <= k < end]
            if local:
                episodes += f.read_episodes(local, transform=transform)
        return episodes

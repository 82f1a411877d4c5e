"""The one episode type, the flat transitions batch learners consume, and helpers for Dict data.

An observation or action is a numpy array, or, for a gymnasium Dict space, a (nested) dict of
arrays: a "tree". Arrays along the time axis are stacked in the first dimension.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.data.spaces import LeafPath, space_leaves
from imitation.errors import SpaceError

Tree = np.ndarray | dict[str, "Tree"]


def tree_leaves(tree: Tree, prefix: LeafPath = ()) -> Iterator[tuple[LeafPath, np.ndarray]]:
    """(path, array) for each array in `tree`, in key order; a bare array has the path ()."""
    if isinstance(tree, dict):  # not Mapping: an ABC check costs more than the rest of this call
        for key, sub in tree.items():
            yield from tree_leaves(sub, prefix + (key,))
    else:
        yield prefix, tree


def tree_from_leaves(leaves: Mapping[LeafPath, np.ndarray]) -> Tree:
    """Inverse of `tree_leaves`: a bare array if the only path is (), else nested dicts."""
    if () in leaves:
        return leaves[()]
    root: dict[str, Any] = {}
    for path, array in leaves.items():
        node = root
        for key in path[:-1]:
            node = node.setdefault(key, {})
        node[path[-1]] = array
    return root


def tree_rows(tree: Tree) -> int:
    """Length of the first axis, which every leaf must share."""
    lengths = {len(array) for _, array in tree_leaves(tree)}
    if len(lengths) != 1:
        raise ValueError(f"leaves disagree on their number of rows: {sorted(lengths)}")
    return lengths.pop()


def stack_samples(samples: Sequence[Any], space: gym.Space) -> Tree:
    """Stack per-step samples of `space` (arrays, ints or dicts of those) into one tree of arrays."""
    if isinstance(space, gym.spaces.Dict):
        return {key: stack_samples([sample[key] for sample in samples], sub) for key, sub in space.spaces.items()}
    assert space.shape is not None  # a leaf space (Box, Discrete, MultiDiscrete, MultiBinary) has one
    return np.asarray(samples, dtype=space.dtype).reshape((len(samples), *space.shape))


@dataclass(frozen=True, kw_only=True)
class Interventions:
    """Who drove each step of an episode in which a person (or a stand-in for one) could take the
    controls from a learner: `human[t]` is true when the person's command was executed at step t,
    `proposed_actions` are the learner's action at every step (also when the person drove) and
    `executed_actions` what the env was stepped with. Hand-overs are where `human` changes, the
    learner holding the controls before step 0 (`handovers`)."""

    human: np.ndarray
    proposed_actions: Tree
    executed_actions: Tree

    def __post_init__(self) -> None:
        if self.human.ndim != 1 or self.human.dtype != np.bool_:
            raise ValueError(f"interventions.human must be a 1-D bool array, got {self.human.dtype}{list(self.human.shape)}")
        for name in ("proposed_actions", "executed_actions"):
            if tree_rows(getattr(self, name)) != len(self.human):
                raise ValueError(f"interventions.{name} need {len(self.human)} rows, got {tree_rows(getattr(self, name))}")

    def handovers(self) -> list[tuple[int, bool]]:
        """(step, to_human) for every change of controller, the learner holding them before step 0."""
        before = np.concatenate([[False], self.human[:-1]])
        return [(int(step), bool(self.human[step])) for step in np.flatnonzero(self.human != before)]

    @property
    def takeovers(self) -> int:
        """Hand-overs to the person."""
        return sum(to_human for _, to_human in self.handovers())


@dataclass(frozen=True, kw_only=True)
class Episode:
    """One episode: `observations` has T+1 rows (the last is the final observation), every
    per-step field T rows.

    `terminated` means the MDP reached a terminal state (no bootstrapping past it); `truncated`
    means it was cut short (time limit, user stop) and the final observation is not terminal.
    `timestamps` (int64 ns, T+1 rows, one per observation) is given for real recordings and is
    None for simulators, whose step times are t_start + i·dt. `interventions` (T rows) says who
    drove each step when a person could take over from a learner. `metadata` holds per-episode
    facts such as `seed` and `source`; it must be JSON-serialisable.
    """

    observations: Tree
    actions: Tree
    rewards: np.ndarray
    terminated: bool = False
    truncated: bool = False
    infos: list[dict[str, Any]] | None = None
    timestamps: np.ndarray | None = None
    interventions: Interventions | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        steps = len(self.rewards)
        if self.rewards.ndim != 1:
            raise ValueError(f"rewards must be 1-D, got shape {self.rewards.shape}")
        if tree_rows(self.observations) != steps + 1:
            raise ValueError(f"observations need T+1 = {steps + 1} rows, got {tree_rows(self.observations)}")
        if tree_rows(self.actions) != steps:
            raise ValueError(f"actions need T = {steps} rows, got {tree_rows(self.actions)}")
        if self.infos is not None and len(self.infos) != steps:
            raise ValueError(f"infos need T = {steps} entries, got {len(self.infos)}")
        if self.timestamps is not None and self.timestamps.shape != (steps + 1,):
            raise ValueError(f"timestamps need shape ({steps + 1},), got {self.timestamps.shape}")
        if self.interventions is not None and len(self.interventions.human) != steps:
            raise ValueError(f"interventions need T = {steps} rows, got {len(self.interventions.human)}")
        if self.terminated and self.truncated:
            raise ValueError("an episode cannot be both terminated and truncated")

    def __len__(self) -> int:
        return len(self.rewards)

    @property
    def episode_return(self) -> float:
        return float(np.sum(self.rewards, dtype=np.float64))


def check_fits_space(tree: Tree, space: gym.Space, what: str) -> None:
    """Raise SpaceError unless every leaf of `tree` has the dtype and row shape of `space`."""
    expected = {path: (dtype, shape) for path, dtype, shape in space_leaves(space)}
    actual = dict(tree_leaves(tree))
    if set(expected) != set(actual):
        raise SpaceError(f"{what}: keys {sorted(actual)} do not match the space's {sorted(expected)}")
    for path, (dtype, shape) in expected.items():
        array = actual[path]
        name = what + "".join(f"[{key!r}]" for key in path)
        if array.dtype != dtype or array.shape[1:] != shape:
            raise SpaceError(f"{name}: got {array.dtype}{list(array.shape[1:])} per row, the space holds {dtype}{list(shape)}")


def first_nonfinite(tree: Tree, what: str) -> tuple[int, str, float] | None:
    """(row, name, value) of the first row of `tree` whose float leaves hold NaN or ±inf, None when
    every value is finite: one vectorised pass per leaf (integer and bool leaves are skipped)."""
    found: tuple[int, str, float] | None = None
    for path, array in tree_leaves(tree):
        if array.dtype.kind != "f" or array.size == 0:
            continue
        finite = np.isfinite(array)
        if finite.all():
            continue
        rows = finite.reshape(len(array), -1)
        row = int(np.argmin(rows.all(axis=1)))
        if found is None or row < found[0]:
            value = float(array.reshape(len(array), -1)[row][~rows[row]][0])
            found = (row, what + "".join(f"[{key!r}]" for key in path), value)
    return found


@dataclass(frozen=True, kw_only=True)
class Transitions:
    """A flat batch of N transitions (s, a, r, s', terminated, truncated) drawn from episodes.

    Rewards are float64, as stored: a finite reward is never narrowed to ±inf. `next_observations` is
    None when it was not asked for (behavioural cloning does not need s'). `terminated[i]` is true only
    on the last transition of a terminated episode (no bootstrap from `next_observations[i]`),
    `truncated[i]` only on the last transition of a truncated one.
    `episode_index[i]` is the dataset-wide index of the episode transition i came from.
    """

    observations: Tree
    actions: Tree
    rewards: np.ndarray
    next_observations: Tree | None
    terminated: np.ndarray
    truncated: np.ndarray
    episode_index: np.ndarray

    def __len__(self) -> int:
        return len(self.rewards)

    @property
    def dones(self) -> np.ndarray:
        """Episode ends of either kind."""
        return self.terminated | self.truncated


def episodes_to_transitions(
    episodes: Sequence[Episode], episode_indices: Sequence[int] | None = None, *, next_observations: bool = True
) -> Transitions:
    """Flatten episodes into one contiguous Transitions batch (one copy of each field)."""
    if not episodes:
        raise ValueError("no episodes to flatten")
    if episode_indices is None:
        episode_indices = range(len(episodes))
    lengths = np.array([len(episode) for episode in episodes], dtype=np.int64)
    total = int(lengths.sum())
    ends = np.cumsum(lengths)
    starts = ends - lengths

    def gather(get: Callable[[Episode], Tree], drop_first: bool, drop_last: bool) -> Tree:
        first = get(episodes[0])
        leaves: dict[LeafPath, np.ndarray] = {}
        for path, array in tree_leaves(first):
            leaves[path] = np.empty((total, *array.shape[1:]), dtype=array.dtype)
        for episode, start, end in zip(episodes, starts, ends):
            for path, array in tree_leaves(get(episode)):
                rows = array[1:] if drop_first else array[:-1] if drop_last else array
                leaves[path][start:end] = rows
        return tree_from_leaves(leaves)

    terminated = np.zeros(total, dtype=bool)
    truncated = np.zeros(total, dtype=bool)
    for episode, end in zip(episodes, ends):
        if len(episode) > 0:
            terminated[end - 1] = episode.terminated
            truncated[end - 1] = episode.truncated
    return Transitions(
        observations=gather(lambda e: e.observations, drop_first=False, drop_last=True),
        actions=gather(lambda e: e.actions, drop_first=False, drop_last=False),
        rewards=np.concatenate([episode.rewards for episode in episodes]).astype(np.float64, copy=False),
        next_observations=gather(lambda e: e.observations, drop_first=True, drop_last=False) if next_observations else None,
        terminated=terminated,
        truncated=truncated,
        episode_index=np.repeat(np.asarray(episode_indices, dtype=np.int64), lengths),
    )

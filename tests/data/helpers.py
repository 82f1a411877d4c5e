"""Build episodes for tests from a space and a seed (no environment needed)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from imitation.data.spaces import space_leaves
from imitation.data.types import Episode, Tree, tree_from_leaves, tree_leaves


def random_rows(space: gym.Space, rows: int, rng: np.random.Generator) -> Tree:
    """`rows` rows of every leaf of `space` filled with random bytes: every bit pattern, NaN
    payloads included, must survive the store (it does not check values against bounds)."""
    leaves = {}
    for path, dtype, shape in space_leaves(space):
        count = rows * int(np.prod(shape, dtype=np.int64))
        leaves[path] = np.frombuffer(rng.bytes(count * dtype.itemsize), dtype=dtype).reshape((rows, *shape)).copy()
    return tree_from_leaves(leaves)


def random_episode(
    observation_space: gym.Space,
    action_space: gym.Space,
    steps: int,
    seed: int,
    *,
    terminated: bool = False,
    truncated: bool = True,
    **extra: Any,
) -> Episode:
    rng = np.random.default_rng(seed)
    rewards = rng.normal(size=steps)
    return Episode(
        observations=random_rows(observation_space, steps + 1, rng),
        actions=random_rows(action_space, steps, rng),
        rewards=rewards,
        terminated=terminated,
        truncated=truncated and not terminated,
        metadata={"seed": seed},
        **extra,
    )


def assert_episodes_equal(actual: Episode, expected: Episode) -> None:
    for field in ("observations", "actions"):
        actual_leaves = dict(tree_leaves(getattr(actual, field)))
        expected_leaves = dict(tree_leaves(getattr(expected, field)))
        assert actual_leaves.keys() == expected_leaves.keys()
        for path, array in expected_leaves.items():
            assert actual_leaves[path].dtype == array.dtype, (field, path)
            assert actual_leaves[path].shape == array.shape, (field, path)
            np.testing.assert_array_equal(actual_leaves[path], array)
    np.testing.assert_array_equal(actual.rewards, expected.rewards)
    assert actual.terminated == expected.terminated and actual.truncated == expected.truncated
    assert actual.infos == expected.infos
    if expected.timestamps is None:
        assert actual.timestamps is None
    else:
        assert actual.timestamps is not None and len(actual.timestamps) == len(expected.timestamps)

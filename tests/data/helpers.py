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


def rewrite_messages(source, target, change) -> None:
    """Copy an MCAP file record by record through the mcap library, `change(topic, log_time, data)`
    returning each message's (log_time, data): a file whose blocks DemoWriter could not have written."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with open(source, "rb") as stream, open(target, "wb") as out:
        reader = make_reader(stream)
        writer = Writer(out, compression=CompressionType.ZSTD)
        writer.start(profile="", library="test")
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        summary = reader.get_summary()
        schema_ids = {s.id: writer.register_schema(s.name, s.encoding, s.data) for s in summary.schemas.values()}
        channel_ids = {
            c.id: writer.register_channel(c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0), c.metadata) for c in summary.channels.values()
        }
        for _, channel, message in reader.iter_messages(log_time_order=False):
            log_time, data = change(channel.topic, message.log_time, message.data)
            writer.add_message(channel_ids[channel.id], log_time=log_time, data=data, publish_time=log_time)
        writer.finish()

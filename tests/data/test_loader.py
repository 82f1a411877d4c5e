"""Demos → torch: transitions line up with episodes, splits are by episode, batches are seeded."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest
import torch
from helpers import random_episode, rewrite_messages

from imitation.data.dataset import DemoDataset
from imitation.data.loader import MinibatchLoader, load_transitions, split_episodes, transitions_to_torch
from imitation.data.mcap.writer import write_episodes
from imitation.errors import ImitationError
from imitation.tensors import resolve_device

BOX = gym.spaces.Box(-1, 1, (3,), np.float32)
ACTIONS = gym.spaces.Discrete(4)


@pytest.fixture
def demo_paths(tmp_path):
    episodes = [random_episode(BOX, ACTIONS, length, seed=i, terminated=i == 1) for i, length in enumerate([4, 6, 3, 5])]
    write_episodes(tmp_path / "a.mcap", episodes[:2], finite_only=False, env_id="T", observation_space=BOX, action_space=ACTIONS)
    write_episodes(tmp_path / "b.mcap", episodes[2:], finite_only=False, env_id="T", observation_space=BOX, action_space=ACTIONS)
    return [tmp_path / "a.mcap", tmp_path / "b.mcap"], episodes


def test_transitions_line_up_with_their_episodes(demo_paths) -> None:
    paths, episodes = demo_paths
    transitions = load_transitions(paths, finite=False)
    assert len(transitions) == 18
    np.testing.assert_array_equal(transitions.episode_index, np.repeat([0, 1, 2, 3], [4, 6, 3, 5]))
    start = 0
    for episode in episodes:
        end = start + len(episode)
        np.testing.assert_array_equal(transitions.observations[start:end], episode.observations[:-1])
        np.testing.assert_array_equal(transitions.next_observations[start:end], episode.observations[1:])
        np.testing.assert_array_equal(transitions.actions[start:end], episode.actions)
        np.testing.assert_allclose(transitions.rewards[start:end], episode.rewards, rtol=1e-6)
        assert transitions.terminated[end - 1] == episode.terminated
        assert transitions.truncated[end - 1] == episode.truncated
        assert not transitions.dones[start : end - 1].any()
        start = end


def test_loading_a_subset_equals_slicing_the_whole(demo_paths) -> None:
    paths, _ = demo_paths
    whole = load_transitions(paths, finite=False)
    subset = load_transitions(DemoDataset(paths), episodes=[3, 1], finite=False)
    mask = np.isin(whole.episode_index, [1, 3])
    np.testing.assert_array_equal(subset.observations, whole.observations[mask])
    np.testing.assert_array_equal(subset.episode_index, whole.episode_index[mask])
    with pytest.raises(ImitationError, match="episode indices"):
        load_transitions(paths, episodes=[9], finite=False)


def test_torch_tensors_keep_dtypes_and_share_cpu_memory(demo_paths) -> None:
    paths, _ = demo_paths
    transitions = load_transitions(paths, finite=False)
    tensors = transitions_to_torch(transitions, "cpu")
    assert tensors.observations.dtype == torch.float32 and tensors.actions.dtype == torch.int64
    assert tensors.terminated.dtype == torch.bool and tensors.rewards.dtype == torch.float64
    assert tensors.observations.is_contiguous()
    assert tensors.observations.data_ptr() == transitions.observations.ctypes.data


def test_split_is_by_whole_episodes_and_seeded() -> None:
    train, validation = split_episodes(10, validation_fraction=0.3, seed=4)
    assert len(validation) == 3 and sorted(train + validation) == list(range(10))
    assert split_episodes(10, validation_fraction=0.3, seed=4) == (train, validation)
    assert split_episodes(10, validation_fraction=0.3, seed=5) != (train, validation)
    assert split_episodes(1, validation_fraction=0.5, seed=0) == ([0], [])
    with pytest.raises(ImitationError):
        split_episodes(10, validation_fraction=1.0, seed=0)


def test_minibatches_cover_every_transition_once_per_epoch_in_a_seeded_order(demo_paths) -> None:
    paths, _ = demo_paths
    tensors = transitions_to_torch(load_transitions(paths, finite=False))
    loader = MinibatchLoader(tensors, batch_size=5, seed=1)
    assert len(loader) == 4
    epoch = [batch.episode_index for batch in loader]
    assert [len(b) for b in epoch] == [5, 5, 5, 3]
    seen = torch.cat([batch.rewards for batch in MinibatchLoader(tensors, batch_size=5, seed=1)])
    assert sorted(seen.tolist()) == sorted(tensors.rewards.tolist())
    again = [batch.episode_index for batch in MinibatchLoader(tensors, batch_size=5, seed=1)]
    assert all(torch.equal(a, b) for a, b in zip(epoch, again))
    second_epoch = [batch.episode_index for batch in loader]
    assert not all(torch.equal(a, b) for a, b in zip(epoch, second_epoch))
    assert len(MinibatchLoader(tensors, batch_size=5, drop_last=True)) == 3


def test_dict_observations_load_as_dicts_of_tensors(tmp_path) -> None:
    space = gym.spaces.Dict({"pos": gym.spaces.Box(-1, 1, (2,), np.float32), "cell": gym.spaces.Discrete(5)})
    write_episodes(tmp_path / "d.mcap", [random_episode(space, ACTIONS, 7, seed=0)], finite_only=False, env_id="T", observation_space=space, action_space=ACTIONS)
    tensors = transitions_to_torch(load_transitions(tmp_path / "d.mcap", finite=False))
    assert tensors.observations["pos"].shape == (7, 2) and tensors.next_observations["cell"].shape == (7,)
    batch = next(iter(MinibatchLoader(tensors, batch_size=3, seed=0)))
    assert batch.observations["pos"].shape == (3, 2)


def test_device_selection() -> None:
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type in ("cpu", "cuda")
    if not torch.cuda.is_available():
        with pytest.raises(ImitationError, match="CUDA is not available"):
            resolve_device("cuda")
    with pytest.raises(ImitationError, match="^device 'potato'"):
        resolve_device("potato")


def test_next_observations_can_be_left_out(demo_paths) -> None:
    paths, _ = demo_paths
    without = load_transitions(paths, next_observations=False, finite=False)
    assert without.next_observations is None
    np.testing.assert_array_equal(without.observations, load_transitions(paths, finite=False).observations)
    tensors = transitions_to_torch(without)
    assert tensors.next_observations is None
    batch = next(iter(MinibatchLoader(tensors, batch_size=4, seed=0)))
    assert batch.next_observations is None and batch.observations.shape == (4, 3)


def test_uncompressed_files_load_the_same(tmp_path) -> None:
    episodes = [random_episode(BOX, ACTIONS, 9, seed=i) for i in range(3)]
    for compression in ("zstd", "none"):
        write_episodes(tmp_path / f"{compression}.mcap", episodes, finite_only=False, env_id="T", observation_space=BOX, action_space=ACTIONS, compression=compression)
    packed, plain = load_transitions(tmp_path / "zstd.mcap", finite=False), load_transitions(tmp_path / "none.mcap", finite=False)
    np.testing.assert_array_equal(packed.observations, plain.observations)
    np.testing.assert_array_equal(packed.next_observations, plain.next_observations)
    assert plain.observations.flags.owndata  # a copy: the mapped file may change after loading


DICT_SPACE = gym.spaces.Dict({"pos": gym.spaces.Box(-1, 1, (2,), np.float32), "mode": gym.spaces.Discrete(3)})


def _assert_transitions_equal(actual, expected) -> None:
    for name in ("observations", "actions", "rewards", "next_observations", "terminated", "truncated", "episode_index"):
        a, b = getattr(actual, name), getattr(expected, name)
        if b is None:
            assert a is None, name
            continue
        for key in a if isinstance(a, dict) else [None]:
            x, y = (a[key], b[key]) if key is not None else (a, b)
            assert x.dtype == y.dtype and x.shape == y.shape, name
            np.testing.assert_array_equal(x, y, err_msg=name)


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
@pytest.mark.parametrize("timestamps", [False, True])
def test_bulk_loading_equals_assembling_episodes(tmp_path, compression, timestamps) -> None:
    """load_transitions places blocks straight into the flat arrays (imitation/data/columns.py);
    with blocks that split episodes, episodes that span chunks, several files, subsets and
    recordings with their own timestamps (the general path) it must equal flattening episodes."""
    from imitation.data.columns import read_transitions
    from imitation.data.types import episodes_to_transitions

    episodes = [random_episode(DICT_SPACE, BOX, length, seed=i, terminated=i % 3 == 0) for i, length in enumerate([7, 0, 12, 5, 9, 1, 11])]
    if timestamps:
        episodes = [
            dataclasses.replace(episode, timestamps=10**9 * i + np.cumsum(np.random.default_rng(i).integers(1, 50, len(episode) + 1)) * 10**6)
            for i, episode in enumerate(episodes)
        ]
    options = dict(finite_only=False, env_id="T", observation_space=DICT_SPACE, action_space=BOX, block_steps=4, chunk_size=300, compression=compression)
    # Three files, so that each file's episodes are numbered after all the files before it.
    paths = [write_episodes(tmp_path / name, part, **options) for name, part in (("a.mcap", episodes[:3]), ("b.mcap", episodes[3:5]), ("c.mcap", episodes[5:]))]
    dataset = DemoDataset(paths)
    for subset in (None, [2, 4, 5], [6]):
        indices = list(range(len(dataset))) if subset is None else subset
        for next_observations in (True, False):
            expected = episodes_to_transitions(dataset.read_episodes(indices), indices, next_observations=next_observations)
            assert (read_transitions(dataset, indices, next_observations=next_observations) is None) == timestamps
            _assert_transitions_equal(load_transitions(dataset, episodes=subset, next_observations=next_observations, finite=False), expected)


def _finite_episodes(lengths: list[int]) -> list:
    from imitation.data.types import Episode

    rng = np.random.default_rng(0)
    return [
        Episode(observations=rng.normal(size=(n + 1, 3)).astype(np.float32), actions=rng.integers(0, 4, n), rewards=rng.normal(size=n), truncated=True)
        for n in lengths
    ]


@pytest.mark.parametrize(
    ("field", "row", "next_observations", "named"),
    [
        ("observations", 2, False, "episode 1, step 2: the observation is nan"),
        ("observations", 5, True, "episode 1, step 5: the observation is nan"),  # the final state: only s' holds it
        ("rewards", 3, False, "episode 1, step 3: the reward is nan"),
    ],
)
def test_loading_for_training_names_the_file_episode_and_step_of_a_nan(tmp_path, field, row, next_observations, named) -> None:
    """b.mcap's second episode (dataset-wide episode 3) holds a NaN, stored as is by a writer
    that does not check; the loader names b.mcap, the episode within it and the step."""
    episodes = _finite_episodes([4, 6, 3, 5])
    array = getattr(episodes[3], field).copy()
    array[row] = np.nan
    episodes[3] = dataclasses.replace(episodes[3], **{field: array})
    options = dict(env_id="T", observation_space=BOX, action_space=ACTIONS, finite_only=False)
    paths = [write_episodes(tmp_path / "a.mcap", episodes[:2], **options), write_episodes(tmp_path / "b.mcap", episodes[2:], **options)]
    with pytest.raises(ImitationError, match=f"^{paths[1]}: {named}; learners need finite"):
        load_transitions(paths, next_observations=next_observations)
    if row == 5:  # the final observation is not part of any transition without s'
        assert len(load_transitions(paths, next_observations=False)) == 18
    assert len(load_transitions(paths, episodes=[0, 1, 2])) == 13  # other episodes are fine
    assert len(load_transitions(paths, next_observations=next_observations, finite=False)) == 18


def test_a_huge_finite_reward_loads_as_itself(tmp_path) -> None:
    """Rewards stay float64 on both paths: 1e300 is finite and must not become inf (float32)."""
    episode = dataclasses.replace(_finite_episodes([4])[0], rewards=np.array([1.0, 1e300, -1e300, 2.0]))
    path = write_episodes(tmp_path / "big.mcap", [episode], env_id="T", observation_space=BOX, action_space=ACTIONS)
    transitions = load_transitions(path)
    assert transitions.rewards.dtype == np.float64
    np.testing.assert_array_equal(transitions.rewards, episode.rewards)


def test_pieces_tile_only_without_gaps_or_overlaps() -> None:
    from imitation.data.columns import _tiles

    assert _tiles([(4, 2), (0, 4)], 6)
    assert not _tiles([(0, 2), (3, 3)], 6)  # a gap at row 2
    assert not _tiles([(0, 4), (2, 4)], 6)  # rows 2 and 3 twice
    assert not _tiles([(0, 4)], 6)
    assert _tiles([], 0)


@pytest.mark.parametrize(
    ("topic", "nth", "change"),
    [
        pytest.param("/observation", 4, lambda log_time, data: (log_time + 1, data), id="off-grid log time"),
        pytest.param("/observation", 4, lambda log_time, data: (log_time, data + b"\0"), id="a block with a partial row"),
        pytest.param("/action", 2, lambda log_time, data: (log_time, data + bytes(8)), id="a block past its episode's end"),
    ],
)
def test_blocks_not_placed_by_their_time_leave_the_bulk_path(tmp_path, topic, nth, change) -> None:
    """One block (the second observation block of episode 1, or episode 0's last action block) is
    moved 1 ns off its time grid, has a byte too many, or a row more than its episode holds: the
    bulk loader must not place it, and hands the file to the general path."""
    from imitation.data.columns import read_transitions

    episodes = _finite_episodes([6, 9, 5])
    good = write_episodes(tmp_path / "good.mcap", episodes, env_id="T", observation_space=BOX, action_space=ACTIONS, block_steps=4)
    seen = []

    def change_one(message_topic, log_time, data):
        if message_topic == topic:
            seen.append(log_time)
            if len(seen) == nth:
                return change(log_time, data)
        return log_time, data

    rewrite_messages(good, tmp_path / "bad.mcap", change_one)
    rewrite_messages(good, tmp_path / "copy.mcap", lambda message_topic, log_time, data: (log_time, data))
    assert read_transitions(DemoDataset(tmp_path / "copy.mcap"), [0, 1, 2], next_observations=True) is not None
    assert read_transitions(DemoDataset(tmp_path / "bad.mcap"), [0, 1, 2], next_observations=True) is None

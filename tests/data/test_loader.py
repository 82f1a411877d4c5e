"""Demos → torch: transitions line up with episodes, splits are by episode, batches are seeded."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from helpers import random_episode

from imitation.data.loader import MinibatchLoader, load_transitions, resolve_device, split_episodes, transitions_to_torch
from imitation.data.store import DemoDataset, write_episodes
from imitation.errors import ImitationError

BOX = gym.spaces.Box(-1, 1, (3,), np.float32)
ACTIONS = gym.spaces.Discrete(4)


@pytest.fixture
def demo_paths(tmp_path):
    episodes = [random_episode(BOX, ACTIONS, length, seed=i, terminated=i == 1) for i, length in enumerate([4, 6, 3, 5])]
    write_episodes(tmp_path / "a.mcap", episodes[:2], env_id="T", observation_space=BOX, action_space=ACTIONS)
    write_episodes(tmp_path / "b.mcap", episodes[2:], env_id="T", observation_space=BOX, action_space=ACTIONS)
    return [tmp_path / "a.mcap", tmp_path / "b.mcap"], episodes


def test_transitions_line_up_with_their_episodes(demo_paths) -> None:
    paths, episodes = demo_paths
    transitions = load_transitions(paths)
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
    whole = load_transitions(paths)
    subset = load_transitions(DemoDataset(paths), episodes=[3, 1])
    mask = np.isin(whole.episode_index, [1, 3])
    np.testing.assert_array_equal(subset.observations, whole.observations[mask])
    np.testing.assert_array_equal(subset.episode_index, whole.episode_index[mask])
    with pytest.raises(ImitationError, match="episode indices"):
        load_transitions(paths, episodes=[9])


def test_torch_tensors_keep_dtypes_and_share_cpu_memory(demo_paths) -> None:
    paths, _ = demo_paths
    transitions = load_transitions(paths)
    tensors = transitions_to_torch(transitions, "cpu")
    assert tensors.observations.dtype == torch.float32 and tensors.actions.dtype == torch.int64
    assert tensors.terminated.dtype == torch.bool and tensors.rewards.dtype == torch.float32
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
    tensors = transitions_to_torch(load_transitions(paths))
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
    write_episodes(tmp_path / "d.mcap", [random_episode(space, ACTIONS, 7, seed=0)], env_id="T", observation_space=space, action_space=ACTIONS)
    tensors = transitions_to_torch(load_transitions(tmp_path / "d.mcap"))
    assert tensors.observations["pos"].shape == (7, 2) and tensors.next_observations["cell"].shape == (7,)
    batch = next(iter(MinibatchLoader(tensors, batch_size=3, seed=0)))
    assert batch.observations["pos"].shape == (3, 2)


def test_device_selection() -> None:
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type in ("cpu", "cuda")
    if not torch.cuda.is_available():
        with pytest.raises(ImitationError, match="CUDA is not available"):
            resolve_device("cuda")
    with pytest.raises(ImitationError, match="--device 'potato'"):
        resolve_device("potato")


def test_next_observations_can_be_left_out(demo_paths) -> None:
    paths, _ = demo_paths
    without = load_transitions(paths, next_observations=False)
    assert without.next_observations is None
    np.testing.assert_array_equal(without.observations, load_transitions(paths).observations)
    tensors = transitions_to_torch(without)
    assert tensors.next_observations is None
    batch = next(iter(MinibatchLoader(tensors, batch_size=4, seed=0)))
    assert batch.next_observations is None and batch.observations.shape == (4, 3)


def test_uncompressed_files_load_the_same(tmp_path) -> None:
    episodes = [random_episode(BOX, ACTIONS, 9, seed=i) for i in range(3)]
    for compression in ("zstd", "none"):
        write_episodes(tmp_path / f"{compression}.mcap", episodes, env_id="T", observation_space=BOX, action_space=ACTIONS, compression=compression)
    packed, plain = load_transitions(tmp_path / "zstd.mcap"), load_transitions(tmp_path / "none.mcap")
    np.testing.assert_array_equal(packed.observations, plain.observations)
    np.testing.assert_array_equal(packed.next_observations, plain.next_observations)
    assert plain.observations.flags.owndata  # a copy: the mapped file may change after loading

"""Sequence windows (imitation/data/windows.py) against episodes built by hand: the observation
history repeats an episode's first observation before its start, the action chunk its last action
past its end, the pad masks say which, and no window crosses into another episode. Then the same
on a real demo file, checked row by row against its episodes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from support import DATASETS

from imitation.data.dataset import DemoDataset
from imitation.data.loader import TransitionTensors, load_transitions, transitions_to_torch
from imitation.data.windows import WindowSpec, gather_windows, window_index
from imitation.errors import ImitationError


def _hand_built() -> TransitionTensors:
    """Episode 7 of 3 steps (observations 10, 11, 12; actions 0, 1, 2), then episode 2 of 2 steps
    (observations 20, 21; actions 3, 4), with a Dict observation beside it (its 'id' leaf the row)."""
    rows = 5
    return TransitionTensors(
        observations={"state": torch.tensor([[10.0], [11.0], [12.0], [20.0], [21.0]]), "id": torch.arange(rows)},
        actions=torch.tensor([0, 1, 2, 3, 4]),
        rewards=torch.zeros(rows),
        next_observations=None,
        terminated=torch.zeros(rows, dtype=torch.bool),
        truncated=torch.zeros(rows, dtype=torch.bool),
        episode_index=torch.tensor([7, 7, 7, 2, 2]),
    )


def test_windows_repeat_the_episode_edges_and_mask_them() -> None:
    data = _hand_built()
    index = window_index(data.episode_index.numpy(), WindowSpec(observations=2, actions=3))
    batch = gather_windows(data, index, np.arange(5))
    assert batch.observations["state"][..., 0].tolist() == [[10, 10], [10, 11], [11, 12], [20, 20], [20, 21]]
    assert batch.observation_pad.tolist() == [[True, False], [False, False], [False, False], [True, False], [False, False]]
    assert batch.actions.tolist() == [[0, 1, 2], [1, 2, 2], [2, 2, 2], [3, 4, 4], [4, 4, 4]]
    assert batch.action_pad.tolist() == [
        [False, False, False],
        [False, False, True],
        [False, True, True],
        [False, False, True],
        [False, True, True],
    ]
    assert batch.observations["id"].tolist() == [[0, 0], [0, 1], [1, 2], [3, 3], [3, 4]]


def test_a_minibatch_gathers_only_its_rows() -> None:
    data = _hand_built()
    index = window_index(data.episode_index.numpy(), WindowSpec(observations=3, actions=1))
    batch = gather_windows(data, index, np.array([4, 0]))
    assert len(batch) == 2
    assert batch.observations["state"][..., 0].tolist() == [[20, 20, 21], [10, 10, 10]]
    assert batch.observation_pad.tolist() == [[True, False, False], [True, True, False]]
    assert batch.actions.tolist() == [[4], [0]] and not batch.action_pad.any()


def test_one_step_windows_are_the_transitions_themselves() -> None:
    data = _hand_built()
    batch = gather_windows(data, window_index(data.episode_index.numpy(), WindowSpec()), np.arange(5))
    assert torch.equal(batch.observations["state"][:, 0], data.observations["state"])
    assert torch.equal(batch.actions[:, 0], data.actions)
    assert not batch.observation_pad.any() and not batch.action_pad.any()


def test_windows_on_a_demo_file_stay_within_their_episodes() -> None:
    dataset = DemoDataset([DATASETS / "Pendulum-v1.mcap"])
    transitions = load_transitions(dataset, next_observations=False)
    data = transitions_to_torch(transitions)
    spec = WindowSpec(observations=2, actions=16)
    index = window_index(transitions.episode_index, spec)
    batch = gather_windows(data, index, np.arange(len(data)))
    episodes = dataset.episodes
    row = 0
    for episode_number in range(len(dataset)):
        steps = episodes[episode_number].length
        actions = np.asarray(transitions.actions[row : row + steps])
        for t in (0, 1, steps - 16, steps - 1):
            expected = actions[np.minimum(np.arange(t, t + 16), steps - 1)]
            assert np.array_equal(batch.actions[row + t].numpy(), expected)
            assert batch.action_pad[row + t].tolist() == [t + k >= steps for k in range(16)]
        assert batch.observation_pad[row].tolist() == [True, False]
        assert torch.equal(batch.observations[row, 0], batch.observations[row, 1])
        row += steps
    assert row == len(data)


@pytest.mark.parametrize(
    ("episodes", "message"),
    [
        (np.array([0, 0, 1, 1, 0]), "contiguous"),
        (np.zeros((2, 2), dtype=np.int64), "one per transition"),
    ],
)
def test_episodes_out_of_order_are_refused(episodes: np.ndarray, message: str) -> None:
    with pytest.raises(ImitationError, match=message):
        window_index(episodes, WindowSpec())


def test_the_longest_window_is_allowed() -> None:
    spec = WindowSpec(observations=1024, actions=1024)
    assert (spec.observations, spec.actions) == (1024, 1024)


@pytest.mark.parametrize("value", [0, -1, 1025, 2.0, True])
def test_window_lengths_are_checked(value: object) -> None:
    with pytest.raises(ImitationError, match="whole number in"):
        WindowSpec(observations=value)  # type: ignore[arg-type]
    with pytest.raises(ImitationError, match="whole number in"):
        WindowSpec(actions=value)  # type: ignore[arg-type]

"""The episode-tail split offline BC uses when there are too few episodes to hold whole ones out."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from helpers import random_episode

from imitation.data.loader import split_episode_tails
from imitation.data.types import episodes_to_transitions

BOX = gym.spaces.Box(-1, 1, (3,), np.float32)
ACTIONS = gym.spaces.Discrete(4)


def test_episode_tails_for_data_with_too_few_episodes() -> None:
    episodes = [random_episode(BOX, ACTIONS, length, seed=length) for length in (10, 1, 5)]
    train, validation = split_episode_tails(episodes_to_transitions(episodes), validation_fraction=0.2)
    # The last 2 of 10 steps and the last 1 of 5; a 1-step episode keeps its only step for training.
    assert validation.tolist() == [8, 9, 15] and sorted(train.tolist() + validation.tolist()) == list(range(16))
    assert split_episode_tails(episodes_to_transitions(episodes), validation_fraction=0.0)[1].size == 0

"""Play one episode of a policy in an environment: the loop that recording and evaluation share."""

from __future__ import annotations

from typing import Any, Callable

import gymnasium as gym
import numpy as np

Policy = Callable[[Any], Any]


def play_episode(env: gym.Env, policy: Policy, *, seed: int | None) -> tuple[float, int]:
    """Reset with `seed`, act with `policy` until the episode ends; its return and length."""
    observation, _ = env.reset(seed=seed)
    episode_return, length, done = 0.0, 0, False
    while not done:
        observation, reward, terminated, truncated, _ = env.step(policy(observation))
        episode_return += float(reward)
        length += 1
        done = terminated or truncated
    return episode_return, length


def collect_transitions(env: gym.Env, policy: Policy, *, episodes: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(s, a, s') of every step of `episodes` episodes (episode i reset with seed `seed + i`)."""
    observations, actions, next_observations = [], [], []
    for i in range(episodes):
        observation, _ = env.reset(seed=seed + i)
        done = False
        while not done:
            action = policy(observation)
            next_observation, _, terminated, truncated, _ = env.step(action)
            observations.append(observation)
            actions.append(action)
            next_observations.append(next_observation)
            observation, done = next_observation, terminated or truncated
    return np.asarray(observations), np.asarray(actions), np.asarray(next_observations)

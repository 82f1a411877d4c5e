"""Play one episode of a policy in an environment: the loop that recording and evaluation share."""

from __future__ import annotations

from typing import Any, Callable

import gymnasium as gym

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

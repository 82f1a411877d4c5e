"""Evaluate a policy by its return in an environment: seeded episodes, deterministic by default."""

from __future__ import annotations

from typing import Any, Callable

import gymnasium as gym
import numpy as np

Policy = Callable[[Any], Any]


def evaluate_policy(policy: Policy, env: gym.Env, *, episodes: int = 10, seed: int = 0) -> dict[str, Any]:
    """Run `episodes` episodes (episode i reset with seed `seed + i`); return statistics."""
    returns, lengths = [], []
    for i in range(episodes):
        observation, _ = env.reset(seed=seed + i)
        episode_return, length, done = 0.0, 0, False
        while not done:
            observation, reward, terminated, truncated, _ = env.step(policy(observation))
            episode_return += float(reward)
            length += 1
            done = terminated or truncated
        returns.append(episode_return)
        lengths.append(length)
    values = np.asarray(returns)
    return {
        "mean_return": float(values.mean()),
        "std_return": float(values.std()),
        "min_return": float(values.min()),
        "max_return": float(values.max()),
        "mean_length": float(np.mean(lengths)),
        "episodes": episodes,
        "returns": returns,
    }

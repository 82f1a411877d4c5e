"""Evaluate a policy by its return in an environment: seeded episodes, deterministic by default."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from imitation.envs.rollout import Policy, play_episode


def evaluate_policy(policy: Policy, env: gym.Env, *, episodes: int = 10, seed: int = 0) -> dict[str, Any]:
    """Run `episodes` episodes (episode i reset with seed `seed + i`); return statistics."""
    returns, lengths = [], []
    for i in range(episodes):
        episode_return, length = play_episode(env, policy, seed=seed + i)
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

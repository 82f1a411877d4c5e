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


def normalized_return(policy_stats: dict[str, Any], env: gym.Env, demos: list[str], *, seed: int) -> dict[str, Any]:
    """The policy's mean return between a uniform random policy (0, same episodes and seeds) and
    the demos' mean return (1)."""
    from imitation.data.dataset import DemoDataset
    from imitation.experts.load import load_expert

    expert_return = float(np.mean([facts.episode_return for facts in DemoDataset(demos).episodes]))
    random_return = evaluate_policy(load_expert("random", env, seed=seed), env, episodes=policy_stats["episodes"], seed=seed)[
        "mean_return"
    ]
    return {
        "normalized_return": (policy_stats["mean_return"] - random_return) / (expert_return - random_return),
        "reference": {"expert_return": expert_return, "random_return": random_return, "demos": demos},
    }

"""Evaluate a policy by its return in an environment: seeded episodes, deterministic by default."""

from __future__ import annotations

import json
import os
from pathlib import Path
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


def run_demos(run: str | os.PathLike) -> list[str]:
    """The demo files a run learnt from, as its config.json names them: BC, DAgger and reward
    runs directly, a PPO run on a learned reward through its reward run. Empty if none (or gone)."""
    config = json.loads((Path(run) / "config.json").read_text())
    demos = config.get("demos") or []
    reward_run = (config.get("ppo") or {}).get("reward_run")
    if not demos and reward_run and (Path(reward_run) / "config.json").is_file():
        demos = run_demos(reward_run)
    return [str(path) for path in demos if Path(path).is_file()]


def normalized_return(policy_stats: dict[str, Any], env: gym.Env, demos: list[str], *, seed: int) -> dict[str, Any]:
    """The policy's mean return between a uniform random policy (0, same episodes and seeds) and
    the demos' mean return (1)."""
    from imitation.data.store import DemoDataset
    from imitation.experts.load import load_expert

    expert_return = float(np.mean([facts.episode_return for facts in DemoDataset(demos).episodes]))
    random_return = evaluate_policy(load_expert("random", env, seed=seed), env, episodes=policy_stats["episodes"], seed=seed)["mean_return"]
    return {
        "normalized_return": (policy_stats["mean_return"] - random_return) / (expert_return - random_return),
        "reference": {"expert_return": expert_return, "random_return": random_return, "demos": demos},
    }

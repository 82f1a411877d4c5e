"""Evaluate a policy by its return in an environment: seeded episodes, deterministic by default."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from imitation.envs.rollout import Policy, play_episode
from imitation.evaluation.task_measures import EpisodeMeasures, averaged

# Evaluation episodes start here, away from training and demo seeds; every run's final evaluation
# and the random policy's reference return use them.
EVAL_SEED = 10_000
EVAL_EPISODES = 10


def evaluate_policy(policy: Policy, env: gym.Env, *, episodes: int = 10, seed: int = 0) -> dict[str, Any]:
    """Run `episodes` episodes (episode i reset with seed `seed + i`); return statistics, with
    the task's own measures where the env's infos report them (success rate, PushT's coverage)."""
    returns, lengths, measured = [], [], []
    for i in range(episodes):
        measures = EpisodeMeasures()
        episode_return, length = play_episode(env, policy, seed=seed + i, on_info=measures.step)
        returns.append(episode_return)
        lengths.append(length)
        measured.append(measures.result())
    values = np.asarray(returns)
    return {
        "mean_return": float(values.mean()),
        "std_return": float(values.std()),
        "min_return": float(values.min()),
        "max_return": float(values.max()),
        "mean_length": float(np.mean(lengths)),
        "episodes": episodes,
        "returns": returns,
        **averaged(measured),
    }


def reference_returns(env: gym.Env, demos: list[str]) -> dict[str, Any]:
    """The two ends of a normalised return, computed one way everywhere: uniform random actions
    (0) over EVAL_EPISODES episodes seeded EVAL_SEED + i, and the demos' mean return (1)."""
    from imitation.data.dataset import DemoDataset
    from imitation.experts.load import load_expert

    dataset = DemoDataset(demos)
    random_policy = load_expert("random", env, seed=EVAL_SEED)
    return {
        "expert_return": float(np.mean([facts.episode_return for facts in dataset.episodes])),
        "random_return": evaluate_policy(random_policy, env, episodes=EVAL_EPISODES, seed=EVAL_SEED)["mean_return"],
        "source": f"the demos' mean return ({len(dataset)} episodes); uniform random actions ({EVAL_EPISODES} episodes, "
        f"seeds {EVAL_SEED}-{EVAL_SEED + EVAL_EPISODES - 1})",
        "demos": [str(path) for path in demos],
    }


def normalized(value: float, random: float, expert: float) -> float:
    """(R − R_random)/(R_expert − R_random): 0 for the random policy, 1 for the expert."""
    return (value - random) / (expert - random)


def normalized_return(policy_stats: dict[str, Any], env: gym.Env, demos: list[str]) -> dict[str, Any]:
    """The policy's mean return between the two ends of `reference_returns`; where a demo file
    was converted from a source without rewards (they are zero), no normalised return but why."""
    from imitation.data.convert.converted import REWARDS_RECORDED
    from imitation.data.mcap.reader import DemoFile

    for path in demos:
        if DemoFile(path).user_metadata.get(REWARDS_RECORDED) is False:
            return {"no_normalized_return": f"{path} was converted from a source without rewards (they are zero)"}
    reference = reference_returns(env, demos)
    return {
        "normalized_return": normalized(policy_stats["mean_return"], reference["random_return"], reference["expert_return"]),
        "reference": reference,
    }

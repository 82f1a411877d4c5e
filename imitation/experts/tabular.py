"""The expert of a tabular MDP: its soft-optimal policy under the true reward.

Soft value iteration (the backward pass of `imitation.algorithms.maxent_irl`) gives a
time-indexed policy π_t(a|s) ∝ exp Q_t(s, a); the expert reads the env's clock to pick π_t and
samples its action from a seeded generator, so recordings are reproducible. This is exactly the
demonstrator that maximum (causal) entropy IRL assumes.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from imitation.algorithms.maxent_irl import Dynamics, soft_value_iteration
from imitation.envs.tabular import TabularEnv, TabularMDP


def soft_optimal_policy(mdp: TabularMDP, reward: np.ndarray | None = None, *, discount: float | None = None) -> np.ndarray:
    """π_t(a|s) of shape (H, S, A), soft-optimal (causal, for any dynamics) for `reward` (default:
    the MDP's true one) and `discount` (default: the MDP's)."""
    dynamics = Dynamics.of(mdp.transition)
    reward = mdp.reward if reward is None else reward
    policy, _ = soft_value_iteration(dynamics, reward, horizon=mdp.horizon, discount=mdp.discount if discount is None else discount)
    return policy


class SoftOptimalExpert:
    """Acts in `env` (a TabularEnv, possibly wrapped) by sampling π_t(·|s) at the env's time t."""

    def __init__(self, env: gym.Env, *, seed: int) -> None:
        unwrapped = env.unwrapped
        assert isinstance(unwrapped, TabularEnv)
        self.env = unwrapped
        self.policy = soft_optimal_policy(unwrapped.mdp)
        self.rng = np.random.default_rng(seed)

    def __call__(self, observation: int) -> int:
        t = min(self.env.time_step, len(self.policy) - 1)
        return int(self.rng.choice(self.policy.shape[2], p=self.policy[t, int(observation)]))

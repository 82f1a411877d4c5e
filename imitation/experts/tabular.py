"""The expert of a tabular MDP: its soft-optimal policy under the true reward.

Soft value iteration (`imitation.envs.tabular_planning`) gives a
time-indexed policy π_t(a|s) ∝ exp Q_t(s, a); the expert reads the env's clock to pick π_t and
samples its action from a seeded generator, so recordings are reproducible. This is exactly the
demonstrator that maximum (causal) entropy IRL assumes.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from imitation.envs.tabular import TabularEnv
from imitation.envs.tabular_planning import soft_optimal_policy


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

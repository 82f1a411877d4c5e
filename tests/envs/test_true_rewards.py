"""The true-reward functions restate each env's `step` reward: checked on real rollouts."""

from __future__ import annotations

import numpy as np
import pytest

import imitation.envs  # noqa: F401 - registers the imitation/ envs
from imitation.envs.make import make_env
from imitation.envs.true_rewards import true_reward


@pytest.mark.parametrize("env_id", ["Pendulum-v1", "imitation/CartPoleFixedHorizon-v0", "CartPole-v1", "MountainCar-v0", "imitation/GridWorld8x8Slippery-v0"])
def test_true_reward_matches_the_env_step(env_id: str) -> None:
    env = make_env(env_id)
    reward = true_reward(env_id, env)
    assert reward is not None
    env.action_space.seed(0)
    observations, actions, next_observations, rewards = [], [], [], []
    observation, _ = env.reset(seed=0)
    for _ in range(300):
        action = env.action_space.sample()
        next_observation, step_reward, terminated, truncated, _ = env.step(action)
        observations.append(observation)
        actions.append(action)
        next_observations.append(next_observation)
        rewards.append(step_reward)
        observation = next_observation
        if terminated or truncated:
            observation, _ = env.reset()
    np.testing.assert_allclose(reward(np.array(observations), np.array(actions), np.array(next_observations)), rewards, rtol=1e-5, atol=1e-5)
    if env_id == "imitation/CartPoleFixedHorizon-v0":
        assert 0 < np.mean(rewards) < 1, "the rollout should both balance and fail"


def test_envs_without_a_known_reward_get_none() -> None:
    assert true_reward("Acrobot-v1", make_env("Acrobot-v1")) is None

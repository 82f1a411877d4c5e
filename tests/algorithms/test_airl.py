"""AIRL's shaped reward f = g + γ (1 − d) h(s') − h(s) (imitation.algorithms.airl) on a rollout of
several envs, with a reward g of (s, a, s'): each step's f computed by hand from g's and h's
weights, in the rollout's (T, n_envs) layout."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from imitation.algorithms.airl import ShapedReward
from imitation.envs.rollout import Rollout
from imitation.rewards import RewardNet, make_reward_model

BOX2 = gym.spaces.Box(-10.0, 10.0, (2,), np.float32)


def linear(weights: list[float], *, inputs: str) -> RewardNet:
    """r = weights · (s, one-hot a, s') as far as `inputs` reads them."""
    net = make_reward_model(BOX2, gym.spaces.Discrete(2), hidden_sizes=[], inputs=inputs, output="linear")
    with torch.no_grad():
        net.net[-1].weight.zero_()
        net.net[-1].weight[0, : len(weights)] = torch.tensor(weights)
        net.net[-1].bias.zero_()
    return net


def test_a_shaped_reward_of_g_reading_s_a_and_s_next_is_computed_step_by_step() -> None:
    # g(s, a, s') = s₀ + 2·[a = 1] + 3·s'₁, h(s) = s₁, γ = ½; 2 steps of 3 envs, env 1 ends at step 0.
    observations = torch.tensor([[[1.0, 2.0], [0.0, -1.0], [4.0, 1.0]], [[2.0, 0.5], [3.0, 3.0], [-2.0, 1.5]]])
    next_observations = torch.tensor([[[2.0, 0.5], [5.0, 7.0], [-2.0, 1.5]], [[1.0, -1.0], [6.0, 2.0], [0.0, 4.0]]])
    actions = torch.tensor([[1, 0, 1], [0, 1, 1]])
    terminated = torch.tensor([[False, True, False], [False, False, True]])
    rollout = Rollout(
        observations=observations,
        actions=actions,
        env_actions=actions,
        next_observations=next_observations,
        log_probs=torch.zeros(2, 3),
        env_rewards=torch.zeros(2, 3),
        terminated=terminated,
        truncated=torch.zeros(2, 3, dtype=torch.bool),
    )
    shaped = ShapedReward(linear([1.0, 0.0, 0.0, 2.0, 0.0, 3.0], inputs="sas"), linear([0.0, 1.0], inputs="s"), gamma=0.5)
    expected = [
        [
            float(s[0]) + 2.0 * int(a) + 3.0 * float(s_next[1]) + 0.5 * (1 - int(d)) * float(s_next[1]) - float(s[1])
            for s, a, s_next, d in zip(observations[t], actions[t], next_observations[t], terminated[t])
        ]
        for t in range(2)
    ]
    f = shaped.relabel(rollout)
    assert f.shape == (2, 3)
    np.testing.assert_allclose(f.numpy(), expected, atol=1e-6)
    assert expected[0] == pytest.approx([1 + 2 + 1.5 + 0.25 - 2, 0 + 21 + 1, 4 + 2 + 4.5 + 0.75 - 1])

"""AIRL (imitation.algorithms.airl) with a reward g of (s, a, s'): the shaped reward
f = g + γ (1 − d) h(s') − h(s) on a rollout of several envs, in its (T, n_envs) layout, and the
discriminator's logit f − log π and PPO reward f − α log π, each computed by hand from g's and
h's weights; a potential h must be of the state alone."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch

from imitation.algorithms.adversarial import Steps
from imitation.algorithms.airl import AIRLDiscriminator
from imitation.rewards import ShapedReward
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


def test_airls_logit_and_ppo_reward_read_g_of_s_a_and_s_next() -> None:
    # g(s, a, s') = s₀ + 2·[a = 1] + 3·s'₁, h(s) = s₁, γ = ½, α = ½. Step 1: s = (1, 2), a = 1,
    # s' = (0, 4): f = 1 + 2 + 12 + 2 − 2 = 15. Step 2: s = (3, −1), a = 0, s' = (5, 6), ended:
    # f = 3 + 18 + 1 = 22. log π = (ln ¼, ln ½).
    g = linear([1.0, 0.0, 0.0, 2.0, 0.0, 3.0], inputs="sas")
    discriminator = AIRLDiscriminator(g, linear([0.0, 1.0], inputs="s"), gamma=0.5, policy_entropy=0.5)
    batch = Steps(
        torch.tensor([[1.0, 2.0], [3.0, -1.0]]),
        torch.tensor([1, 0]),
        torch.tensor([[0.0, 4.0], [5.0, 6.0]]),
        torch.tensor([0.0, 1.0]),
    )
    log_pi = torch.tensor([math.log(0.25), math.log(0.5)])
    logits, inputs = discriminator.logits(batch, log_pi, penalised=True)
    assert logits.tolist() == pytest.approx([15 + math.log(4), 22 + math.log(2)], abs=1e-5)
    assert all(tensor.requires_grad for tensor in inputs) and len(inputs) == 3
    rewards = discriminator.policy_rewards(batch, log_pi)
    assert rewards.tolist() == pytest.approx([15 + 0.5 * math.log(4), 22 + 0.5 * math.log(2)], abs=1e-5)


def test_airls_potential_must_be_of_the_state_alone() -> None:
    for inputs in ("sa", "sas"):
        with pytest.raises(ValueError) as error:
            AIRLDiscriminator(linear([1.0], inputs="s"), linear([1.0], inputs=inputs), gamma=0.9)
        assert str(error.value) == "AIRL's potential h is a function of the state alone"

"""GAIL's discriminator (imitation.algorithms.gail) with a net of (s, a, s'): its logit d(s, a, s')
and PPO's reward softplus(d), computed by hand from the net's weights; the inputs want a
gradient exactly when the step is penalised."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch

from imitation.algorithms.adversarial import Steps
from imitation.algorithms.gail import GAILDiscriminator
from imitation.rewards import make_reward_model


def test_gails_logit_and_reward_read_s_a_and_s_next() -> None:
    # d = s₀ + 2·[a = 1] + 3·s'₁ − 1: step 1, s = (1, 2), a = 1, s' = (0, 4): d = 14; step 2,
    # s = (−3, 0), a = 0, s' = (5, 0.5): d = −2.5.
    net = make_reward_model(
        gym.spaces.Box(-10.0, 10.0, (2,), np.float32), gym.spaces.Discrete(2), hidden_sizes=[], inputs="sas", output="softplus"
    )
    with torch.no_grad():
        net.net[-1].weight.copy_(torch.tensor([[1.0, 0.0, 0.0, 2.0, 0.0, 3.0]]))
        net.net[-1].bias.fill_(-1.0)
    discriminator = GAILDiscriminator(net)
    batch = Steps(
        torch.tensor([[1.0, 2.0], [-3.0, 0.0]]),
        torch.tensor([1, 0]),
        torch.tensor([[0.0, 4.0], [5.0, 0.5]]),
        torch.tensor([0.0, 1.0]),
    )
    for penalised in (True, False):
        logits, inputs = discriminator.logits(batch, None, penalised=penalised)
        assert logits.tolist() == pytest.approx([14.0, -2.5], abs=1e-5)
        assert [tensor.requires_grad for tensor in inputs] == [penalised]
    rewards = discriminator.policy_rewards(batch, None)
    assert rewards.tolist() == pytest.approx([math.log1p(math.exp(14.0)), math.log1p(math.exp(-2.5))], abs=1e-5)
    assert discriminator.reward_nets() == [net] and discriminator.recovered_reward() is net

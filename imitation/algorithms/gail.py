"""Generative adversarial imitation learning (Ho & Ermon 2016; docs/THEORY.md §8.5).

The discriminator is a free classifier of (s, a), D = σ(d(s, a)), trained by
`imitation.algorithms.adversarial`'s loss; PPO optimises (`AdversarialConfig.gail_reward`)

    "softplus":  r(s, a) = −log(1 − D(s, a)) = softplus(d(s, a))      (Ho & Ermon's),
    "logit":     r(s, a) = log D(s, a) − log(1 − D(s, a)) = d(s, a),

both high where a step looks like the demos'. The first flattens to 0 wherever D is sure a step is
the policy's (d ≪ 0), so a discriminator that wins early leaves PPO little to climb; the logit keeps
its slope there, and is what many GAIL implementations optimise (it is AIRL's reward with f = d
and no entropy term). At the optimum the policy's occupancy measure matches the demos', the
imitation Ho & Ermon derive from IRL composed with RL. D is exported as a reward too, with the
caveat that it is not a recovered reward: at the saddle point it is ½ everywhere, and its value
between is only what told the current policy from the demos.
"""

from __future__ import annotations

import torch
from torch import nn

from imitation.algorithms.adversarial import Steps
from imitation.rewards import RewardNet

# The reward net's output for each GAIL reward: the net pays the reward itself when exported.
GAIL_OUTPUTS = {"softplus": "softplus", "logit": "linear"}


class GAILDiscriminator(nn.Module):
    """D's logit d(s, a): a RewardNet whose output is the reward PPO optimises, softplus(d) or d
    itself, so that as an exported reward it pays that reward."""

    uses_policy = False

    def __init__(self, net: RewardNet) -> None:
        super().__init__()
        self.net = net

    def reward_nets(self) -> list[RewardNet]:
        return [self.net]

    def logits(self, steps: Steps, log_pi: torch.Tensor | None, *, penalised: bool) -> tuple[torch.Tensor, list[torch.Tensor]]:
        inputs = [
            tensor.requires_grad_(penalised)
            for tensor in self.net.prepare(steps.observations, steps.env_actions, steps.next_observations)
        ]
        return self.net.net_output(inputs), inputs

    def policy_rewards(self, steps: Steps, log_pi: torch.Tensor | None) -> torch.Tensor:
        return self.net.score(self.net.prepare(steps.observations, steps.env_actions, steps.next_observations))

    def recovered_reward(self) -> RewardNet:
        return self.net

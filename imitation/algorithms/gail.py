"""Generative adversarial imitation learning (Ho & Ermon 2016; docs/THEORY.md §8.5).

The discriminator is a free classifier of (s, a), D = σ(d(s, a)), trained by
`imitation.algorithms.adversarial`'s loss; PPO optimises

    r(s, a) = −log(1 − D(s, a)) = softplus(d(s, a)),

which is high where a step looks like the demos'. At the optimum the policy's occupancy measure
matches the demos', the imitation Ho & Ermon derive from IRL composed with RL. D is exported as a
reward too, with the caveat that it is not a recovered reward: at the saddle point it is ½
everywhere, and its value between is only what told the current policy from the demos.
"""

from __future__ import annotations

import torch
from torch import nn

from imitation.algorithms.adversarial import Steps
from imitation.rewards import RewardNet


def gail_reward(logits: torch.Tensor) -> torch.Tensor:
    """−log(1 − σ(logit)) = softplus(logit), computed stably."""
    return nn.functional.softplus(logits)


class GAILDiscriminator(nn.Module):
    """D's logit d(s, a): a RewardNet whose output is softplus, so that as an exported reward it
    pays −log(1 − D) itself."""

    uses_policy = False

    def __init__(self, net: RewardNet) -> None:
        super().__init__()
        if net.config.output != "softplus":
            raise ValueError("GAIL's reward net must have the softplus output, −log(1 − D)")
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
        logits, _ = self.logits(steps, None, penalised=False)
        return gail_reward(logits)

    def recovered_reward(self) -> RewardNet:
        return self.net

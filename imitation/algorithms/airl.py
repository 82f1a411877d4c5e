"""Adversarial inverse reinforcement learning (Fu, Luo & Levine 2018; docs/THEORY.md §8.5).

The discriminator is structured by the policy's own density, as in guided cost learning, with a
shaping term that lets the reward g be recovered apart from the dynamics:

    f(s, a, s') = g(s) + γ (1 − d) h(s') − h(s)        (d = 1 where s' ended the episode)
    D(s, a, s') = exp f / (exp f + π(a|s)),            logit D = f − log π(a|s)

trained by `imitation.algorithms.adversarial`'s loss. PPO optimises

    log D − log(1 − D) = f − log π(a|s),

maximum-entropy RL on f (α log π with α = `policy_entropy`, 1 by default). At the optimum f is the
advantage of the expert's soft-optimal policy, and for a state-only g (the default, `inputs="s"`)
with deterministic dynamics g recovers the true reward up to a constant, h the soft value; g is
the exported reward, for `train ppo --reward` and `eval reward`. `imitation.rewards.ShapedReward`
is f itself as PPO's reward (`train ppo --reward RUN --shaped`): g shaped by the learnt h.
"""

from __future__ import annotations

import torch
from torch import nn

from imitation.algorithms.adversarial import Steps
from imitation.rewards import RewardNet, airl_shaped_reward


class AIRLDiscriminator(nn.Module):
    """D from the reward g (a RewardNet, exported) and the potential h (a RewardNet on s)."""

    uses_policy = True

    def __init__(self, reward: RewardNet, potential: RewardNet, *, gamma: float, policy_entropy: float = 1.0) -> None:
        super().__init__()
        if potential.config.inputs != "s":
            raise ValueError("AIRL's potential h is a function of the state alone")
        self.reward = reward
        self.potential = potential
        self.gamma = gamma
        self.policy_entropy = policy_entropy

    def reward_nets(self) -> list[RewardNet]:
        return [self.reward, self.potential]

    def shaped(self, steps: Steps, *, penalised: bool = False) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """f of each step, and the inputs of g, h(s) and h(s') it is differentiable in."""
        parts = [
            self.reward.prepare(steps.observations, steps.env_actions, steps.next_observations),
            self.potential.prepare(steps.observations, steps.env_actions, steps.observations),
            self.potential.prepare(steps.next_observations, steps.env_actions, steps.next_observations),
        ]
        parts = [[tensor.requires_grad_(penalised) for tensor in part] for part in parts]
        g = self.reward.score(parts[0])
        potential, next_potential = self.potential.score(parts[1]), self.potential.score(parts[2])
        shaped = airl_shaped_reward(g, potential, next_potential, steps.terminated.to(g.device), self.gamma)
        return shaped, [tensor for part in parts for tensor in part]

    def logits(self, steps: Steps, log_pi: torch.Tensor | None, *, penalised: bool) -> tuple[torch.Tensor, list[torch.Tensor]]:
        assert log_pi is not None  # uses_policy
        shaped, inputs = self.shaped(steps, penalised=penalised)
        return shaped - log_pi.to(shaped.device), inputs

    def policy_rewards(self, steps: Steps, log_pi: torch.Tensor | None) -> torch.Tensor:
        assert log_pi is not None  # uses_policy
        shaped, _ = self.shaped(steps)
        return shaped - self.policy_entropy * log_pi.to(shaped.device)

    def recovered_reward(self) -> RewardNet:
        return self.reward

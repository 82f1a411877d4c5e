"""Advantage estimation shared by the on-policy learners (PPO, policy gradient's actor-critic):
truncated GAE(γ, λ) over a rollout (docs/THEORY.md §4),

    δ_t = r_t + γ (1 - term_t) V(s_{t+1}) - V(s_t)
    Â_t = δ_t + γ λ (1 - done_t) Â_{t+1}

where done_t = term_t or trunc_t. On truncation (a time limit) s_{t+1} is the episode's true final
state and V(s_{t+1}) is bootstrapped; on termination it is not. The critic's target is
R_t = Â_t + V(s_t).
"""

from __future__ import annotations

import torch


def compute_gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    next_values: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
    *,
    gamma: float,
    gae_lambda: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """GAE over a rollout of shape (T, n_envs); returns (advantages, returns = Â + V).

    `next_values[t]` is V(s_{t+1}) of the state that followed step t: the next state in the
    rollout, the true final state when step t was truncated, anything when it terminated."""
    not_terminal = 1.0 - terminated.float()
    continues = 1.0 - (terminated | truncated).float()
    deltas = rewards + gamma * not_terminal * next_values - values
    advantages = torch.zeros_like(rewards)
    running = torch.zeros_like(rewards[0])
    for t in reversed(range(rewards.shape[0])):
        running = deltas[t] + gamma * gae_lambda * continues[t] * running
        advantages[t] = running
    return advantages, advantages + values

"""PPO's update step against an independent implementation of the notes' loss.

The oracle below writes -L + c_v ½(V - R)² - c_H H out with torch.distributions, for the clipped
and the KL objective, with and without value clipping; both take plain SGD steps (Adam's first
step is about lr · sign(g), which hides the size of every term) from the same weights over the
same shuffled minibatches, and the weights and logged statistics must agree afterwards."""

from __future__ import annotations

import copy
import dataclasses

import gymnasium as gym
import numpy as np
import pytest
import torch
from torch.distributions import Categorical, Normal, kl_divergence

from imitation.algorithms.ppo import PPOConfig, UpdateBatch, ppo_update
from imitation.policies import ActorCritic, make_policy

BOX3 = gym.spaces.Box(-np.inf, np.inf, (3,), np.float32)
SIZE = 64


def _setting(continuous: bool) -> tuple[ActorCritic, UpdateBatch]:
    torch.manual_seed(0)
    action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32) if continuous else gym.spaces.Discrete(3)
    policy = make_policy(BOX3, action_space, hidden_sizes=[8], log_std_init=-0.3)
    torch.nn.init.normal_(policy.action_head.weight)  # leave the near-uniform initial policy
    features = torch.randn(SIZE, 3)
    with torch.no_grad():
        out = policy.action_head(policy.actor_trunk(features))
        # π_k: the current policy shifted, so that ratios reach beyond 1 ± ε.
        parameters = out + 0.4 * torch.randn_like(out)
        old_log_std = policy.log_std.detach() + 0.2 if continuous else None
        old = Normal(parameters, old_log_std.exp()) if continuous else Categorical(logits=parameters)
        actions = old.sample()
        log_probs = old.log_prob(actions).sum(-1) if continuous else old.log_prob(actions)
        values = policy.value(features) + 0.5 * torch.randn(SIZE)
    batch = UpdateBatch(
        inputs=features, actions=actions, log_probs=log_probs, advantages=2.0 * torch.randn(SIZE) + 0.7, returns=values + torch.randn(SIZE),
        values=values, parameters=parameters if continuous else torch.log_softmax(parameters, -1), old_log_std=old_log_std,
    )
    return policy, batch


def _oracle(policy: ActorCritic, batch: UpdateBatch, config: PPOConfig, beta: float, learning_rate: float) -> list[list[float]]:
    """The update written from the notes; returns per-minibatch [policy loss, value loss, KL estimate, clip fraction]."""
    optimizer = torch.optim.SGD(policy.parameters(), lr=learning_rate)
    rows = []
    for _ in range(config.n_epochs):
        order = torch.randperm(SIZE)
        for start in range(0, SIZE, config.batch_size):
            i = order[start : start + config.batch_size]
            out = policy.action_head(policy.actor_trunk(batch.inputs[i]))
            if policy.is_continuous:
                new, old = Normal(out, policy.log_std.exp()), Normal(batch.parameters[i], batch.old_log_std.exp())
                log_prob, entropy, kl = new.log_prob(batch.actions[i]).sum(-1), new.entropy().sum(-1), kl_divergence(old, new).sum(-1)
            else:
                new, old = Categorical(logits=out), Categorical(logits=batch.parameters[i])
                log_prob, entropy, kl = new.log_prob(batch.actions[i]), new.entropy(), kl_divergence(old, new)
            ratio = torch.exp(log_prob - batch.log_probs[i])
            a = batch.advantages[i]
            if config.normalize_advantages and len(i) > 1:
                a = (a - a.mean()) / (a.std() + 1e-8)
            eps = config.clip_range
            if config.objective == "clip":
                surrogate = torch.min(ratio * a, torch.clamp(ratio, 1 - eps, 1 + eps) * a)
            else:
                surrogate = ratio * a - beta * kl
            v = policy.value_head(policy.critic_trunk(batch.inputs[i])).squeeze(-1)
            value_loss = 0.5 * (v - batch.returns[i]) ** 2
            if config.clip_value_loss:
                v_clipped = batch.values[i] + torch.clamp(v - batch.values[i], -eps, eps)
                value_loss = torch.max(value_loss, 0.5 * (v_clipped - batch.returns[i]) ** 2)
            loss = -surrogate.mean() + config.value_coef * value_loss.mean() - config.entropy_coef * entropy.mean()
            optimizer.zero_grad()
            loss.backward()
            gradients = [p.grad for p in policy.parameters() if p.grad is not None]
            norm = torch.sqrt(sum((g**2).sum() for g in gradients))
            if norm > config.max_grad_norm:
                for g in gradients:
                    g.mul_(config.max_grad_norm / (norm + 1e-6))
            optimizer.step()
            log_ratio = torch.log(ratio.detach())
            rows.append([-surrogate.mean().item(), value_loss.mean().item(),
                         (ratio.detach() - 1 - log_ratio).mean().item(), ((ratio.detach() - 1).abs() > eps).float().mean().item()])
    return rows


SETTINGS = {
    "clip": dict(objective="clip"),
    "clip, clipped values, entropy, clipped gradients": dict(objective="clip", clip_value_loss=True, entropy_coef=0.05, max_grad_norm=0.3),
    "kl": dict(objective="kl", value_coef=0.7, clip_range=0.1),
    "clip, raw advantages": dict(objective="clip", normalize_advantages=False),
    # Minibatches of two; of three, and one of one at the end (whose advantage is left as it is).
    "clip, minibatches of two": dict(objective="clip", batch_size=2, n_epochs=1),
    "clip, minibatches of three and one": dict(objective="clip", batch_size=3, n_epochs=1),
}


@pytest.mark.parametrize("continuous", [False, True], ids=["categorical", "gaussian"])
@pytest.mark.parametrize("setting", SETTINGS)
def test_the_update_is_the_notes_loss_minimised_by_minibatch_steps(setting: str, continuous: bool) -> None:
    options = dict(n_epochs=2, batch_size=SIZE // 2, max_grad_norm=1e6) | SETTINGS[setting]
    config = PPOConfig(env_id="unused", **options)
    policy, batch = _setting(continuous)
    oracle = copy.deepcopy(policy)
    beta = 0.8
    torch.manual_seed(1)
    measured = ppo_update(policy, torch.optim.SGD(policy.parameters(), lr=0.05), batch, config, beta)
    torch.manual_seed(1)
    rows = _oracle(oracle, batch, config, beta, learning_rate=0.05)
    for (name, mine), theirs in zip(policy.named_parameters(), oracle.parameters()):
        assert torch.allclose(mine, theirs, atol=1e-6), name
    means = np.mean(rows, axis=0)
    assert [measured.policy_loss, measured.value_loss, measured.approx_kl, measured.clip_fraction] == pytest.approx(means.tolist(), abs=1e-6)
    assert 0 < measured.clip_fraction < 1 and not measured.stopped_early
    with torch.no_grad():
        entropy = policy.entropy(policy.distribution(batch.inputs)).mean().item()
    assert measured.entropy == pytest.approx(entropy)


def test_the_kl_early_stop_ends_the_epochs_after_the_minibatch_that_passes_it() -> None:
    """target_kl: once the last minibatch's KL estimate exceeds 1.5 · target_kl, no more epochs."""
    policy, batch = _setting(continuous=False)
    config = PPOConfig(env_id="unused", n_epochs=5, batch_size=SIZE // 4, max_grad_norm=1e6)
    first_epoch = copy.deepcopy(policy)
    torch.manual_seed(1)
    rows = _oracle(first_epoch, batch, dataclasses.replace(config, n_epochs=1), 1.0, learning_rate=0.05)
    torch.manual_seed(1)
    stopped = ppo_update(policy, torch.optim.SGD(policy.parameters(), lr=0.05), batch, dataclasses.replace(config, target_kl=rows[-1][2] / 1.5 * 0.99), 1.0)
    assert stopped.stopped_early
    for mine, theirs in zip(policy.parameters(), first_epoch.parameters()):
        assert torch.allclose(mine, theirs, atol=1e-6)
    # With the threshold just above the first epoch's estimate, a second epoch runs.
    policy, batch = _setting(continuous=False)
    torch.manual_seed(1)
    ppo_update(policy, torch.optim.SGD(policy.parameters(), lr=0.05), batch, dataclasses.replace(config, target_kl=rows[-1][2] / 1.5 * 1.01), 1.0)
    assert not all(torch.allclose(mine, theirs, atol=1e-6) for mine, theirs in zip(policy.parameters(), first_epoch.parameters()))

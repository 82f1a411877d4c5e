"""Guided cost learning's reward side, on PPO's rollouts of fixed-horizon CartPole."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS

import imitation.envs  # noqa: F401  (registers the ids)
from imitation.algorithms.gcl import GCLConfig, GuidedCostLearning
from imitation.algorithms.ppo import PPOConfig, Rollout, ppo_defaults, train_ppo
from imitation.data.loader import load_transitions, transitions_to_torch
from imitation.data.store import DemoDataset
from imitation.policies import make_policy
from imitation.rewards import make_reward_model

ENV_ID = "imitation/CartPoleFixedHorizon-v0"


@pytest.mark.parametrize("objective", ["discriminator", "importance"])
def test_reward_learns_to_rate_demo_states_above_policy_states(objective: str) -> None:
    env = gym.make(ENV_ID)
    demos = transitions_to_torch(load_transitions(DemoDataset([DATASETS / "CartPoleFixedHorizon-v0.mcap"]), next_observations=True))
    torch.manual_seed(0)
    reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[32, 32], normalize_observations=True)
    config = PPOConfig(env_id=ENV_ID, total_steps=8 * 256, **ppo_defaults(ENV_ID))
    learner = GuidedCostLearning(reward, demos, GCLConfig(objective=objective, warmup_steps=300, learning_rate=1e-3), updates=8)
    seen: list[tuple[Rollout, torch.Tensor]] = []

    def hook(rollout: Rollout, policy) -> torch.Tensor:
        rewards = learner(rollout, policy)
        seen.append((rollout, rewards))
        return rewards

    train_ppo(config, rollout_rewards=hook, progress=False)
    assert len(learner.history) == 8 and len(seen) == 8
    rollout, rewards = seen[-1]
    assert rewards.shape == rollout.env_rewards.shape == (32, 8)
    with torch.no_grad():
        on_demos = reward(demos.observations, demos.actions, demos.next_observations)
        on_failures = reward(*(t.reshape(-1, *t.shape[2:]) for t in (rollout.observations, rollout.env_actions, rollout.next_observations)))
    assert on_demos.mean().item() == pytest.approx(0.0, abs=1e-4)  # centred on the demos
    failed = rollout.observations.reshape(-1, 5)[:, 4] == 1.0
    assert failed.any() and on_failures[failed].mean() < on_demos.mean() - 0.5
    # PPO optimises the updated reward with the entropy term: r_θ(s) - α log π_k(a|s), α = 1.
    assert torch.allclose(rewards.reshape(-1), on_failures - rollout.log_probs.reshape(-1), atol=1e-5)


def test_observation_scale_is_the_space_range_where_finite_else_the_widest_spread() -> None:
    env = gym.make(ENV_ID)  # x, θ and the flag are bounded; the velocities are not
    reward = make_reward_model(env.observation_space, env.action_space, normalize_observations=True)
    demos = torch.zeros(100, 5) + torch.linspace(-0.01, 0.01, 100)[:, None]
    wide = torch.linspace(-2.0, 2.0, 100)[:, None].repeat(1, 5)
    reward.set_observation_statistics(demos, wide)
    half_range = (env.observation_space.high - env.observation_space.low) / 2
    expected = torch.tensor([half_range[0], wide[:, 1].std(), half_range[2], wide[:, 3].std(), 0.5])
    assert torch.allclose(reward.observation_mean, demos.mean(0))
    assert torch.allclose(reward.observation_std, expected)
    np.testing.assert_allclose(reward.inputs(wide[:1], wide[:1], wide[:1]).numpy(), ((wide[:1] - demos.mean(0)) / expected).numpy(), rtol=1e-6)


def test_the_pool_keeps_each_rollout_although_ppo_refills_its_buffers_in_place() -> None:
    env = gym.make(ENV_ID)
    demos = transitions_to_torch(load_transitions(DemoDataset([DATASETS / "CartPoleFixedHorizon-v0.mcap"]), next_observations=True))
    torch.manual_seed(0)
    reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[8], normalize_observations=True)
    learner = GuidedCostLearning(reward, demos, GCLConfig(warmup_steps=1, reward_steps=1, batch_size=8), updates=2)
    policy = make_policy(env.observation_space, env.action_space)
    steps = 6
    buffers = Rollout(
        observations=demos.observations[:steps].reshape(3, 2, 5).clone(), actions=torch.zeros(3, 2), env_actions=torch.zeros(3, 2),
        next_observations=demos.next_observations[:steps].reshape(3, 2, 5).clone(), log_probs=torch.zeros(3, 2),
        env_rewards=torch.zeros(3, 2), terminated=torch.zeros(3, 2, dtype=torch.bool), truncated=torch.zeros(3, 2, dtype=torch.bool),
    )
    first = buffers.observations.reshape(-1, 5).clone()
    learner(buffers, policy)
    buffers.observations.fill_(7.0)  # the next rollout, written into the same buffers
    learner(buffers, policy)
    assert len(learner.pool.observations) == 2 * steps
    assert torch.equal(learner.pool.observations[:steps], first) and (learner.pool.observations[steps:] == 7.0).all()


def test_centring_the_reward_on_the_demos_leaves_the_discriminator_unchanged() -> None:
    """r_θ's mean over the demos is set to 0 after each update; log Z moves with it, so the
    classifier the loss fitted is the same before and after."""
    env = gym.make(ENV_ID)
    demos = transitions_to_torch(load_transitions(DemoDataset([DATASETS / "CartPoleFixedHorizon-v0.mcap"]), next_observations=True))
    torch.manual_seed(0)
    reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[16], normalize_observations=True)
    learner = GuidedCostLearning(reward, demos, GCLConfig(), updates=1)
    with torch.no_grad():
        reward.net[-1].bias += 3.0
        before = reward(demos.observations, demos.actions, demos.next_observations) - learner.log_partition
        learner._center_on_demos()
        after = reward(demos.observations, demos.actions, demos.next_observations) - learner.log_partition
    assert reward(demos.observations, demos.actions, demos.next_observations).mean().item() == pytest.approx(0.0, abs=1e-5)
    assert torch.allclose(before, after, atol=1e-5)


def _two_rollouts_under_two_policies():
    """A learner that has pooled one rollout of each of two different policies."""
    env = gym.make(ENV_ID)
    demos = transitions_to_torch(load_transitions(DemoDataset([DATASETS / "CartPoleFixedHorizon-v0.mcap"]), next_observations=True))
    torch.manual_seed(0)
    reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[8], normalize_observations=True)
    learner = GuidedCostLearning(reward, demos, GCLConfig(warmup_steps=1, reward_steps=1, batch_size=8), updates=2)
    policies = [make_policy(env.observation_space, env.action_space, hidden_sizes=[8]) for _ in range(2)]
    with torch.no_grad():
        policies[1].action_head.bias.copy_(torch.tensor([2.0, -2.0]))  # far from uniform: the two densities differ
    steps = 6
    for k, policy in enumerate(policies):
        rows = slice(k * steps, (k + 1) * steps)
        learner(Rollout(
            observations=demos.observations[rows].reshape(3, 2, 5), actions=demos.actions[rows].reshape(3, 2).float(),
            env_actions=demos.actions[rows].reshape(3, 2).float(), next_observations=demos.next_observations[rows].reshape(3, 2, 5),
            log_probs=torch.zeros(3, 2), env_rewards=torch.zeros(3, 2), terminated=torch.zeros(3, 2, dtype=torch.bool),
            truncated=torch.zeros(3, 2, dtype=torch.bool),
        ), policy)
    return learner, policies, demos


def _probability(policy, observations: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
    with torch.no_grad():
        return policy.distribution(policy.encode(observations)).probs.gather(-1, actions.long().reshape(-1, 1)).squeeze(-1)


def test_every_point_is_weighted_by_one_density_the_mixture_of_the_pooled_samplers() -> None:
    """Finn et al.'s q(a|s) = (1/K) Σ_k π_k(a|s), for rollout 1's steps, rollout 2's and the demos
    alike, not each step under the policy that drew it."""
    learner, (first, second), demos = _two_rollouts_under_two_policies()
    pool = learner.pool
    mixture = 0.5 * (_probability(first, pool.observations, pool.env_actions) + _probability(second, pool.observations, pool.env_actions))
    assert not torch.allclose(_probability(first, pool.observations, pool.env_actions), _probability(second, pool.observations, pool.env_actions), atol=0.05)
    assert torch.allclose(pool.log_mass - np.log(2), mixture.log(), atol=1e-5)
    demo_mixture = 0.5 * (_probability(first, demos.observations, demos.actions) + _probability(second, demos.observations, demos.actions))
    assert torch.allclose(learner.demo_log_mass - np.log(2), demo_mixture.log(), atol=1e-5)


def test_the_importance_objective_weights_every_point_by_exp_r_over_the_demo_policy_mixture() -> None:
    """log Ẑ = log (1/2N) Σ_j exp r_j / μ_j with μ_j = ½ exp(r_j - log Z) + ½ q_j, against the
    weights written out as probabilities; log Z then holds the estimate."""
    learner, _, _ = _two_rollouts_under_two_policies()
    rewards = torch.tensor([0.3, -1.2, 2.0, 0.1])
    log_q = torch.tensor([-0.1, -2.0, -0.7, -3.0])
    with torch.no_grad():
        learner.log_partition.fill_(0.4)
    mu = 0.5 * rewards.exp() / np.exp(0.4) + 0.5 * log_q.exp()
    expected = float(np.log((rewards.exp() / mu).mean()))
    estimate = learner._log_partition_estimate(rewards, log_q)
    assert estimate.item() == pytest.approx(expected, rel=1e-6)
    assert learner.log_partition.item() == pytest.approx(expected, rel=1e-6)

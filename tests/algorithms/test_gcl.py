"""Guided cost learning's reward side, on PPO's rollouts of fixed-horizon CartPole."""

from __future__ import annotations

import copy

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS

import imitation.envs  # noqa: F401  (registers the ids)
from imitation.algorithms.beside_ppo import env_action_log_probs
from imitation.algorithms.gcl import GCLConfig, GuidedCostLearning, RewardLearner
from imitation.algorithms.ppo import PPO, PPOConfig
from imitation.data.dataset import DemoDataset
from imitation.data.loader import load_transitions, transitions_to_torch
from imitation.envs.rollout import Rollout
from imitation.errors import ConfigError
from imitation.jobs.loop import run
from imitation.jobs.presets import ppo_settings
from imitation.policies import make_policy
from imitation.rewards import make_reward_model

ENV_ID = "imitation/CartPoleFixedHorizon-v0"


def learn_from(learner: RewardLearner, rollout: Rollout, policy) -> tuple[torch.Tensor, dict[str, float]]:
    """One outer-loop pass of the reward side, as GCL's step does it: pool the rollout, learn,
    and the rewards PPO then optimises, r_θ(s) - α log π_k(a|s); with the reward update's statistics."""
    log_pi = learner.add_rollout(rollout, policy)
    statistics = learner.learn()
    return learner.reward.relabel(rollout) - learner.config.policy_entropy * log_pi, statistics


@pytest.mark.parametrize("objective", ["discriminator", "importance"])
def test_reward_learns_to_rate_demo_states_above_policy_states(objective: str) -> None:
    env = gym.make(ENV_ID)
    demos = transitions_to_torch(load_transitions(DemoDataset([DATASETS / "CartPoleFixedHorizon-v0.mcap"]), next_observations=True))
    torch.manual_seed(0)
    reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[32, 32], normalize_observations=True)
    config = PPOConfig(env_id=ENV_ID, total_steps=8 * 256, **ppo_settings(ENV_ID))
    ppo = PPO(config)
    learner = GuidedCostLearning(ppo, reward, demos, GCLConfig(objective=objective, warmup_steps=300, learning_rate=1e-3))
    seen: list[tuple[Rollout, torch.Tensor]] = []
    update = ppo.update

    def spy(rollout: Rollout, rewards: torch.Tensor) -> dict[str, float]:
        seen.append((rollout, rewards))  # the rewards PPO optimises
        return update(rollout, rewards)

    ppo.update = spy
    try:
        run(learner)
    finally:
        ppo.close()
    assert learner.rewards.learned == 8 and len(seen) == 8
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
    learner = RewardLearner(reward, demos, GCLConfig(warmup_steps=1, reward_steps=1, batch_size=8), updates=2)
    policy = make_policy(env.observation_space, env.action_space)
    steps = 6
    buffers = Rollout(
        observations=demos.observations[:steps].reshape(3, 2, 5).clone(), actions=torch.zeros(3, 2), env_actions=torch.zeros(3, 2),
        next_observations=demos.next_observations[:steps].reshape(3, 2, 5).clone(), log_probs=torch.zeros(3, 2),
        env_rewards=torch.zeros(3, 2), terminated=torch.zeros(3, 2, dtype=torch.bool), truncated=torch.zeros(3, 2, dtype=torch.bool),
    )
    first = buffers.observations.reshape(-1, 5).clone()
    learn_from(learner, buffers, policy)
    buffers.observations.fill_(7.0)  # the next rollout, written into the same buffers
    learn_from(learner, buffers, policy)
    assert len(learner.pool.observations) == 2 * steps
    assert torch.equal(learner.pool.observations[:steps], first) and (learner.pool.observations[steps:] == 7.0).all()


def test_centring_the_reward_on_the_demos_leaves_the_discriminator_unchanged() -> None:
    """r_θ's mean over the demos is set to 0 after each update; log Z moves with it, so the
    classifier the loss fitted is the same before and after."""
    env = gym.make(ENV_ID)
    demos = transitions_to_torch(load_transitions(DemoDataset([DATASETS / "CartPoleFixedHorizon-v0.mcap"]), next_observations=True))
    torch.manual_seed(0)
    reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[16], normalize_observations=True)
    learner = RewardLearner(reward, demos, GCLConfig(), updates=1)
    with torch.no_grad():
        reward.net[-1].bias += 3.0
        before = reward(demos.observations, demos.actions, demos.next_observations) - learner.log_partition
        learner._center_on_demos()
        after = reward(demos.observations, demos.actions, demos.next_observations) - learner.log_partition
    assert reward(demos.observations, demos.actions, demos.next_observations).mean().item() == pytest.approx(0.0, abs=1e-5)
    assert torch.allclose(before, after, atol=1e-5)


def _two_rollouts_under_two_policies(**options):
    """A learner that has pooled one rollout of each of two different policies."""
    env = gym.make(ENV_ID)
    demos = transitions_to_torch(load_transitions(DemoDataset([DATASETS / "CartPoleFixedHorizon-v0.mcap"]), next_observations=True))
    torch.manual_seed(0)
    reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[8], normalize_observations=True, inputs=options.pop("inputs", "s"))
    learner = RewardLearner(reward, demos, GCLConfig(warmup_steps=1, reward_steps=1, batch_size=8, **options), updates=2)
    policies = [make_policy(env.observation_space, env.action_space, hidden_sizes=[8]) for _ in range(2)]
    with torch.no_grad():
        policies[1].action_head.bias.copy_(torch.tensor([2.0, -2.0]))  # far from uniform: the two densities differ
    steps = 6
    for k, policy in enumerate(policies):
        rows = slice(k * steps, (k + 1) * steps)
        learn_from(learner, Rollout(
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


@pytest.mark.parametrize("objective", ["discriminator", "importance"])
def test_one_reward_step_is_the_objective_with_the_gradient_penalty_written_out(objective: str) -> None:
    """A step of `_step` against the module docstring's loss computed here, on r(s, a, s') (so
    every input counts), both with plain SGD (whose step shows every term's size)."""
    learner, _, demos = _two_rollouts_under_two_policies(inputs="sas", objective=objective, gradient_penalty=0.5)
    learner.optimizer = torch.optim.SGD([*learner.reward.parameters(), learner.log_partition], lr=0.1)
    oracle, log_partition = copy.deepcopy(learner.reward), learner.log_partition.detach().clone().requires_grad_(True)
    draws = torch.Generator()
    draws.set_state(learner.generator.get_state())
    loss, demo_accuracy, sample_accuracy = learner._step(1, 1)

    demo_index, pool_index = torch.randint(len(demos), (8,), generator=draws), torch.randint(12, (8,), generator=draws)
    pool = learner.pool
    inputs = oracle.inputs(
        torch.cat([demos.observations[demo_index], pool.observations[pool_index]]), torch.cat([demos.actions[demo_index], pool.env_actions[pool_index]]),
        torch.cat([demos.next_observations[demo_index], pool.next_observations[pool_index]]),
    ).requires_grad_(True)
    r = oracle.net(inputs)[:, 0]
    log_q = torch.cat([learner.demo_log_mass[demo_index], pool.log_mass[pool_index]]) - np.log(2)  # K = 2 samplers
    logits = r - log_partition - log_q
    if objective == "importance":
        log_mu = torch.logaddexp(r.detach() - log_partition.detach(), log_q) - np.log(2)
        expected_estimate = torch.logsumexp(r - log_mu, 0) - np.log(16)
        expected = -r[:8].mean() + expected_estimate
    else:
        expected = torch.nn.functional.binary_cross_entropy_with_logits(logits, torch.tensor([1.0] * 8 + [0.0] * 8))
    (gradient,) = torch.autograd.grad(r.sum(), inputs, create_graph=True)
    expected = expected + 0.5 * (gradient**2).sum(1).mean()
    assert loss == pytest.approx(expected.item(), rel=1e-5)
    assert (demo_accuracy, sample_accuracy) == (pytest.approx((logits[:8] > 0).float().mean().item()), pytest.approx((logits[8:] < 0).float().mean().item()))
    expected.backward()
    with torch.no_grad():
        for parameter in oracle.parameters():
            parameter -= 0.1 * parameter.grad
    for (name, mine), theirs in zip(learner.reward.named_parameters(), oracle.parameters()):
        assert torch.allclose(mine, theirs, atol=1e-6), name
    if objective == "importance":
        assert learner.log_partition.item() == pytest.approx(expected_estimate.item(), rel=1e-5)
    else:
        assert learner.log_partition.item() == pytest.approx((log_partition - 0.1 * log_partition.grad).item(), rel=1e-5)


def test_each_rollout_takes_its_reward_steps_with_the_learning_rate_annealed_and_logs_their_means() -> None:
    """Rollout k (from 0) takes reward_steps (+ warmup_steps when k = 0) steps at lr·max(0, 1 - k/updates);
    its row holds the means of the steps' loss and accuracies."""
    env = gym.make(ENV_ID)
    demos = transitions_to_torch(load_transitions(DemoDataset([DATASETS / "CartPoleFixedHorizon-v0.mcap"]), next_observations=True))
    torch.manual_seed(0)
    reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[8], normalize_observations=True)
    learner = RewardLearner(reward, demos, GCLConfig(warmup_steps=3, reward_steps=2, batch_size=8, learning_rate=0.01), updates=2)
    steps, take_step = [], learner._step
    learner._step = lambda step, total: steps.append((step, total, take_step(step, total))) or steps[-1][2]
    policy = make_policy(env.observation_space, env.action_space)
    first = demos.observations[:6].reshape(3, 2, 5) * 3.0
    rates, history = [], []
    for k in range(3):
        observations = first if k == 0 else demos.observations[6:12].reshape(3, 2, 5)
        _, statistics = learn_from(learner, Rollout(
            observations=observations, actions=torch.zeros(3, 2), env_actions=torch.zeros(3, 2), next_observations=observations,
            log_probs=torch.zeros(3, 2), env_rewards=torch.zeros(3, 2), terminated=torch.zeros(3, 2, dtype=torch.bool),
            truncated=torch.zeros(3, 2, dtype=torch.bool),
        ), policy)
        history.append(statistics)
        rates.append(learner.optimizer.param_groups[0]["lr"])
    assert [(step, total) for step, total, _ in steps] == [(1, 5), (2, 5), (3, 5), (4, 5), (5, 5), (1, 2), (2, 2), (1, 2), (2, 2)]
    assert rates == pytest.approx([0.01, 0.005, 0.0])
    first_row = np.mean([result for _, _, result in steps[:5]], axis=0)
    assert history[0] == pytest.approx(dict(zip(("reward_loss", "demo_accuracy", "sample_accuracy"), first_row)))
    # The observation statistics come from the demos and the first rollout only.
    expected = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[8], normalize_observations=True)
    expected.set_observation_statistics(demos.observations, first.reshape(6, 5))
    assert torch.allclose(reward.observation_std, expected.observation_std) and torch.allclose(reward.observation_mean, expected.observation_mean)


def test_the_samplers_are_copies_of_the_policy_as_it_was() -> None:
    learner, (first, second), _ = _two_rollouts_under_two_policies()
    before = [parameter.clone() for parameter in learner.samplers[1].parameters()]
    with torch.no_grad():
        second.action_head.bias.add_(5.0)  # PPO's update changes the policy in place
    assert all(torch.equal(a, b) for a, b in zip(before, learner.samplers[1].parameters()))


def test_continuous_actions_keep_their_dimensions_in_the_pool_and_the_entropy_term() -> None:
    """Pendulum's (T, n, 1) actions: the pool holds one action per step, and PPO's reward is
    r_θ(s) - α log π_k(a|s) per step (α = 0.5 here)."""
    env = gym.make("Pendulum-v1")
    demos = transitions_to_torch(load_transitions(DemoDataset([DATASETS / "Pendulum-v1.mcap"]), next_observations=True))
    torch.manual_seed(0)
    reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[8], normalize_observations=True)
    learner = RewardLearner(reward, demos, GCLConfig(warmup_steps=1, reward_steps=1, batch_size=8, policy_entropy=0.5), updates=1)
    policy = make_policy(env.observation_space, env.action_space, hidden_sizes=[8], log_std_init=-0.5)
    shaped = lambda tensor: tensor[:8].reshape(4, 2, *tensor.shape[1:])  # noqa: E731
    rollout = Rollout(
        observations=shaped(demos.observations), actions=shaped(demos.actions), env_actions=shaped(demos.actions),
        next_observations=shaped(demos.next_observations), log_probs=torch.zeros(4, 2), env_rewards=torch.zeros(4, 2),
        terminated=torch.zeros(4, 2, dtype=torch.bool), truncated=torch.zeros(4, 2, dtype=torch.bool),
    )
    rewards, _ = learn_from(learner, rollout, policy)
    assert learner.pool.env_actions.shape == (8, 1)
    with torch.no_grad():
        log_probs = policy.env_action_log_prob(policy.distribution(policy.encode(demos.observations[:8])), demos.actions[:8])
        expected = reward(demos.observations[:8], demos.actions[:8], demos.next_observations[:8]) - 0.5 * log_probs
    assert torch.allclose(rewards.reshape(-1), expected, atol=1e-5)


def test_log_probabilities_of_a_pool_longer_than_one_chunk_are_those_of_one_pass() -> None:
    """The pool is scored in chunks of 65,536 steps: 70,000 steps give the same values as one pass."""
    env = gym.make("Pendulum-v1")
    torch.manual_seed(0)
    policy = make_policy(env.observation_space, env.action_space, hidden_sizes=[4])
    observations, actions = torch.randn(70_000, 3), torch.rand(70_000, 1) * 4 - 2
    with torch.no_grad():
        expected = policy.env_action_log_prob(policy.distribution(policy.encode(observations)), actions)
    assert torch.allclose(env_action_log_probs(policy, observations, actions), expected, atol=1e-6)


@pytest.mark.parametrize(("changes", "field"), [
    ({"learning_rate": 0.0}, "learning_rate"),
    ({"learning_rate": 1e30}, "learning_rate"),
    ({"learning_rate": float("nan")}, "learning_rate"),
    ({"policy_entropy": -0.1}, "policy_entropy"),
    ({"policy_entropy": float("inf")}, "policy_entropy"),
    ({"policy_entropy": float("nan")}, "policy_entropy"),
    ({"objective": "adversarial"}, "objective"),
])
def test_config_out_of_range_is_refused_naming_the_field(changes: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=f"^{field} ") as raised:
        GCLConfig(**changes).validate()
    assert raised.value.owner == "GCLConfig"


def test_config_at_the_edges_of_its_ranges_is_accepted() -> None:
    """α = 0 (no entropy term: PPO optimises r_θ alone) and a learning rate just under the bound."""
    GCLConfig(policy_entropy=0.0, learning_rate=1e29).validate()


def test_without_annealing_every_reward_step_runs_at_the_configured_learning_rate() -> None:
    learner, _, _ = _two_rollouts_under_two_policies(learning_rate=0.02, anneal_lr=False)
    assert learner.learned == 2
    assert [group["lr"] for group in learner.optimizer.param_groups] == [0.02]


def test_a_fresh_reward_learner_round_trips_its_state_before_any_rollout() -> None:
    """A checkpoint taken before the first rollout (no pool, no samplers yet) restores as such."""
    env = gym.make(ENV_ID)
    demos = transitions_to_torch(
        load_transitions(DemoDataset([DATASETS / "CartPoleFixedHorizon-v0.mcap"]), next_observations=True)
    )

    def fresh() -> RewardLearner:
        torch.manual_seed(0)
        reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[8])
        return RewardLearner(reward, demos, GCLConfig(), updates=2)

    tensors, state = fresh().state_dict()
    assert state["samplers"] == 0 and state["sampler_policy"] is None and state["learned"] == 0
    assert not any(name.startswith(("pool.", "sampler.")) for name in tensors)
    restored = fresh()
    restored.load_state_dict((tensors, state))
    assert restored.pool is None and restored.samplers == [] and restored.learned == 0
    assert torch.equal(restored.demo_log_mass, torch.full((len(demos),), -float("inf")))


def test_progress_adds_the_demo_accuracy_to_ppos_columns() -> None:
    env = gym.make(ENV_ID)
    demos = transitions_to_torch(
        load_transitions(DemoDataset([DATASETS / "CartPoleFixedHorizon-v0.mcap"]), next_observations=True)
    )
    ppo = PPO(PPOConfig(env_id=ENV_ID, total_steps=256, **ppo_settings(ENV_ID)))
    try:
        reward = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[8])
        learner = GuidedCostLearning(ppo, reward, demos, GCLConfig())
        row = {"return": 12.34, "steps_per_second": 1500.4, "demo_accuracy": 0.876}
        assert learner.progress(row) == {"ret": "12.3", "sps": "1500", "demo_acc": "0.88"}
    finally:
        ppo.close()

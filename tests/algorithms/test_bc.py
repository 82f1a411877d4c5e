"""Behavioural cloning: the loss is the one in the notes, early stopping keeps the best weights,
and short runs on the bundled demos clone the expert."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS

from imitation.algorithms.bc import BCConfig, BehaviouralCloning, bc_loss, policy_options
from imitation.data.loader import TransitionTensors, load_transitions, transitions_to_torch
from imitation.data.mcap.reader import DemoFile
from imitation.envs.make import make_env
from imitation.errors import ImitationError
from imitation.evaluation.policy import evaluate_policy
from imitation.jobs.loop import run
from imitation.policies import SingleObservationPolicy, make_policy

BOX4 = gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)


def batch_of(observations: torch.Tensor, actions: torch.Tensor) -> TransitionTensors:
    n = len(observations)
    return TransitionTensors(
        observations=observations, actions=actions, rewards=torch.zeros(n), next_observations=None,
        terminated=torch.zeros(n, dtype=torch.bool), truncated=torch.zeros(n, dtype=torch.bool), episode_index=torch.zeros(n, dtype=torch.long),
    )


def test_discrete_loss_is_cross_entropy_and_regularisers_add_up() -> None:
    torch.manual_seed(0)
    policy = make_policy(BOX4, gym.spaces.Discrete(3), hidden_sizes=[8])
    torch.nn.init.normal_(policy.action_head.weight)  # so that the head's share of the L2 term shows
    batch = batch_of(torch.randn(10, 4), torch.randint(0, 3, (10,)))
    logits = policy.action_head(policy.actor_trunk(policy.encode(batch.observations)))
    cross_entropy = torch.nn.functional.cross_entropy(logits, batch.actions)
    loss, parts = bc_loss(policy, batch, BCConfig(l2_coef=0.0))  # unregularised (the default has a little weight decay)
    assert loss.item() == pytest.approx(cross_entropy.item(), rel=1e-5)
    entropy = torch.distributions.Categorical(logits=logits).entropy().mean()
    l2 = sum((p**2).sum() for n, p in policy.named_parameters() if n.startswith(("actor_trunk", "action_head")))
    regularised, _ = bc_loss(policy, batch, BCConfig(entropy_coef=0.1, l2_coef=0.01))
    assert regularised.item() == pytest.approx((cross_entropy - 0.1 * entropy + 0.01 * l2).item(), rel=1e-5)


def test_continuous_mse_loss_fits_the_mean() -> None:
    policy = make_policy(BOX4, gym.spaces.Box(-1, 1, (2,), np.float32), hidden_sizes=[8])
    batch = batch_of(torch.randn(6, 4), torch.randn(6, 2))
    mean = policy.action_head(policy.actor_trunk(policy.encode(batch.observations)))
    loss, _ = bc_loss(policy, batch, BCConfig(loss="mse", l2_coef=0.0))
    assert loss.item() == pytest.approx(((mean - batch.actions) ** 2).sum(-1).mean().item(), rel=1e-5)
    with pytest.raises(ImitationError, match="mse is for continuous"):
        BCConfig(loss="mse").validate(continuous=False)


def test_early_stopping_keeps_the_best_epoch() -> None:
    torch.manual_seed(0)
    # Labels unrelated to the inputs: validation loss can only get worse as training memorises noise.
    train = batch_of(torch.randn(64, 4), torch.randint(0, 2, (64,)))
    validation = batch_of(torch.randn(64, 4), torch.randint(0, 2, (64,)))
    policy = make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[64, 64])
    learner = BehaviouralCloning(policy, train, validation, BCConfig(epochs=200, patience=5, batch_size=16, learning_rate=1e-2))
    history = run(learner)
    assert len(history) < 200
    best = min(history, key=lambda row: row["validation_loss"])
    assert learner.best_epoch == best["epoch"] and len(history) == learner.best_epoch + 5
    with torch.no_grad():
        final, _ = bc_loss(learner.policy, validation, BCConfig(l2_coef=0.0))
    assert final.item() == pytest.approx(best["validation_loss"], rel=1e-4)


@pytest.mark.parametrize(("env_id", "minimum"), [("CartPole-v1", 475.0)])
def test_short_bc_clones_the_bundled_expert(env_id: str, minimum: float) -> None:
    env = make_env(env_id)
    config = BCConfig(epochs=30, patience=30, seed=0)
    policy = make_policy(env.observation_space, env.action_space, **policy_options(config))
    data = transitions_to_torch(load_transitions(DATASETS / f"{env_id}.mcap", next_observations=False))
    learner = BehaviouralCloning(policy, data, None, config)
    run(learner)
    trained = learner.policy
    assert evaluate_policy(SingleObservationPolicy(trained), env, episodes=5, seed=0)["mean_return"] >= minimum


def test_short_bc_on_the_bundled_pendulum_demos_reaches_eight_tenths_of_the_expert() -> None:
    """The default suite's continuous learning check: 60 epochs of the default BC (seed 0) in a
    few seconds, normalised between uniform random actions (0) and the demos (1)."""
    env = make_env("Pendulum-v1")
    demos = DATASETS / "Pendulum-v1.mcap"
    env.action_space.seed(0)
    random_return = evaluate_policy(lambda o: env.action_space.sample(), env, episodes=10, seed=10_000)["mean_return"]
    expert_return = float(np.mean([f.episode_return for f in DemoFile(demos).episodes]))
    config = BCConfig(epochs=60, patience=60, seed=0)
    policy = make_policy(env.observation_space, env.action_space, **policy_options(config))
    learner = BehaviouralCloning(policy, transitions_to_torch(load_transitions(demos, next_observations=False)), None, config)
    run(learner)
    trained = learner.policy
    learned = evaluate_policy(SingleObservationPolicy(trained), env, episodes=10, seed=0)["mean_return"]
    assert (learned - random_return) / (expert_return - random_return) >= 0.8


@pytest.mark.slow
def test_acceptance_pendulum_normalised_return() -> None:
    env = make_env("Pendulum-v1")
    data = transitions_to_torch(load_transitions(DATASETS / "Pendulum-v1.mcap", next_observations=False))
    random_return = evaluate_policy(lambda o: env.action_space.sample(), env, episodes=20, seed=10_000)["mean_return"]
    expert_return = float(np.mean([f.episode_return for f in DemoFile(DATASETS / "Pendulum-v1.mcap").episodes]))
    config = BCConfig(seed=0)
    policy = make_policy(env.observation_space, env.action_space, **policy_options(config))
    learner = BehaviouralCloning(policy, data, None, config)
    run(learner)
    trained = learner.policy
    learned = evaluate_policy(SingleObservationPolicy(trained), env, episodes=10, seed=0)["mean_return"]
    assert (learned - random_return) / (expert_return - random_return) >= 0.9

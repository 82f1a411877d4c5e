"""GAIL and AIRL where episodes end by termination (imitation.algorithms.adversarial, gail, airl):
CartPole-v1's policy episodes terminate when the pole falls, and MountainCar-v0's bundled demos
each terminate at the flag. The steps the discriminator reads keep each step's termination, the
demos' and the rollouts', and the reward PPO gets is f − log π with f = g(s) + γ (1 − d) h(s') − h(s)
(AIRL) or the net of (s, a, s') (GAIL with `inputs="sas"`), recomputed from the exported nets.
The loss of a penalised discriminator step is the cross-entropy plus λ E‖∇_x logit‖² of that step's
minibatch."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS

from imitation.algorithms.adversarial import (
    AdversarialConfig,
    AdversarialImitation,
    Steps,
    discriminator_loss,
    input_gradient_penalty,
)
from imitation.algorithms.airl import AIRLDiscriminator
from imitation.rewards import ShapedReward
from imitation.algorithms.gail import GAILDiscriminator
from imitation.algorithms.beside_ppo import env_action_log_probs
from imitation.algorithms.ppo import PPO, PPOConfig
from imitation.data.dataset import DemoDataset
from imitation.data.loader import TransitionTensors, load_transitions, transitions_to_torch
from imitation.jobs.loop import run
from imitation.rewards import RewardNet, make_reward_model

GAMMA = 0.9


def demos(env_id: str) -> TransitionTensors:
    return transitions_to_torch(load_transitions(DemoDataset([DATASETS / f"{env_id}.mcap"]), next_observations=True))


def make_learner(env_id: str, method: str, *, inputs: str | None = None, **changes) -> AdversarialImitation:
    """A learner of 2 env copies × 256 steps a rollout: MountainCar's 200-step limit and CartPole's
    falls both end episodes inside the first rollout."""
    torch.manual_seed(0)
    env = gym.make(env_id)
    config = PPOConfig(
        env_id=env_id, total_steps=3 * 512, n_envs=2, n_steps=256, batch_size=128, hidden_sizes=[16], gamma=GAMMA, device="cpu"
    )
    adversarial = AdversarialConfig(
        **{"method": method, "inputs": inputs, "batch_size": 64, "discriminator_steps": 3, "seed": 0} | changes
    )

    def net(net_inputs: str, output: str = "linear") -> RewardNet:
        return make_reward_model(
            env.observation_space,
            env.action_space,
            hidden_sizes=[16],
            inputs=net_inputs,
            output=output,
            normalize_observations=True,
        )

    if method == "gail":
        discriminator = GAILDiscriminator(net(adversarial.reward_inputs, "softplus"))
    else:
        discriminator = AIRLDiscriminator(net(adversarial.reward_inputs), net("s"), gamma=GAMMA)
    return AdversarialImitation(PPO(config), discriminator, demos(env_id), adversarial)


def expected_rewards(learner: AdversarialImitation, steps: Steps, terminated: torch.Tensor) -> torch.Tensor:
    """PPO's reward of each step from the exported nets and the given termination flags."""
    discriminator = learner.discriminator.discriminator
    observations, actions, next_observations = steps.observations, steps.env_actions, steps.next_observations
    if isinstance(discriminator, GAILDiscriminator):
        return discriminator.net.rewards_of(observations, actions, next_observations)
    g = discriminator.reward.rewards_of(observations, actions, next_observations)
    h = discriminator.potential.rewards_of(observations, actions, observations)
    next_h = discriminator.potential.rewards_of(next_observations, actions, next_observations)
    with torch.no_grad():
        log_pi = env_action_log_probs(learner.ppo.policy, observations, actions)
    return g + GAMMA * (1.0 - terminated.float()) * next_h - h - log_pi


@pytest.mark.parametrize(("method", "inputs"), [("airl", None), ("gail", "sas")])
@pytest.mark.parametrize("env_id", ["CartPole-v1", "MountainCar-v0"])
def test_the_discriminator_reads_each_steps_termination_and_pays_ppo_accordingly(
    env_id: str, method: str, inputs: str | None
) -> None:
    learner = make_learner(env_id, method, inputs=inputs)
    try:
        loaded = demos(env_id)
        demo_steps = learner.discriminator.demos
        assert torch.equal(demo_steps.terminated, loaded.terminated.float())
        rollout = learner.ppo.collect_rollout()
        steps = learner.discriminator.add_rollout(rollout)
        flags = rollout.terminated.reshape(-1)
        assert torch.equal(steps.terminated, flags.float())
        if env_id == "CartPole-v1":
            assert flags.any(), "a random policy's CartPole episodes fall and terminate"
        else:
            assert demo_steps.terminated.sum() == 50, "each MountainCar demo terminates at the flag"
        learner.discriminator.learn(learner.ppo.policy)  # D away from its initial weights
        policy = learner.ppo.policy
        torch.testing.assert_close(
            learner.discriminator.policy_rewards(steps, policy), expected_rewards(learner, steps, flags), rtol=1e-5, atol=1e-5
        )
        torch.testing.assert_close(
            learner.discriminator.policy_rewards(demo_steps, policy),
            expected_rewards(learner, demo_steps, loaded.terminated),
            rtol=1e-5,
            atol=1e-5,
        )
        if method == "airl":
            discriminator = learner.discriminator.discriminator
            assert isinstance(discriminator, AIRLDiscriminator)
            shaped = ShapedReward(discriminator.reward, discriminator.potential, gamma=GAMMA).relabel(rollout).reshape(-1)
            with torch.no_grad():
                log_pi = env_action_log_probs(policy, steps.observations, steps.env_actions)
            torch.testing.assert_close(
                learner.discriminator.policy_rewards(steps, policy), shaped - log_pi, rtol=1e-5, atol=1e-5
            )
    finally:
        learner.ppo.close()


@pytest.mark.parametrize("method", ["gail", "airl"])
def test_the_learner_runs_on_cartpole_whose_episodes_terminate_and_pools_their_flags(method: str) -> None:
    learner = make_learner("CartPole-v1", method, pool_rollouts=3)
    try:
        rows = run(learner)
    finally:
        learner.ppo.close()
    assert len(rows) == 3 and all(math.isfinite(row["discriminator_loss"]) for row in rows)
    pooled = torch.cat([steps.terminated for steps in learner.discriminator.rollouts])
    assert len(pooled) == 3 * 512 and 0 < pooled.sum() < len(pooled)
    # The newest pooled rollout is the one PPO's storage still holds: flags as the env gave them.
    assert torch.equal(
        learner.discriminator.rollouts[-1].terminated, learner.ppo.rollout_storage.terminated.reshape(-1).float()
    )


@pytest.mark.parametrize("method", ["gail", "airl"])
def test_a_penalised_steps_loss_is_the_cross_entropy_plus_lambda_times_the_input_gradient_norm(method: str) -> None:
    """One discriminator step with λ = 10: its loss against the same minibatch drawn again from the
    generator's state before it, the weights as they were; and λ E‖∇_x logit‖² only lowers E‖∇_x logit‖²
    over 40 steps, compared with the unpenalised discriminator from the same start."""
    penalised = make_learner("MountainCar-v0", method, gradient_penalty=10.0, discriminator_steps=1, learning_rate=1e-2)
    plain = make_learner("MountainCar-v0", method, discriminator_steps=1, learning_rate=1e-2)
    try:
        for learner in (penalised, plain):
            learner.discriminator.add_rollout(learner.ppo.collect_rollout())
        side = penalised.discriminator
        discriminator, policy, size = side.discriminator, penalised.ppo.policy, side.config.batch_size
        weights = {name: tensor.clone() for name, tensor in discriminator.state_dict().items()}
        generator = side.generator.get_state()
        loss = side.learn(policy)["discriminator_loss"]
        # The same draws again, with the weights from before the step.
        side.generator.set_state(generator)
        discriminator.load_state_dict(weights)
        batch = side.demos.select(torch.randint(len(side.demos), (size,), generator=side.generator)).cat(side._negatives(size))
        log_pi = env_action_log_probs(policy, batch.observations, batch.env_actions) if discriminator.uses_policy else None
        discriminator.train()
        logits, inputs = discriminator.logits(batch, log_pi, penalised=True)
        penalty = input_gradient_penalty(logits, inputs).item()
        assert penalty > 0
        assert loss == pytest.approx(discriminator_loss(logits[:size], logits[size:]).item() + 10.0 * penalty, rel=1e-5)

        def gradient_norm(learner: AdversarialImitation) -> float:
            side = learner.discriminator
            batch = side.demos.select(torch.arange(0, len(side.demos), 10)).cat(side.rollouts[-1])
            log_pi = (
                env_action_log_probs(learner.ppo.policy, batch.observations, batch.env_actions)
                if side.discriminator.uses_policy
                else None
            )
            logits, inputs = side.discriminator.logits(batch, log_pi, penalised=True)
            return input_gradient_penalty(logits, inputs).item()

        for learner in (penalised, plain):
            learner.discriminator.discriminator.load_state_dict(weights)
            learner.discriminator.config.discriminator_steps = 40
            learner.discriminator.learn(learner.ppo.policy)
        assert gradient_norm(penalised) < 0.5 * gradient_norm(plain)
    finally:
        penalised.ppo.close()
        plain.ppo.close()


def test_gails_state_action_next_state_discriminator_reads_the_next_state() -> None:
    """With `inputs="sas"`, D's logit and PPO's reward are the net's of (s, a, s'), not of (s, a, s)."""
    space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    torch.manual_seed(0)
    net = make_reward_model(space, gym.spaces.Discrete(2), hidden_sizes=[8], inputs="sas", output="softplus")
    discriminator = GAILDiscriminator(net)
    batch = Steps(
        torch.tensor([[0.1, 0.2], [0.3, -0.4]]), torch.tensor([0, 1]), torch.tensor([[0.9, -0.7], [-0.5, 0.6]]), torch.zeros(2)
    )
    logits, inputs = discriminator.logits(batch, None, penalised=True)
    with torch.no_grad():
        expected = net.net_output(net.prepare(batch.observations, batch.env_actions, batch.next_observations))
        same_state = net.net_output(net.prepare(batch.observations, batch.env_actions, batch.observations))
    torch.testing.assert_close(logits.detach(), expected)
    assert not torch.allclose(expected, same_state)
    torch.testing.assert_close(
        discriminator.policy_rewards(batch, None), net(batch.observations, batch.env_actions, batch.next_observations)
    )
    assert sum(tensor.numel() for tensor in inputs) == 2 * (2 + 2 + 2)  # s, one-hot a, s' of each step


def test_airls_logit_and_reward_drop_the_next_potential_where_the_step_terminated() -> None:
    """g(s) = s₀, h(s) = s₁, γ = ½, π(a|s) = ¼; s = (1, 2), s' = (3, 4): f = 1 + 2 − 2 = 1 when the
    episode goes on, 1 − 2 = −1 when s' ended it."""
    box = gym.spaces.Box(-10.0, 10.0, (2,), np.float32)

    def linear(weights: list[float]) -> RewardNet:
        net = make_reward_model(box, gym.spaces.Discrete(2), hidden_sizes=[], inputs="s")
        with torch.no_grad():
            net.net[-1].weight.copy_(torch.tensor([weights]))
            net.net[-1].bias.zero_()
        return net

    discriminator = AIRLDiscriminator(linear([1.0, 0.0]), linear([0.0, 1.0]), gamma=0.5)
    observations, next_observations = torch.tensor([[1.0, 2.0]] * 2), torch.tensor([[3.0, 4.0]] * 2)
    batch = Steps(observations, torch.tensor([0, 0]), next_observations, torch.tensor([0.0, 1.0]))
    log_pi = torch.full((2,), math.log(0.25))
    logits, _ = discriminator.logits(batch, log_pi, penalised=False)
    assert logits.tolist() == pytest.approx([1.0 + math.log(4.0), -1.0 + math.log(4.0)])
    assert discriminator.policy_rewards(batch, log_pi).tolist() == pytest.approx([1.0 + math.log(4.0), -1.0 + math.log(4.0)])

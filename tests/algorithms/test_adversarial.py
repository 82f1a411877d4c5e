"""GAIL and AIRL: the discriminator's loss and the rewards against hand-worked values, the
discriminator learner's steps, pool and checkpoint, on PPO's rollouts of fixed-horizon CartPole."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS

import imitation.envs  # noqa: F401  (registers the ids)
from imitation.algorithms.adversarial import (
    AdversarialConfig,
    AdversarialImitation,
    DiscriminatorLearner,
    Steps,
    discriminator_loss,
    input_gradient_penalty,
    rollout_steps,
)
from imitation.algorithms.airl import AIRLDiscriminator
from imitation.rewards import ShapedReward, airl_shaped_reward
from imitation.algorithms.gail import GAILDiscriminator
from imitation.algorithms.ppo import PPO, PPOConfig
from imitation.checkpoints import snapshot
from imitation.data.dataset import DemoDataset
from imitation.data.loader import TransitionTensors, load_transitions, transitions_to_torch
from imitation.envs.rollout import Rollout
from imitation.errors import ConfigError
from imitation.jobs.loop import Checkpointing, run
from imitation.jobs.presets import ppo_settings
from imitation.rewards import RewardNet, constant_reward_like, make_reward_model

ENV_ID = "imitation/CartPoleFixedHorizon-v0"
BOX2 = gym.spaces.Box(-10.0, 10.0, (2,), np.float32)


def linear(weights: list[float], bias: float = 0.0, *, inputs: str = "s", output: str = "linear") -> RewardNet:
    net = make_reward_model(BOX2, gym.spaces.Discrete(2), hidden_sizes=[], inputs=inputs, output=output)
    last = net.net[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.weight[0, : len(weights)] = torch.tensor(weights)
        last.bias.fill_(bias)
    return net


def steps(observations, actions, next_observations, terminated) -> Steps:
    return Steps(
        torch.tensor(observations, dtype=torch.float32),
        torch.tensor(actions),
        torch.tensor(next_observations, dtype=torch.float32),
        torch.tensor(terminated, dtype=torch.float32),
    )


def test_the_discriminator_loss_is_the_cross_entropy_of_demos_as_1_and_samples_as_0() -> None:
    # (ln 2 + ln(1 + e⁻²)) / 2 + (ln(1 + e⁻¹) + ln(1 + e)) / 2, worked by hand.
    loss = discriminator_loss(torch.tensor([0.0, 2.0]), torch.tensor([-1.0, 1.0]))
    assert loss.item() == pytest.approx((0.693147 + 0.126928) / 2 + (0.313262 + 1.313262) / 2, abs=1e-5)
    assert loss.item() == pytest.approx(1.223300, abs=1e-5)


def test_gails_reward_is_minus_log_one_minus_d() -> None:
    # D = ½ pays ln 2; D = ¾ (logit ln 3) pays −ln ¼ = ln 4; a confident "policy" (logit −30) pays ~e⁻³⁰.
    batch = steps([[1.0, 1.0]], [1], [[0.0, 0.0]], [0.0])
    logits = [0.0, math.log(3.0), -30.0, 30.0]
    rewards = [GAILDiscriminator(linear([0.0, 0.0], d, inputs="sa", output="softplus")).policy_rewards(batch, None).item() for d in logits]
    assert rewards == pytest.approx([math.log(2.0), math.log(4.0), math.exp(-30.0), 30.0], rel=1e-6)


def test_airls_shaped_reward_drops_the_next_potential_after_a_termination() -> None:
    # g = 1, h(s) = 2, h(s') = 3, γ = 0.9: 1 + 2.7 − 2 = 1.7, and 1 − 2 = −1 once s' ended the episode.
    f = airl_shaped_reward(torch.tensor([1.0, 1.0]), torch.tensor([2.0, 2.0]), torch.tensor([3.0, 3.0]), torch.tensor([0.0, 1.0]), 0.9)
    assert f.tolist() == pytest.approx([1.7, -1.0])


def test_airls_shaped_reward_relabels_a_rollouts_steps_as_g_plus_discounted_next_h_minus_h() -> None:
    # g(s) = s₀, h(s) = s₁, γ = ½. Step 1: s = (1, 2), s' = (3, 4): f = 1 + 2 − 2 = 1. Step 2: s = (3, 4),
    # s' = (5, 6), which ended the episode: f = 3 − 4 = −1.
    rollout = Rollout(
        observations=torch.tensor([[[1.0, 2.0]], [[3.0, 4.0]]]),
        actions=torch.zeros(2, 1, dtype=torch.long),
        env_actions=torch.zeros(2, 1, dtype=torch.long),
        next_observations=torch.tensor([[[3.0, 4.0]], [[5.0, 6.0]]]),
        log_probs=torch.zeros(2, 1),
        env_rewards=torch.zeros(2, 1),
        terminated=torch.tensor([[False], [True]]),
        truncated=torch.zeros(2, 1, dtype=torch.bool),
    )
    f = ShapedReward(linear([1.0, 0.0]), linear([0.0, 1.0]), gamma=0.5).relabel(rollout)
    assert f.shape == (2, 1) and f[:, 0].tolist() == pytest.approx([1.0, -1.0])


def test_airls_logit_is_f_minus_log_pi_so_d_is_exp_f_over_exp_f_plus_pi() -> None:
    # g(s) = s₀, h(s) = s₁; s = (1, 2), s' = (3, 4), γ = ½: f = 1 + 2 − 2 = 1; π(a|s) = ¼.
    discriminator = AIRLDiscriminator(linear([1.0, 0.0]), linear([0.0, 1.0]), gamma=0.5, policy_entropy=1.0)
    batch = steps([[1.0, 2.0]], [0], [[3.0, 4.0]], [0.0])
    log_pi = torch.tensor([math.log(0.25)])
    logits, inputs = discriminator.logits(batch, log_pi, penalised=True)
    assert logits.item() == pytest.approx(1.0 + math.log(4.0), abs=1e-6)
    assert torch.sigmoid(logits).item() == pytest.approx(math.e / (math.e + 0.25), abs=1e-6)
    # PPO's reward: log D − log(1 − D) = f − log π with α = 1; f alone with α = 0.
    assert discriminator.policy_rewards(batch, log_pi).item() == pytest.approx(1.0 + math.log(4.0), abs=1e-6)
    discriminator.policy_entropy = 0.0
    assert discriminator.policy_rewards(batch, log_pi).item() == pytest.approx(1.0, abs=1e-6)
    # The gradient of f with respect to g's input (1, 0), h(s)'s (0, −1) and h(s')'s (0, ½): ‖·‖² = 1 + 1 + ¼.
    assert input_gradient_penalty(logits, inputs).item() == pytest.approx(2.25, abs=1e-6)
    assert discriminator.recovered_reward() is discriminator.reward


def test_gails_logit_is_its_nets_linear_output_and_its_exported_reward_pays_softplus_of_it() -> None:
    net = linear([2.0, -1.0], 0.5, inputs="sa", output="softplus")
    discriminator = GAILDiscriminator(net)
    batch = steps([[1.0, 1.0]], [1], [[0.0, 0.0]], [0.0])
    logits, _ = discriminator.logits(batch, None, penalised=False)
    assert logits.item() == pytest.approx(1.5)  # 2·1 − 1·1 + 0.5 (the action's one-hot weights are 0)
    assert discriminator.policy_rewards(batch, None).item() == pytest.approx(math.log1p(math.exp(1.5)), abs=1e-6)
    assert net(batch.observations, batch.env_actions, batch.next_observations).item() == pytest.approx(math.log1p(math.exp(1.5)), abs=1e-6)
    # The constant control of `eval reward` still pays 1 through the softplus.
    assert constant_reward_like(net)(batch.observations, batch.env_actions, batch.next_observations).item() == pytest.approx(1.0, abs=1e-6)


def test_gails_logit_reward_is_the_logit_log_d_minus_log_one_minus_d_and_is_what_its_net_exports() -> None:
    # The same net with a linear output: PPO's reward is d = 1.5 itself, log σ(1.5) − log(1 − σ(1.5)).
    net = linear([2.0, -1.0], 0.5, inputs="sa")
    discriminator = GAILDiscriminator(net)
    batch = steps([[1.0, 1.0]], [1], [[0.0, 0.0]], [0.0])
    d = torch.sigmoid(torch.tensor(1.5)).item()
    assert discriminator.policy_rewards(batch, None).item() == pytest.approx(math.log(d) - math.log(1 - d), abs=1e-6)
    assert discriminator.policy_rewards(batch, None).item() == pytest.approx(1.5, abs=1e-6)
    # Where D is sure a step is the policy's (logit −30), softplus has flattened to ~e⁻³⁰; the logit has not.
    sure = linear([0.0, 0.0], -30.0, inputs="sa")
    assert GAILDiscriminator(sure).policy_rewards(batch, None).item() == pytest.approx(-30.0)
    assert net(batch.observations, batch.env_actions, batch.next_observations).item() == pytest.approx(1.5, abs=1e-6)
    with pytest.raises(ConfigError, match="gail_reward must be one of softplus, logit, got 'log'"):
        AdversarialConfig(gail_reward="log").validate()


def test_the_penalty_of_a_linear_logit_is_its_squared_weight_norm() -> None:
    x = torch.tensor([[1.0, 2.0], [-3.0, 0.5]], requires_grad=True)
    logits = x @ torch.tensor([3.0, 4.0])
    assert input_gradient_penalty(logits, [x]).item() == pytest.approx(25.0)


def demos() -> object:
    return transitions_to_torch(load_transitions(DemoDataset([DATASETS / "CartPoleFixedHorizon-v0.mcap"]), next_observations=True))


def make_learner(method: str, seed: int, config: PPOConfig, **changes) -> AdversarialImitation:
    torch.manual_seed(seed)
    env = gym.make(ENV_ID)
    adversarial = AdversarialConfig(**{"method": method, "batch_size": 64, "discriminator_steps": 4, "seed": seed} | changes)

    def net(inputs: str, output: str = "linear") -> RewardNet:
        return make_reward_model(env.observation_space, env.action_space, hidden_sizes=[16], inputs=inputs, output=output, normalize_observations=True)

    if method == "gail":
        discriminator = GAILDiscriminator(net("sa", "softplus"))
    else:
        discriminator = AIRLDiscriminator(net("s"), net("s"), gamma=config.gamma)
    return AdversarialImitation(PPO(config), discriminator, demos(), adversarial)


@pytest.mark.parametrize("method", ["gail", "airl"])
def test_the_discriminator_learns_to_tell_demo_steps_from_a_random_policys(method: str) -> None:
    config = PPOConfig(env_id=ENV_ID, total_steps=256, **ppo_settings(ENV_ID) | {"device": "cpu"})
    learner = make_learner(method, 0, config, discriminator_steps=200, learning_rate=1e-2)
    rollout = learner.ppo.collect_rollout()
    learner.discriminator.add_rollout(rollout)
    statistics = learner.discriminator.learn(learner.ppo.policy)
    assert statistics["demo_accuracy"] > 0.7 and statistics["sample_accuracy"] > 0.7
    # Afterwards PPO's reward pays the demos' steps more than the policy's.
    rewards = learner.discriminator.policy_rewards(learner.discriminator.rollouts[-1], learner.ppo.policy)
    demo_rewards = learner.discriminator.policy_rewards(learner.discriminator.demos, learner.ppo.policy)
    assert demo_rewards.mean() > rewards.mean() + 1.0


def test_the_pool_keeps_the_last_rollouts_as_copies() -> None:
    config = PPOConfig(env_id=ENV_ID, total_steps=3 * 256, **ppo_settings(ENV_ID) | {"device": "cpu"})
    learner = make_learner("gail", 0, config, pool_rollouts=2)
    pooled = []
    for _ in range(3):
        rollout = learner.ppo.collect_rollout()
        pooled.append(learner.discriminator.add_rollout(rollout).observations.clone())
        learner.ppo.update(rollout, rollout.env_rewards)
    assert len(learner.discriminator.rollouts) == 2
    for kept, expected in zip(learner.discriminator.rollouts, pooled[1:]):
        assert torch.equal(kept.observations, expected)  # not overwritten by PPO's next rollout


def pooled_learner(pool_rollouts: int, latest_share: float) -> AdversarialImitation:
    """An AIRL learner (seed 0) after three PPO updates, each one's rollout added to its pool."""
    config = PPOConfig(env_id=ENV_ID, total_steps=3 * 256, **ppo_settings(ENV_ID) | {"device": "cpu"})
    learner = make_learner("airl", 0, config, pool_rollouts=pool_rollouts, latest_share=latest_share)
    for _ in range(3):
        rollout = learner.ppo.collect_rollout()
        learner.discriminator.add_rollout(rollout)
        learner.ppo.update(rollout, rollout.env_rewards)
    return learner


def test_a_share_of_the_negatives_comes_from_the_latest_rollout() -> None:
    for share, low, high in ((0.5, 128 + 20, 128 + 70), (0.0, 50, 120)):
        learner = pooled_learner(3, share).discriminator
        # Rollouts told apart by their observations: rollout k's are all k.
        learner.rollouts = [steps([[k] * 4] * 256, [0] * 256, [[k] * 4] * 256, [0.0] * 256) for k in range(3)]
        from_latest = int((learner._negatives(256).observations[:, 0] == 2).sum())
        # ρ·256 drawn from the latest, and about a third of the rest drawn from the whole pool.
        assert low <= from_latest <= high, (share, from_latest)


def test_the_pool_is_read_as_its_rollouts_one_after_another() -> None:
    learner = pooled_learner(3, 0.0).discriminator
    learner.rollouts[1] = learner.rollouts[1].select(torch.arange(100))  # rollouts of unequal lengths too
    pool = learner.rollouts[0].cat(*learner.rollouts[1:])
    # The second index draws one step from each of two rollouts.
    for index in (torch.tensor([611, 0, 255, 256, 355, 356, 300, 0, 611]), torch.tensor([300, 5])):
        for name in Steps.__dataclass_fields__:
            assert torch.equal(getattr(learner.pool_select(index), name), getattr(pool.select(index), name)), name


def test_all_negatives_from_the_latest_rollout_is_a_pool_of_one() -> None:
    pooled, latest_only = pooled_learner(3, 1.0), pooled_learner(1, 0.0)
    assert len(pooled.discriminator.rollouts) == 3 and len(latest_only.discriminator.rollouts) == 1
    assert pooled.discriminator.learn(pooled.ppo.policy) == latest_only.discriminator.learn(latest_only.ppo.policy)


def test_the_discriminator_steps_every_policy_updates_updates() -> None:
    config = PPOConfig(env_id=ENV_ID, total_steps=4 * 256, **ppo_settings(ENV_ID) | {"device": "cpu"})
    learner = make_learner("airl", 0, config, policy_updates=2)
    learned = []
    while not learner.done:
        learner.step()
        learned.append(learner.discriminator.learned)
    # Rounds at updates 0 and 2: the first PPO update already reads a trained discriminator.
    assert learned == [1, 1, 2, 2] and learner.ppo.updates == 4


@pytest.mark.parametrize("method", ["gail", "airl"])
def test_a_discriminator_restored_from_its_checkpoint_goes_on_exactly_as_the_original(method: str) -> None:
    config = PPOConfig(env_id=ENV_ID, total_steps=3 * 256, **ppo_settings(ENV_ID) | {"device": "cpu"})
    source = make_learner(method, 0, config)
    rollouts = []
    for _ in range(3):
        rollout = source.ppo.collect_rollout()
        rollouts.append(rollout.cpu_copy())
        source.ppo.update(rollout, rollout.env_rewards)
    policy = source.ppo.policy
    original = make_learner(method, 0, config, pool_rollouts=2).discriminator
    for rollout in rollouts[:2]:
        original.add_rollout(rollout)
        original.learn(policy)
    checkpoint = snapshot(*original.state_dict())  # the loop's copy: state_dict() hands out live tensors
    copy = make_learner(method, 1, config, pool_rollouts=2).discriminator  # other weights: the checkpoint must set them
    copy.load_state_dict(checkpoint)
    assert copy.learned == 2 and len(copy.rollouts) == 2
    assert copy.last == original.last and set(copy.last) == {"discriminator_loss", "demo_accuracy", "sample_accuracy"}
    results = []
    for learner in (original, copy):
        steps = learner.add_rollout(rollouts[2])
        results.append((learner.learn(policy), learner.policy_rewards(steps, policy)))
    assert results[0][0] == results[1][0]
    assert torch.equal(results[0][1], results[1][1])
    for name, tensor in original.discriminator.state_dict().items():
        assert torch.equal(copy.discriminator.state_dict()[name], tensor), name


def test_the_discriminator_rides_in_ppos_checkpoints_and_resumes_with_them() -> None:
    config = PPOConfig(env_id=ENV_ID, total_steps=4 * 256, **ppo_settings(ENV_ID) | {"device": "cpu"})
    saved = []
    first = make_learner("airl", 0, config, pool_rollouts=3)
    run(first, checkpoints=Checkpointing(save=lambda tensors, state: saved.append((tensors, state)), every=2))
    tensors, state = saved[0]
    assert state["update"] == 2 and state["learner"]["learned"] == 2 and tensors["learner.pool.1.terminated"].shape == (256,)
    resumed = make_learner("airl", 1, config, pool_rollouts=3)
    rows = run(resumed, checkpoints=Checkpointing(save=lambda *a: None, resume=saved[0]))
    assert resumed.discriminator.learned == 4 and len(rows) == 2 and all("discriminator_loss" in row for row in rows)
    assert len(resumed.discriminator.rollouts) == 3, "the pool kept the rollouts from before the interruption"


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"method": "gan"}, "method"),
        ({"inputs": "a"}, "inputs"),
        ({"gail_reward": "log"}, "gail_reward"),
        ({"batch_size": 0}, "batch_size"),
        ({"discriminator_steps": 0}, "discriminator_steps"),
        ({"policy_updates": 0}, "policy_updates"),
        ({"pool_rollouts": 0}, "pool_rollouts"),
        ({"latest_share": 1.5}, "latest_share"),
        ({"latest_share": float("nan")}, "latest_share"),
        ({"learning_rate": float("nan")}, "learning_rate"),
        ({"learning_rate": 0.0}, "learning_rate"),
        ({"learning_rate": 1e30}, "learning_rate"),
        ({"gradient_penalty": float("inf")}, "gradient_penalty"),
        ({"gradient_penalty": -1.0}, "gradient_penalty"),
        ({"policy_entropy": float("inf")}, "policy_entropy"),
    ],
)
def test_config_out_of_range_is_refused_naming_the_field(changes: dict, field: str) -> None:
    with pytest.raises(ConfigError) as error:
        AdversarialConfig(**changes).validate()
    assert error.value.field == field


# ------------------------------------------------------------------------------------------------
# Rounds on hand-made steps: a linear GAIL logit of the state alone, demos and rollouts given as lists.


def transitions(states: list[list[float]]) -> TransitionTensors:
    observations, n = torch.tensor(states), len(states)
    return TransitionTensors(
        observations=observations,
        actions=torch.zeros(n, dtype=torch.long),
        rewards=torch.zeros(n),
        next_observations=observations.clone(),
        terminated=torch.zeros(n, dtype=torch.bool),
        truncated=torch.zeros(n, dtype=torch.bool),
        episode_index=torch.zeros(n, dtype=torch.long),
    )


def one_copy_rollout(states: list[list[float]]) -> Rollout:
    observations, length = torch.tensor(states)[:, None], len(states)
    return Rollout(
        observations=observations,
        actions=torch.zeros(length, 1, dtype=torch.long),
        env_actions=torch.zeros(length, 1, dtype=torch.long),
        next_observations=observations.clone(),
        log_probs=torch.zeros(length, 1),
        env_rewards=torch.zeros(length, 1),
        terminated=torch.zeros(length, 1, dtype=torch.bool),
        truncated=torch.zeros(length, 1, dtype=torch.bool),
    )


def test_a_round_reports_its_steps_mean_loss_and_accuracies_and_leaves_d_in_eval_mode() -> None:
    """logit = 2 s₀ and every state's s₀ = ¼: each of the 3 steps sees logit ½ on all 8 steps of its
    minibatch, so its cross-entropy is softplus(−½) + softplus(½), ∇_s logit = (2, 0) gives
    E‖∇_x logit‖² = 4, and λ = ½ adds 2. A learning rate of 1e-12 keeps the weights where they were."""
    discriminator = GAILDiscriminator(linear([2.0, 0.0]))
    config = AdversarialConfig(batch_size=4, discriminator_steps=3, learning_rate=1e-12, gradient_penalty=0.5)
    learner = DiscriminatorLearner(discriminator, transitions([[0.25, 1.0]] * 5), config)
    pooled = learner.add_rollout(one_copy_rollout([[0.25, -1.0]] * 6))
    statistics = learner.learn(None)  # GAIL's logit reads no policy, nor does its reward (the logit here)
    assert learner.policy_rewards(pooled, None).tolist() == pytest.approx([0.5] * 6)
    cross_entropy = math.log1p(math.exp(-0.5)) + math.log1p(math.exp(0.5))
    # Demo steps (logit ½ > 0) all told apart, policy steps (logit ½ ≥ 0) none.
    expected = {"discriminator_loss": cross_entropy + 2.0, "demo_accuracy": 1.0, "sample_accuracy": 0.0}
    assert statistics == pytest.approx(expected)
    assert learner.last == statistics and learner.learned == 1
    assert not discriminator.training
    assert [int(state["step"]) for state in learner.optimizer.state.values()] == [3, 3]  # weight and bias, 3 steps each
    # A discriminator that cannot tell anything apart (D = ½ everywhere) tells no step apart: 2 ln 2, no
    # penalty. One step only: the next would read weights that the first step moved.
    one_step = AdversarialConfig(batch_size=4, discriminator_steps=1, learning_rate=1e-12, gradient_penalty=0.5)
    undecided = DiscriminatorLearner(GAILDiscriminator(linear([0.0, 0.0])), transitions([[0.25, 1.0]] * 5), one_step)
    undecided.add_rollout(one_copy_rollout([[0.25, -1.0]] * 6))
    expected = {"discriminator_loss": 2 * math.log(2.0), "demo_accuracy": 0.0, "sample_accuracy": 0.0}
    assert undecided.learn(None) == pytest.approx(expected)


def test_the_first_rollout_widens_the_demos_spread_once_and_a_warm_start_keeps_its_statistics() -> None:
    """On an unbounded space the statistics are the demos' mean and, per dimension, the larger std
    of the demos' and the first rollout's states; later rollouts change nothing, and a discriminator
    started from a saved one keeps the statistics its weights were fitted to."""
    space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)
    demos = [[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]]  # mean (1, 1), std √(4/3) each
    first, wide = [[0.0, 0.0], [4.0, 0.0]] * 2, [[0.0, 0.0], [40.0, 40.0]] * 2  # first: std (√(16/3), 0)

    def statistics_after(
        rollouts: list[list[list[float]]], *, fit_statistics: bool, through_learner: bool = False
    ) -> list[list[float]]:
        net = make_reward_model(space, gym.spaces.Discrete(2), hidden_sizes=[], inputs="s", normalize_observations=True)
        config = AdversarialConfig(pool_rollouts=2)
        warm_start = {} if fit_statistics else {"fit_statistics": False}  # fitting is the default of both
        if through_learner:
            settings = {"n_envs": 1, "n_steps": 8, "total_steps": 8, "batch_size": 8, "hidden_sizes": [4], "device": "cpu"}
            ppo = PPO(PPOConfig(env_id="CartPole-v1", **settings))
            ppo.close()
            side = AdversarialImitation(ppo, GAILDiscriminator(net), transitions(demos), config, **warm_start).discriminator
        else:
            side = DiscriminatorLearner(GAILDiscriminator(net), transitions(demos), config, **warm_start)
        for states in rollouts:
            side.add_rollout(one_copy_rollout(states))
        return [net.observation_mean.tolist(), net.observation_std.tolist()]

    fitted = [[1.0, 1.0], [math.sqrt(16 / 3), math.sqrt(4 / 3)]]
    assert statistics_after([first], fit_statistics=True) == [pytest.approx(row) for row in fitted]
    assert statistics_after([first, wide], fit_statistics=True) == [pytest.approx(row) for row in fitted]
    assert statistics_after([first], fit_statistics=True, through_learner=True) == [pytest.approx(row) for row in fitted]
    assert statistics_after([first], fit_statistics=False) == statistics_after([], fit_statistics=False)
    # The learner hands a warm start on to its discriminator: the net's own mean 0 and std 1 stay.
    assert statistics_after([first], fit_statistics=False, through_learner=True) == [[0.0, 0.0], [1.0, 1.0]]


def test_a_learner_checkpointed_before_its_first_round_has_no_statistics_and_restores_as_fresh() -> None:
    config = AdversarialConfig(batch_size=4, discriminator_steps=1, learning_rate=1e-12)

    def learner() -> DiscriminatorLearner:
        return DiscriminatorLearner(GAILDiscriminator(linear([2.0, 0.0])), transitions([[0.25, 1.0]] * 5), config)

    fresh = learner()
    tensors, state = snapshot(*fresh.state_dict())
    assert (state["learned"], state["pooled"], state["last"]) == (0, 0, {})
    # A learner one round on, restored from it, is fresh again: no round, no pool, nothing to log.
    restored = learner()
    restored.add_rollout(one_copy_rollout([[0.25, -1.0]] * 6))
    restored.learn(None)
    restored.load_state_dict((tensors, state))
    assert (restored.learned, restored.rollouts, restored.last) == (0, [], {})


def test_a_rollouts_steps_are_its_time_by_envs_grid_row_by_row_with_box_actions_kept_whole() -> None:
    """3 steps of 2 envs: state 10 t + e, action (t + ½, −e) of 2 dimensions, only env 1's last step terminal."""
    observations = torch.tensor([[[10.0 * t + e] for e in range(2)] for t in range(3)])
    env_actions = torch.tensor([[[t + 0.5, -float(e)] for e in range(2)] for t in range(3)])
    terminated = torch.tensor([[False, False], [False, False], [False, True]])
    rollout = Rollout(
        observations=observations,
        actions=env_actions.clone(),
        env_actions=env_actions,
        next_observations=observations + 1.0,
        log_probs=torch.zeros(3, 2),
        env_rewards=torch.zeros(3, 2),
        terminated=terminated,
        truncated=torch.zeros(3, 2, dtype=torch.bool),
    )
    steps = rollout_steps(rollout)
    assert len(steps) == 6
    assert steps.observations.tolist() == [[0.0], [1.0], [10.0], [11.0], [20.0], [21.0]]
    assert steps.env_actions.tolist() == [[0.5, 0.0], [0.5, -1.0], [1.5, 0.0], [1.5, -1.0], [2.5, 0.0], [2.5, -1.0]]
    assert steps.next_observations.tolist() == [[1.0], [2.0], [11.0], [12.0], [21.0], [22.0]]
    assert steps.terminated.tolist() == [0.0, 0.0, 0.0, 0.0, 0.0, 1.0]

"""The policy-gradient learner's critic wiring (imitation.algorithms.policy_gradient): the weights
of a batch bootstrap from V(s_{t+1}) of the state that followed each step (the next step's state
inside an episode, the true final state where a time limit or a rollout's end cut it) and from
nothing after a termination. Checked on a hand-made batch against numbers worked by hand, and on
batches CartPole-v1 (which terminates) really produced, against a per-step restatement."""

from __future__ import annotations

import dataclasses
import math
import time
from decimal import Decimal

import gymnasium as gym
import numpy as np
import pytest
import torch

from imitation.algorithms.policy_gradient import Batch, PGConfig, PolicyGradient
from imitation.checkpoints import snapshot, unprefixed
from imitation.errors import ConfigError, ImitationError
from imitation.policies import ActorCritic, PolicyConfig

GAMMA = 0.5


def learner_with_critic_s0(**options) -> PolicyGradient:
    """A CartPole learner whose linear critic reads V(s) = s₀."""
    config = PGConfig(
        env_id="CartPole-v1", estimator="actor-critic", gamma=GAMMA, n_envs=1, batch_steps=5, hidden_sizes=[], **options
    )
    learner = PolicyGradient(config)
    with torch.no_grad():
        learner.policy.value_head.weight.copy_(torch.tensor([[1.0, 0.0, 0.0, 0.0]]))
        learner.policy.value_head.bias.zero_()
    return learner


def hand_batch() -> Batch:
    """Episode A: s₀ = 1, 2, 3, terminated; episode B: s₀ = 4, 5, truncated in the state s₀ = 7.
    Every reward 1."""
    features = torch.zeros(5, 4)
    features[:, 0] = torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0])
    final = torch.zeros(5, 4)
    final[4, 0] = 7.0
    return Batch(
        features=features,
        actions=torch.zeros(5, dtype=torch.long),
        rewards=torch.ones(5),
        terminated=torch.tensor([False, False, True, False, False]),
        truncated=torch.tensor([False, False, False, False, True]),
        final_features=final,
        episode_returns=[3.0, 2.0],
        pieces=2,
    )


@pytest.mark.parametrize(
    ("options", "advantages"),
    [
        # TD(0): δ_t = r_t + γ (1 − d_t) V(s_{t+1}) − V(s_t).
        # A: 1 + ½·2 − 1, 1 + ½·3 − 2, 1 − 3;  B: 1 + ½·5 − 4, 1 + ½·7 − 5.
        ({"gae_lambda": 0.0}, [1.0, 0.5, -2.0, -0.5, -0.5]),
        ({"n_step": 1}, [1.0, 0.5, -2.0, -0.5, -0.5]),
        # Two steps: r_t + γ r_{t+1} + γ² V(s_{t+2}), cut by the episode's end.
        # A: 1 + ½ + ¼·3 − 1, 1 + ½ − 2, 1 − 3;  B: 1 + ½ + ¼·7 − 4, 1 + ½·7 − 5.
        ({"n_step": 2}, [1.25, -0.5, -2.0, -0.75, -0.5]),
    ],
    ids=["gae-0", "td0", "2-step"],
)
def test_the_critic_bootstraps_from_the_next_state_and_not_after_a_termination(options: dict, advantages: list[float]) -> None:
    learner = learner_with_critic_s0(**options)
    try:
        weights, targets, values = learner.weights(hand_batch())
    finally:
        learner.close()
    assert values.tolist() == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert weights.tolist() == pytest.approx(advantages)
    assert targets.tolist() == pytest.approx([a + v for a, v in zip(advantages, [1.0, 2.0, 3.0, 4.0, 5.0])])


def td0_by_step(learner: PolicyGradient, batch: Batch) -> torch.Tensor:
    """δ_t of every step, one step at a time from the batch's flags."""
    value = learner.policy.value
    deltas = []
    with torch.no_grad():
        for t in range(len(batch.rewards)):
            following = 0.0
            if batch.truncated[t]:
                following = value(batch.final_features[t][None])[0]
            elif not batch.terminated[t]:
                following = value(batch.features[t + 1][None])[0]
            deltas.append(batch.rewards[t] + learner.config.gamma * following - value(batch.features[t][None])[0])
    return torch.stack([torch.as_tensor(delta, dtype=torch.float32) for delta in deltas])


@pytest.mark.parametrize("rollout_steps", [None, 30], ids=["episodes", "rollouts"])
def test_cartpole_batches_are_weighted_by_td0_of_the_state_each_step_reached(rollout_steps: int | None) -> None:
    """Whole episodes (CartPole-v1's random-policy episodes terminate) and 30-step rollouts of 4
    copies (pieces cut at the rollout's end are truncated and bootstrapped from where they got to)."""
    config = PGConfig(
        env_id="CartPole-v1",
        estimator="actor-critic",
        gae_lambda=0.0,
        gamma=0.9,
        n_envs=4,
        batch_steps=120,
        rollout_steps=rollout_steps,
        total_steps=2000,
        hidden_sizes=[8],
    )
    learner = PolicyGradient(config)
    try:
        for _ in range(2):  # the second batch with a critic that has been fitted once
            batch = learner.collect()
            assert batch.terminated.any()
            assert batch.truncated.any() == (rollout_steps is not None)
            weights, targets, values = learner.weights(batch)
            torch.testing.assert_close(weights, td0_by_step(learner, batch), rtol=1e-5, atol=1e-5)
            torch.testing.assert_close(targets, weights + values)
            learner.step()
    finally:
        learner.close()


def test_progress_shows_the_return_and_steps_and_a_config_reads_back_from_its_json() -> None:
    learner = learner_with_critic_s0(n_step=2)
    try:
        assert learner.progress({"return": 12.345, "step": 1024.0}) == {"ret": "12.3", "steps": "1024"}
    finally:
        learner.close()
    config = learner.config
    saved = dataclasses.asdict(config) | {"written_by": "a later version"}
    assert PGConfig.from_json(saved) == config


def test_the_checkpoint_alone_rebuilds_the_policy_and_a_damaged_one_is_one_line_naming_the_learner() -> None:
    learner = learner_with_critic_s0(n_step=2)
    try:
        learner.step()
        tensors, state = snapshot(*learner.state_dict())
        policy = ActorCritic(PolicyConfig.from_json(state["policy"]))
        policy.load_state_dict(unprefixed("policy", tensors))
        features = torch.randn(3, 4)
        assert torch.equal(policy.value(features), learner.policy.value(features))
        with pytest.raises(ImitationError, match=r"^the checkpoint's next batch is 1000000000, outside 0\.\.\d+ for this run"):
            learner.load_state_dict((tensors, state | {"batch": 10**9}))
        with pytest.raises(ImitationError, match=r"^the checkpoint does not fit this policy gradient run \(RuntimeError: Error\(s\) in loading"):
            learner.load_state_dict(({name: t for name, t in tensors.items() if name != "policy.value_head.weight"}, state))
    finally:
        learner.close()


def reward_to_go_by_hand(batch: Batch, gamma: float) -> torch.Tensor:
    """G_t = r_t + γ G_{t+1}, restarted at each episode's end (none of these is truncated)."""
    assert not batch.truncated.any()
    returns, running = [], 0.0
    for t in reversed(range(len(batch.rewards))):
        running = float(batch.rewards[t]) + (0.0 if batch.terminated[t] else gamma * running)
        returns.append(running)
    return torch.tensor(returns[::-1])


def test_a_steps_row_restates_its_batch_the_pre_update_networks_and_the_annealed_learning_rates() -> None:
    """REINFORCE with a baseline on CartPole-v1 (whose random-policy episodes terminate well inside
    the 40-step batch): every field of the row recomputed from the same batch, collected by a twin
    learner with the same seed and generator state, and its networks before the step; the second
    row's learning rate has fallen by the share of the total steps already taken."""
    config = PGConfig(
        env_id="CartPole-v1",
        estimator="baseline",
        gamma=0.9,
        n_envs=2,
        batch_steps=40,
        total_steps=400,
        hidden_sizes=[8],
        entropy_coef=0.01,
        value_steps=1,
        learning_rate=0.02,
        value_learning_rate=0.03,
    )
    learner, twin = PolicyGradient(config), PolicyGradient(config)
    try:
        generator = torch.get_rng_state()
        batch = twin.collect()
        with torch.no_grad():
            values = twin.policy.value(batch.features)
            returns = reward_to_go_by_hand(batch, 0.9)
            weights = returns - values
            log_probs, entropy = twin.policy.log_prob_and_entropy(twin.policy.distribution(batch.features), batch.actions)
            surrogate = -(log_probs * weights / (weights.std() + 1e-8)).sum() / batch.pieces
        torch.set_rng_state(generator)
        started = time.perf_counter()
        row = learner.step()
        elapsed = time.perf_counter() - started
        clock = learner.clock.seconds
        second = learner.step()
        value_rate = learner.value_optimizer.param_groups[0]["lr"]
    finally:
        learner.close()
        twin.close()
    steps, episodes = len(batch.rewards), len(batch.episode_returns)
    losses = ("policy_loss", "value_loss", "explained_variance", "entropy")
    timings = ("learning_rate", "steps_per_second", "seconds_update")
    assert row.keys() == {"step", "return", "batch_return", "episodes", *losses, *timings}
    assert row["step"] == steps
    assert row["episodes"] == episodes == batch.pieces and episodes >= 2
    assert row["return"] == row["batch_return"] == pytest.approx(sum(batch.episode_returns) / episodes)
    assert row["policy_loss"] == pytest.approx(float(surrogate - 0.01 * entropy.mean()), rel=1e-5)
    assert row["entropy"] == pytest.approx(float(entropy.mean()), rel=1e-6)
    assert row["value_loss"] == pytest.approx(float(0.5 * ((values - returns) ** 2).mean()), rel=1e-5)
    explained = 1.0 - float(torch.var(returns - values) / (torch.var(returns) + 1e-8))
    assert row["explained_variance"] == pytest.approx(explained, rel=1e-5)
    assert row["learning_rate"] == 0.02, "nothing is annealed before the first step"
    assert 0 < row["seconds_update"] < elapsed
    assert steps / clock <= row["steps_per_second"] and steps / row["steps_per_second"] <= elapsed
    remaining = 1.0 - steps / 400
    assert second["learning_rate"] == pytest.approx(remaining * 0.02) and value_rate == pytest.approx(remaining * 0.03)
    assert learner.batches == 2 and second["step"] == learner.global_step > steps


def test_a_row_without_a_critic_or_a_finished_episode_holds_nan_there() -> None:
    """Reward-to-go fits no critic: no value loss, no explained variance. A first 30-step rollout of
    Pendulum-v1 (200-step episodes) finishes no episode: no return yet."""
    no_critic = PolicyGradient(
        PGConfig(env_id="CartPole-v1", estimator="reward-to-go", n_envs=1, batch_steps=20, total_steps=100, hidden_sizes=[8])
    )
    cut = PolicyGradient(
        PGConfig(env_id="Pendulum-v1", estimator="actor-critic", n_envs=1, rollout_steps=30, total_steps=90, hidden_sizes=[8])
    )
    try:
        rows = no_critic.step(), cut.step()
    finally:
        no_critic.close()
        cut.close()
    assert math.isnan(rows[0]["value_loss"]) and math.isnan(rows[0]["explained_variance"])
    assert not math.isnan(rows[0]["return"]) and rows[0]["episodes"] >= 1
    assert math.isnan(rows[1]["return"]) and math.isnan(rows[1]["batch_return"]) and rows[1]["episodes"] == 0
    assert not math.isnan(rows[1]["value_loss"]) and not math.isnan(rows[1]["explained_variance"])


def test_a_gradient_clipped_to_a_tiny_norm_barely_moves_the_policy() -> None:
    """Adam's first step moves each weight by about the learning rate whatever the gradient's scale,
    unless the gradient is far below its ε (1e-8): clipped to norm 1e-12, the actor barely moves;
    the critic, which is not clipped, moves as usual."""
    moved = {}
    for max_grad_norm in (None, 1e-12):
        rates = {"learning_rate": 0.1, "value_learning_rate": 0.1}
        learner = learner_with_critic_s0(max_grad_norm=max_grad_norm, gae_lambda=0.0, **rates)
        try:
            before = [p.detach().clone() for p in (*learner.actor_parameters, *learner.critic_parameters)]
            learner.step()
            after = [p.detach() for p in (*learner.actor_parameters, *learner.critic_parameters)]
            actor = len(learner.actor_parameters)
        finally:
            learner.close()
        changes = [float((a - b).abs().max()) for a, b in zip(after, before)]
        moved[max_grad_norm] = (max(changes[:actor]), max(changes[actor:]))
    assert moved[None][0] > 0.05 and moved[1e-12][0] < 1e-3
    assert moved[None][1] > 0.05 and moved[1e-12][1] > 0.05


def test_config_bounds_are_inclusive_where_the_maths_allows_and_errors_name_their_config() -> None:
    accepted = [
        {"estimator": "actor-critic", "rollout_steps": 1, "n_envs": 2, "total_steps": 2},
        {"total_steps": 2000, "batch_steps": 2000},  # exactly one batch
        {"gamma": 0.0, "gae_lambda": 1.0},
        {"gamma": 1.0, "gae_lambda": 0.0},
    ]
    for changes in accepted:
        PGConfig(env_id="CartPole-v1", **changes).validate()
    refused = [
        ({"learning_rate": 0.0}, "learning_rate must be a positive number below 1e30, got 0.0"),
        ({"value_learning_rate": 1e30}, "value_learning_rate must be a positive number below 1e30, got 1e+30"),
        ({"estimator": "actor-critic", "rollout_steps": 0}, "rollout_steps must be at least 1, got 0"),
        ({"value_steps": 0}, "value_steps must be at least 1, got 0"),
    ]
    for changes, message in refused:
        with pytest.raises(ConfigError) as error:
            PGConfig(env_id="CartPole-v1", **changes).validate()
        assert str(error.value) == message and error.value.owner == "PGConfig"


def test_rewards_are_divided_by_the_running_std_of_the_discounted_return() -> None:
    """CartPole-v1 pays 1 a step. The scaler starts at mean 0, variance 1 and a count of 1e-4, and
    folds in the batch's running discounted returns x_t = 1 + γ x_{t-1} (restarted with each
    episode) by Chan et al.'s pooled moments; every reward is then 1 / √(var + 1e-8)."""
    config = PGConfig(
        env_id="CartPole-v1", estimator="reward-to-go", gamma=0.9, n_envs=2, batch_steps=60, total_steps=600,
        hidden_sizes=[8], normalize_rewards=True,
    )
    learner = PolicyGradient(config)
    try:
        batch = learner.collect()
    finally:
        learner.close()
    running, discounted = 0.0, []
    for end in (batch.terminated | batch.truncated).tolist():
        running = 1.0 + 0.9 * running
        discounted.append(running)
        running = 0.0 if end else running
    x, prior = np.array(discounted), 1e-4
    n, mean = len(x), x.mean()
    var = (prior + x.var() * n + mean**2 * prior * n / (prior + n)) / (prior + n)
    assert batch.terminated.sum() >= 2
    assert batch.rewards.tolist() == pytest.approx([1.0 / math.sqrt(var + 1e-8)] * n, rel=1e-6)


@pytest.mark.parametrize(("env_id", "bound"), [("CartPole-v1", 10.0), ("Pendulum-v1", -10.0)])
def test_scaled_rewards_are_clipped_to_ten_either_way(env_id: str, bound: float) -> None:
    """A scaler that has seen 1e12 returns of variance 1e-10 makes every reward of these envs (1 a
    step; Pendulum's below −1e-3 wherever the pole starts) ten thousand times its std: clipped."""
    config = PGConfig(
        env_id=env_id, estimator="actor-critic", n_envs=1, rollout_steps=10, total_steps=10, hidden_sizes=[8],
        normalize_rewards=True,
    )
    learner = PolicyGradient(config)
    try:
        assert learner.reward_scaler is not None
        learner.reward_scaler.var.fill_(1e-10)
        learner.reward_scaler.count.fill_(1e12)
        batch = learner.collect()
    finally:
        learner.close()
    assert batch.rewards.tolist() == [bound] * 10


def test_recent_returns_are_the_last_twenty_episodes_and_fixed_rates_stay_fixed() -> None:
    config = PGConfig(
        env_id="CartPole-v1", estimator="baseline", n_envs=4, batch_steps=600, total_steps=2400, hidden_sizes=[8],
        anneal_lr=False, learning_rate=0.02, value_learning_rate=0.03,
    )
    learner = PolicyGradient(config)
    try:
        batch = learner.collect()
        assert len(batch.episode_returns) > 20 and list(learner.recent_returns) == batch.episode_returns[-20:]
        rows = [learner.step(), learner.step()]
        rates = [group["lr"] for optimizer in (learner.optimizer, learner.value_optimizer) for group in optimizer.param_groups]
    finally:
        learner.close()
    assert [row["learning_rate"] for row in rows] == [0.02, 0.02] and rates == [0.02, 0.03]


class DictObservationEnv(gym.Env):
    """A position and a velocity as two Dict leaves: observations policy gradient does not take."""

    observation_space = gym.spaces.Dict(
        {"position": gym.spaces.Box(-1.0, 1.0, (1,), np.float32), "velocity": gym.spaces.Box(-1.0, 1.0, (1,), np.float32)}
    )
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return {"position": np.zeros(1, np.float32), "velocity": np.zeros(1, np.float32)}, {}

    def step(self, action):
        return self.reset()[0], 0.0, True, False, {}


def test_dict_observations_are_refused_in_one_line_naming_policy_gradient() -> None:
    gym.register(id="imitation-tests/DictObservation-v0", entry_point=DictObservationEnv)
    try:
        with pytest.raises(ImitationError, match=r"^policy gradient takes Box or Discrete observations, not "):
            PolicyGradient(PGConfig(env_id="imitation-tests/DictObservation-v0", batch_steps=10, total_steps=10))
    finally:
        gym.registry.pop("imitation-tests/DictObservation-v0")


def test_a_checkpoint_before_the_first_rollout_holds_no_episode_and_resumes_as_the_fresh_run() -> None:
    """Rollouts carry episodes across batches, but before the first one there is none in progress:
    nothing to replay, and the resumed learner resets its copies as the fresh run does."""
    config = PGConfig(
        env_id="Pendulum-v1", estimator="actor-critic", n_envs=2, rollout_steps=20, total_steps=80, hidden_sizes=[8]
    )
    fresh = PolicyGradient(config)
    try:
        expected = fresh.collect()
    finally:
        fresh.close()
    first, resumed = PolicyGradient(config), PolicyGradient(config)
    try:
        tensors, state = snapshot(*first.state_dict())
        assert state["episodes_in_progress"] is None and not any(name.startswith("episode_actions") for name in tensors)
        resumed.load_state_dict((tensors, state))
        batch = resumed.collect()
    finally:
        first.close()
        resumed.close()
    assert torch.equal(batch.features, expected.features) and torch.equal(batch.rewards, expected.rewards)


def test_a_critic_off_constant_targets_explains_less_than_nothing() -> None:
    """At γ = 0 every CartPole-v1 target is its reward, 1: the targets' variance is 0, and the
    explained variance 1 − Var(G − V) / (Var(G) + 1e-8) of an untrained critic is far below 0."""
    config = PGConfig(
        env_id="CartPole-v1", estimator="baseline", gamma=0.0, n_envs=1, batch_steps=20, total_steps=100, hidden_sizes=[8]
    )
    learner = PolicyGradient(config)
    try:
        row = learner.step()
    finally:
        learner.close()
    assert row["explained_variance"] < -1.0


class ScriptedEnv(gym.Env):
    """Two state numbers, the step count twice; reward 1; episodes of `length` steps that end with
    the flags given. `fault` puts a non-finite value in the reset state, or in the reward (a float,
    or a Decimal, a number float() reads) or the next state of step `at`."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def __init__(self, length: int = 10, ends: tuple[bool, bool] = (True, False), fault: str = "", at: int = 0) -> None:
        self.length, self.ends, self.fault, self.at = length, ends, fault, at

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.array([np.nan if self.fault == "reset" else 0.0, 0.0], np.float32), {}

    def step(self, action):
        self.t += 1
        observation, reward = np.full(2, float(self.t), np.float32), 1.0
        if self.t == self.at and self.fault == "reward":
            reward = float("nan")
        if self.t == self.at and self.fault == "decimal-reward":
            reward = Decimal("NaN")
        if self.t == self.at and self.fault == "observation":
            observation[1] = np.inf
        over = self.t >= self.length
        return observation, reward, over and self.ends[0], over and self.ends[1], {}


@pytest.fixture(scope="module")
def scripted_envs():
    ids = {
        "imitation-tests/EndsBothWays-v0": {"length": 2, "ends": (True, True)},
        "imitation-tests/ThreeSteps-v0": {"length": 3},
        "imitation-tests/NaNReward-v0": {"fault": "reward", "at": 3},
        "imitation-tests/NaNDecimalReward-v0": {"fault": "decimal-reward", "at": 3},
        "imitation-tests/TruncatedAtThree-v0": {"length": 3, "ends": (False, True)},
        "imitation-tests/InfFinalState-v0": {"length": 3, "ends": (False, True), "fault": "observation", "at": 3},
        "imitation-tests/InfObservation-v0": {"fault": "observation", "at": 2},
        "imitation-tests/NaNReset-v0": {"fault": "reset"},
    }
    for env_id, kwargs in ids.items():
        gym.register(id=env_id, entry_point=ScriptedEnv, kwargs=kwargs)
    yield
    for env_id in ids:
        gym.registry.pop(env_id)


def test_a_step_that_terminates_and_is_truncated_at_once_counts_as_terminated(scripted_envs) -> None:
    """No bootstrap after a termination, whatever the time limit says: no final state kept, and
    TD(0)'s advantage of the last step is its reward minus V(s)."""
    config = PGConfig(
        env_id="imitation-tests/EndsBothWays-v0", estimator="actor-critic", gae_lambda=0.0, n_envs=1, batch_steps=6,
        total_steps=60,
    )
    learner = PolicyGradient(config)
    try:
        batch = learner.collect()
        weights, _, values = learner.weights(batch)
    finally:
        learner.close()
    assert batch.terminated.tolist() == [False, True] * 3 and not batch.truncated.any()
    assert not batch.final_features.any()
    torch.testing.assert_close(weights[1::2], 1.0 - values[1::2])


def test_every_copy_steps_in_each_round_until_the_batch_is_full(scripted_envs) -> None:
    """Two copies of 3-step episodes and a 4-step batch: both copies step side by side, so the
    batch is full at their first episodes' ends (6 steps, one episode each), and neither starts
    another."""
    config = PGConfig(
        env_id="imitation-tests/ThreeSteps-v0", estimator="reward-to-go", n_envs=2, batch_steps=4, total_steps=40
    )
    learner = PolicyGradient(config)
    try:
        batch = learner.collect()
    finally:
        learner.close()
    assert batch.episode_returns == [3.0, 3.0] and batch.terminated.tolist() == [False, False, True] * 2
    assert learner.episodes == 2 and learner.global_step == 6


@pytest.mark.filterwarnings("ignore:.*is not within the observation space")
@pytest.mark.parametrize(
    ("env_id", "what", "step"),
    [
        ("imitation-tests/NaNReward-v0", "reward", 3),
        ("imitation-tests/NaNDecimalReward-v0", "reward", 3),
        ("imitation-tests/InfObservation-v0", "observation", 2),
        # The true final state of a truncated episode: V's bootstrap would read it.
        ("imitation-tests/InfFinalState-v0", "observation", 3),
        ("imitation-tests/NaNReset-v0", "observation", 0),
    ],
)
def test_a_non_finite_value_from_the_env_stops_the_batch_naming_the_env_step(
    scripted_envs, env_id: str, what: str, step: int
) -> None:
    learner = PolicyGradient(PGConfig(env_id=env_id, n_envs=1, batch_steps=20, total_steps=100))
    try:
        with pytest.raises(ImitationError) as error:
            learner.collect()
    finally:
        learner.close()
    assert str(error.value) == (
        f"{env_id}: the environment returned a non-finite {what} at env step {step}; "
        "policy gradient needs finite observations and rewards"
    )


def test_the_policy_loss_divides_the_weights_by_their_std_unless_told_not_to_or_given_one() -> None:
    """−Σ log π(a|s) w / m on two hand-made steps of one piece, w = (1, 3) divided by its std √2,
    or taken as it is; equal weights (std 0) are divided by 1e-8; a single weight has no std and is
    taken as it is."""
    learner = learner_with_critic_s0(normalize_advantages=True)
    raw = learner_with_critic_s0(normalize_advantages=False)
    try:
        batch = hand_batch()
        two = Batch(batch.features[:2], batch.actions[:2], batch.rewards[:2], batch.terminated[:2], batch.truncated[:2],
                    batch.final_features[:2], [], 1)
        one = Batch(batch.features[:1], batch.actions[:1], batch.rewards[:1], batch.terminated[:1], batch.truncated[:1],
                    batch.final_features[:1], [], 1)
        with torch.no_grad():
            log_probs = learner.policy.log_prob(learner.policy.distribution(two.features), two.actions)

            def loss(model: PolicyGradient, chosen: Batch, weights: list[float]) -> float:
                return float(model.policy_loss(chosen, torch.tensor(weights))[0])

            surrogate = float(-(log_probs * torch.tensor([1.0, 3.0])).sum())
            assert loss(learner, two, [1.0, 3.0]) == pytest.approx(surrogate / math.sqrt(2))
            assert loss(raw, two, [1.0, 3.0]) == pytest.approx(surrogate)
            assert loss(learner, two, [2.0, 2.0]) == pytest.approx(float(-(log_probs * 2.0).sum()) / 1e-8)
            assert loss(learner, one, [2.0]) == pytest.approx(float(-(log_probs[0] * 2.0)))
    finally:
        learner.close()
        raw.close()


def test_a_truncated_episode_is_bootstrapped_from_its_true_final_state(scripted_envs) -> None:
    """Three steps cut by a time limit in the state (3, 3), a linear critic V(s) = s₀ and γ = ½:
    TD(0)'s advantages are 1 + ½·1 − 0, 1 + ½·2 − 1 and, from the kept final state, 1 + ½·3 − 2."""
    config = PGConfig(
        env_id="imitation-tests/TruncatedAtThree-v0", estimator="actor-critic", gae_lambda=0.0, gamma=0.5, n_envs=1,
        batch_steps=3, total_steps=30, hidden_sizes=[],
    )
    learner = PolicyGradient(config)
    try:
        with torch.no_grad():
            learner.policy.value_head.weight.copy_(torch.tensor([[1.0, 0.0]]))
            learner.policy.value_head.bias.zero_()
        batch = learner.collect()
        weights, _, _ = learner.weights(batch)
    finally:
        learner.close()
    assert batch.truncated.tolist() == [False, False, True] and not batch.terminated.any()
    assert batch.final_features.tolist() == [[0.0, 0.0], [0.0, 0.0], [3.0, 3.0]]
    assert weights.tolist() == pytest.approx([1.5, 1.0, 0.5])


def test_the_policy_is_built_with_the_configured_activation_normaliser_and_initial_std(scripted_envs) -> None:
    """ReLU hidden layers; states normalised by the batch's: one 3-step episode of ThreeSteps-v0
    acts from (0, 0), (1, 1), (2, 2), whose mean is 1 and variance ⅔ (the prior's count 1e-4
    aside); on Pendulum-v1, σ = e^−1.5 before any update."""
    config = PGConfig(
        env_id="imitation-tests/ThreeSteps-v0", estimator="reward-to-go", n_envs=1, batch_steps=3, total_steps=30,
        hidden_sizes=[16], activation="relu", normalize_observations=True,
    )
    learner = PolicyGradient(config)
    try:
        learner.collect()
        with torch.no_grad():
            encoded = learner.policy.encode(torch.tensor([[1.0, 1.0], [2.0, 2.0], [-1.0, 4.0]]))
            x = torch.randn(64, 2)
            trunk = learner.policy.actor_trunk
            hidden, relu = trunk(x), torch.relu(trunk[0](x))
    finally:
        learner.close()
    scale = math.sqrt(1.5)
    assert encoded.tolist() == [pytest.approx([0.0, 0.0], abs=1e-4), pytest.approx([scale, scale], rel=1e-4),
                                pytest.approx([-2 * scale, 3 * scale], rel=1e-4)]
    assert (relu == 0).any() and torch.equal(hidden, relu)
    pendulum = PolicyGradient(
        PGConfig(env_id="Pendulum-v1", n_envs=1, batch_steps=200, total_steps=200, hidden_sizes=[8], log_std_init=-1.5)
    )
    try:
        with torch.no_grad():
            distribution = pendulum.policy.distribution(torch.zeros(2, 3))
    finally:
        pendulum.close()
    assert distribution.stddev.flatten().tolist() == pytest.approx([math.exp(-1.5)] * 2)


@pytest.mark.parametrize(
    ("device", "message"),
    [
        ("tpu", "device 'tpu': Expected one of"),
        pytest.param(
            "cuda", "device cuda: CUDA is not available on this machine",
            marks=pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA"),
        ),
    ],
)
def test_a_device_that_is_not_there_is_refused_naming_the_device(device: str, message: str) -> None:
    with pytest.raises(ConfigError) as error:
        PolicyGradient(PGConfig(env_id="CartPole-v1", device=device))
    assert str(error.value).startswith(message) and error.value.field == "device"

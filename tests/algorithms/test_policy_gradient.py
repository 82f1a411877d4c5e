"""Policy gradient (imitation.algorithms.policy_gradient) against the maths:

- the score ∇_θ log π of the softmax and Gaussian policies against their closed forms on linear
  features;
- each estimator's expected gradient on a two-state MDP, by enumerating its trajectories, against
  ∇J(θ) computed in closed form;
- the baseline's unbiasedness, exactly and as a statistical test on sampled episodes (tolerance:
  4 standard errors), and its lower variance;
- the n-step targets, reward-to-go and trajectory returns against values worked by hand, GAE at
  λ = 0 and λ = 1 against TD(0) and reward-to-go minus V, truncation included;
- resume equals an uninterrupted run; a short CartPole run learns.
"""

from __future__ import annotations

import math
from contextlib import closing

import gymnasium as gym
import numpy as np
import pytest
import torch

from imitation.algorithms.policy_gradient import (
    PGConfig,
    PolicyGradient,
    n_step_targets,
    policy_gradient_weights,
    reward_to_go,
    running_returns,
    surrogate_loss,
    trajectory_returns,
)
from imitation.algorithms.advantages import compute_gae
from imitation.checkpoints import snapshot
from imitation.envs.make import make_env
from imitation.errors import ConfigError, ImitationError
from imitation.evaluation.policy import evaluate_policy
from imitation.policies import SingleObservationPolicy, make_policy

# ------------------------------------------------------------------------------------------------
# Score functions on linear features


def test_softmax_score_is_features_minus_their_expectation() -> None:
    """Logits W s + b: φ(s, a) = e_a ⊗ [s, 1], so ∇_W log π(a|s) = (e_a − π(·|s)) sᵀ and ∇_b = e_a − π(·|s)."""
    torch.manual_seed(0)
    space = gym.spaces.Box(-5, 5, (3,), np.float32)
    policy = make_policy(space, gym.spaces.Discrete(4), hidden_sizes=[])
    with torch.no_grad():
        policy.action_head.weight.normal_()
        policy.action_head.bias.normal_()
    for _ in range(5):
        state, action = torch.randn(1, 3), torch.randint(0, 4, (1,))
        log_prob = policy.log_prob(policy.distribution(policy.encode(state)), action)
        grad_w, grad_b = torch.autograd.grad(log_prob.sum(), [policy.action_head.weight, policy.action_head.bias])
        probabilities = torch.softmax(policy.action_head.weight @ state[0] + policy.action_head.bias, -1).detach()
        expected_b = torch.nn.functional.one_hot(action[0], 4).float() - probabilities
        assert torch.allclose(grad_b, expected_b, atol=1e-6)
        assert torch.allclose(grad_w, torch.outer(expected_b, state[0]), atol=1e-6)


def test_gaussian_score_is_the_scaled_error_times_the_features() -> None:
    """μ = W s + b, σ = exp(log σ): ∇_W log π(a|s) = (a − μ) sᵀ / σ², ∇_b = (a − μ) / σ², and
    ∇_{log σ} = (a − μ)² / σ² − 1."""
    torch.manual_seed(1)
    space = gym.spaces.Box(-5, 5, (3,), np.float32)
    policy = make_policy(space, gym.spaces.Box(-2, 2, (2,), np.float32), hidden_sizes=[], log_std_init=-0.3)
    with torch.no_grad():
        policy.action_head.weight.normal_()
    for _ in range(5):
        state, action = torch.randn(1, 3), torch.randn(1, 2)
        log_prob = policy.log_prob(policy.distribution(policy.encode(state)), action)
        grads = torch.autograd.grad(log_prob.sum(), [policy.action_head.weight, policy.action_head.bias, policy.log_std])
        mean = (policy.action_head.weight @ state[0] + policy.action_head.bias).detach()
        variance = torch.exp(2 * policy.log_std).detach()
        error = action[0] - mean
        assert torch.allclose(grads[0], torch.outer(error / variance, state[0]), atol=1e-5)
        assert torch.allclose(grads[1], error / variance, atol=1e-5)
        assert torch.allclose(grads[2], error**2 / variance - 1, atol=1e-5)


# ------------------------------------------------------------------------------------------------
# A two-state MDP whose gradient is known in closed form

R0, P_CONTINUE, R1 = (1.0, 0.0), (0.2, 0.9), (0.0, 2.0)


class TwoStateMDP(gym.Env):
    """s0: action a earns R0[a], then moves to s1 with probability P_CONTINUE[a], else the episode
    terminates; s1: action a earns R1[a] and the episode terminates. Observations are the state
    index (the policy's features are its one-hot)."""

    observation_space = gym.spaces.Discrete(2)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[int, dict]:
        super().reset(seed=seed)
        self.state = 0
        return 0, {}

    def step(self, action: int) -> tuple[int, float, bool, bool, dict]:
        if self.state == 0:
            if self.np_random.random() < P_CONTINUE[int(action)]:
                self.state = 1
                return 1, R0[int(action)], False, False, {}
            return 0, R0[int(action)], True, False, {}
        return 1, R1[int(action)], True, False, {}


TWO_STATE = "tests/TwoStateMDP-v0"
if TWO_STATE not in gym.registry:
    gym.register(TWO_STATE, entry_point=TwoStateMDP)


def tabular_policy(seed: int = 0):
    torch.manual_seed(seed)
    policy = make_policy(gym.spaces.Discrete(2), gym.spaces.Discrete(2), hidden_sizes=[])
    with torch.no_grad():
        policy.action_head.weight.copy_(torch.tensor([[0.3, -0.4], [-0.2, 0.5]]))
        policy.action_head.bias.copy_(torch.tensor([0.1, -0.1]))
    return policy


def action_probabilities(policy) -> torch.Tensor:
    """π(·|s) for s = 0, 1 (rows), differentiable in θ."""
    return torch.softmax(policy.action_head(policy.encode(torch.tensor([0, 1]))), -1)


def exact_gradient(policy, gamma: float) -> torch.Tensor:
    """∇J(θ) with J = Σ_a π(a|s0) (R0[a] + γ P[a] Σ_b π(b|s1) R1[b]), by autograd of the closed form."""
    pi = action_probabilities(policy)
    v1 = (pi[1] * torch.tensor(R1)).sum()
    j = (pi[0] * (torch.tensor(R0) + gamma * torch.tensor(P_CONTINUE) * v1)).sum()
    return flat(torch.autograd.grad(j, actor_parameters(policy)))


def exact_values(policy, gamma: float) -> torch.Tensor:
    with torch.no_grad():
        pi = action_probabilities(policy)
        v1 = (pi[1] * torch.tensor(R1)).sum()
        v0 = (pi[0] * (torch.tensor(R0) + gamma * torch.tensor(P_CONTINUE) * v1)).sum()
    return torch.stack([v0, v1])


def actor_parameters(policy) -> list[torch.Tensor]:
    return [policy.action_head.weight, policy.action_head.bias]


def flat(grads) -> torch.Tensor:
    return torch.cat([g.reshape(-1) for g in grads])


def trajectories() -> list[tuple[list[int], list[int], list[float]]]:
    """Every trajectory of the MDP: (states, actions, rewards)."""
    paths = []
    for a0 in (0, 1):
        paths.append(([0], [a0], [R0[a0]]))
        for a1 in (0, 1):
            paths.append(([0, 1], [a0, a1], [R0[a0], R1[a1]]))
    return paths


def trajectory_probability(policy, states: list[int], actions: list[int]) -> float:
    with torch.no_grad():
        pi = action_probabilities(policy)
    a0 = actions[0]
    if len(states) == 1:
        return float(pi[0, a0] * (1 - P_CONTINUE[a0]))
    return float(pi[0, a0] * P_CONTINUE[a0] * pi[1, actions[1]])


def estimate(
    policy, states, actions, rewards, estimator: str, *, values: torch.Tensor, gamma: float, **options
) -> torch.Tensor:
    """ĝ of one episode, through the module's weights and surrogate loss."""
    features = policy.encode(torch.tensor(states))
    value = values[torch.tensor(states)]
    next_value = torch.cat([value[1:], torch.zeros(1)])
    length = len(states)
    terminated = torch.zeros(length, dtype=torch.bool)
    terminated[-1] = True
    weights, _ = policy_gradient_weights(
        estimator, torch.tensor(rewards), value, next_value, terminated, torch.zeros_like(terminated), gamma=gamma, **options
    )
    log_probs = policy.log_prob(policy.distribution(features), torch.tensor(actions))
    return -flat(torch.autograd.grad(surrogate_loss(log_probs, weights, 1), actor_parameters(policy)))


def moments(policy, estimator: str, *, values: torch.Tensor, gamma: float, **options) -> tuple[torch.Tensor, torch.Tensor]:
    """E[ĝ] and E[|ĝ − E ĝ|²] over the enumerated trajectories."""
    probabilities, estimates = [], []
    for states, actions, rewards in trajectories():
        probabilities.append(trajectory_probability(policy, states, actions))
        estimates.append(estimate(policy, states, actions, rewards, estimator, values=values, gamma=gamma, **options))
    p, g = torch.tensor(probabilities), torch.stack(estimates)
    assert math.isclose(float(p.sum()), 1.0, abs_tol=1e-6)
    mean = (p[:, None] * g).sum(0)
    return mean, (p * ((g - mean) ** 2).sum(1)).sum()


@pytest.mark.parametrize(
    ("estimator", "options"),
    [
        ("return", {}),
        ("reward-to-go", {}),
        ("baseline", {}),
        ("actor-critic", {"n_step": 1}),
        ("actor-critic", {"n_step": 2}),
        ("actor-critic", {"gae_lambda": 0.0}),
        ("actor-critic", {"gae_lambda": 0.6}),
        ("actor-critic", {"gae_lambda": 1.0}),
    ],
)
def test_each_estimator_is_unbiased_on_the_two_state_mdp(estimator: str, options: dict) -> None:
    """With γ = 1 the reward-to-go needs no γ^t factor, so every estimator's expectation is ∇J
    exactly: the baseline for any b(s) (here a deliberately poor one), actor-critic with the
    true V^π (n-step and GAE targets are then unbiased)."""
    policy = tabular_policy()
    true_gradient = exact_gradient(policy, 1.0)
    values = exact_values(policy, 1.0) if estimator == "actor-critic" else torch.tensor([3.0, -2.0])
    mean, _ = moments(policy, estimator, values=values, gamma=1.0, **options)
    assert torch.allclose(mean, true_gradient, atol=1e-6), (mean, true_gradient)
    assert true_gradient.abs().max() > 0.05  # the comparison is not between zeros


def test_the_whole_return_estimator_is_the_gradient_of_the_discounted_objective() -> None:
    """R(τ) = Σ γ^t r_t weights every score of τ: E[ĝ] = ∇J_γ for γ < 1 too."""
    policy = tabular_policy(1)
    mean, _ = moments(policy, "return", values=torch.zeros(2), gamma=0.7)
    assert torch.allclose(mean, exact_gradient(policy, 0.7), atol=1e-6)


def test_actor_critic_with_a_wrong_critic_is_biased_and_monte_carlo_is_not() -> None:
    """The check above bites: TD(0) through a critic off by +1 at s1 misses ∇J; GAE(λ = 1),
    which is the reward-to-go minus V, does not depend on V(s1) in expectation."""
    policy = tabular_policy()
    true_gradient = exact_gradient(policy, 1.0)
    wrong = exact_values(policy, 1.0) + torch.tensor([0.0, 1.0])
    td, _ = moments(policy, "actor-critic", values=wrong, gamma=1.0, n_step=1)
    monte_carlo, _ = moments(policy, "actor-critic", values=wrong, gamma=1.0, gae_lambda=1.0)
    assert (td - true_gradient).abs().max() > 0.05
    assert torch.allclose(monte_carlo, true_gradient, atol=1e-6)


def test_the_baseline_lowers_the_variance_exactly() -> None:
    """Over the enumerated trajectories: E|ĝ − ∇J|² of REINFORCE with b = V^π is below the one
    without a baseline, and below the whole-return estimator's."""
    policy = tabular_policy()
    _, whole = moments(policy, "return", values=torch.zeros(2), gamma=1.0)
    _, to_go = moments(policy, "reward-to-go", values=torch.zeros(2), gamma=1.0)
    _, with_baseline = moments(policy, "baseline", values=exact_values(policy, 1.0), gamma=1.0)
    assert with_baseline < 0.5 * to_go and to_go <= whole + 1e-9, (whole, to_go, with_baseline)


def test_the_baseline_is_unbiased_and_lowers_the_variance_on_sampled_episodes() -> None:
    """Statistical test through the learner: one batch of ≈ 530 episodes of the two-state MDP,
    each giving ĝ with and without b(s) = V_φ(s) (the critic set to V^π + an error). The mean
    difference of the paired estimates is within 4 standard errors of 0 in every component, each
    mean within 4 standard errors of the exact ∇J, and the total variance with the baseline is lower."""
    config = PGConfig(
        env_id=TWO_STATE,
        estimator="baseline",
        total_steps=10_000,
        n_envs=8,
        batch_steps=800,
        gamma=1.0,
        hidden_sizes=[],
        normalize_advantages=False,
        seed=3,
    )
    learner = PolicyGradient(config)
    try:
        policy = learner.policy
        with torch.no_grad():
            policy.action_head.weight.copy_(tabular_policy().action_head.weight)
            policy.action_head.bias.copy_(tabular_policy().action_head.bias)
            policy.value_head.weight.copy_((exact_values(policy, 1.0) + torch.tensor([0.1, -0.1]))[None])
            policy.value_head.bias.zero_()
        batch = learner.collect()
        with_b, _, _ = learner.weights(batch)
        true_gradient = exact_gradient(policy, 1.0)
    finally:
        learner.close()
    without_b = reward_to_go(batch.rewards, torch.zeros_like(batch.rewards), batch.terminated, batch.truncated, gamma=1.0)
    # ∇ log π(a_t|s_t) of every step in the closed form checked above: (e_a − π(·|s)) ⊗ [φ(s), 1].
    with torch.no_grad():
        probabilities = torch.softmax(policy.action_head(batch.features), -1)
    error = torch.nn.functional.one_hot(batch.actions.long(), 2).float() - probabilities
    scores = torch.cat([(error[:, :, None] * batch.features[:, None, :]).reshape(len(error), -1), error], 1)
    ends = batch.terminated | batch.truncated
    episode = torch.cumsum(ends.long(), 0) - ends.long()  # each step's episode index
    n = batch.pieces
    assert n > 450
    plain_g = torch.zeros(n, scores.shape[1]).index_add_(0, episode, scores * without_b[:, None])
    baseline_g = torch.zeros(n, scores.shape[1]).index_add_(0, episode, scores * with_b[:, None])
    difference = baseline_g - plain_g
    assert (difference.mean(0).abs() <= 4 * difference.std(0) / math.sqrt(n) + 1e-9).all()
    for sample in (plain_g, baseline_g):
        assert ((sample.mean(0) - true_gradient).abs() <= 4 * sample.std(0) / math.sqrt(n) + 1e-9).all()
    assert baseline_g.var(0).sum() < 0.6 * plain_g.var(0).sum()


# ------------------------------------------------------------------------------------------------
# Targets worked by hand: episode A (s0, s1, s2) earns 1, 2, 3 and terminates; episode B (s3, s4)
# earns 4, 5 and is truncated, its true final state valued 10. V = 0.1 … 0.5, γ = 0.5.

REWARDS = torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0])
VALUES = torch.tensor([0.1, 0.2, 0.3, 0.4, 0.5])
NEXT_VALUES = torch.tensor([0.2, 0.3, 99.0, 0.5, 10.0])  # 99: after a termination, never read
TERMINATED = torch.tensor([False, False, True, False, False])
TRUNCATED = torch.tensor([False, False, False, False, True])


def test_reward_to_go_and_trajectory_returns_by_hand() -> None:
    # G4 = 5 + ½·10 = 10, G3 = 4 + ½·10 = 9; G2 = 3, G1 = 2 + ½·3 = 3.5, G0 = 1 + ½·3.5 = 2.75.
    assert torch.allclose(
        reward_to_go(REWARDS, NEXT_VALUES, TERMINATED, TRUNCATED, gamma=0.5), torch.tensor([2.75, 3.5, 3.0, 9.0, 10.0])
    )
    # R(τ_A) = 1 + ½·2 + ¼·3 = 2.75, R(τ_B) = 4 + ½·5 = 6.5 (no critic: the truncated tail counts 0).
    assert torch.allclose(
        trajectory_returns(REWARDS, TERMINATED, TRUNCATED, gamma=0.5), torch.tensor([2.75, 2.75, 2.75, 6.5, 6.5])
    )


def test_trajectory_returns_of_a_stream_that_stops_inside_an_episode() -> None:
    """An episode still running where the stream stops is summed as far as it goes: its first step
    starts it, whatever the stream's last step was."""
    rewards = torch.tensor([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])
    terminated = torch.tensor([[False, True], [False, False], [False, False]])
    returns = trajectory_returns(rewards, terminated, torch.zeros_like(terminated), gamma=0.5)
    # Column 0: one episode 1 + ½·2 + ¼·3; column 1: 1, then an episode 2 + ½·3 still running.
    assert returns.tolist() == [[2.75, 1.0], [2.75, 3.5], [2.75, 3.5]]


@pytest.mark.parametrize(
    ("n", "expected"),
    [
        # t0: 1 + ½·V(s1)=.2; t1: 2 + ½·.3; t2: 3 (terminal); t3: 4 + ½·.5; t4: 5 + ½·10.
        (1, [1.1, 2.15, 3.0, 4.25, 10.0]),
        # t0: 1 + ½·2 + ¼·V(s2)=.3; t1: 2 + ½·3 (terminal within 2); t3: 4 + ½·5 + ¼·10.
        (2, [2.075, 3.5, 3.0, 9.0, 10.0]),
        # n past every episode's end: the reward-to-go.
        (3, [2.75, 3.5, 3.0, 9.0, 10.0]),
        (7, [2.75, 3.5, 3.0, 9.0, 10.0]),
    ],
)
def test_n_step_targets_by_hand(n: int, expected: list[float]) -> None:
    targets = n_step_targets(REWARDS, NEXT_VALUES, TERMINATED, TRUNCATED, gamma=0.5, n=n)
    assert torch.allclose(targets, torch.tensor(expected)), targets


def test_n_step_targets_across_env_copies() -> None:
    """A (T, copies) stream is n independent columns."""
    stacked = [torch.stack([x, x.flip(0)], 1) for x in (REWARDS, NEXT_VALUES)]
    flags = [torch.stack([x, x], 1) for x in (TERMINATED, TRUNCATED)]
    targets = n_step_targets(stacked[0], stacked[1], *flags, gamma=0.5, n=2)
    assert torch.allclose(targets[:, 0], torch.tensor([2.075, 3.5, 3.0, 9.0, 10.0]))
    assert torch.allclose(
        targets[:, 1], n_step_targets(REWARDS.flip(0), NEXT_VALUES.flip(0), TERMINATED, TRUNCATED, gamma=0.5, n=2)
    )


def _gae(gae_lambda: float) -> torch.Tensor:
    advantages, _ = compute_gae(
        REWARDS[:, None],
        VALUES[:, None],
        NEXT_VALUES[:, None],
        TERMINATED[:, None],
        TRUNCATED[:, None],
        gamma=0.5,
        gae_lambda=gae_lambda,
    )
    return advantages[:, 0]


def test_gae_at_zero_is_td0_and_at_one_the_reward_to_go_minus_v() -> None:
    td0 = n_step_targets(REWARDS, NEXT_VALUES, TERMINATED, TRUNCATED, gamma=0.5, n=1) - VALUES
    assert torch.allclose(_gae(0.0), td0)
    monte_carlo = reward_to_go(REWARDS, NEXT_VALUES, TERMINATED, TRUNCATED, gamma=0.5) - VALUES
    assert torch.allclose(_gae(1.0), monte_carlo)
    weights, targets = policy_gradient_weights(
        "actor-critic", REWARDS, VALUES, NEXT_VALUES, TERMINATED, TRUNCATED, gamma=0.5, gae_lambda=1.0
    )
    assert torch.allclose(weights, monte_carlo) and torch.allclose(targets, monte_carlo + VALUES)
    # λ = 1 is the default: without n, actor-critic's advantage is then the Monte Carlo one.
    weights, _ = policy_gradient_weights("actor-critic", REWARDS, VALUES, NEXT_VALUES, TERMINATED, TRUNCATED, gamma=0.5)
    assert torch.allclose(weights, monte_carlo)


def test_the_estimators_weights_and_critic_targets() -> None:
    args = (REWARDS, VALUES, NEXT_VALUES, TERMINATED, TRUNCATED)
    rtg = torch.tensor([2.75, 3.5, 3.0, 9.0, 10.0])
    weights, targets = policy_gradient_weights("baseline", *args, gamma=0.5)
    assert torch.allclose(weights, rtg - VALUES) and torch.allclose(targets, rtg)
    weights, _ = policy_gradient_weights("reward-to-go", *args, gamma=0.5)
    # Without a critic nothing bootstraps the truncated episode: G4 = 5, G3 = 4 + ½·5.
    assert torch.allclose(weights, torch.tensor([2.75, 3.5, 3.0, 6.5, 5.0]))
    weights, targets = policy_gradient_weights("actor-critic", *args, gamma=0.5, n_step=2)
    assert torch.allclose(targets, torch.tensor([2.075, 3.5, 3.0, 9.0, 10.0])) and torch.allclose(weights, targets - VALUES)


def test_surrogate_loss_averages_over_episodes() -> None:
    log_probs = torch.tensor([-1.0, -2.0, -0.5], requires_grad=True)
    loss = surrogate_loss(log_probs, torch.tensor([2.0, 1.0, 4.0]), 2)
    assert loss.item() == pytest.approx(-(-2.0 - 2.0 - 2.0) / 2)
    (grad,) = torch.autograd.grad(loss, log_probs)
    assert torch.allclose(grad, torch.tensor([-1.0, -0.5, -2.0]))


# ------------------------------------------------------------------------------------------------
# The learner


def test_config_errors_name_the_field() -> None:
    with pytest.raises(ConfigError, match="estimator must be one of"):
        PGConfig(env_id="CartPole-v1", estimator="q").validate()
    with pytest.raises(ConfigError, match="n_step is for the actor-critic estimator, not baseline"):
        PGConfig(env_id="CartPole-v1", n_step=3).validate()
    with pytest.raises(ConfigError, match="n_step must be at least 1, got 0"):
        PGConfig(env_id="CartPole-v1", estimator="actor-critic", n_step=0).validate()
    with pytest.raises(ConfigError, match=r"total_steps 10 is less than one batch \(2000 steps\)"):
        PGConfig(env_id="CartPole-v1", total_steps=10).validate()
    with pytest.raises(ConfigError, match=r"gae_lambda must lie in \[0, 1\], got 1.5"):
        PGConfig(env_id="CartPole-v1", gae_lambda=1.5).validate()
    with pytest.raises(ConfigError, match="rollout_steps is for the actor-critic estimator, not baseline"):
        PGConfig(env_id="CartPole-v1", rollout_steps=8).validate()
    with pytest.raises(ConfigError, match=r"total_steps 100 is less than one batch \(128 steps\)"):
        PGConfig(env_id="CartPole-v1", estimator="actor-critic", total_steps=100, n_envs=4, rollout_steps=32).validate()


def test_a_rollout_cuts_running_episodes_and_carries_them_over() -> None:
    """Pendulum's 200-step episodes in rollouts of 30 steps: every piece but the ones a time limit
    ends is cut, marked truncated with the state it reached as its final state, and the next
    rollout carries on from that very state."""
    config = PGConfig(
        env_id="Pendulum-v1", estimator="actor-critic", n_envs=2, rollout_steps=30, total_steps=600, hidden_sizes=[8]
    )
    learner = PolicyGradient(config)
    try:
        first = learner.collect()
        reached = [np.array(observation) for observation in learner.observations]
        second = learner.collect()
        later = [learner.collect() for _ in range(5)]
        seventh = later[-1]
    finally:
        learner.close()
    assert learner.global_step == 7 * 60
    # Each copy's first episode, 200 steps over seven rollouts: its return sums the pieces of it in
    # each (copy 0's first in every batch; the seventh holds both episodes' last 20 steps first).
    pieces = [batch.rewards for batch in (first, second, *later[:-1])]
    for copy in range(2):
        expected = sum(float(rewards[30 * copy : 30 * copy + 30].sum()) for rewards in pieces)
        expected += float(seventh.rewards[20 * copy : 20 * copy + 20].sum())
        assert seventh.episode_returns[copy] == pytest.approx(expected, rel=1e-5)
    assert len(first.rewards) == len(second.rewards) == 60 == first.pieces * 30
    assert first.truncated.tolist() == [False] * 29 + [True] + [False] * 29 + [True]
    assert first.episode_returns == [] and len(seventh.episode_returns) == 2  # steps 180–210 end both episodes
    assert seventh.pieces == 4 and int((seventh.truncated | seventh.terminated).sum()) == 4
    for copy, state in enumerate(reached):
        assert torch.allclose(first.final_features[30 * copy + 29], torch.as_tensor(state))
        assert torch.allclose(second.features[30 * copy], torch.as_tensor(state))


def test_a_batch_holds_complete_episodes_and_counts_its_steps() -> None:
    config = PGConfig(env_id="CartPole-v1", total_steps=1000, n_envs=3, batch_steps=100, hidden_sizes=[8])
    learner = PolicyGradient(config)
    try:
        batch = learner.collect()
    finally:
        learner.close()
    ends = batch.terminated | batch.truncated
    assert bool(ends[-1]) and int(ends.sum()) == batch.pieces == len(batch.episode_returns) == learner.episodes
    assert len(batch.rewards) == learner.global_step >= 100
    assert sum(batch.episode_returns) == pytest.approx(float(batch.rewards.sum()))


@pytest.mark.parametrize(
    ("env_id", "estimator", "options"),
    [
        ("CartPole-v1", "reward-to-go", {}),
        ("Pendulum-v1", "actor-critic", {"n_step": 5, "n_envs": 1, "normalize_observations": True, "normalize_rewards": True}),
        # Checkpoints between rollouts fall inside episodes: the resumed run replays them.
        ("Pendulum-v1", "actor-critic", {"rollout_steps": 70, "normalize_observations": True}),
        ("CartPole-v1", "actor-critic", {"rollout_steps": 40, "n_step": 3}),
    ],
)
def test_resume_equals_an_uninterrupted_run(env_id: str, estimator: str, options: dict) -> None:
    settings = {"n_envs": 2, "total_steps": 600, "batch_steps": 150, "hidden_sizes": [8]} | options
    config = PGConfig(env_id=env_id, estimator=estimator, **settings)

    def rows(learner: PolicyGradient, count: int | None = None) -> list[dict[str, float]]:
        taken = []
        while not learner.done and (count is None or len(taken) < count):
            taken.append({k: v for k, v in learner.step().items() if not k.startswith(("seconds", "steps_per"))})
        return taken

    uninterrupted = PolicyGradient(config)
    try:
        expected = rows(uninterrupted)
        expected_parameters = snapshot(*uninterrupted.state_dict())[0]
    finally:
        uninterrupted.close()
    first = PolicyGradient(config)
    try:
        before = rows(first, 2)
        checkpoint = snapshot(*first.state_dict())
        torch.manual_seed(123)  # the checkpoint must restore the generators, not rely on them
    finally:
        first.close()
    resumed = PolicyGradient(config)
    try:
        resumed.load_state_dict(checkpoint)
        after = rows(resumed)
        parameters = snapshot(*resumed.state_dict())[0]
    finally:
        resumed.close()
    assert len(expected) >= 3
    assert repr(before + after) == repr(expected)  # exactly, NaN fields included
    for name, tensor in expected_parameters.items():
        if name.startswith("policy."):
            assert torch.equal(parameters[name], tensor), name


def test_a_short_cartpole_run_learns() -> None:
    """REINFORCE with a baseline on a linear softmax policy, 10k steps: the deterministic policy
    balances far longer than before training (measured: 180 at seed 0, 135 and 176 at seeds 1, 2)."""
    config = PGConfig(
        env_id="CartPole-v1",
        estimator="baseline",
        total_steps=10_000,
        n_envs=4,
        batch_steps=500,
        hidden_sizes=[],
        learning_rate=0.1,
        value_learning_rate=0.05,
    )
    learner = PolicyGradient(config)
    try:
        with closing(make_env("CartPole-v1")) as env:
            before = evaluate_policy(SingleObservationPolicy(learner.policy), env, episodes=5, seed=10_000)
            while not learner.done:
                learner.step()
            after = evaluate_policy(SingleObservationPolicy(learner.policy), env, episodes=5, seed=10_000)
    finally:
        learner.close()
    assert after["mean_return"] >= max(100.0, 4 * before["mean_return"]), (before, after)


def test_running_returns_restart_with_each_episode() -> None:
    # A: 1, 2 + ½·1 = 2.5, 3 + ½·2.5 = 4.25; B: 4, 5 + ½·4 = 7.
    assert torch.allclose(
        running_returns(REWARDS, TERMINATED | TRUNCATED, gamma=0.5).float(), torch.tensor([1.0, 2.5, 4.25, 4.0, 7.0])
    )


def test_a_diverged_loss_stops_training_naming_the_batch(monkeypatch) -> None:
    config = PGConfig(env_id="CartPole-v1", total_steps=400, n_envs=1, batch_steps=100, hidden_sizes=[8])
    learner = PolicyGradient(config)
    try:
        weights = learner.weights
        monkeypatch.setattr(
            learner, "weights", lambda batch: (torch.full_like(weights(batch)[0], float("nan")), *weights(batch)[1:])
        )
        with pytest.raises(ImitationError, match=r"^policy gradient batch 1: the loss is nan \(diverged; try a lower --lr\)$"):
            learner.step()
    finally:
        learner.close()

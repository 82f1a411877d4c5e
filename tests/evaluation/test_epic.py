"""EPIC reward distance: its invariances, values worked by hand, the sampled estimator against the
exact one and against a continuous case solved analytically, the coverage batch."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import imitation.evaluation.epic as epic_module
from imitation.data.types import Transitions
from imitation.envs.tabular import random_mdp
from imitation.errors import ImitationError
from imitation.evaluation.epic import (
    EpicResult, TransitionBatch, canonicalize_sampled, canonicalize_tabular, coverage_samples, epic_distance_sampled,
    epic_distance_tabular, pearson_distance, tabulate, torch_reward, uniform_space_samples,
)
from imitation.rewards import all_state_rewards, make_reward_model

S, A = 6, 3


def _random_reward(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(S, A, S))


def _shaped(reward: np.ndarray, potential: np.ndarray, discount: float) -> np.ndarray:
    """R(s, a, s') + γΦ(s') − Φ(s)."""
    return reward + discount * potential[None, None, :] - potential[:, None, None]


def _uniform_batch(n: int, seed: int) -> TransitionBatch:
    """n transitions with s, a, s' independently uniform on [-1, 1] (1-D each)."""
    s, a, t = np.random.default_rng(seed).uniform(-1, 1, size=(3, n, 1))
    return TransitionBatch(s, a, t)


# ------------------------------------------------------------------------------------------------
# Tabular


def test_identical_rewards_are_at_distance_zero() -> None:
    reward = _random_reward()
    result = epic_distance_tabular(reward, reward.copy(), S, A, discount=0.9)
    assert result.epic == pytest.approx(0.0, abs=1e-7) and result.pearson == pytest.approx(1.0)


@pytest.mark.parametrize("discount", [0.0, 0.5, 0.99, 1.0])
def test_tabular_is_invariant_to_scale_and_potential_shaping(discount: float) -> None:
    reward = _random_reward(1)
    potential = 5 * np.random.default_rng(2).normal(size=S)
    other = _shaped(3.7 * reward, potential, discount)
    result = epic_distance_tabular(reward, other, S, A, discount=discount)
    assert result.epic <= 1e-6
    # The shaping changed the raw rewards a lot: canonicalisation, not the Pearson distance, removed it.
    assert result.pearson < 0.6


def test_tabular_invariance_holds_for_any_canonicalisation_and_coverage_distributions() -> None:
    rng = np.random.default_rng(3)
    reward = _random_reward(4)
    other = _shaped(0.2 * reward, rng.normal(size=S), 0.9)
    result = epic_distance_tabular(
        reward, other, S, A, discount=0.9, state_dist=rng.random(S), action_dist=rng.random(A), transition_dist=rng.random((S, A, S))
    )
    assert result.epic <= 1e-6


def test_shaping_with_another_discount_is_a_different_reward() -> None:
    """Φ(s') − Φ(s) is not a potential shaping when γ = 0.5: EPIC must see it."""
    reward = _random_reward(5)
    potential = 5 * np.random.default_rng(6).normal(size=S)
    assert epic_distance_tabular(reward, _shaped(reward, potential, 1.0), S, A, discount=0.5).epic > 0.1


def test_negated_reward_is_at_distance_one() -> None:
    reward = _random_reward(7)
    result = epic_distance_tabular(reward, -reward, S, A, discount=0.9)
    assert result.epic == pytest.approx(1.0, abs=1e-9) and result.pearson == pytest.approx(-1.0)


# Two states, one action, γ = 0.5, D_S, D_A and the coverage uniform; rewards as R[s, s'].
#   R_goal   = [[0, 1], [0, 1]]  (1 for reaching state 1)
#   R_in     = [[0, 0], [1, 1]]  (1 for being in state 1)
#   R_single = [[0, 1], [0, 0]]  (1 only for the move 0 → 1)
# C(R)(s, s') = R(s, s') + γm(s') − m(s) − γc, m(x) = mean_{s'} R(x, s'), c = mean_x m(x):
#   R_goal:   m = (½, ½), c = ½:  C = R − ½ = [[−½, ½], [−½, ½]]
#   R_in:     m = (0, 1), c = ½:  C = [s = 1] + ½s' − s − ¼ = [[−¼, ¼], [−¼, ¼]] = ½ C(R_goal)
#   R_single: m = (½, 0), c = ¼:  C = R + ½m(s') − m(s) − ⅛ = [[−⅜, ⅜], [⅛, −⅛]]
# EPIC(R_goal, R_in) = 0 (C proportional) though the raw rewards are uncorrelated: ρ = 0.
# EPIC(R_goal, R_single): both C have mean 0; cov = (3/16 + 3/16 − 1/16 − 1/16)/4 = 1/16,
#   var C_goal = 1/4, var C_single = (9/64·2 + 1/64·2)/4 = 5/64, ρ = (1/16)/√(5/256) = 1/√5,
#   EPIC = √((1 − 1/√5)/2) ≈ 0.5257. Raw: means ½ and ¼, cov = ¼ − ⅛ = ⅛, vars ¼ and 3/16,
#   ρ = (1/8)/√(3/64) = 1/√3.
# With D_S = (¾, ¼) instead, R_single has m = (¼, 0), c = ¾·¼ = 3/16:
#   C = R + ½m(s') − m(s) − 3/32 = [[4 − 8 − 3, 32 − 8 − 3], [4 − 3, −3]] / 32.
# And a reward r(a) = a on two actions with D_A = (¾, ¼): m(x) = c = ¼, so C = r(a) − ¼
#   (r(a) − ½ under the uniform D_A).
R_GOAL = np.array([[0.0, 1.0], [0.0, 1.0]])[:, None, :]
R_IN = np.array([0.0, 1.0])
R_SINGLE = np.array([[0.0, 1.0], [0.0, 0.0]])[:, None, :]
C_GOAL = np.array([[-0.5, 0.5], [-0.5, 0.5]])[:, None, :]
C_SINGLE = np.array([[-0.375, 0.375], [0.125, -0.125]])[:, None, :]
C_SINGLE_SKEWED = np.array([[-7, 21], [1, -3]])[:, None, :] / 32


def test_two_state_example_worked_by_hand() -> None:
    assert np.allclose(canonicalize_tabular(R_GOAL, 0.5), C_GOAL)
    assert np.allclose(canonicalize_tabular(np.broadcast_to(R_IN[:, None, None], (2, 1, 2)), 0.5), 0.5 * C_GOAL)
    assert np.allclose(canonicalize_tabular(R_SINGLE, 0.5), C_SINGLE)
    assert np.allclose(canonicalize_tabular(R_SINGLE, 0.5, state_dist=np.array([0.75, 0.25])), C_SINGLE_SKEWED)
    on_action = np.broadcast_to(np.array([0.0, 1.0])[None, :, None], (2, 2, 2))
    assert np.allclose(canonicalize_tabular(on_action, 0.5, action_dist=np.array([3.0, 1.0])), on_action - 0.25)

    goal_vs_in = epic_distance_tabular(R_GOAL, R_IN, 2, 1, discount=0.5)
    assert goal_vs_in.epic == pytest.approx(0.0, abs=1e-7) and goal_vs_in.pearson == pytest.approx(0.0, abs=1e-12)
    goal_vs_single = epic_distance_tabular(R_GOAL, R_SINGLE, 2, 1, discount=0.5)
    assert goal_vs_single.epic == pytest.approx(np.sqrt((1 - 1 / np.sqrt(5)) / 2), abs=1e-12)
    assert goal_vs_single.pearson == pytest.approx(1 / np.sqrt(3), abs=1e-12)


def test_pearson_distance_values() -> None:
    assert pearson_distance(1.0) == 0.0 and pearson_distance(-1.0) == 1.0 and pearson_distance(0.0) == pytest.approx(np.sqrt(0.5))
    # Round-off past either end of [-1, 1] is clipped: the distance stays within [0, 1].
    assert pearson_distance(1.0 + 1e-12) == 0.0 and pearson_distance(-1.0 - 1e-12) == 1.0


def test_coverage_weights_count_like_repeated_transitions() -> None:
    """Integer weights on the transitions give the Pearson distance of the list in which each
    transition appears that many times."""
    reward, other = _random_reward(8), _random_reward(9)
    counts = np.random.default_rng(10).integers(0, 4, size=(S, A, S))
    result = epic_distance_tabular(reward, other, S, A, discount=0.9, transition_dist=counts)
    repeat = counts.reshape(-1)
    canonical = [np.repeat(canonicalize_tabular(r, 0.9).reshape(-1), repeat) for r in (reward, other)]
    assert result.epic == pytest.approx(pearson_distance(np.corrcoef(*canonical)[0, 1]), abs=1e-12)
    assert result.pearson == pytest.approx(np.corrcoef(np.repeat(reward.reshape(-1), repeat), np.repeat(other.reshape(-1), repeat))[0, 1], abs=1e-12)
    assert abs(result.epic - epic_distance_tabular(reward, other, S, A, discount=0.9).epic) > 1e-3, "the weights must matter"


def test_state_and_state_action_rewards_broadcast_over_the_missing_axes() -> None:
    rng = np.random.default_rng(11)
    state_reward, state_action_reward, other = rng.normal(size=S), rng.normal(size=(S, A)), _random_reward(12)
    full_state = np.broadcast_to(state_reward[:, None, None], (S, A, S))
    full_state_action = np.broadcast_to(state_action_reward[:, :, None], (S, A, S))
    assert epic_distance_tabular(state_reward, other, S, A, 0.9) == epic_distance_tabular(full_state, other, S, A, 0.9)
    assert epic_distance_tabular(state_action_reward, other, S, A, 0.9) == epic_distance_tabular(full_state_action, other, S, A, 0.9)
    with pytest.raises(ImitationError, match=r"shape \(S,\), \(S, A\) or \(S, A, S'\)"):
        epic_distance_tabular(np.zeros(S + 1), other, S, A, 0.9)
    with pytest.raises(ImitationError, match="shape"):
        epic_distance_tabular(np.zeros((A, S)), other, S, A, 0.9)


def test_rewards_without_preferences() -> None:
    """A constant or a pure shaping prefers nothing: uncorrelated with a reward that does
    prefer something (√½), equivalent to another such reward (0)."""
    reward = _random_reward(13)
    potential = np.random.default_rng(14).normal(size=S)
    constant, shaping = np.full(S, 2.5), _shaped(np.zeros((S, A, S)), potential, 0.9)
    assert epic_distance_tabular(constant, reward, S, A, 0.9).epic == pytest.approx(np.sqrt(0.5))
    assert epic_distance_tabular(shaping, reward, S, A, 0.9).epic == pytest.approx(np.sqrt(0.5))
    assert epic_distance_tabular(constant, shaping, S, A, 0.9).epic == pytest.approx(0.0)
    assert epic_distance_tabular(constant, 3 * constant, S, A, 0.9).pearson == pytest.approx(1.0)


def test_bad_tabular_inputs_are_one_line_errors() -> None:
    reward = _random_reward()
    with pytest.raises(ImitationError, match="discount must be in"):
        epic_distance_tabular(reward, reward, S, A, discount=1.5)
    with pytest.raises(ImitationError, match="state_dist must be non-negative"):
        epic_distance_tabular(reward, reward, S, A, 0.9, state_dist=-np.ones(S))
    with pytest.raises(ImitationError, match=r"transition_dist must have shape \(6, 3, 6\)"):
        epic_distance_tabular(reward, reward, S, A, 0.9, transition_dist=np.ones((S, A)))


def test_reward_networks_enter_as_tables() -> None:
    """A state-feature reward network gives the same table as all_state_rewards; a network on
    (s, a, s') is tabulated transition by transition."""
    mdp = random_mdp(seed=0, n_states=S, n_actions=A)
    torch.manual_seed(0)
    on_states = make_reward_model(gym.spaces.Discrete(S), gym.spaces.Discrete(A), feature_table=mdp.features, hidden_sizes=[8])
    per_state = all_state_rewards(on_states, S).detach().numpy()
    assert np.allclose(tabulate(torch_reward(on_states), S, A), per_state[:, None, None], atol=1e-6)
    on_transitions = make_reward_model(gym.spaces.Discrete(S), gym.spaces.Discrete(A), inputs="sas", hidden_sizes=[8])
    table = tabulate(torch_reward(on_transitions), S, A)
    with torch.no_grad():
        assert table[4, 2, 1] == pytest.approx(on_transitions(torch.tensor([4]), torch.tensor([2]), torch.tensor([1])).item(), abs=1e-6)
    assert epic_distance_tabular(per_state, table, S, A, 0.9).epic > 0.1


# ------------------------------------------------------------------------------------------------
# Sampled


def _table_reward(table: np.ndarray) -> epic_module.RewardFn:
    return lambda s, a, t: table[s, a, t]


def test_sampled_canonicalisation_over_the_whole_product_is_the_exact_one() -> None:
    """With the pairs (A, S') enumerating D_A × D_S (state 0 three times out of four for the
    skewed D_S), the Monte-Carlo means are the expectations: the hand-worked values come out."""
    s, t = (index.reshape(-1) for index in np.indices((2, 2)))
    transitions = TransitionBatch(s, np.zeros(4, dtype=int), t)
    pairs = (np.array([0, 1]), np.array([0, 0]))
    assert np.allclose(canonicalize_sampled(_table_reward(R_GOAL), transitions, *pairs, discount=0.5), C_GOAL.reshape(-1))
    assert np.allclose(canonicalize_sampled(_table_reward(R_SINGLE), transitions, *pairs, discount=0.5), C_SINGLE.reshape(-1))
    skewed_pairs = (np.array([0, 0, 0, 1]), np.zeros(4, dtype=int))
    assert np.allclose(canonicalize_sampled(_table_reward(R_SINGLE), transitions, *skewed_pairs, discount=0.5), C_SINGLE_SKEWED.reshape(-1))


@pytest.mark.parametrize("discount", [0.5, 1.0])
def test_sampled_agrees_with_tabular_on_a_discrete_mdp(discount: float) -> None:
    """All S·A·S' transitions as the coverage batch; the D_S and D_A pools are the states and
    actions of a 'trajectory' where the action is a function of the state, so the estimator must
    draw A and S' independently to get the product distribution the tabular EPIC uses."""
    reward, other = _random_reward(15), _random_reward(16) + 0.7 * _random_reward(15)
    exact = epic_distance_tabular(reward, other, S, A, discount)
    s, a, t = (index.reshape(-1) for index in np.indices((S, A, S)))
    pool_states = np.tile(np.arange(S), 50)
    sampled = epic_distance_sampled(
        _table_reward(reward), _table_reward(other), TransitionBatch(s, a, t), pool_states, pool_states % A, discount, seed=0, n_mean_samples=20_000
    )
    assert 0.2 < exact.epic < 0.6
    assert sampled.epic == pytest.approx(exact.epic, abs=0.003)  # errors seen over seeds: ≤ 6e-4
    assert sampled.pearson == pytest.approx(exact.pearson, abs=1e-12)


def _continuous_pools(seed: int) -> tuple[np.ndarray, np.ndarray]:
    states, actions = np.random.default_rng(seed).uniform(-1, 1, size=(2, 512, 1))
    return states, actions


def test_sampled_is_invariant_to_scale_and_potential_shaping_on_a_continuous_state() -> None:
    """r = s against 2.5·(s + γΦ(s') − Φ(s)) with Φ(s) = s², on 1-D states in [-1, 1]."""
    discount = 0.9

    def reward(s: np.ndarray, a: np.ndarray, t: np.ndarray) -> np.ndarray:
        return s[:, 0]

    def shaped(s: np.ndarray, a: np.ndarray, t: np.ndarray) -> np.ndarray:
        return 2.5 * (s[:, 0] + discount * t[:, 0] ** 2 - s[:, 0] ** 2)

    batch = _uniform_batch(4096, seed=0)
    result = epic_distance_sampled(reward, shaped, batch, *_continuous_pools(1), discount, seed=2)
    assert result.epic <= 0.02
    assert result.pearson < 0.95
    assert epic_distance_sampled(reward, reward, batch, *_continuous_pools(1), discount).epic == pytest.approx(0.0, abs=1e-7)
    assert epic_distance_sampled(reward, lambda s, a, t: -reward(s, a, t), batch, *_continuous_pools(1), discount).epic == pytest.approx(1.0)


@pytest.mark.parametrize("discount", [0.5, 1.0])
def test_sampled_matches_a_continuous_case_solved_analytically(discount: float) -> None:
    """s, a, s' independent and uniform on [-1, 1] (coverage and D_S, D_A alike).
    R_A = a·s': m_A(x) = E[A·S'] = 0, so C_A = a·s'.
    R_B = a·s' + s: m_B(x) = x, c_B = E[S] = 0, so C_B = a·s' + γs'.
    var(a·s') = E[a²]E[s'²] = 1/9, var(γs') = γ²/3, cov(a·s', s') = E[a]E[s'²] = 0, hence
    ρ = (1/9) / √(1/9 · (1/9 + γ²/3)): 1/2 at γ = 1, 2/√7 at γ = ½. The raw rewards have
    var(R_B) = 1/9 + 1/3 and ρ = 1/2 for every γ."""

    def bilinear(s: np.ndarray, a: np.ndarray, t: np.ndarray) -> np.ndarray:
        return a[:, 0] * t[:, 0]

    def with_state(s: np.ndarray, a: np.ndarray, t: np.ndarray) -> np.ndarray:
        return a[:, 0] * t[:, 0] + s[:, 0]

    correlation = (1 / 9) / np.sqrt(1 / 9 * (1 / 9 + discount**2 / 3))
    result = epic_distance_sampled(bilinear, with_state, _uniform_batch(8192, seed=3), *_continuous_pools(4), discount, seed=5)
    assert result.epic == pytest.approx(pearson_distance(correlation), abs=0.02)
    assert result.pearson == pytest.approx(0.5, abs=0.03)


def test_sampled_evaluates_in_bounded_batches_once_per_distinct_state() -> None:
    """4096 rollout transitions × 512 mean samples: no reward call holds more than the chunk
    (memory stays bounded however large the batch), and states shared between s_{t+1} and s'_t
    are evaluated once."""
    calls: list[int] = []

    def counting(s: np.ndarray, a: np.ndarray, t: np.ndarray) -> np.ndarray:
        calls.append(len(s))
        return s[:, 0] * a[:, 0] + t.sum(1)

    rng = np.random.default_rng(6)
    trajectory = rng.normal(size=(4097, 4))
    batch = TransitionBatch(trajectory[:-1], rng.normal(size=(4096, 1)), trajectory[1:])
    epic_distance_sampled(counting, counting, batch, rng.normal(size=(512, 4)), rng.normal(size=(512, 1)), 0.9)
    assert max(calls) <= epic_module._CHUNK_ROWS
    assert sum(calls) == 2 * (4096 + (4097 + 512) * 512)


def test_torch_rewards_work_in_the_sampled_estimator() -> None:
    space, action_space = gym.spaces.Box(-1, 1, (2,), np.float32), gym.spaces.Box(-1, 1, (1,), np.float32)
    torch.manual_seed(1)
    model = torch_reward(make_reward_model(space, action_space, inputs="sas", hidden_sizes=[16]))
    rng = np.random.default_rng(7)
    batch = TransitionBatch(*rng.uniform(-1, 1, size=(3, 256, 2)).astype(np.float32))
    batch = batch._replace(actions=batch.actions[:, :1])
    pools = rng.uniform(-1, 1, size=(64, 2)).astype(np.float32), rng.uniform(-1, 1, size=(64, 1)).astype(np.float32)
    assert epic_distance_sampled(model, lambda s, a, t: 3 * model(s, a, t), batch, *pools, 0.9, n_mean_samples=64).epic == pytest.approx(0.0, abs=1e-6)


def test_bad_sampled_inputs_are_one_line_errors() -> None:
    batch = _uniform_batch(8, seed=0)
    reward = lambda s, a, t: s[:, 0]  # noqa: E731
    pools = _continuous_pools(0)
    with pytest.raises(ImitationError, match="one non-zero length"):
        epic_distance_sampled(reward, reward, batch._replace(actions=batch.actions[:3]), *pools, 0.9)
    with pytest.raises(ImitationError, match="action_samples is empty"):
        epic_distance_sampled(reward, reward, batch, pools[0], pools[1][:0], 0.9)
    with pytest.raises(ImitationError, match=r"returned shape \(8, 1\)"):
        epic_distance_sampled(lambda s, a, t: s, reward, batch, *pools, 0.9)
    with pytest.raises(ImitationError, match="must pair up"):
        canonicalize_sampled(reward, batch, pools[0], pools[1][:3], 0.9)


# ------------------------------------------------------------------------------------------------
# Coverage


def _transitions(observations: np.ndarray, actions: np.ndarray, next_observations: np.ndarray | None) -> Transitions:
    n = len(observations)
    return Transitions(
        observations=observations, actions=actions, rewards=np.zeros(n, np.float32), next_observations=next_observations,
        terminated=np.zeros(n, bool), truncated=np.zeros(n, bool), episode_index=np.zeros(n, np.int64),
    )


def test_coverage_is_demos_then_rollouts_then_uniform_samples_of_the_bounds() -> None:
    """CartPole: cart position and pole angle are bounded, the two velocities are not and take
    the demos' range."""
    env = gym.make("CartPole-v1")
    rng = np.random.default_rng(8)
    demo_states = rng.uniform(-0.5, 0.5, size=(101, 4)).astype(np.float32)
    demos = _transitions(demo_states[:-1], rng.integers(0, 2, size=100), demo_states[1:])
    rollouts = TransitionBatch(*rng.uniform(-0.1, 0.1, size=(3, 50, 4)).astype(np.float32))._replace(actions=np.ones(50, dtype=np.int64))
    batch = coverage_samples(env, demos, rollouts, n_uniform=2000, seed=0)
    assert [len(part) for part in batch] == [2150] * 3
    assert np.array_equal(batch.observations[:100], demos.observations) and np.array_equal(batch.next_observations[100:150], rollouts.next_observations)
    uniform = np.concatenate([batch.observations[150:], batch.next_observations[150:]])
    high = env.observation_space.high
    for bounded in (0, 2):
        assert np.all(np.abs(uniform[:, bounded]) <= high[bounded]) and np.abs(uniform[:, bounded]).max() > 0.9 * high[bounded]
    for unbounded in (1, 3):
        assert demo_states[:, unbounded].min() <= uniform[:, unbounded].min() and uniform[:, unbounded].max() <= demo_states[:, unbounded].max()
    assert set(np.unique(batch.actions[150:])) == {0, 1}
    assert batch.observations.dtype == np.float32
    again = coverage_samples(env, demos, rollouts, n_uniform=2000, seed=0)
    assert all(np.array_equal(x, y) for x, y in zip(batch, again))


def test_coverage_errors() -> None:
    env = gym.make("CartPole-v1")
    states = np.zeros((4, 4), np.float32)
    with pytest.raises(ImitationError, match="demos need next observations"):
        coverage_samples(env, _transitions(states, np.zeros(4, np.int64), None), n_uniform=10)
    with pytest.raises(ImitationError, match="Box or Discrete"):
        uniform_space_samples(gym.spaces.MultiBinary(3), 5, rng=np.random.default_rng(0), reference=np.zeros((0, 3)))
    with pytest.raises(ImitationError, match="unbounded Box dimension needs reference"):
        uniform_space_samples(env.observation_space, 5, rng=np.random.default_rng(0), reference=np.zeros((0, 4)))


def test_uniform_samples_of_a_shifted_discrete_and_a_half_bounded_box() -> None:
    rng = np.random.default_rng(0)
    values = uniform_space_samples(gym.spaces.Discrete(3, start=2), 3000, rng=rng, reference=np.zeros((0,)))
    assert set(np.unique(values)) == {2, 3, 4} and values.dtype == np.int64
    # Dimension 0 is bounded below only: its range comes from the reference, as dimension 1's does.
    box = gym.spaces.Box(np.array([0.0, -np.inf, -1.0]), np.array([np.inf, np.inf, 1.0]), dtype=np.float32)
    reference = np.array([[2.0, -3.0, 0.0], [5.0, 4.0, 0.0]])
    samples = uniform_space_samples(box, 5000, rng=rng, reference=reference)
    assert samples.dtype == np.float32 and samples.shape == (5000, 3)
    for dimension, (low, high) in enumerate([(2.0, 5.0), (-3.0, 4.0), (-1.0, 1.0)]):
        assert low <= samples[:, dimension].min() < low + 0.01 and high - 0.01 < samples[:, dimension].max() <= high
    # A flat reference is read as rows of the space's shape.
    flat = uniform_space_samples(box, 5000, rng=np.random.default_rng(0), reference=reference.reshape(-1))
    assert np.array_equal(flat, uniform_space_samples(box, 5000, rng=np.random.default_rng(0), reference=reference))


def test_coverage_without_rollouts_or_uniform_samples_and_its_default_seed() -> None:
    """Unbounded dimensions take the range of the demos' states (not the rollouts'), and the
    default seed is 0."""
    env = gym.make("CartPole-v1")
    rng = np.random.default_rng(3)
    demo_states = rng.uniform(-0.5, 0.5, size=(11, 4)).astype(np.float32)
    demos = _transitions(demo_states[:-1], rng.integers(0, 2, size=10), demo_states[1:])
    only_demos = coverage_samples(env, demos, n_uniform=0)
    assert all(np.array_equal(part, expected) for part, expected in zip(only_demos, (demos.observations, demos.actions, demos.next_observations)))
    wide = TransitionBatch(*rng.uniform(-3.0, 3.0, size=(3, 20, 4)).astype(np.float32))._replace(actions=np.ones(20, dtype=np.int64))
    batch = coverage_samples(env, demos, wide, n_uniform=500)
    uniform = np.concatenate([batch.observations[30:], batch.next_observations[30:]])
    for unbounded in (1, 3):
        assert demo_states[:, unbounded].min() <= uniform[:, unbounded].min() and uniform[:, unbounded].max() <= demo_states[:, unbounded].max()
    assert all(np.array_equal(x, y) for x, y in zip(batch, coverage_samples(env, demos, wide, n_uniform=500, seed=0)))
    assert not np.array_equal(batch.observations, coverage_samples(env, demos, wide, n_uniform=500, seed=1).observations)
    with pytest.raises(ImitationError, match="n_uniform must be non-negative"):
        coverage_samples(env, demos, n_uniform=-1)


def test_unbounded_actions_take_the_range_of_the_demos_actions() -> None:
    class Unbounded(gym.Env):
        observation_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        action_space = gym.spaces.Box(-np.inf, np.inf, (1,), np.float32)

    rng = np.random.default_rng(5)
    states = rng.uniform(-1, 1, size=(11, 2)).astype(np.float32)
    demos = _transitions(states[:-1], rng.uniform(-0.2, 0.7, size=(10, 1)).astype(np.float32), states[1:])
    rollouts = TransitionBatch(states[:5], np.full((5, 1), 9.0, np.float32), states[1:6])
    actions = coverage_samples(Unbounded(), demos, rollouts, n_uniform=400).actions[15:]
    assert demos.actions.min() <= actions.min() and actions.max() <= demos.actions.max()


def test_a_feature_table_is_indexed_by_state_minus_start() -> None:
    table = np.array([[1.0, 0.0], [0.0, 1.0], [2.0, 2.0]])
    model = make_reward_model(gym.spaces.Discrete(3, start=5), gym.spaces.Discrete(2), feature_table=table, hidden_sizes=[])
    assert model.inputs(torch.tensor([5, 7]), torch.zeros(2), torch.zeros(2)).tolist() == [[1.0, 0.0], [2.0, 2.0]]


def test_reward_inputs_one_hot_shifted_discrete_values_and_standardise_boxes() -> None:
    """Discrete(4, start=-1) values v are one-hot at v + 1; Box observations become (s - μ) / σ
    with μ the demos' mean per dimension and σ the half range where finite, else the widest std
    (at least 1e-3)."""
    discrete = make_reward_model(gym.spaces.Discrete(4, start=-1), gym.spaces.Discrete(2, start=3), inputs="sa", hidden_sizes=[])
    inputs = discrete.inputs(torch.tensor([-1, 2]), torch.tensor([3, 4]), torch.tensor([0, 0]))
    assert inputs.tolist() == [[1, 0, 0, 0, 1, 0], [0, 0, 0, 1, 0, 1]]
    box = gym.spaces.Box(np.array([-1.0, -np.inf, -np.inf]), np.array([1.0, np.inf, np.inf]), dtype=np.float32)
    model = make_reward_model(box, gym.spaces.Discrete(2), normalize_observations=True, hidden_sizes=[])
    demos = torch.tensor([[0.0, 10.0, 5.0], [0.5, 14.0, 5.0], [1.0, 12.0, 5.0]])
    model.set_observation_statistics(demos, torch.tensor([[0.0, 0.0, 5.0], [0.0, 3.0, 5.0]]))
    assert model.observation_mean.tolist() == pytest.approx([0.5, 12.0, 5.0])
    assert model.observation_std.tolist() == pytest.approx([1.0, 2.1213203, 1e-3])  # half range; max(2, 3/√2); floor
    expected = (demos - torch.tensor([0.5, 12.0, 5.0])) / torch.tensor([1.0, 2.1213203, 1e-3])
    assert torch.allclose(model.inputs(demos, torch.zeros(3), demos), expected, atol=1e-5)


def test_a_reward_within_round_off_of_a_constant_states_no_preference() -> None:
    """Spread ≤ 1e-6 of the reward's magnitude √E[R²] is no preference: here R ≈ -5 with a
    spread of 2e-6 (within 5e-6), against a reward that does prefer."""
    weights = np.full(8, 1 / 8)
    flat = -5.0 + 2e-6 * np.array([1, -1] * 4)
    varied = np.arange(8.0)
    result = epic_module._distances(flat, varied, flat, varied, weights)
    assert result.pearson == 0.0 and result.epic == pytest.approx(np.sqrt(0.5))
    spread = -5.0 + 1e-4 * np.array([1, -1] * 4)  # 20 times the tolerance: a preference, tiny as it is
    assert epic_module._distances(spread, spread, spread, spread, weights).pearson == pytest.approx(1.0)


def test_distributions_with_negative_or_no_mass_are_refused_by_name() -> None:
    reward = _random_reward()
    with pytest.raises(ImitationError, match="action_dist must be non-negative"):
        epic_distance_tabular(reward, reward, S, A, 0.9, action_dist=np.array([-0.5, 1.0, 1.0]))
    with pytest.raises(ImitationError, match="state_dist"):
        epic_distance_tabular(reward, reward, S, A, 0.9, state_dist=np.zeros(S))


def test_sampled_estimates_take_one_pair_and_draw_without_replacement_from_a_pool_of_their_size() -> None:
    batch = _uniform_batch(8, seed=0)
    reward = lambda s, a, t: s[:, 0] * a[:, 0] + t[:, 0] ** 2  # noqa: E731
    states, actions = _continuous_pools(0)
    one = canonicalize_sampled(reward, batch, states[:1], actions[:1], 0.9)
    s, a, t = (x[:, 0] for x in batch)
    m = lambda x: x * actions[0, 0] + states[0, 0] ** 2  # noqa: E731
    np.testing.assert_allclose(one, reward(*batch) + 0.9 * m(t) - m(s) - 0.9 * m(states[0, 0]), rtol=1e-10)
    with pytest.raises(ImitationError, match="must pair up"):
        canonicalize_sampled(reward, batch, states[:0], actions[:0], 0.9)
    # n_mean_samples = the pools' size: each sample once, so the draw is the pools in some order
    # and the estimate that of the whole pools, whatever the seed.
    whole = epic_distance_sampled(reward, lambda s, a, t: s[:, 0], batch, states[:64], actions[:64], 0.9, seed=3, n_mean_samples=64)
    other = epic_distance_sampled(reward, lambda s, a, t: s[:, 0], batch, states[:64], actions[:64], 0.9, seed=4, n_mean_samples=64)
    assert whole.epic != pytest.approx(epic_distance_sampled(reward, lambda s, a, t: s[:, 0], batch, states[:64], actions[:64], 0.9, seed=3, n_mean_samples=32).epic, abs=1e-9)
    assert whole.epic == pytest.approx(other.epic, abs=1e-12)
    assert epic_distance_sampled(reward, reward, batch, states, actions, 0.9, n_mean_samples=1).epic == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(ImitationError, match="n_mean_samples must be at least 1"):
        epic_distance_sampled(reward, reward, batch, states, actions, 0.9, n_mean_samples=0)
    with pytest.raises(ImitationError, match="state_samples is empty"):
        epic_distance_sampled(reward, reward, batch, states[:0], actions, 0.9)


def test_the_sampled_estimate_is_seeded_and_seeds_at_zero() -> None:
    batch = _uniform_batch(16, seed=1)
    reward, other = (lambda s, a, t: s[:, 0] * a[:, 0] + t[:, 0] ** 2), (lambda s, a, t: s[:, 0] + a[:, 0])  # noqa: E731
    states, actions = _continuous_pools(1)
    default = epic_distance_sampled(reward, other, batch, states, actions, 0.9, n_mean_samples=16)
    assert default == epic_distance_sampled(reward, other, batch, states, actions, 0.9, seed=0, n_mean_samples=16)
    assert default != epic_distance_sampled(reward, other, batch, states, actions, 0.9, seed=1, n_mean_samples=16)


def test_float32_rewards_are_compared_in_float64() -> None:
    """A float32 table (a network's output) gives the float64 result, not float32 round-off."""
    reward, other = _random_reward(0).astype(np.float32), _random_reward(1)
    exact = epic_distance_tabular(reward.astype(np.float64), other, S, A, 0.9)
    assert epic_distance_tabular(reward, other, S, A, 0.9) == exact
    weights = np.random.default_rng(2).random(S).astype(np.float32)
    assert epic_distance_tabular(reward, other, S, A, 0.9, state_dist=weights) == epic_distance_tabular(reward, other, S, A, 0.9, state_dist=weights.astype(np.float64))
    batch = _uniform_batch(8, seed=0)
    states, actions = _continuous_pools(0)
    single = lambda s, a, t: (s[:, 0] * a[:, 0] + 1e-3 * t[:, 0]).astype(np.float32)  # noqa: E731
    double = lambda s, a, t: single(s, a, t).astype(np.float64)  # noqa: E731
    reference = lambda s, a, t: s[:, 0] - t[:, 0]  # noqa: E731
    assert epic_distance_sampled(single, reference, batch, states, actions, 0.9) == epic_distance_sampled(double, reference, batch, states, actions, 0.9)


def test_one_transition_is_a_batch_and_rollouts_without_next_states_are_named() -> None:
    batch = _uniform_batch(1, seed=0)
    reward = lambda s, a, t: s[:, 0]  # noqa: E731
    assert epic_distance_sampled(reward, reward, batch, *_continuous_pools(0), 0.9).epic == 0.0
    env = gym.make("CartPole-v1")
    states = np.zeros((4, 4), np.float32)
    demos = _transitions(states, np.zeros(4, np.int64), states)
    with pytest.raises(ImitationError, match="the rollouts need next observations"):
        coverage_samples(env, demos, _transitions(states, np.zeros(4, np.int64), None), n_uniform=1)


def test_integer_reward_tables_are_compared_as_floats() -> None:
    """An int8 table is read as float64: 20² or 100² would wrap around in int8 arithmetic, and
    two constant rewards (no preference either) must still be at distance 0."""
    constant_a, constant_b = np.full(3, 20, dtype=np.int8), np.full((3, 2), 100, dtype=np.int8)
    assert epic_distance_tabular(constant_a, constant_b, 3, 2, 0.9) == EpicResult(epic=0.0, pearson=1.0)
    varied = np.array([0, 20, 100], dtype=np.int8)
    as_floats = epic_distance_tabular(varied.astype(float), constant_b.astype(float), 3, 2, 0.9)
    assert epic_distance_tabular(varied, constant_b, 3, 2, 0.9) == as_floats

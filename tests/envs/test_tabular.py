"""The tabular MDPs: registered ids, well-formed dynamics, exact H-step episodes, the expert."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

import imitation.envs  # noqa: F401  (registers the ids)
from imitation.envs.rollout import play_episode
from imitation.envs.tabular import TabularMDP, cliff_world, gridworld, random_mdp, tabular_mdp_of
from imitation.envs.tabular_planning import (
    DenseDynamics,
    Dynamics,
    SparseDynamics,
    check_horizon,
    expected_return,
    soft_optimal_policy,
    soft_optimal_returns,
    soft_value_iteration,
)
from imitation.errors import ConfigError, ImitationError
from imitation.experts.load import load_expert

TABULAR_IDS = ["imitation/GridWorld8x8-v0", "imitation/GridWorld8x8Slippery-v0", "imitation/CliffWorld-v0", "imitation/RandomMDP-v0"]


@pytest.mark.parametrize("env_id", TABULAR_IDS)
def test_registered_tabular_env_runs_exactly_the_horizon(env_id: str) -> None:
    env = gym.make(env_id)
    mdp = tabular_mdp_of(env, where="test")
    assert env.observation_space == gym.spaces.Discrete(mdp.n_states)
    assert np.allclose(mdp.transition.sum(-1), 1.0) and np.isclose(mdp.initial.sum(), 1.0)
    _, length = play_episode(env, lambda observation: env.action_space.sample(), seed=3)
    assert length == mdp.horizon


def test_grid_moves_deterministic_and_slippery() -> None:
    deterministic, slippery = gridworld(), gridworld(slip=0.2)
    # From the start (0, 0), "right" reaches (0, 1); slipping turns it up (wall: stay) or down.
    assert deterministic.transition[0, 1, 1] == 1.0
    assert slippery.transition[0, 1, 1] == pytest.approx(0.8)
    assert slippery.transition[0, 1, 0] == pytest.approx(0.1) and slippery.transition[0, 1, 8] == pytest.approx(0.1)
    goal = 63
    assert np.all(deterministic.transition[goal, :, goal] == 1.0), "the goal is absorbing"
    assert Dynamics.of(deterministic.transition).is_deterministic and not Dynamics.of(slippery.transition).is_deterministic


def test_env_reward_is_the_state_reward_of_the_state_left() -> None:
    env = gym.make("imitation/GridWorld8x8-v0")
    env.reset(seed=0)
    mdp = tabular_mdp_of(env, where="test")
    state = env.unwrapped.state
    _, reward, _, _, _ = env.step(2)
    assert reward == mdp.reward[state]


def test_expert_returns_match_the_exact_expected_return() -> None:
    env = gym.make("imitation/GridWorld8x8Slippery-v0")
    mdp = tabular_mdp_of(env, where="test")
    expert = load_expert("scripted", env, seed=0)
    returns = [play_episode(env, expert, seed=seed)[0] for seed in range(300)]
    exact = expected_return(Dynamics.of(mdp.transition), mdp, soft_optimal_policy(mdp))
    assert np.mean(returns) == pytest.approx(exact, abs=4 * np.std(returns) / np.sqrt(len(returns)))
    uniform = np.full((mdp.horizon, mdp.n_states, mdp.n_actions), 1.0 / mdp.n_actions)
    assert exact > expected_return(Dynamics.of(mdp.transition), mdp, uniform) + 10


def test_random_mdp_is_reproducible_and_sparse() -> None:
    a, b = random_mdp(seed=4), random_mdp(seed=4)
    assert np.array_equal(a.transition, b.transition) and np.array_equal(a.reward, b.reward)
    assert ((a.transition > 0).sum(-1) == 4).all()
    assert cliff_world().grid_shape == (4, 7)


def test_malformed_mdp_and_non_tabular_env_are_refused() -> None:
    good = gridworld()
    with pytest.raises(ImitationError, match="sum to 1"):
        TabularMDP(transition=good.transition * 0.5, initial=good.initial, features=good.features, reward=good.reward, horizon=30)
    with pytest.raises(ImitationError, match="not a tabular MDP"):
        tabular_mdp_of(gym.make("CartPole-v1"), where="--method mce")


def _stay_or_swap(reward: np.ndarray, horizon: int) -> TabularMDP:
    """Two states, action 0 stays and action 1 swaps, start in s0, γ = 1."""
    transition = np.array([[[1.0, 0.0], [0.0, 1.0]], [[0.0, 1.0], [1.0, 0.0]]])
    return TabularMDP(transition=transition, initial=np.array([1.0, 0.0]), features=np.eye(2), reward=reward, horizon=horizon)


def test_soft_optimal_returns_by_hand() -> None:
    """Stay-or-swap with r = (1, 2), H = 2: the return is r(s0) + E[r(s_1)] = 2 + π_0(swap|s0), and
    V_1(s1) - V_1(s0) = r(s1) - r(s0) (both add the same log Σ_a), so π_0(swap|s0) = σ(γ (r(s1) - r(s0))).
    At γ = 0.5 (not the MDP's 1): a learned r' = (0, 2) earns 2 + σ(1), the true one 2 + σ(0.5), the
    uniform policy 2.5."""
    mdp = _stay_or_swap(np.array([1.0, 2.0]), horizon=2)
    returns = soft_optimal_returns(mdp, np.array([0.0, 2.0]), discount=0.5)
    sigmoid = lambda x: 1 / (1 + np.exp(-x))  # noqa: E731
    learned, expert = 2 + sigmoid(1.0), 2 + sigmoid(0.5)
    assert returns == pytest.approx({
        "learned_policy_return": learned,
        "expert_return": expert,
        "random_return": 2.5,
        "normalized_return": (learned - 2.5) / (expert - 2.5),
    }, rel=1e-12)
    # The policies behind them: soft-optimal for the reward and discount given, the MDP's by default.
    assert soft_optimal_policy(mdp, np.array([0.0, 2.0]), discount=0.5)[0, 0, 1] == pytest.approx(sigmoid(1.0))
    assert soft_optimal_policy(mdp)[0, 0, 1] == pytest.approx(sigmoid(1.0))


@pytest.mark.parametrize("discount", [0.0, -0.5, 1.5, float("nan")])
def test_discount_outside_zero_to_one_is_refused(discount: float) -> None:
    with pytest.raises(ConfigError, match=r"discount must be in \(0, 1\]"):
        check_horizon(10, discount)


def _ring(n_states: int, n_actions: int, width: int) -> np.ndarray:
    """P[s, a, ·] uniform over the `width` states s + a, …, s + a + width - 1 (mod S)."""
    transition = np.zeros((n_states, n_actions, n_states))
    for a in range(n_actions):
        for k in range(width):
            transition[np.arange(n_states), a, (np.arange(n_states) + a + k) % n_states] = 1.0 / width
    return transition


@pytest.mark.parametrize(("n_states", "width", "kind"), [
    (256, 3, DenseDynamics),  # up to 256 states: dense
    (257, 3, SparseDynamics),
    (264, 33, SparseDynamics),  # 33 successors = 264 // 8: still sparse
    (264, 34, DenseDynamics),  # more than an eighth of the states: dense
])
def test_dynamics_are_sparse_only_for_many_states_with_few_successors(n_states: int, width: int, kind: type) -> None:
    """Either way P is the same: Σ_{s'} P v and Σ_{s, a} m P agree with the dense products; the
    sparse form keeps just the `width` successors of each (s, a)."""
    transition = _ring(n_states, 2, width)
    dynamics = Dynamics.of(transition)
    assert type(dynamics) is kind
    if kind is SparseDynamics:
        assert dynamics.successors.shape == dynamics.probabilities.shape == (n_states, 2, width)
    rng = np.random.default_rng(0)
    values, mass = rng.normal(size=n_states), rng.random((n_states, 2))
    np.testing.assert_allclose(dynamics.expectation(values), np.einsum("sat,t->sa", transition, values), rtol=1e-12)
    np.testing.assert_allclose(dynamics.propagate(mass), np.einsum("sa,sat->t", mass, transition), rtol=1e-12)


def test_single_action_sparse_dynamics_keep_the_action_axis() -> None:
    """With one action the (S, 1) shape of log Σ_{s'} P exp v must survive (S, 1) + (S,) broadcasting
    to (S, S) otherwise), and so must the soft-optimal policy's (H, S, 1)."""
    transition = _ring(300, 1, 2)
    dynamics = Dynamics.of(transition)
    assert isinstance(dynamics, SparseDynamics)
    values = np.random.default_rng(0).normal(size=300)
    logs = dynamics.log_expectation_of_exp(values)
    assert logs.shape == (300, 1)
    np.testing.assert_allclose(logs, np.log(np.einsum("sat,t->sa", transition, np.exp(values))), rtol=1e-12)
    policy, start_values = soft_value_iteration(dynamics, values, horizon=3, discount=1.0, method="maxent")
    assert policy.shape == (3, 300, 1) and np.allclose(policy, 1.0) and start_values.shape == (300,)


def test_maxent_backup_over_impossible_successors_warns_nothing() -> None:
    """log P(s'|s, a) is -inf where P is 0, on purpose (exp(-inf) = 0): no 'divide by zero' warning."""
    grid = gridworld()
    sparse_transition = _ring(300, 2, 3)
    sparse_transition[0, 0] = np.eye(300)[5]  # fewer successors than the width: zero-padded
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        soft_value_iteration(Dynamics.of(grid.transition), grid.reward, horizon=3, discount=1.0, method="maxent")
        sparse = Dynamics.of(sparse_transition)
        assert isinstance(sparse, SparseDynamics)
        sparse.log_expectation_of_exp(np.zeros(300))

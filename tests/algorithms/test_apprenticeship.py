"""Apprenticeship learning (projection method): its formulas against values worked by hand, the
mixture's weights, the exact tabular version on the bundled gridworld demos (the acceptance
figures of issue 18), the PPO solver's mechanics, and exact resumption."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS

from imitation.algorithms.apprenticeship import (
    Apprenticeship,
    ApprenticeshipConfig,
    PPOSolver,
    TabularSolver,
    box_feature_reward,
    box_feature_scales,
    discounted_feature_sum,
    mixture_weights,
    optimal_policy,
    projection_step,
    reward_features,
    reward_weights,
    set_reward_weights,
)
from imitation.algorithms.maxent_irl import demo_visitation
from imitation.checkpoints import snapshot
from imitation.data.dataset import DemoDataset
from imitation.envs.make import make_env
from imitation.envs.tabular import TabularMDP, tabular_mdp_of
from imitation.envs.tabular_planning import Dynamics, expected_return, soft_optimal_policy
from imitation.errors import ConfigError
from imitation.jobs.presets import ppo_config

GRIDS = ["imitation/GridWorld8x8-v0", "imitation/GridWorld8x8Slippery-v0"]


# ------------------------------------------------------------------------------------------------
# The formulas, by hand


def test_reward_weights_are_the_unit_direction_to_the_expert() -> None:
    weights, distance = reward_weights(np.array([3.0, 4.0]), np.zeros(2))
    np.testing.assert_allclose(weights, [0.6, 0.8])
    assert distance == 5.0
    weights, distance = reward_weights(np.array([1.0, 1.0]), np.array([1.0, 1.0]))
    assert distance == 0.0 and not weights.any()


def test_projection_step_by_hand() -> None:
    # μ̄ = (0, 0), μ = (2, 0), μ_E = (1, 1): α = (2·1 + 0·1) / 4 = 0.5, μ̄' = (1, 0).
    mu_bar, alpha = projection_step(np.zeros(2), np.array([2.0, 0.0]), np.array([1.0, 1.0]))
    assert alpha == 0.5
    np.testing.assert_allclose(mu_bar, [1.0, 0.0])
    # μ̄ = (1, 1), μ = (1, 3), μ_E = (2, 2): step (0, 2), α = (0·1 + 2·1) / 4 = 0.5, μ̄' = (1, 2).
    mu_bar, alpha = projection_step(np.array([1.0, 1.0]), np.array([1.0, 3.0]), np.array([2.0, 2.0]))
    assert alpha == 0.5
    np.testing.assert_allclose(mu_bar, [1.0, 2.0])
    # μ_E = (3, 1) projects beyond μ (α = 6/4): clipped to the segment's end, μ̄' = μ.
    mu_bar, alpha = projection_step(np.zeros(2), np.array([2.0, 0.0]), np.array([3.0, 1.0]))
    assert alpha == 1.0
    np.testing.assert_allclose(mu_bar, [2.0, 0.0])
    # μ_E = (-1, 1) lies behind μ̄ (α = -2/4): clipped to 0, μ̄ stays.
    mu_bar, alpha = projection_step(np.zeros(2), np.array([2.0, 0.0]), np.array([-1.0, 1.0]))
    assert alpha == 0.0
    np.testing.assert_allclose(mu_bar, [0.0, 0.0])
    # μ = μ̄: no direction, α = 0.
    assert projection_step(np.ones(2), np.ones(2), np.zeros(2))[1] == 0.0


def test_mixture_weights_by_hand() -> None:
    np.testing.assert_allclose(mixture_weights(np.array([0.5, 0.5]), 0.2), [0.4, 0.4, 0.2])
    np.testing.assert_allclose(mixture_weights(np.array([1.0]), 1.0), [0.0, 1.0])


def test_the_weights_follow_the_projections() -> None:
    # Three projections worked in a row: λ stays a distribution and Σ λ_j μ^(j) = μ̄ each time.
    mu_expert = np.array([1.0, 1.0])
    mus = [np.array([0.0, 0.0]), np.array([2.0, 0.0]), np.array([0.0, 3.0]), np.array([1.5, 1.5])]
    mu_bar, lambdas = mus[0], np.ones(1)
    for index, mu in enumerate(mus[1:], start=1):
        mu_bar, alpha = projection_step(mu_bar, mu, mu_expert)
        lambdas = mixture_weights(lambdas, alpha)
        np.testing.assert_allclose(lambdas @ np.stack(mus[: index + 1]), mu_bar, atol=1e-12)
        assert np.all(lambdas >= 0) and np.isclose(lambdas.sum(), 1.0)
    # By hand: μ̄^(1) = (1, 0) (α = 0.5), then toward (0, 3): step (-1, 3), α = (0 + 3)/10 = 0.3,
    # μ̄^(2) = (0.7, 0.9); λ = (0.35, 0.35, 0.3).
    mu_bar, lambdas = mus[0], np.ones(1)
    for mu in mus[1:3]:
        mu_bar, alpha = projection_step(mu_bar, mu, mu_expert)
        lambdas = mixture_weights(lambdas, alpha)
    np.testing.assert_allclose(mu_bar, [0.7, 0.9])
    np.testing.assert_allclose(lambdas, [0.35, 0.35, 0.3])


def test_discounted_feature_sum_by_hand() -> None:
    features = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    np.testing.assert_allclose(discounted_feature_sum(features, 0.5), [1.25, 0.75])
    np.testing.assert_allclose(discounted_feature_sum(features, 1.0), [2.0, 2.0])


def _line_mdp(horizon: int | None, discount: float = 1.0) -> TabularMDP:
    """States 0 → 1 → 2 on a line; action 0 stays, action 1 moves right; 2 is absorbing;
    r = (1, 0, 3), one-hot features, start in 0."""
    transition = np.zeros((3, 2, 3))
    for state in range(3):
        transition[state, 0, state] = 1.0
        transition[state, 1, min(state + 1, 2)] = 1.0
    transition[2, 1] = [0.0, 0.0, 1.0]
    return TabularMDP(
        transition=transition,
        initial=np.array([1.0, 0.0, 0.0]),
        features=np.eye(3),
        reward=np.array([1.0, 0.0, 3.0]),
        horizon=horizon,
        discount=discount,
    )


def test_value_iteration_by_hand() -> None:
    mdp = _line_mdp(2)
    dynamics = Dynamics.of(mdp.transition)
    # H = 1: from 0, stay earns 1 + V_1(0) = 2, right 1 + V_1(1) = 1: stay.
    assert optimal_policy(dynamics, mdp.reward, horizon=1, discount=1.0)[0, 0].argmax() == 0
    # H = 2: V_1 = (2, 3, 6); from 0 at t = 0, stay 1 + 2 = 3, right 1 + 3 = 4: right; at t = 1 stay.
    policy = optimal_policy(dynamics, mdp.reward, horizon=2, discount=1.0)
    assert policy.shape == (2, 3, 2) and policy[0, 0].argmax() == 1 and policy[1, 0].argmax() == 0
    assert policy[1, 1].argmax() == 1
    np.testing.assert_array_equal(policy.sum(-1), 1.0)
    # Infinite horizon, γ = 0.5: staying in 0 is worth 1/(1-γ) = 2; going right 1 + γ·(0 + γ·3/(1-γ)) = 2.5.
    stationary = optimal_policy(dynamics, mdp.reward, horizon=None, discount=0.5)
    assert stationary.shape == (3, 2) and stationary[0].argmax() == 1
    # γ = 0.2: stay 1.25 beats right 1 + 0.2·0.2·3.75 = 1.15.
    assert optimal_policy(dynamics, mdp.reward, horizon=None, discount=0.2)[0].argmax() == 0


def test_exact_feature_expectations_by_hand() -> None:
    right = np.zeros((2, 3, 2))
    right[..., 1] = 1.0
    # Always right from 0 for H = 2: states 0, 1, 2 once each; with γ = 0.5: (1, 0.5, 0.25).
    np.testing.assert_allclose(TabularSolver(_line_mdp(2), 1.0).feature_expectations(right), [1.0, 1.0, 1.0])
    np.testing.assert_allclose(TabularSolver(_line_mdp(2), 0.5).feature_expectations(right), [1.0, 0.5, 0.25])
    # Uniform random for H = 1: s_0 = 0, then 0 or 1 by halves.
    solver = TabularSolver(_line_mdp(1), 1.0)
    np.testing.assert_allclose(solver.random_policy(), [1.5, 0.5, 0.0])


def test_box_features_by_hand() -> None:
    space = gym.spaces.Box(np.array([-2.0, -np.inf, 0.0], dtype=np.float32), np.array([2.0, np.inf, 1.0], dtype=np.float32))
    demos = np.array([[0.5, -4.0, 0.0], [1.0, 3.0, 0.0]], dtype=np.float32)
    scales = box_feature_scales(space, demos)
    np.testing.assert_allclose(scales, [2.0, np.inf, 1.0])  # the unbounded coordinate gets no feature
    reward = box_feature_reward(space, gym.spaces.Discrete(2), scales)
    features = reward_features(reward, np.array([[1.0, -2.0, 1.0], [-1.0, 5.0, 0.0]], dtype=np.float32))
    # φ = (|s_0|/2, |s_2|/1).
    np.testing.assert_allclose(features, [[0.5, 1.0], [0.5, 0.0]])
    set_reward_weights(reward, np.array([1.0, -2.0]))
    states = torch.tensor([[1.0, -2.0, 1.0], [-1.0, 5.0, 0.0]])
    np.testing.assert_allclose(reward(states, torch.zeros(2), states).detach().numpy(), [0.5 - 2.0, 0.5])
    # No coordinate bounded: every one scaled by the demos' largest |s_k|.
    unbounded = gym.spaces.Box(-np.inf, np.inf, shape=(3,), dtype=np.float32)
    np.testing.assert_allclose(box_feature_scales(unbounded, demos), [1.0, 4.0, 1e-3])


def test_config_checks() -> None:
    with pytest.raises(ConfigError, match="iterations must be at least 1"):
        ApprenticeshipConfig(iterations=0).validate()
    with pytest.raises(ConfigError, match=r"tolerance must be in \[0, 1\)"):
        ApprenticeshipConfig(tolerance=1.0).validate()
    with pytest.raises(ConfigError, match="episodes must be at least 1"):
        ApprenticeshipConfig(episodes=0).validate()


# ------------------------------------------------------------------------------------------------
# Tabular: the bundled gridworld demos


def _grid(env_id: str) -> tuple[TabularMDP, np.ndarray]:
    mdp = tabular_mdp_of(make_env(env_id), where="test")
    episodes = DemoDataset([DATASETS / f"{env_id.split('/')[1]}.mcap"]).read_episodes()
    occupancy = demo_visitation(episodes, n_states=mdp.n_states, horizon=mdp.horizon, discount=1.0)
    return mdp, occupancy @ mdp.features


def _learn(learner: Apprenticeship) -> list[dict[str, float]]:
    rows = []
    while not learner.done:
        rows.append(learner.step())
    return rows


@pytest.mark.parametrize("env_id", GRIDS)
def test_tabular_mixture_matches_the_expert_and_earns_what_it_does(env_id: str) -> None:
    """Issue 18: ‖μ̄ - μ_E‖₂ ≤ 0.05 ‖μ_E‖₂ and the mixture's exact true return, normalised
    between the uniform random policy and the soft-optimal expert, ≥ 0.9."""
    mdp, mu_expert = _grid(env_id)
    solver = TabularSolver(mdp, 1.0)
    learner = Apprenticeship(solver, mu_expert, ApprenticeshipConfig())
    rows = _learn(learner)
    assert learner.converged and learner.distance <= 0.01 * np.linalg.norm(mu_expert)
    # The weights reproduce μ̄, and each μ^(j) is that of the policy kept for it.
    assert np.all(learner.lambdas >= 0) and np.isclose(learner.lambdas.sum(), 1.0)
    np.testing.assert_allclose(learner.lambdas @ learner.mus, learner.mu_bar, atol=1e-9)
    for policy, mu in zip(solver.policies, learner.mus, strict=True):
        np.testing.assert_allclose(solver.feature_expectations(policy), mu)
    # t^(i) falls every iteration (the projection never moves away from μ_E).
    distances = [np.linalg.norm(mu_expert - learner.mus[0])] + [row["distance"] for row in rows]
    assert all(later <= earlier + 1e-12 for earlier, later in zip(distances, distances[1:]))
    # The mixture's exact return: the members' returns weighted by λ.
    dynamics = Dynamics.of(mdp.transition)
    returns = np.array([expected_return(dynamics, mdp, policy) for policy in solver.policies])
    expert = expected_return(dynamics, mdp, soft_optimal_policy(mdp))
    normalised = (learner.lambdas @ returns - returns[0]) / (expert - returns[0])
    assert 0.9 <= normalised <= 1.2, normalised
    # Each member but π^(0) is optimal for its reward: no deterministic deviation at t = 0 from s_0 does better.
    for weights, policy in zip(learner.weights, solver.policies[1:], strict=True):
        best = optimal_policy(dynamics, mdp.features @ weights, horizon=mdp.horizon, discount=1.0)
        assert solver.feature_expectations(policy) @ weights == pytest.approx(solver.feature_expectations(best) @ weights)


def test_tabular_learner_resumes_exactly() -> None:
    mdp, mu_expert = _grid(GRIDS[1])
    config = ApprenticeshipConfig(iterations=6, tolerance=0.0)
    whole = Apprenticeship(TabularSolver(mdp, 1.0), mu_expert, config)
    rows = _learn(whole)
    first = Apprenticeship(TabularSolver(mdp, 1.0), mu_expert, config)
    head = [first.step() for _ in range(3)]
    checkpoint = snapshot(*first.state_dict())
    resumed = Apprenticeship(TabularSolver(mdp, 1.0), mu_expert, config)
    resumed.load_state_dict(checkpoint)
    assert resumed.completed == 3
    tail = _learn(resumed)
    assert head + tail == rows
    np.testing.assert_array_equal(resumed.lambdas, whole.lambdas)
    np.testing.assert_array_equal(resumed.mus, whole.mus)
    np.testing.assert_array_equal(np.stack(resumed.solver.policies), np.stack(whole.solver.policies))  # type: ignore[attr-defined]


# ------------------------------------------------------------------------------------------------
# Box observations: the PPO solver


CARTPOLE = "imitation/CartPoleFixedHorizon-v0"


def _cartpole_learner(iterations: int) -> Apprenticeship:
    env = make_env(CARTPOLE)
    assert isinstance(env.observation_space, gym.spaces.Box)
    episodes = DemoDataset([DATASETS / "CartPoleFixedHorizon-v0.mcap"]).read_episodes()[:3]
    observations = [np.asarray(episode.observations, dtype=np.float32) for episode in episodes]
    reward = box_feature_reward(
        env.observation_space, env.action_space, box_feature_scales(env.observation_space, np.concatenate(observations))
    )
    config = ApprenticeshipConfig(iterations=iterations, tolerance=0.0, solver_steps=64, episodes=1, discount=0.99)
    mu_expert = np.mean([discounted_feature_sum(reward_features(reward, o), 0.99) for o in observations], axis=0)
    # A small PPO (2 envs × 32 steps, 2 epochs): the mechanics, not the learning, are under test.
    solver_config = ppo_config(CARTPOLE, learned_reward=True, total_steps=64, n_envs=2, n_steps=32, batch_size=32, n_epochs=2)
    solver = PPOSolver(solver_config, reward, config)
    return Apprenticeship(solver, mu_expert, config)


def test_ppo_solver_iterations_and_exact_resume() -> None:
    whole = _cartpole_learner(2)
    rows = _learn(whole)
    solver = whole.solver
    assert isinstance(solver, PPOSolver)
    assert len(solver.policies) == 3 and solver.steps == 2 * 64 and whole.mus.shape == (3, 3)
    np.testing.assert_allclose(whole.lambdas @ whole.mus, whole.mu_bar, atol=1e-9)
    # φ = (|x|/4.8, |θ|/0.419, failed): the expert never fails, the untrained policy does.
    assert whole.mu_expert[2] == 0.0 and whole.mus[0][2] > 0.0
    first = _cartpole_learner(2)
    head = [first.step()]
    resumed = _cartpole_learner(2)
    resumed.load_state_dict(snapshot(*first.state_dict()))
    assert head + _learn(resumed) == rows
    np.testing.assert_array_equal(resumed.mus, whole.mus)
    resumed_solver = resumed.solver
    assert isinstance(resumed_solver, PPOSolver)
    for a, b in zip(resumed_solver.policies, solver.policies, strict=True):
        for (name, x), y in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
            assert torch.equal(x, y), name

"""Apprenticeship learning's stationary value iteration (imitation.algorithms.apprenticeship.
optimal_policy with no horizon) at its edges, worked by hand: it starts from the value of staying
in each state forever, r/(1 - γ), which is exact for absorbing states, so a goal behind a detour is
found at once even for γ within 10⁻⁵ of 1; it stops at the first sweep that changes no value by
10⁻¹⁰ or more, greedy for the values that sweep read; and without convergence it stops after
100,000 sweeps, greedy for the last sweep's values."""

from __future__ import annotations

import numpy as np
import pytest

from imitation.algorithms.apprenticeship import optimal_policy
from imitation.envs.tabular_planning import Dynamics


def decision_mdp(stay: float) -> Dynamics:
    """State 0 chooses: action 0 goes to state 1, absorbing; action 1 to state 2, which moves on
    to state 3, absorbing, with probability 1 - `stay` per step (stays otherwise). Every other
    state's two actions do the same."""
    transition = np.zeros((4, 2, 4))
    transition[0, 0, 1] = transition[0, 1, 2] = 1.0
    transition[1, :, 1] = 1.0
    transition[2, :, 2], transition[2, :, 3] = stay, 1.0 - stay
    transition[3, :, 3] = 1.0
    return Dynamics.of(transition)


def test_a_goal_behind_a_detour_is_found_for_a_discount_near_one() -> None:
    """γ = 1 - 10⁻⁵; the absorbing state 1 pays a = γ(1 - 10⁻⁶) a step, state 3 (one step later,
    through state 2 which pays 0) 1 a step: Q(0, 0) = γa/(1 - γ) falls short of Q(0, 1) =
    γ²/(1 - γ) by γ² 10⁻⁶/(1 - γ) ≈ 0.1. Starting from the values of staying, both are exact after
    two sweeps; a start from, say, r(1 - γ) would still lack e⁻¹ of each after the 100,000 sweeps
    allowed, and the longer way round would look the worse."""
    gamma = 1.0 - 1e-5
    reward = np.array([0.0, gamma * (1.0 - 1e-6), 0.0, 1.0])
    policy = optimal_policy(decision_mdp(0.0), reward, horizon=None, discount=gamma)
    assert policy[0].tolist() == [0.0, 1.0]


@pytest.mark.parametrize(("goal", "action"), [(1e-10, 1), (5e-11, 0)], ids=["change-at-tolerance", "change-below"])
def test_value_iteration_stops_at_the_first_sweep_that_changes_no_value_by_the_tolerance(goal: float, action: int) -> None:
    """γ = 1/2; state 3 pays `goal` a step, state 1 pays c = 10⁻¹¹, states 0 and 2 nothing, and
    state 2 always moves on to 3. V₀ = r/(1 - γ) = (0, 2c, 0, 2·goal); the first sweep gives
    Q(0, ·) = (γ V₀(1), γ V₀(2)) = (c, 0), V₁ = (c, 2c, goal, 2·goal): it changed V(2) by `goal`.
    At 10⁻¹⁰, not below the tolerance, a second sweep reads V₁: Q(0, ·) = (c, goal/2) picks the
    way to the goal (action 1); below it, the first sweep's greedy action 0 is the answer. All
    these values are exact in floating point (halving and doubling)."""
    reward = np.array([0.0, 1e-11, 0.0, goal])
    policy = optimal_policy(decision_mdp(0.0), reward, horizon=None, discount=0.5)
    assert policy[0].tolist() == np.eye(2)[action].tolist()


def test_without_convergence_the_policy_is_greedy_for_the_100000th_sweep() -> None:
    """γ = 1 - 10⁻⁶ and state 2 left for state 3 (paying 1 a step) with probability 1 - p, p = 1 - 10⁻⁵:
    from V₀(2) = 0, V_k(2) = γ(1 - p)/(1 - γ) · (1 - (γp)^k)/(1 - γp), which still grows by about 3
    a sweep at k = 100,000. State 1 pays a, set so that Q(0, 0) = γa/(1 - γ) lies halfway between
    Q(0, 1) = γ V_k(2) for k = 99,999 (the values the last of 100,000 sweeps reads) and k = 100,000:
    the answer is action 0 (the 100,001st sweep would pick action 1)."""
    gamma, stay = 1.0 - 1e-6, 1.0 - 1e-5

    def value(sweeps: int) -> float:
        return gamma * (1.0 - stay) / (1.0 - gamma) * (1.0 - (gamma * stay) ** sweeps) / (1.0 - gamma * stay)

    assert value(100_000) - value(99_999) > 3.0  # far from the fixed point: no convergence check passes
    a = (1.0 - gamma) * (value(99_999) + value(100_000)) / 2.0
    policy = optimal_policy(decision_mdp(stay), np.array([0.0, a, 0.0, 1.0]), horizon=None, discount=gamma)
    assert policy[0].tolist() == [1.0, 0.0]

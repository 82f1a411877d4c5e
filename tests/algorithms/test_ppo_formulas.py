"""PPO's formulas against values worked by hand: GAE, the KL-penalty rule and objective, the clipped objective."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch.distributions import Categorical, Normal

from imitation.algorithms.ppo import RewardScaler, clipped_surrogate, kl_penalty_objective, policy_kl, update_kl_penalty
from imitation.algorithms.advantages import compute_gae

GAMMA, LAMBDA = 0.9, 0.5


def gae(rewards, values, next_values, terminated, truncated):
    as_column = lambda xs, dtype=torch.float32: torch.tensor(xs, dtype=dtype)[:, None]  # noqa: E731
    advantages, returns = compute_gae(
        as_column(rewards), as_column(values), as_column(next_values),
        as_column(terminated, torch.bool), as_column(truncated, torch.bool), gamma=GAMMA, gae_lambda=LAMBDA,
    )
    return advantages[:, 0].tolist(), returns[:, 0].tolist()


def test_gae_without_episode_ends() -> None:
    # δ = 1 + 0.9·V(s') − V(s) = 0.86, 0.87, 0.88;  Â2 = 0.88, Â1 = 0.87 + 0.45·0.88, Â0 = 0.86 + 0.45·Â1
    advantages, returns = gae([1, 1, 1], [0.5, 0.4, 0.3], [0.4, 0.3, 0.2], [0, 0, 0], [0, 0, 0])
    assert advantages == pytest.approx([1.4297, 1.266, 0.88])
    assert returns == pytest.approx([1.9297, 1.666, 1.18])


def test_gae_of_a_one_step_rollout() -> None:
    # δ0 = 1 + 0.9·2 − 0.5 = 2.3 = Â0 (n_steps = 1 is a valid rollout length).
    advantages, returns = gae([1], [0.5], [2.0], [0], [0])
    assert advantages == pytest.approx([2.3]) and returns == pytest.approx([2.8])


def test_gae_termination_does_not_bootstrap() -> None:
    # Step 1 terminates: δ1 = 1 − 0.4 (no γV), and Â1 does not look into the next episode.
    advantages, _ = gae([1, 1, 1], [0.5, 0.4, 0.3], [0.4, 123.0, 0.2], [0, 1, 0], [0, 0, 0])
    assert advantages == pytest.approx([0.86 + 0.45 * 0.6, 0.6, 0.88])


def test_gae_truncation_bootstraps_from_the_final_state() -> None:
    # Step 1 is cut by a time limit; its true next state has V = 2: δ1 = 1 + 0.9·2 − 0.4 = 2.4.
    advantages, _ = gae([1, 1, 1], [0.5, 0.4, 0.3], [0.4, 2.0, 0.2], [0, 0, 0], [0, 1, 0])
    assert advantages == pytest.approx([0.86 + 0.45 * 2.4, 2.4, 0.88])


def test_gae_with_several_envs_ending_mid_rollout() -> None:
    rewards = torch.tensor([[1.0, 0.0], [0.0, 1.0], [2.0, 0.0]])
    values = torch.zeros(3, 2)
    next_values = torch.tensor([[0.0, 1.0], [0.0, 0.0], [1.0, 5.0]])
    terminated = torch.tensor([[False, False], [True, False], [False, False]])
    truncated = torch.tensor([[False, False], [False, True], [False, False]])
    advantages, _ = compute_gae(rewards, values, next_values, terminated, truncated, gamma=GAMMA, gae_lambda=LAMBDA)
    # env 0: δ = 1, 0, 2.9; ends at t=1 → Â = 1 + 0.45·0, 0, 2.9
    # env 1: δ = 0.9, 1, 4.5; truncated at t=1 (V(final)=0) → Â = 0.9 + 0.45·1, 1, 4.5
    assert advantages[:, 0].tolist() == pytest.approx([1.0, 0.0, 2.9])
    assert advantages[:, 1].tolist() == pytest.approx([0.9 + 0.45, 1.0, 4.5])


@pytest.mark.parametrize(
    ("kl", "expected"),
    [(0.015, 2.0), (0.03, 2.0), (0.0149, 1.0), (0.01, 1.0), (0.0067, 1.0), (0.01 / 1.5, 0.5), (0.001, 0.5)],
)
def test_kl_penalty_rule(kl: float, expected: float) -> None:
    # δ = 0.01: double at KL ≥ 0.015, halve at KL ≤ 0.00667, keep in between.
    assert update_kl_penalty(1.0, kl, 0.01) == pytest.approx(expected)


def gradient_of_clipped_objective(ratio: float, advantage: float) -> float:
    log_ratio = torch.tensor(float(torch.log(torch.tensor(ratio))), requires_grad=True)
    clipped_surrogate(log_ratio.exp(), torch.tensor(advantage), 0.2).backward()
    return float(log_ratio.grad)


def test_clipped_objective_gradient_vanishes_where_the_notes_say() -> None:
    # Â > 0: no incentive to push r above 1 + ε; Â < 0: none to push it below 1 − ε.
    assert gradient_of_clipped_objective(1.3, +1.0) == 0.0
    assert gradient_of_clipped_objective(0.7, -1.0) == 0.0
    # Inside the trust region the gradient is Â·r (d/dlog r of r·Â).
    assert gradient_of_clipped_objective(1.1, +1.0) == pytest.approx(1.1)
    assert gradient_of_clipped_objective(0.9, -1.0) == pytest.approx(-0.9)
    # Pessimism: when the change makes things worse, the gradient is not clipped away.
    assert gradient_of_clipped_objective(0.7, +1.0) == pytest.approx(0.7)
    assert gradient_of_clipped_objective(1.3, -1.0) == pytest.approx(-1.3)


def test_clipped_objective_values() -> None:
    ratio = torch.tensor([0.5, 1.0, 1.5, 0.5, 1.5])
    advantage = torch.tensor([1.0, 2.0, 1.0, -1.0, -1.0])
    assert clipped_surrogate(ratio, advantage, 0.2).tolist() == pytest.approx([0.5, 2.0, 1.2, -0.8, -1.5])


# Old N(0, 1) and new N(1, 2²) in one action dim (the other dim unchanged): the two directions differ,
#   D_KL(π_k || π_θ) = log 2 + (1 + 1) / 8 - 1/2 = 0.4431,   D_KL(π_θ || π_k) = -log 2 + (4 + 1) / 2 - 1/2 = 1.3069.
GAUSSIAN_KL = math.log(2) + 0.25 - 0.5


def test_kl_is_of_the_new_policy_from_the_old_one_summed_over_action_dims() -> None:
    old = Normal(torch.tensor([[0.0, 0.5]]), torch.tensor([[1.0, 0.3]]))
    new = Normal(torch.tensor([[1.0, 0.5]]), torch.tensor([[2.0, 0.3]]))
    assert policy_kl(old, new).tolist() == pytest.approx([GAUSSIAN_KL])
    assert policy_kl(new, old).tolist() == pytest.approx([-math.log(2) + 2.5 - 0.5])
    # Categorical: π_k = (½, ½), π_θ = (0.9, 0.1): ½ log(0.5/0.9) + ½ log(0.5/0.1) = 0.5108 (the other way 0.3681).
    assert policy_kl(Categorical(probs=torch.tensor([[0.5, 0.5]])), Categorical(probs=torch.tensor([[0.9, 0.1]]))).tolist() == pytest.approx([0.5108], abs=1e-4)


def test_kl_penalty_objective_by_hand() -> None:
    """r Â - β D_KL(π_k || π_θ): r = 1.2, Â = 0.5, β = 2."""
    old = Normal(torch.tensor([[0.0]]), torch.tensor([[1.0]]))
    new = Normal(torch.tensor([[1.0]]), torch.tensor([[2.0]]))
    value = kl_penalty_objective(torch.tensor([1.2]), torch.tensor([0.5]), old, new, beta=2.0)
    assert value.tolist() == pytest.approx([0.6 - 2.0 * GAUSSIAN_KL])


def test_reward_scaling_divides_by_the_running_std_of_the_discounted_return() -> None:
    """R_t = γ R_{t-1} + r_t per env (restarting after an episode ends); each reward is divided by
    the std of every R so far and clipped to ±10."""
    scaler = RewardScaler(n_envs=2, gamma=GAMMA)
    rng = np.random.default_rng(0)
    returns, seen = np.zeros(2), []
    for t in range(200):
        rewards = rng.normal(1.0, 2.0, size=2)
        if t == 190:
            rewards[:] = (-1e4, 1e4)  # far beyond ten standard deviations
        dones = np.array([t % 7 == 6, t % 11 == 10])
        returns = GAMMA * returns + rewards
        seen += list(returns)
        expected = np.clip(rewards / np.sqrt(np.var(seen) + 1e-8), -10.0, 10.0)
        scaled = scaler(rewards, dones)
        np.testing.assert_allclose(scaled, expected, rtol=2e-3)
        assert t != 190 or scaled.tolist() == [-10.0, 10.0]
        returns[dones] = 0.0


def test_reward_scaling_stays_finite_after_a_long_run_of_zero_rewards() -> None:
    """A sparse reward (0 until the first success) drives the returns' running variance from its
    prior 1 down to 1e-4 / (1e-4 + n): below the 1e-8 guard after 2·10⁴ returns. The scaled
    rewards stay 0 meanwhile, and the first success is clipped to 10, not NaN."""
    scaler = RewardScaler(n_envs=1000, gamma=GAMMA)
    for _ in range(20):
        assert not scaler(np.zeros(1000), np.zeros(1000, dtype=bool)).any()
    assert scaler.stats.var.item() < 1e-8
    rewards = np.zeros(1000)
    rewards[0] = 1.0
    assert scaler(rewards, np.zeros(1000, dtype=bool))[:2].tolist() == [10.0, 0.0]

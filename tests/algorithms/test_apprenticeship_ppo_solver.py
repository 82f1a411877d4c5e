"""Apprenticeship learning's sampled solver (imitation.algorithms.apprenticeship.PPOSolver), step by
step: iteration i is seeded with seed + 1000 i, PPO optimises r = wᵀφ for `solver_steps` steps
from the previous policy, and μ(π) is the mean over `episodes` episodes (reset with the
iteration's seed + episode, the policy acting deterministically) of Σ_t γ^t φ(s_t), recomputed
here by hand. On a tiny env whose observations are float64, as MuJoCo's are; and the feature
scales of Box spaces of any shape."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

from imitation.algorithms.apprenticeship import (
    ApprenticeshipConfig,
    PPOSolver,
    box_feature_reward,
    box_feature_scales,
)
from imitation.checkpoints import snapshot
from imitation.envs.make import make_env
from imitation.jobs.presets import ppo_config
from imitation.policies import SingleObservationPolicy

ENV_ID = "TestApprenticeshipWalk-v0"
SEED, GAMMA, EPISODES = 5, 0.9, 2


class Walk(gym.Env):
    """A point on [−1, 1]² (float64) nudged by one of 4 moves, 6 steps an episode."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float64)
    action_space = gym.spaces.Discrete(4)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.t, self.x = 0, self.np_random.uniform(-0.5, 0.5, 2)
        return self.x.copy(), {}

    def step(self, action):
        self.t += 1
        self.x = np.clip(self.x + 0.2 * np.array([[1, 0], [-1, 0], [0, 1], [0, -1]][int(action)]), -1.0, 1.0)
        return self.x.copy(), 0.0, False, self.t >= 6, {}


gym.register(ENV_ID, entry_point=Walk)


def solver() -> PPOSolver:
    env = make_env(ENV_ID)
    reward = box_feature_reward(
        env.observation_space, env.action_space, box_feature_scales(env.observation_space, np.zeros((0, 2)))
    )
    config = ApprenticeshipConfig(iterations=2, tolerance=0.0, solver_steps=32, episodes=EPISODES, discount=GAMMA, seed=SEED)
    ppo = ppo_config(
        ENV_ID, learned_reward=True, total_steps=4096, n_envs=2, n_steps=16, batch_size=16, n_epochs=2, hidden_sizes=[8]
    )
    return PPOSolver(ppo, reward, config)


def mu_by_hand(policy, seed: int) -> np.ndarray:
    """Σ_t γ^t |s_t| (φ_k = |s_k|/1 on [−1, 1]²), averaged over the episodes reset with seed, seed + 1."""
    env, act = make_env(ENV_ID), SingleObservationPolicy(policy)
    sums = []
    for episode in range(EPISODES):
        state, _ = env.reset(seed=seed + episode)
        states, done = [state], False
        while not done:
            state, _, terminated, truncated, _ = env.step(act(state))
            states.append(state)
            done = terminated or truncated
        sums.append(sum(GAMMA**t * np.abs(s) for t, s in enumerate(states)))
    return np.mean(sums, axis=0)


def test_each_iteration_is_seeded_apart_trains_on_w_phi_from_the_last_policy_and_measures_mu_by_its_episodes() -> None:
    sampled = solver()
    mus = [sampled.random_policy()]
    ppo = sampled._ppo(17)
    assert ppo.reward is sampled.reward and (ppo.config.seed, ppo.config.total_steps) == (17, 32)
    ppo.close()
    for weights in (np.array([1.0, -1.0]), np.array([-0.5, 2.0])):
        mus.append(sampled.solve(weights))
        np.testing.assert_array_equal(sampled.reward.net[-1].weight.detach().numpy()[0], np.tile(weights, 2))
    assert len(sampled.policies) == 3 and sampled.steps == 2 * 32
    for i, (policy, mu) in enumerate(zip(sampled.policies, mus, strict=True)):
        np.testing.assert_allclose(mu, mu_by_hand(policy, SEED + 1000 * i), rtol=1e-6)
    # Each solve starts from the policy before it: a few PPO steps leave it close, not equal.
    for before, after in zip(sampled.policies, sampled.policies[1:]):
        assert not torch.equal(before.action_head.weight, after.action_head.weight)


@pytest.mark.parametrize("policies", [0, 1])
def test_the_solvers_checkpoint_holds_its_policies_from_none_on(policies: int) -> None:
    sampled = solver()
    for _ in range(policies):
        sampled.random_policy()
    tensors, state = snapshot(*sampled.state_dict())
    assert state["policies"] == policies and (state["policy"] is None) == (policies == 0)
    restored = solver()
    restored.load_state_dict((tensors, state))
    assert len(restored.policies) == policies
    for a, b in zip(restored.policies, sampled.policies, strict=True):
        for name, tensor in a.state_dict().items():
            assert torch.equal(tensor, b.state_dict()[name]), name


def test_feature_scales_of_a_box_of_any_shape_are_one_per_coordinate() -> None:
    grid = gym.spaces.Box(
        np.array([[-2.0, 0.0], [-np.inf, -1.0]], dtype=np.float32), np.array([[2.0, 3.0], [np.inf, 0.5]], dtype=np.float32)
    )
    scales = box_feature_scales(grid, np.zeros((0, 2, 2), dtype=np.float32))
    assert scales.tolist() == [2.0, 3.0, np.inf, 1.0]
    unbounded = gym.spaces.Box(-np.inf, np.inf, (2, 2), np.float32)
    # No coordinate bounded and no observations to measure: every scale is the floor 1e-3.
    assert box_feature_scales(unbounded, np.zeros((0, 2, 2), dtype=np.float32)).tolist() == [1e-3] * 4
    seen = np.array([[[1.0, -2.0], [0.0, 0.5]], [[-3.0, 1.0], [0.0, 0.25]]], dtype=np.float32)
    assert box_feature_scales(unbounded, seen).tolist() == pytest.approx([3.0, 2.0, 1e-3, 0.5])

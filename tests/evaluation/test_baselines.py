"""The trivial baselines beside a BC result are scored as the notes define them: a constant
Gaussian (or class frequencies), the episode's previous action, the current state; and they
apply only where they make sense."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch

from imitation.data.loader import TransitionTensors
from imitation.evaluation.baselines import MIN_STD, baseline_scores, policy_scores
from imitation.policies import make_policy


def tensors(observations: np.ndarray, actions: np.ndarray, episodes: np.ndarray) -> TransitionTensors:
    n = len(actions)
    return TransitionTensors(
        observations=torch.as_tensor(observations), actions=torch.as_tensor(actions), rewards=torch.zeros(n, dtype=torch.float64),
        next_observations=None, terminated=torch.zeros(n, dtype=torch.bool), truncated=torch.zeros(n, dtype=torch.bool),
        episode_index=torch.as_tensor(episodes),
    )


def gaussian_nll(residuals: np.ndarray, std: np.ndarray) -> float:
    return float(np.mean(np.sum(0.5 * (residuals / std) ** 2 + np.log(std) + 0.5 * math.log(2 * math.pi), axis=-1)))


def test_constant_hold_and_copy_state_are_the_closed_forms() -> None:
    rng = np.random.default_rng(0)
    train_actions = rng.normal(size=(40, 2))
    train_states = train_actions + rng.normal(scale=0.1, size=(40, 2))
    held_actions = rng.normal(size=(10, 2))
    held_states = held_actions + 0.5
    train = tensors(train_states, train_actions, np.repeat([0, 1], 20))
    held = tensors(held_states, held_actions, np.repeat([2, 3], 5))
    scores = baseline_scores(train, held, gym.spaces.Box(-np.inf, np.inf, (2,)))

    mean, std = train_actions.mean(0), train_actions.std(0)
    assert scores["constant"]["nll"] == pytest.approx(gaussian_nll(held_actions - mean, std))
    assert scores["constant"]["mse"] == pytest.approx(np.mean(np.sum((held_actions - mean) ** 2, -1)))

    # hold: a_{t-1} within the episode; each episode's first step falls back to the training mean
    previous = np.vstack([mean, held_actions[:4], mean, held_actions[5:9]])
    train_previous = np.vstack([mean, train_actions[:19], mean, train_actions[20:39]])
    hold_std = (train_actions - train_previous).std(0)
    assert scores["hold"]["nll"] == pytest.approx(gaussian_nll(held_actions - previous, hold_std))
    assert scores["hold"]["mse"] == pytest.approx(np.mean(np.sum((held_actions - previous) ** 2, -1)))

    copy_std = (train_actions - train_states).std(0)
    assert scores["copy_state"]["nll"] == pytest.approx(gaussian_nll(held_actions - held_states, copy_std))
    assert scores["copy_state"]["mse"] == pytest.approx(0.5)  # 0.5² on each of 2 dims


def test_copy_state_needs_one_shape_and_a_still_dimension_gets_the_floor() -> None:
    train = tensors(np.zeros((10, 3)), np.zeros((10, 2)), np.zeros(10, dtype=np.int64))
    held = tensors(np.zeros((4, 3)), np.full((4, 2), 1.0), np.zeros(4, dtype=np.int64))
    scores = baseline_scores(train, held, gym.spaces.Box(-np.inf, np.inf, (2,)))
    assert set(scores) == {"constant", "hold"}
    assert np.isfinite(scores["constant"]["nll"]) and scores["constant"]["nll"] == pytest.approx(gaussian_nll(np.ones((4, 2)), np.full(2, MIN_STD)))


def test_discrete_actions_get_class_frequencies() -> None:
    space = gym.spaces.Discrete(3, start=1)
    train = tensors(np.zeros((6, 1)), np.array([1, 1, 1, 2, 2, 3]), np.zeros(6, dtype=np.int64))
    held = tensors(np.zeros((2, 1)), np.array([1, 3]), np.zeros(2, dtype=np.int64))
    scores = baseline_scores(train, held, space)
    frequencies = np.array([4, 3, 2]) / 9  # add-one counts of classes 1, 2, 3
    assert scores == {"constant": {"nll": pytest.approx(-(np.log(frequencies[0]) + np.log(frequencies[2])) / 2), "error_rate": 0.5}}


def test_the_policy_is_scored_as_the_baselines_are() -> None:
    space = gym.spaces.Box(-10, 10, (2,), np.float32)
    policy = make_policy(gym.spaces.Box(-1, 1, (3,), np.float32), space, hidden_sizes=[])
    held = tensors(np.zeros((5, 3), np.float32), np.ones((5, 2), np.float32), np.zeros(5, dtype=np.int64))
    with torch.no_grad():
        policy.action_head.weight.zero_()
        policy.action_head.bias.fill_(0.5)
        policy.log_std.fill_(math.log(2.0))
    scores = policy_scores(policy, held)
    assert scores["mse"] == pytest.approx(2 * 0.25)
    assert scores["nll"] == pytest.approx(gaussian_nll(np.full((5, 2), 0.5), np.full(2, 2.0)), rel=1e-6)

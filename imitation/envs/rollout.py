"""Rollouts: one episode of a policy (the loop that recording and evaluation share), and the
batch of vector-env steps that on-policy learners and learned rewards share (`Rollout`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np
import torch

Policy = Callable[[Any], Any]


@runtime_checkable
class Episodic(Protocol):
    """A policy that keeps something of the episode so far (a history of observations, a chunk of
    planned actions), forgotten by `reset` when the next one starts."""

    def reset(self) -> None: ...


def start_episode(policy: Policy | None) -> None:
    """Tell `policy` a new episode starts, where it keeps anything between steps."""
    if isinstance(policy, Episodic):
        policy.reset()


@dataclass
class Rollout:
    """n_steps steps of n_envs environments, (T, n_envs) leading dims, as the environments saw
    them: what a learned reward needs to relabel it (`next_observations` holds the true final
    state where an episode ended) and what importance weights need (`log_probs`, log π_k(a_t|s_t)
    of the sampled actions). `actions` are the policy's (class indices for categorical heads),
    `env_actions` what the environments were given."""

    observations: torch.Tensor
    actions: torch.Tensor
    env_actions: torch.Tensor
    next_observations: torch.Tensor
    log_probs: torch.Tensor
    env_rewards: torch.Tensor
    terminated: torch.Tensor
    truncated: torch.Tensor

    def cpu_copy(self) -> Rollout:
        """A copy on the CPU, for what outlives the rollout: PPO refills its buffers in place
        (on its own device) with the next one."""
        return Rollout(**{name: _cpu_copy(getattr(self, name)) for name in Rollout.__dataclass_fields__})


def _cpu_copy(tree: Any) -> Any:
    """A tensor, or a dict of them (Dict observations), copied to the CPU."""
    if isinstance(tree, dict):
        return {key: _cpu_copy(value) for key, value in tree.items()}
    return tree.to("cpu", copy=True)


def play_episode(
    env: gym.Env, policy: Policy, *, seed: int | None, on_info: Callable[[dict[str, Any]], None] | None = None
) -> tuple[float, int]:
    """Reset with `seed`, act with `policy` until the episode ends; its return and length.
    `on_info` sees each step's info."""
    observation, _ = env.reset(seed=seed)
    start_episode(policy)
    episode_return, length, done = 0.0, 0, False
    while not done:
        observation, reward, terminated, truncated, info = env.step(policy(observation))
        if on_info is not None:
            on_info(info)
        episode_return += float(reward)
        length += 1
        done = terminated or truncated
    return episode_return, length


def collect_transitions(
    env: gym.Env, policy: Policy, *, episodes: int, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(s, a, s', r) of every step of `episodes` episodes (episode i reset with seed `seed + i`),
    r the env's reward as float64."""
    observations, actions, next_observations, rewards = [], [], [], []
    for i in range(episodes):
        observation, _ = env.reset(seed=seed + i)
        start_episode(policy)
        done = False
        while not done:
            action = policy(observation)
            next_observation, reward, terminated, truncated, _ = env.step(action)
            observations.append(observation)
            actions.append(action)
            next_observations.append(next_observation)
            rewards.append(float(reward))
            observation, done = next_observation, terminated or truncated
    return np.asarray(observations), np.asarray(actions), np.asarray(next_observations), np.asarray(rewards)

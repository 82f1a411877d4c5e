"""The previous action as an input: a policy of (s_t, a_{t-1}) rather than of s_t alone.

For actions that are a command stream (a teleoperator's joint targets or velocity command at
30 Hz), the command just sent carries what the state alone does not: where the operator is
heading. A policy conditioned on it sees

    x_t = [ s_t , a_{t-1} , 1{t = 0} ]        with a_{-1} = 0,

the observation flattened, the previous action flattened, and a flag that marks an episode's
first step (where there is no previous action, and the zeros mean nothing). Offline the column is
built from the demos (`with_previous_actions`); in an environment `PreviousActionObservation`
builds the same input from the actions the environment received, so a policy trained on
recordings acts in a simulator unchanged.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np


def previous_action_space(observation_space: gym.Space, action_space: gym.Space) -> gym.spaces.Box:
    """The space of x_t for Box observations and Box actions."""
    if not isinstance(observation_space, gym.spaces.Box) or not isinstance(action_space, gym.spaces.Box):
        raise TypeError(
            "the previous action is an input for Box observations and Box actions, not "
            f"{type(observation_space).__name__} and {type(action_space).__name__}"
        )
    low = np.concatenate([observation_space.low.reshape(-1), action_space.low.reshape(-1), [0.0]])
    high = np.concatenate([observation_space.high.reshape(-1), action_space.high.reshape(-1), [1.0]])
    # zeros stand for the missing a_{-1}, so they must lie in the space even where the actions' bounds exclude 0
    low[observation_space.low.size : -1] = np.minimum(low[observation_space.low.size : -1], 0.0)
    high[observation_space.low.size : -1] = np.maximum(high[observation_space.low.size : -1], 0.0)
    return gym.spaces.Box(low.astype(np.float64), high.astype(np.float64), dtype=np.float64)


def previous_actions(actions: np.ndarray, episode_index: np.ndarray, first: Any = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """a_{t-1} of the same episode for every row (rows in episode and time order; `first` where
    there is none), and the mask of the rows that start an episode."""
    previous = np.empty_like(actions)
    previous[1:] = actions[:-1]
    starts = np.ones(len(actions), dtype=bool)
    starts[1:] = episode_index[1:] != episode_index[:-1]
    previous[starts] = first
    return previous, starts


def with_previous_actions(observations: np.ndarray, actions: np.ndarray, episode_index: np.ndarray) -> np.ndarray:
    """x_t for every row of a recording (rows in episode and time order), in float64: the
    observations' own precision is kept."""
    flat_actions = actions.reshape(len(actions), -1)
    previous, starts = previous_actions(flat_actions, episode_index)
    return np.concatenate([observations.reshape(len(observations), -1), previous, starts[:, None]], axis=1, dtype=np.float64)


class PreviousActionObservation(gym.Wrapper):
    """An environment whose observations are x_t: the wrapped one's, the action it received last
    (zeros after a reset) and the first-step flag."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.observation_space = previous_action_space(env.observation_space, env.action_space)
        self._previous = np.zeros(int(np.prod(env.action_space.shape or ())), dtype=np.float64)

    def _input(self, observation: Any, first: bool) -> np.ndarray:
        return np.concatenate([np.asarray(observation, dtype=np.float64).reshape(-1), self._previous, [float(first)]])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        observation, info = self.env.reset(seed=seed, options=options)
        self._previous = np.zeros_like(self._previous)
        return self._input(observation, True), info

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        self._previous = np.asarray(action, dtype=np.float64).reshape(-1)
        return self._input(observation, False), reward, terminated, truncated, info

"""The true reward R(s, a, s') of an environment as a batched function, for judging learned rewards.

`eval reward` compares a recovered reward with the env's own, so it needs the env's reward as
a function of transitions rather than as something `step` returns: each entry below restates
the env's reward in terms of its observations, and a test checks it against `step` on real
rollouts. Envs not listed have no known reward function (EPIC is then not computed).
"""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np

from imitation.envs.tabular import TabularEnv

RewardFn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def _pendulum(observations: np.ndarray, actions: np.ndarray, next_observations: np.ndarray) -> np.ndarray:
    """−(θ² + 0.1·θ̇² + 0.001·u²) at the state the torque is applied in, θ normalised to [−π, π)
    and u clipped to the torque limit (Pendulum-v1's `step`)."""
    theta = np.arctan2(observations[:, 1], observations[:, 0])
    torque = np.clip(np.asarray(actions, dtype=np.float64).reshape(len(observations), -1)[:, 0], -2.0, 2.0)
    return -(theta**2 + 0.1 * observations[:, 2] ** 2 + 0.001 * torque**2)


def _cartpole_fixed_horizon(observations: np.ndarray, actions: np.ndarray, next_observations: np.ndarray) -> np.ndarray:
    """+1 for a step that leaves the pole within CartPole-v1's limits, i.e. 1 − failed(s'). The
    flag is 0 or 1 on every reachable state; between them (uniform coverage samples of the
    observation box) the reward is taken as linear in it."""
    return 1.0 - next_observations[:, 4].astype(np.float64)


def _constant(value: float) -> RewardFn:
    def reward(observations: np.ndarray, actions: np.ndarray, next_observations: np.ndarray) -> np.ndarray:
        return np.full(len(observations), value)

    return reward


_KNOWN: dict[str, RewardFn] = {
    "Pendulum-v1": _pendulum,
    "imitation/CartPoleFixedHorizon-v0": _cartpole_fixed_horizon,
    "CartPole-v1": _constant(1.0),
    "MountainCar-v0": _constant(-1.0),
}


def true_reward(env_id: str, env: gym.Env) -> RewardFn | None:
    """The env's reward as a batched R(s, a, s'), or None when it is not known.

    Tabular envs pay r(s_t) for the state a step starts in."""
    if env_id in _KNOWN:
        return _KNOWN[env_id]
    if not isinstance(env.unwrapped, TabularEnv):
        return None
    state_reward = np.asarray(env.unwrapped.mdp.reward, dtype=np.float64)

    def tabular(observations: np.ndarray, actions: np.ndarray, next_observations: np.ndarray) -> np.ndarray:
        return state_reward[np.asarray(observations, dtype=np.int64).reshape(-1)]

    return tabular

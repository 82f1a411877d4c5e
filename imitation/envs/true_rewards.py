"""The true reward R(s, a, s') of an environment as a batched function, for judging learned rewards.

`eval reward` compares a recovered reward with the env's own, so it needs the env's reward as
a function of transitions rather than as something `step` returns: each entry below restates
the env's reward in terms of its observations, and a test checks it against `step` on real
rollouts. Envs not listed have no known reward function (EPIC is then not computed).

The fixed-horizon MuJoCo tasks pay the forward speed (x(s') − x(s))/dt, and their observations
leave out x (gymnasium's default, which the zoo's experts were trained on). Each observation
holds the x velocity at its instant, so the speed over the step is estimated by the trapezoid
rule from both ends, (ẋ(s) + ẋ(s'))/2: exact for a constant acceleration within the step, off
by what contacts add inside it. Every other term (control and contact costs, the healthy
bonus) is exact. EPIC against such a reward measures the recovered reward's distance from this
estimate, which the test of this module bounds against the env's own speed.
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


def _locomotion(
    speed_index: int,
    control_weight: float,
    healthy: Callable[[np.ndarray], np.ndarray] | None = None,
    contact_forces: slice | None = None,
    contact_weight: float = 0.0,
) -> RewardFn:
    """A gymnasium v5 locomotion reward: ẋ − w_c‖a‖² (+ 1 while healthy(s'), − w_f‖F(s')‖²), with
    ẋ the trapezoid estimate above from observation index `speed_index`, F the clipped contact
    forces the observation holds at `contact_forces`."""

    def reward(observations: np.ndarray, actions: np.ndarray, next_observations: np.ndarray) -> np.ndarray:
        before, after = np.asarray(observations, np.float64), np.asarray(next_observations, np.float64)
        speed = 0.5 * (before[:, speed_index] + after[:, speed_index])
        controls = np.asarray(actions, dtype=np.float64).reshape(len(before), -1)
        total = speed - control_weight * np.sum(controls**2, axis=1)
        if healthy is not None:
            total += healthy(after)
        if contact_forces is not None:
            total -= contact_weight * np.sum(after[:, contact_forces] ** 2, axis=1)
        return total

    return reward


def _hopper_healthy(observations: np.ndarray) -> np.ndarray:
    """Hopper-v5: height z > 0.7, torso angle in (−0.2, 0.2), every observation after z within
    (−100, 100) (the env checks its unclipped velocities; the observation's are clipped to ±10)."""
    z, angle, rest = observations[:, 0], observations[:, 1], observations[:, 1:]
    return ((z > 0.7) & (np.abs(angle) < 0.2) & np.all(np.abs(rest) < 100.0, axis=1)).astype(np.float64)


def _walker_healthy(observations: np.ndarray) -> np.ndarray:
    """Walker2d-v5: height z in (0.8, 2), torso angle in (−1, 1)."""
    z, angle = observations[:, 0], observations[:, 1]
    return ((z > 0.8) & (z < 2.0) & (np.abs(angle) < 1.0)).astype(np.float64)


def _ant_healthy(observations: np.ndarray) -> np.ndarray:
    """Ant-v5: a finite state with the torso's height z in [0.2, 1]."""
    z = observations[:, 0]
    return (np.all(np.isfinite(observations), axis=1) & (z >= 0.2) & (z <= 1.0)).astype(np.float64)


def _constant(value: float) -> RewardFn:
    def reward(observations: np.ndarray, actions: np.ndarray, next_observations: np.ndarray) -> np.ndarray:
        return np.full(len(observations), value)

    return reward


def _known_rewards() -> dict[str, RewardFn]:
    """The listed envs' rewards by id. Built on each lookup (a few closures) rather than once at
    import, so that the reward `true_reward` returns is made by the code as it is at call time:
    mutation testing swaps functions in at run time, and a closure built at import would escape it."""
    return {
        "Pendulum-v1": _pendulum,
        "imitation/CartPoleFixedHorizon-v0": _cartpole_fixed_horizon,
        "CartPole-v1": _constant(1.0),
        "MountainCar-v0": _constant(-1.0),
        "imitation/HalfCheetahFixedHorizon-v0": _locomotion(8, control_weight=0.1),
        "imitation/HopperFixedHorizon-v0": _locomotion(5, control_weight=1e-3, healthy=_hopper_healthy),
        "imitation/Walker2dFixedHorizon-v0": _locomotion(8, control_weight=1e-3, healthy=_walker_healthy),
        "imitation/SwimmerFixedHorizon-v0": _locomotion(3, control_weight=1e-4),
        "imitation/AntFixedHorizon-v0": _locomotion(
            13, control_weight=0.5, healthy=_ant_healthy, contact_forces=slice(27, None), contact_weight=5e-4
        ),
    }


def true_reward(env_id: str, env: gym.Env) -> RewardFn | None:
    """The env's reward as a batched R(s, a, s'), or None when it is not known.

    Tabular envs pay r(s_t) for the state a step starts in."""
    known = _known_rewards()
    if env_id in known:
        return known[env_id]
    if not isinstance(env.unwrapped, TabularEnv):
        return None
    state_reward = np.asarray(env.unwrapped.mdp.reward, dtype=np.float64)

    def tabular(observations: np.ndarray, actions: np.ndarray, next_observations: np.ndarray) -> np.ndarray:
        return state_reward[np.asarray(observations, dtype=np.int64).reshape(-1)]

    return tabular

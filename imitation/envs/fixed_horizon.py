"""Fixed-horizon variants of early-terminating control tasks, for judging learned rewards.

When an episode ends as soon as the agent fails, any positive constant reward teaches it to
avoid failing: the termination signal carries the task. IRL evaluations therefore run on
variants where every episode lasts exactly the horizon, nothing terminates, and the true reward
is only paid while the task's success condition holds.

Failure leads to an absorbing state, marked by an indicator in the observation, as
Kostrikov et al. (2019, "Discriminator-actor-critic") treat terminal states in adversarial
imitation: the system freezes where it failed and stays there, earning 0, until the horizon.
Unlike a termination this pays a constant reward the same either way, so it leaks nothing; and
the learned reward gets to judge "having failed" as one thing, which it must learn from the
demos never doing it, instead of extrapolating to every pose a falling pole can take, which PPO
retrained on the reward would learn to fall into (bench/RESULTS.md, "Maximum-entropy IRL").
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium.envs.classic_control.cartpole import CartPoleEnv

CARTPOLE_HORIZON = 500
MUJOCO_HORIZON = 1000

# gymnasium v5 locomotion tasks as seals has them: nothing terminates (a fallen Hopper, Walker or
# Ant lies where it fell, and the healthy bonus stops), every episode lasts 1000 steps.
# Observations are v5's own, the layout rl-baselines3-zoo's v3 experts were trained on (seals adds
# the x position, which no zoo expert reads); v5's dynamics differ from v3's only by small fixes.
MUJOCO_FIXED_HORIZON: dict[str, dict[str, Any]] = {
    f"imitation/{name}FixedHorizon-v0": dict(
        entry_point=f"gymnasium.envs.mujoco.{module}_v5:{name}Env",
        max_episode_steps=MUJOCO_HORIZON,
        kwargs={"terminate_when_unhealthy": False} if unhealthy else {},
    )
    for name, module, unhealthy in [
        ("HalfCheetah", "half_cheetah", False),
        ("Hopper", "hopper", True),
        ("Walker2d", "walker2d", True),
        ("Swimmer", "swimmer", False),
        ("Ant", "ant", True),
    ]
}


class CartPoleFixedHorizon(CartPoleEnv):
    """CartPole-v1 without termination: observations (x, ẋ, θ, θ̇, failed); reward +1 for a step
    that leaves the pole within CartPole-v1's limits (|x| ≤ 2.4, |θ| ≤ 12°); the first step past
    them freezes the state with failed = 1, which then repeats with reward 0 until the 500-step
    time limit (set at registration)."""

    def __init__(self, render_mode: str | None = None) -> None:
        super().__init__(render_mode=render_mode)
        assert isinstance(self.observation_space, gym.spaces.Box)  # CartPole's
        low, high = self.observation_space.low, self.observation_space.high
        self.observation_space = gym.spaces.Box(
            np.append(low, np.float32(0.0)), np.append(high, np.float32(1.0)), dtype=np.float32
        )
        self.failed_observation: np.ndarray | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        self.failed_observation = None
        observation, info = super().reset(seed=seed, options=options)
        return np.append(observation, np.float32(0.0)), info

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        if self.failed_observation is not None:
            return self.failed_observation.copy(), 0.0, False, False, {}
        observation, _, failed, truncated, info = super().step(action)
        if failed:
            self.failed_observation = np.append(observation, np.float32(1.0))
            return self.failed_observation.copy(), 0.0, False, truncated, info
        return np.append(observation, np.float32(0.0)), 1.0, False, truncated, info

"""Noise injected under an expert's actions while its demos are recorded (DART; Laskey et al. 2017).

With probability ε the environment executes a uniformly random action a ~ U(A) instead of the
action it was given; a recorder wrapped around this env still stores the given action, the
expert's label. The demos then cover the states just off the expert's path, where a cloned
policy ends up after its first mistakes, each labelled with what the expert would do there:

    s_{t+1} ~ P(· | s_t, ã_t),   ã_t = a ~ U(A) with probability ε, else π*(s_t);   stored: (s_t, π*(s_t)).
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np


class ActionNoise(gym.Wrapper):
    """Execute a uniformly random action with probability `epsilon`, seeded with `seed`."""

    def __init__(self, env: gym.Env, epsilon: float, *, seed: int) -> None:
        super().__init__(env)
        if not 0.0 <= epsilon <= 1.0:
            raise ValueError(f"the action noise is a probability in [0, 1], got {epsilon}")
        self.epsilon = epsilon
        self.rng = np.random.default_rng(seed)
        self.action_space.seed(seed)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        if self.rng.random() < self.epsilon:
            action = self.action_space.sample()
        return self.env.step(action)

"""Noise injected under an expert's actions while its demos are recorded (DART; Laskey et al. 2017).

With probability ε the environment executes a random action instead of the action it was given;
a recorder wrapped around this env still stores the given action, the expert's label. The demos
then cover the states just off the expert's path, where a cloned policy ends up after its first
mistakes, each labelled with what the expert would do there:

    s_{t+1} ~ P(· | s_t, ã_t),   stored: (s_t, π*(s_t)),
    ã_t = b with probability εβ,   a ~ U(A) with probability ε(1 − β),   π*(s_t) otherwise,

where b ~ U(A) is drawn once per episode. Uniform noise (β = 0) has mean zero and the expert undoes
it within a few steps, so the demos stay close to the expert's own path. A bias β > 0 gives the
noise a mean: the expert is recorded fighting a steady push, in the drifted states (a balancing
cart held off centre, moving) that a clone with a small bias of its own drifts into.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np


class ActionNoise(gym.Wrapper):
    """Execute a random action with probability `epsilon`: the episode's own action b with probability
    `bias`, else a uniform one; seeded with `seed`."""

    def __init__(self, env: gym.Env, epsilon: float, *, seed: int, bias: float = 0.0) -> None:
        super().__init__(env)
        if not 0.0 <= epsilon <= 1.0:
            raise ValueError(f"the action noise is a probability in [0, 1], got {epsilon}")
        if not 0.0 <= bias <= 1.0:
            raise ValueError(f"the noise bias is a probability in [0, 1], got {bias}")
        self.epsilon = epsilon
        self.bias = bias
        self.rng = np.random.default_rng(seed)
        self.action_space.seed(seed)
        self.episode_action: Any = None

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        if self.bias > 0:
            self.episode_action = self.action_space.sample()
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        if self.rng.random() < self.epsilon:
            biased = self.bias > 0 and self.rng.random() < self.bias
            action = self.episode_action if biased else self.action_space.sample()
        return self.env.step(action)

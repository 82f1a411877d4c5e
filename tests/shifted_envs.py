"""Environments whose discrete actions do not start at 0, for tests through the CLI:
`--env shifted_envs:ShiftedDiscrete-v0` makes gymnasium import this module (tests/ must be on
PYTHONPATH), which registers them.

Each step shows targets one-hot and pays 1 for each action component that names its target,
so only a policy that maps class indices to env actions (index + start) and back scores the
full EPISODE_STEPS per component; a policy off by one scores 0 on that component."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

EPISODE_STEPS = 20


class ShiftedTargets(gym.Env):
    """Targets t_i ∈ {0 … n_i - 1}; the right action component is a_i = t_i + start_i."""

    def __init__(self, sizes: tuple[int, ...], starts: tuple[int, ...], multi: bool) -> None:
        self.sizes, self.starts = np.asarray(sizes), np.asarray(starts)
        self.observation_space = gym.spaces.Box(0.0, 1.0, (int(self.sizes.sum()),), np.float32)
        self.action_space = gym.spaces.MultiDiscrete(self.sizes, start=self.starts) if multi else gym.spaces.Discrete(int(sizes[0]), start=int(starts[0]))
        self.targets = np.zeros(len(sizes), np.int64)
        self.t = 0

    def _observe(self) -> np.ndarray:
        self.targets = np.array([self.np_random.integers(n) for n in self.sizes])
        observation = np.zeros(self.observation_space.shape, np.float32)
        observation[np.concatenate([[0], np.cumsum(self.sizes)[:-1]]) + self.targets] = 1.0
        return observation

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.t = 0
        return self._observe(), {}

    def step(self, action):
        reward = float((np.atleast_1d(action) == self.targets + self.starts).sum())
        self.t += 1
        return self._observe(), reward, False, self.t >= EPISODE_STEPS, {}


gym.register("ShiftedDiscrete-v0", entry_point=ShiftedTargets, kwargs={"sizes": (3,), "starts": (1,), "multi": False})
gym.register("ShiftedMultiDiscrete-v0", entry_point=ShiftedTargets, kwargs={"sizes": (3, 2), "starts": (1, -1), "multi": True})

"""Environments that go wrong on purpose, for tests through the CLI: `--env nan_envs:NaNObservation-v0`
makes gymnasium import this module (tests/ must be on PYTHONPATH), which registers them.

Each copy counts its own step() calls across episodes (episodes last 50 steps) and returns a NaN
observation, a NaN reward, or a NaN final observation (the last of an episode) on a known call,
so where it happens is known exactly."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

BAD_CALL = 290  # step 40 of episode 5 (episodes last 50 steps)
EPISODE_STEPS = 50


class GoesNaN(gym.Env):
    observation_space = gym.spaces.Box(-1.0, 1.0, (4,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def __init__(self, what: str = "observation", bad_call: int = BAD_CALL) -> None:
        self.what = what
        self.bad_call = bad_call
        self.calls = 0
        self.t = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.t = 0
        return self.np_random.uniform(-0.1, 0.1, 4).astype(np.float32), {}

    def step(self, action):
        self.calls += 1
        self.t += 1
        observation = self.np_random.uniform(-0.1, 0.1, 4).astype(np.float32)
        reward = 1.0 if action == 1 else 0.0
        if self.calls == self.bad_call:
            if self.what == "observation":
                observation[2] = np.nan
            else:
                reward = float("nan")
        return observation, reward, False, self.t >= EPISODE_STEPS, {}


gym.register("NaNObservation-v0", entry_point=GoesNaN, kwargs={"what": "observation"})
gym.register("NaNReward-v0", entry_point=GoesNaN, kwargs={"what": "reward"})
gym.register("NaNFinalObservation-v0", entry_point=GoesNaN, kwargs={"what": "observation", "bad_call": 300})  # step 50 of episode 5

"""Record episodes of a gymnasium environment into an MCAP demo file as they finish.

`RecordEpisodes` wraps an env and hands every finished episode to a `DemoWriter`. With a
durable writer (the default of `record_demos`) each episode is on disk as soon as it ends, so a
crash or `kill -9` loses at most the episode in progress.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from imitation.data.mcap.writer import DemoWriter
from imitation.data.types import Episode, stack_samples
from imitation.envs.rollout import Policy, play_episode
from imitation.progress import progress_bar


class RecordEpisodes(gym.Wrapper):
    """Buffers the current episode and writes it when it terminates or is truncated.

    An episode abandoned by calling `reset()` before it ended is discarded: it is neither a
    terminal nor a time-limit ending, so it would mislabel its last state.
    """

    def __init__(self, env: gym.Env, writer: DemoWriter, *, record_infos: bool = False) -> None:
        super().__init__(env)
        self.writer = writer
        self.record_infos = record_infos
        self._observations: list[Any] = []
        self._actions: list[Any] = []
        self._rewards: list[float] = []
        self._infos: list[dict[str, Any]] = []
        self._metadata: dict[str, Any] = {}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        observation, info = self.env.reset(seed=seed, options=options)
        self._observations = [observation]
        self._actions, self._rewards, self._infos = [], [], []
        self._metadata = {"seed": seed}
        return observation, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        if not self._observations:
            raise RuntimeError("call reset() before step()")
        observation, reward, terminated, truncated, info = self.env.step(action)
        self._observations.append(observation)
        self._actions.append(action)
        self._rewards.append(float(reward))
        if self.record_infos:
            self._infos.append(info)
        if terminated or truncated:
            self.writer.write(
                Episode(
                    observations=stack_samples(self._observations, self.observation_space),
                    actions=stack_samples(self._actions, self.action_space),
                    rewards=np.asarray(self._rewards, dtype=np.float64),
                    terminated=bool(terminated),
                    truncated=bool(truncated) and not terminated,
                    infos=self._infos if self.record_infos else None,
                    metadata=self._metadata,
                )
            )
            self._observations = []
        return observation, reward, terminated, truncated, info


def run_episodes(
    env: RecordEpisodes,
    policy: Policy,
    *,
    episodes: int,
    seed: int,
    progress: bool = True,
) -> list[float]:
    """Run `episodes` episodes of `policy`, episode i reset with seed `seed + i`; their returns."""
    returns: list[float] = []
    with progress_bar(total=episodes, desc="recording", unit="episode", enabled=progress) as bar:
        for i in range(episodes):
            episode_return, _ = play_episode(env, policy, seed=seed + i)
            returns.append(episode_return)
            bar.set_postfix({"ret": f"{episode_return:.1f}", "mean": f"{np.mean(returns):.1f}"})
            bar.update()
    return returns

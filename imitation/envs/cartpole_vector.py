"""CartPole stepped by gymnasium's own vectorised implementation (`CartPoleVectorEnv`: every copy
in one numpy step), presented as PPO's other vector envs are (`SyncVectorEnv` with
`RecordEpisodeStatistics`): same-step autoreset, each ended episode's true final observation in
info["final_obs"] and its return and length in info["final_info"]["episode"].

gymnasium ships it with next-step autoreset, where the step after an episode ends resets that
copy and ignores its action. Here the copy is reset at once instead, so every step of a rollout
is a transition. Each copy draws its starts from its own generator, seeded as SyncVectorEnv
seeds its envs, so a seed gives the episodes the single-env CartPoles give.
That reaches into `CartPoleVectorEnv`'s state arrays (state, steps, prev_done);
tests/envs/test_cartpole_vector.py checks it step for step against gymnasium's single-env
CartPole."""

from __future__ import annotations

import time
from typing import Any, cast

import gymnasium as gym
import numpy as np
from gymnasium.envs.classic_control.cartpole import CartPoleVectorEnv
from gymnasium.utils import seeding

VECTORISED_CARTPOLES = ("CartPole-v0", "CartPole-v1")


class SameStepCartPole(gym.vector.VectorWrapper):
    """`n_envs` copies of `env_id` (one of VECTORISED_CARTPOLES) in one CartPoleVectorEnv, reset
    on the step their episode ends."""

    def __init__(self, env_id: str, n_envs: int) -> None:
        if env_id not in VECTORISED_CARTPOLES:
            raise ValueError(f"{env_id} is not one of {VECTORISED_CARTPOLES}")
        super().__init__(gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point"))
        cartpole = self.env.unwrapped
        assert isinstance(cartpole, CartPoleVectorEnv)
        self.cartpole: CartPoleVectorEnv = cartpole
        self.metadata = {**self.env.metadata, "autoreset_mode": gym.vector.AutoresetMode.SAME_STEP}
        self.returns = np.zeros(n_envs)
        self.lengths = np.zeros(n_envs, dtype=np.int64)
        self.started = np.zeros(n_envs)
        self.generators: list[np.random.Generator | None] = [None] * n_envs

    def reset(
        self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """Copy i starts from its own generator, seeded `seed + i` as SyncVectorEnv seeds its
        envs, so that a seed gives the same episodes as the single-env CartPoles would."""
        seeds: list[int | None] = [None] * self.num_envs
        if isinstance(seed, int):
            seeds = [seed + i for i in range(self.num_envs)]
        elif seed is not None:
            seeds = list(seed)
        _, info = self.env.reset(options=options)  # the reset bounds, the step counters
        for i, value in enumerate(seeds):
            if value is not None or self.generators[i] is None:
                self.generators[i] = seeding.np_random(value)[0]
        self._draw_starts(np.ones(self.num_envs, dtype=bool))
        self.returns[:], self.lengths[:], self.started[:] = 0.0, 0, time.perf_counter()
        return np.ascontiguousarray(self.states.T, dtype=np.float32), info

    @property
    def states(self) -> np.ndarray:
        """CartPoleVectorEnv's (4, n_envs) state, which its reset has set."""
        return cast(np.ndarray, self.cartpole.state)

    def _draw_starts(self, rows: np.ndarray) -> None:
        """New episodes for `rows`, each copy's start drawn from its own generator, as CartPoleEnv.reset draws it."""
        cartpole = self.cartpole
        for i in np.flatnonzero(rows):
            generator = self.generators[i]
            assert generator is not None  # reset() made one for every copy
            self.states[:, i] = generator.uniform(low=cartpole.low, high=cartpole.high, size=(4,))
        cartpole.steps[rows] = 0
        cartpole.prev_done[rows] = False

    def step(self, actions: Any) -> tuple[Any, Any, Any, Any, dict[str, Any]]:
        observations, rewards, terminated, truncated, _ = self.env.step(actions)
        # Row-major, as SyncVectorEnv's: a transposed array's matmul rounds differently.
        observations = np.ascontiguousarray(observations)
        self.returns += rewards
        self.lengths += 1
        ended = terminated | truncated
        if not ended.any():
            return observations, rewards, terminated, truncated, {}
        final_observations = np.full(self.num_envs, None, dtype=object)
        for i in np.flatnonzero(ended):
            final_observations[i] = observations[i].copy()
        self._draw_starts(ended)
        observations[ended] = self.states[:, ended].T
        now = time.perf_counter()
        episode = {
            "r": np.where(ended, self.returns, 0.0),
            "_r": ended,
            "l": np.where(ended, self.lengths, 0),
            "_l": ended,
            "t": np.where(ended, np.round(now - self.started, 6), 0.0),
            "_t": ended,
        }
        self.returns[ended], self.lengths[ended], self.started[ended] = 0.0, 0, now
        info = {
            "final_obs": final_observations,
            "_final_obs": ended,
            "final_info": {"episode": episode, "_episode": ended},
            "_final_info": ended,
        }
        return observations, rewards, terminated, truncated, info

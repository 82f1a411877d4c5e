"""Vector envs for the on-policy learners and the policy searches: n copies of an env as a policy
observes it (rendered frames, stacked), with same-step autoreset and each episode's return."""

from __future__ import annotations

from typing import Any

import gymnasium as gym

from imitation.envs.cartpole_vector import VECTORISED_CARTPOLES, SameStepCartPole
from imitation.envs.make import make_env
from imitation.envs.pixels import PixelRecipe, StackFrames, make_pixel_env


def make_observed_env(env_id: str, pixels: PixelRecipe | None = None, frame_stack: int = 1) -> gym.Env:
    """env_id as PPO's policy observes it: its rendered frames with `pixels`, the last
    `frame_stack` frames of each image leaf (`StackFrames`) when that is above 1."""
    env = make_pixel_env(env_id, pixels) if pixels is not None else make_env(env_id)
    return StackFrames(env, frame_stack) if frame_stack > 1 else env


def make_vector_env(
    env_id: str,
    n_envs: int,
    *,
    asynchronous: bool = False,
    pixels: PixelRecipe | None = None,
    frame_stack: int = 1,
    vectorised: bool = True,
) -> gym.vector.VectorEnv:
    """n copies of env_id (observed as `make_observed_env` says) with same-step autoreset (the
    final observation comes in info["final_obs"], so truncated episodes can be bootstrapped from
    their true last state), recording each episode's return of the environment's own reward.
    CartPole, which gymnasium vectorises, runs as one numpy env (`SameStepCartPole`) unless
    `vectorised` is False (a caller that resets the copies one by one needs separate envs)."""
    make_observed_env(env_id, pixels, frame_stack).close()  # fail here, with one line, on an unknown id or no images
    if vectorised and env_id in VECTORISED_CARTPOLES and pixels is None and frame_stack == 1 and not asynchronous:
        return SameStepCartPole(env_id, n_envs)

    def factory() -> gym.Env:
        return gym.wrappers.RecordEpisodeStatistics(make_observed_env(env_id, pixels, frame_stack))

    if asynchronous:
        # spawn, not fork: forking a process that already runs torch threads can deadlock.
        return gym.vector.AsyncVectorEnv(
            [factory] * n_envs, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP, context="spawn"
        )
    return gym.vector.SyncVectorEnv([factory] * n_envs, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)


def finished_episode_returns(info: dict[str, Any]) -> list[float]:
    """True returns of the episodes that ended at this vector step."""
    final = info.get("final_info", {})
    if "episode" not in final:
        return []
    episode = final["episode"]
    return [float(r) for r in episode["r"][episode["_r"]]]

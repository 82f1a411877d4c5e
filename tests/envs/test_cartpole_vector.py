"""SameStepCartPole: gymnasium's vectorised CartPole, reset on the step an episode ends, gives
bit for bit what PPO's usual vector env (SyncVectorEnv of CartPole-v1 with RecordEpisodeStatistics,
same-step autoreset) gives from the same seed under the same actions."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from imitation.envs.vector import make_vector_env
from imitation.envs.cartpole_vector import SameStepCartPole

N_ENVS = 6


def _reference(n_envs: int) -> gym.vector.SyncVectorEnv:
    return gym.vector.SyncVectorEnv(
        [lambda: gym.wrappers.RecordEpisodeStatistics(gym.make("CartPole-v1"))] * n_envs,
        autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,
    )


def _actions(observations: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Even copies balance (a pole-angle controller, so some episodes reach the time limit), odd ones act at random."""
    balancing = (observations[:, 2] + 0.5 * observations[:, 3] > 0).astype(np.int64)
    return np.where(np.arange(len(observations)) % 2 == 0, balancing, rng.integers(0, 2, len(observations)))


def test_steps_episode_ends_and_statistics_equal_the_single_env_cartpoles() -> None:
    envs, reference = SameStepCartPole("CartPole-v1", N_ENVS), _reference(N_ENVS)
    rng = np.random.default_rng(0)
    observations, _ = envs.reset(seed=3)
    np.testing.assert_array_equal(observations, reference.reset(seed=3)[0])
    ended_by = {"terminated": 0, "truncated": 0}
    for _ in range(1500):
        actions = _actions(observations, rng)
        observations, rewards, terminated, truncated, info = envs.step(actions)
        expected_observations, expected_rewards, expected_terminated, expected_truncated, expected_info = reference.step(
            actions
        )
        np.testing.assert_array_equal(rewards, expected_rewards)
        np.testing.assert_array_equal(terminated, expected_terminated)
        np.testing.assert_array_equal(truncated, expected_truncated)
        ended = terminated | truncated
        np.testing.assert_array_equal(observations, expected_observations)
        assert observations.flags.c_contiguous  # as SyncVectorEnv's: the policy's matmul rounds by layout
        if not ended.any():
            assert info == {}
            continue
        ended_by["terminated"] += int(terminated.sum())
        ended_by["truncated"] += int((truncated & ~terminated).sum())
        rows = np.flatnonzero(ended)
        for i in rows:
            np.testing.assert_array_equal(info["final_obs"][i], expected_info["final_obs"][i])
        assert all(info["final_obs"][i] is None for i in np.flatnonzero(~ended))
        episode, expected_episode = info["final_info"]["episode"], expected_info["final_info"]["episode"]
        np.testing.assert_array_equal(episode["_r"], expected_episode["_r"])
        np.testing.assert_array_equal(episode["r"][ended], expected_episode["r"][ended])
        np.testing.assert_array_equal(episode["l"][ended], expected_episode["l"][ended])
        assert np.all(np.abs(observations[rows]) <= 0.05)  # the ended copies start afresh at once
    assert ended_by["terminated"] > 10 and ended_by["truncated"] >= 2, ended_by
    envs.close()
    reference.close()


def test_ppo_gets_it_for_cartpole_with_the_single_envs_spaces() -> None:
    envs = make_vector_env("CartPole-v1", 4)
    single = gym.make("CartPole-v1")
    assert isinstance(envs, SameStepCartPole)
    assert envs.metadata["autoreset_mode"] == gym.vector.AutoresetMode.SAME_STEP
    assert envs.single_observation_space == single.observation_space and envs.single_action_space == single.action_space
    envs.close()
    separate = (
        make_vector_env("CartPole-v1", 2, asynchronous=True),
        make_vector_env("CartPole-v1", 2, vectorised=False),
        make_vector_env("Pendulum-v1", 2),
    )
    for others in separate:
        assert not isinstance(others, SameStepCartPole)
        others.close()
    with pytest.raises(ValueError, match="Pendulum-v1 is not one of"):
        SameStepCartPole("Pendulum-v1", 2)

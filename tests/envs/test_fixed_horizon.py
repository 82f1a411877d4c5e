"""The fixed-horizon tasks: CartPole (always 500 steps, +1 while within its limits, absorbing failure) and the
MuJoCo locomotion tasks (always 1000 steps)."""

from __future__ import annotations

import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from support import REPO

import imitation.envs  # noqa: F401  (registers the ids)
from imitation.envs.rollout import play_episode
from imitation.experts.scripted import cartpole

ENV_ID = "imitation/CartPoleFixedHorizon-v0"


def test_a_failing_policy_still_runs_500_steps_and_freezes_after_the_fall() -> None:
    env = gym.make(ENV_ID)
    observation, _ = env.reset(seed=0)
    rewards, observations = [], [observation]
    for _ in range(500):
        observation, reward, terminated, truncated, _ = env.step(1)  # always push right: falls
        assert not terminated
        rewards.append(reward)
        observations.append(observation)
    assert truncated
    fell_at = rewards.index(0.0)
    assert 5 < fell_at < 40 and set(rewards[:fell_at]) == {1.0} and set(rewards[fell_at:]) == {0.0}
    frozen = np.array(observations[fell_at + 1 :])
    assert (frozen == frozen[0]).all() and frozen[0][4] == 1.0
    assert all(o[4] == 0.0 for o in observations[: fell_at + 1])
    assert abs(frozen[0][2]) > 12 * np.pi / 180 or abs(frozen[0][0]) > 2.4


def test_the_scripted_expert_earns_the_full_horizon_and_a_constant_reward_teaches_nothing() -> None:
    env = gym.make(ENV_ID)
    assert play_episode(env, cartpole, seed=1000) == (500.0, 500)
    # Every policy's episode lasts 500 steps, so a constant reward pays them all the same.
    assert play_episode(env, lambda o: 1, seed=1000)[1] == 500


@pytest.mark.parametrize("name", ["HalfCheetah", "Hopper", "Walker2d", "Swimmer", "Ant"])
def test_the_mujoco_tasks_run_1000_steps_and_a_fallen_body_stops_earning_the_healthy_bonus(name: str) -> None:
    env = gym.make(f"imitation/{name}FixedHorizon-v0")
    reference = gym.make(f"{name}-v5")
    assert env.observation_space == reference.observation_space and env.action_space == reference.action_space
    env.reset(seed=0)
    env.action_space.seed(0)
    rewards, unhealthy = [], []
    for step in range(1, 1001):
        _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        assert not terminated and truncated == (step == 1000)
        rewards.append(float(reward))
        unhealthy.append(hasattr(env.unwrapped, "is_healthy") and not env.unwrapped.is_healthy)
    if name in ("Hopper", "Walker2d"):
        # Random torques topple them within the horizon; v5 would have ended the episode there.
        assert any(unhealthy)
        fallen = [r for r, down in zip(rewards, unhealthy) if down]
        upright = [r for r, down in zip(rewards, unhealthy) if not down]
        assert np.mean(upright) - np.mean(fallen) > 0.5  # the healthy bonus of 1 is paid only while healthy


def test_making_halfcheetah_leaves_no_mujoco_log_and_prints_nothing(tmp_path) -> None:
    # gymnasium's HalfCheetah model uses an attribute MuJoCo deprecates; MuJoCo would print that and
    # append it to MUJOCO_LOG.TXT in the working directory, the user's folder.
    code = "import imitation.envs; from imitation.envs.make import make_env; make_env('imitation/HalfCheetahFixedHorizon-v0').reset(seed=0)"
    completed = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert completed.returncode == 0 and "deprecated" not in completed.stderr
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()

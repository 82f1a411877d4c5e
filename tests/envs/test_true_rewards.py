"""The true-reward functions restate each env's `step` reward: checked on real rollouts."""

from __future__ import annotations

import numpy as np
import pytest

import imitation.envs  # noqa: F401 - registers the imitation/ envs
from imitation.envs.make import make_env
from imitation.envs.tabular import TabularEnv, TabularMDP
from imitation.envs.true_rewards import true_reward


def random_steps(env, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[dict]]:
    """s, a, s', r and info of `steps` uniformly random steps from reset(seed=0), reset again after an end."""
    env.action_space.seed(0)
    observations, actions, next_observations, rewards, infos = [], [], [], [], []
    observation, _ = env.reset(seed=0)
    for _ in range(steps):
        action = env.action_space.sample()
        next_observation, step_reward, terminated, truncated, info = env.step(action)
        observations.append(observation)
        actions.append(action)
        next_observations.append(next_observation)
        rewards.append(step_reward)
        infos.append(info)
        observation = next_observation
        if terminated or truncated:
            observation, _ = env.reset()
    return np.array(observations), np.array(actions), np.array(next_observations), np.array(rewards), infos


@pytest.mark.parametrize(
    "env_id",
    ["Pendulum-v1", "imitation/CartPoleFixedHorizon-v0", "CartPole-v1", "MountainCar-v0", "imitation/GridWorld8x8Slippery-v0"],
)
def test_true_reward_matches_the_env_step(env_id: str) -> None:
    env = make_env(env_id)
    reward = true_reward(env_id, env)
    assert reward is not None
    observations, actions, next_observations, rewards, _ = random_steps(env, 300)
    computed = reward(observations, actions, next_observations)
    assert (
        computed.dtype == np.float64 and computed.shape == rewards.shape
    )  # as step pays it, whatever the observations' dtype
    np.testing.assert_allclose(computed, rewards, rtol=1e-5, atol=1e-5)
    if env_id == "imitation/CartPoleFixedHorizon-v0":
        assert 0 < np.mean(rewards) < 1, "the rollout should both balance and fail"


def test_pendulums_torque_is_clipped_to_its_limits_as_the_env_clips_it() -> None:
    """Actions outside [−2, 2] (a learned policy's Gaussian samples) cost what the env charges."""
    env = make_env("Pendulum-v1")
    reward = true_reward("Pendulum-v1", env)
    assert reward is not None
    for torque in (-7.0, -2.5, -2.0, 1.5, 2.5, 9.0):
        observation, _ = env.reset(seed=3)
        next_observation, step_reward, *_ = env.unwrapped.step(np.array([torque], dtype=np.float32))
        got = reward(observation[None], np.array([[torque]], dtype=np.float32), next_observation[None])
        assert got[0] == pytest.approx(step_reward, rel=1e-6), torque


def test_envs_without_a_known_reward_get_none() -> None:
    assert true_reward("Acrobot-v1", make_env("Acrobot-v1")) is None


SPEED_INDEX = {"HalfCheetah": 8, "Hopper": 5, "Walker2d": 8, "Swimmer": 3, "Ant": 13}


@pytest.mark.parametrize("name", list(SPEED_INDEX))
def test_mujoco_true_reward_is_exact_but_for_the_trapezoid_speed(name: str) -> None:
    """Every term but the forward speed is the env's own (so reward − estimated speed equals the
    step's reward − the env's speed), and the trapezoid speed tracks the env's (x' − x)/dt."""
    env_id = f"imitation/{name}FixedHorizon-v0"
    env = make_env(env_id)
    reward = true_reward(env_id, env)
    assert reward is not None
    before, actions, after, rewards, infos = random_steps(env, 300)
    speeds = np.array([info["x_velocity"] for info in infos])
    estimate = 0.5 * (before[:, SPEED_INDEX[name]] + after[:, SPEED_INDEX[name]])
    np.testing.assert_allclose(reward(before, actions, after) - estimate, rewards - speeds, atol=1e-6)
    assert np.corrcoef(estimate, speeds)[0, 1] > 0.95


@pytest.mark.parametrize(
    ("name", "z_index", "z_range", "angle_range"),
    [("Hopper", 1, (0.5, 0.9), (-0.4, 0.4)), ("Walker2d", 1, (0.6, 2.2), (-1.5, 1.5)), ("Ant", 2, (0.1, 1.1), None)],
)
def test_mujoco_healthy_bonus_is_the_envs_own_on_poses_at_its_limits(name, z_index, z_range, angle_range) -> None:
    """Poses set on either side of the height and angle limits: the reward's healthy bonus is 1
    exactly when the env says it is healthy (a random rollout rarely reaches the height limits
    with the torso upright)."""
    env_id = f"imitation/{name}FixedHorizon-v0"
    env = make_env(env_id)
    reward = true_reward(env_id, env)
    assert reward is not None
    env.reset(seed=0)
    model = env.unwrapped
    rng = np.random.default_rng(0)
    expected, bonus = [], []
    for _ in range(200):
        position = model.init_qpos.copy()
        position[z_index] = rng.uniform(*z_range)
        if angle_range is not None:
            position[2] = rng.uniform(*angle_range)
        model.set_state(position, model.init_qvel)
        observation = model._get_obs()[None]
        contact = 5e-4 * np.sum(observation[:, 27:] ** 2) if name == "Ant" else 0.0
        still = np.zeros((1, *env.action_space.shape))
        bonus.append(float(reward(observation, still, observation)[0] - observation[0, SPEED_INDEX[name]] + contact))
        expected.append(float(model.is_healthy))
    np.testing.assert_allclose(bonus, expected, atol=1e-9)
    assert 0 < np.mean(expected) < 1


def test_ants_healthy_bonus_holds_at_both_height_limits_and_is_lost_only_by_a_non_finite_state() -> None:
    """Ant-v5 is healthy with z in [0.2, 1] inclusive and every coordinate finite, state by state:
    a non-finite coordinate in one state costs that state its bonus, not the batch's others."""
    env_id = "imitation/AntFixedHorizon-v0"
    env = make_env(env_id)
    reward = true_reward(env_id, env)
    assert reward is not None
    env.reset(seed=0)
    model = env.unwrapped
    poses = []
    for z in (0.2, 1.0):
        position = model.init_qpos.copy()
        position[2] = z
        model.set_state(position, model.init_qvel)
        assert model.is_healthy
        poses.append(model._get_obs())
    states = np.stack(poses + [poses[0].copy()])
    states[2, 20] = np.nan  # a velocity, not z or the forward speed
    still = np.zeros((3, *env.action_space.shape))
    bonus = reward(states, still, states) - states[:, SPEED_INDEX["Ant"]] + 5e-4 * np.sum(states[:, 27:] ** 2, axis=1)
    assert bonus[:2].tolist() == pytest.approx([1.0, 1.0])


def test_a_tabular_reward_reads_states_given_as_a_column_or_as_floats() -> None:
    env_id = "imitation/GridWorld8x8-v0"
    env = make_env(env_id)
    reward = true_reward(env_id, env)
    assert reward is not None
    expected = np.asarray(env.unwrapped.mdp.reward)[[0, 5, 63]]
    column = np.array([[0], [5], [63]])
    assert reward(column, np.zeros(3), column).tolist() == expected.tolist()
    assert reward(column.astype(np.float32).ravel(), np.zeros(3), column.ravel()).tolist() == expected.tolist()


@pytest.mark.parametrize("state_reward", [np.array([3, -2, 7]), np.array([0.3, -0.2, 0.7], dtype=np.float32)])
def test_a_tabular_reward_is_float64_as_step_pays_it_whatever_the_mdps_dtype(state_reward: np.ndarray) -> None:
    mdp = TabularMDP(
        transition=np.full((3, 1, 3), 1 / 3), initial=np.full(3, 1 / 3), features=np.eye(3), reward=state_reward, horizon=4
    )
    env = TabularEnv(mdp)
    reward = true_reward("a tabular env of no registered id", env)
    assert reward is not None
    paid = []
    for state in range(3):
        env.state = state
        paid.append(env.step(0)[1])
    states = np.arange(3)
    values = reward(states, np.zeros(3, np.int64), states)
    assert values.dtype == np.float64 and values.tolist() == paid


LIMIT_POSES = {
    # (z, torso angle, first joint angle) at, just inside and past each limit; Hopper's state
    # bound (|x| < 100) is reachable in its observation through a joint angle only.
    "Hopper": [
        (0.7, 0.0, 0.0),
        (0.7 + 1e-9, 0.0, 0.0),
        (1.2, 0.2, 0.0),
        (1.2, -0.2 + 1e-9, 0.0),
        (1.2, 0.0, 100.0),
        (1.2, 0.0, -100.0 + 1e-9),
        (1.2, 0.0, 100.5),
        (1.2, 0.0, 150.0),
        (1.2, 0.19, 99.0),
    ],
    "Walker2d": [
        (0.8, 0.0, 0.0),
        (0.8 + 1e-9, 0.0, 0.0),
        (2.0, 0.0, 0.0),
        (2.0 - 1e-9, 0.0, 0.0),
        (1.2, 1.0, 0.0),
        (1.2, -1.0, 0.0),
        (1.2, 1.0 - 1e-9, 0.0),
        (1.2, 0.0, 150.0),
    ],
}


@pytest.mark.parametrize("name", list(LIMIT_POSES))
def test_hopper_and_walker_healthy_bonus_is_the_envs_own_at_their_exact_limits(name: str) -> None:
    """Poses exactly at each bound (the env's are strict: at the bound is unhealthy), a hair
    inside it, and past it, in one batch: each state's bonus is 1 exactly when the env says it is
    healthy, whatever the batch's other states."""
    env_id = f"imitation/{name}FixedHorizon-v0"
    env = make_env(env_id)
    reward = true_reward(env_id, env)
    assert reward is not None
    env.reset(seed=0)
    model = env.unwrapped
    states, expected = [], []
    for z, angle, joint in LIMIT_POSES[name]:
        position = model.init_qpos.copy()
        position[1:4] = z, angle, joint
        model.set_state(position, model.init_qvel)
        states.append(model._get_obs())
        expected.append(float(model.is_healthy))
    states = np.array(states)
    still = np.zeros((len(states), *env.action_space.shape))
    bonus = reward(states, still, states) - states[:, SPEED_INDEX[name]]
    np.testing.assert_allclose(bonus, expected, atol=1e-9)
    assert 0 < np.mean(expected) < 1


@pytest.mark.parametrize("name", ["HalfCheetah", "Walker2d", "Ant"])
def test_mujoco_true_reward_depends_on_the_values_not_the_dtype_they_are_stored_in(name: str) -> None:
    """The same steps stored as float32 (as a demo file may hold them) and as float64 get the same
    reward to the last bit: control costs, contact costs and health are computed from the values.
    Walker2d's extra step stands at z = float32(0.8) = 0.800000012 > 0.8, healthy in float64."""
    env_id = f"imitation/{name}FixedHorizon-v0"
    env = make_env(env_id)
    reward = true_reward(env_id, env)
    assert reward is not None
    before, actions, after, _, _ = random_steps(env, 40)
    if name == "Walker2d":
        tall = after[:1].copy()
        tall[0, :2] = 0.8, 0.0
        before, actions, after = (
            np.concatenate([before, tall]),
            np.concatenate([actions, actions[:1]]),
            np.concatenate([after, tall]),
        )
    stored = [np.asarray(part, np.float32) for part in (before, actions, after)]
    as_float32 = reward(*stored)
    assert np.array_equal(as_float32, reward(*(part.astype(np.float64) for part in stored)))
    if name == "Walker2d":
        assert as_float32[-1] - float(stored[2][-1, 8]) + 1e-3 * np.sum(
            stored[1][-1].astype(np.float64) ** 2
        ) == pytest.approx(1.0, abs=1e-9)

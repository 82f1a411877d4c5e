"""A policy of the previous action (imitation/envs/previous_action.py, policies.py): the input
x_t = [s_t, a_{t-1}, 1{t=0}] is the same built offline from demos as online by the env wrapper; the
Gaussian's mean is a_{t-1} plus the head's output in the units of the actions' changes; and the
command line trains, evaluates and refuses such policies where they cannot act."""

from __future__ import annotations

import json
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS, TURTLE_MAP, run_cli_many, write_map
from test_cli import assert_one_line_error, last_json

from imitation.algorithms.bc import BCConfig, BehaviouralCloning
from imitation.data.loader import TransitionTensors
from imitation.envs.previous_action import PreviousActionObservation, previous_action_space, with_previous_actions
from imitation.errors import ConfigError, ImitationError
from imitation.jobs.bc import _conditions_on_previous_action, _states_alone
from imitation.policies import PolicyConfig, acting_env, make_policy
from imitation.policy_kinds import load_policy


def test_the_env_wrapper_builds_the_input_the_demos_give() -> None:
    """Two Pendulum episodes of random actions: x_t online equals x_t built from the recorded
    (s_t, a_t) afterwards, with zeros and the flag at each episode's first step."""
    env = PreviousActionObservation(gym.make("Pendulum-v1", max_episode_steps=5))
    assert env.observation_space.shape == (3 + 1 + 1,)
    env.action_space.seed(0)
    online, states, actions, episodes = [], [], [], []
    for episode in range(2):
        x, _ = env.reset(seed=episode)
        done = False
        while not done:
            action = env.action_space.sample()
            online.append(x)
            states.append(x[:3])
            actions.append(action)
            episodes.append(episode)
            x, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
    offline = with_previous_actions(np.asarray(states), np.asarray(actions), np.asarray(episodes))
    np.testing.assert_array_equal(np.asarray(online), offline)
    assert offline[:, -1].tolist() == [1, 0, 0, 0, 0] * 2
    np.testing.assert_array_equal(offline[[0, 5], 3], [0.0, 0.0])
    np.testing.assert_array_equal(offline[1:5, 3], np.asarray(actions)[0:4, 0])
    assert offline.dtype == np.float64


def test_a_policy_of_the_previous_action_acts_in_the_wrapped_env_and_others_in_the_env_itself() -> None:
    env = gym.make("Pendulum-v1")
    plain = make_policy(env.observation_space, env.action_space)
    conditioned = make_policy(
        previous_action_space(env.observation_space, env.action_space), env.action_space, previous_action=True
    )
    assert acting_env(plain, env) is env
    wrapped = acting_env(conditioned, env)
    assert isinstance(wrapped, PreviousActionObservation) and wrapped.env is env
    assert wrapped.observation_space == conditioned.observation_space


def test_the_input_space_holds_the_zeros_that_stand_for_no_previous_action() -> None:
    space = previous_action_space(gym.spaces.Box(-1.0, 1.0, (2,)), gym.spaces.Box(1.0, 3.0, (1,)))
    np.testing.assert_array_equal(space.low, [-1.0, -1.0, 0.0, 0.0])
    np.testing.assert_array_equal(space.high, [1.0, 1.0, 3.0, 1.0])
    with pytest.raises(TypeError, match="Box observations and Box actions, not Box and Discrete"):
        previous_action_space(gym.spaces.Box(-1.0, 1.0, (2,)), gym.spaces.Discrete(2))


def test_the_mean_is_the_previous_action_plus_the_head_in_units_of_the_changes() -> None:
    """μ = a_{t-1} + m + s·f(x_t), σ = s·exp(log_std), with m, s the mean and std of a_t − a_{t-1}."""
    inputs = previous_action_space(gym.spaces.Box(-np.inf, np.inf, (2,)), gym.spaces.Box(-np.inf, np.inf, (2,)))
    policy = make_policy(
        inputs, gym.spaces.Box(-np.inf, np.inf, (2,)), hidden_sizes=[8], normalize_observations=True,
        normalize_actions=True, previous_action=True,
    )
    x = torch.tensor([[0.5, -0.5, 10.0, -4.0, 0.0], [1.0, 2.0, 12.0, -3.0, 0.0], [0.0, 0.0, 0.0, 0.0, 1.0]])
    actions = torch.tensor([[12.0, -3.0], [13.0, -1.0], [11.0, -2.0]])
    policy.fit_action_normalizer(actions, x)
    changes = actions.double() - x[:, 2:4].double()
    assert torch.allclose(policy.action_mean, changes.mean(0).float())
    assert torch.allclose(policy.action_scale, changes.std(0, unbiased=False).float())
    policy.update_normalizer(x)
    with torch.no_grad():
        policy.log_std.fill_(math.log(0.5))
    features = policy.encode(x)
    head = policy.action_head(policy.actor_trunk(policy.obs_rms.normalize(x)))
    distribution = policy.distribution(features)
    assert torch.allclose(distribution.mean, x[:, 2:4] + policy.action_mean + policy.action_scale * head)
    assert torch.allclose(distribution.stddev, (policy.action_scale * 0.5).expand(3, 2))
    assert policy.value(features).shape == (3,)
    with pytest.raises(ImitationError, match="PPO's rollouts do not sample it"):
        policy.sample(features)
    with pytest.raises(ImitationError, match="takes Box actions and Box observations"):
        make_policy(gym.spaces.Box(-1, 1, (2,)), gym.spaces.Box(-1, 1, (2,)), previous_action=True)
    with pytest.raises(TypeError, match="previous_action true or false"):
        PolicyConfig.from_json(policy.config.to_json() | {"previous_action": "yes"})


def test_bc_fits_the_head_to_the_changes_of_the_command() -> None:
    """BC's learner standardises a policy of the previous action by a_t − a_{t-1}, not by a_t."""
    actions = np.array([[1.0], [3.0], [4.0], [10.0], [9.0]])
    x = with_previous_actions(np.zeros((5, 2)), actions, np.array([0, 0, 0, 1, 1]))
    train = TransitionTensors(
        observations=torch.as_tensor(x), actions=torch.as_tensor(actions, dtype=torch.float32), rewards=torch.zeros(5),
        next_observations=None, terminated=torch.zeros(5, dtype=torch.bool), truncated=torch.zeros(5, dtype=torch.bool),
        episode_index=torch.tensor([0, 0, 0, 1, 1]),
    )
    inputs = previous_action_space(gym.spaces.Box(-1, 1, (2,)), gym.spaces.Box(-20, 20, (1,)))
    policy = make_policy(inputs, gym.spaces.Box(-20, 20, (1,)), hidden_sizes=[4], normalize_actions=True, previous_action=True)
    BehaviouralCloning(policy, train, None, BCConfig(epochs=1))
    changes = torch.tensor([1.0, 2.0, 1.0, 10.0, -1.0])  # the first step of each episode changes from a_{-1} = 0
    assert torch.allclose(policy.action_mean, changes.mean().reshape(1))
    assert torch.allclose(policy.action_scale, changes.std(unbiased=False).reshape(1))


def test_the_baselines_see_the_states_the_input_was_built_from() -> None:
    states = np.arange(12.0).reshape(3, 2, 2)
    x = with_previous_actions(states, np.ones((3, 1)), np.zeros(3, dtype=np.int64))
    tensors = TransitionTensors(
        observations=torch.as_tensor(x), actions=torch.ones(3, 1), rewards=torch.zeros(3), next_observations=None,
        terminated=torch.zeros(3, dtype=torch.bool), truncated=torch.zeros(3, dtype=torch.bool), episode_index=torch.zeros(3),
    )
    alone = _states_alone(gym.spaces.Box(-np.inf, np.inf, (2, 2)))(tensors)
    assert torch.equal(alone.observations, torch.as_tensor(states))


def test_auto_conditions_offline_set_points_and_recordings() -> None:
    """auto: on offline for set-points (the actions have the observations' shape) and for a
    recording's command streams (demos that keep a real clock's times, as bags do), whatever their
    shape; off with an env, for simulator demos of other shapes, and when streamed."""
    positions, targets = gym.spaces.Box(-1, 1, (26,)), gym.spaces.Box(-1, 1, (26,))
    pose, velocity = gym.spaces.Box(-1, 1, (5,)), gym.spaces.Box(-1, 1, (2,))
    auto, on, off = BCConfig(), BCConfig(previous_action="on"), BCConfig(previous_action="off")
    assert _conditions_on_previous_action(auto, positions, targets, offline=True)
    assert not _conditions_on_previous_action(auto, positions, targets, offline=False)
    assert not _conditions_on_previous_action(auto, pose, velocity, offline=True)
    assert _conditions_on_previous_action(auto, pose, velocity, offline=True, recording=True)
    assert not _conditions_on_previous_action(auto, pose, velocity, offline=False, recording=True)
    assert not _conditions_on_previous_action(BCConfig(stream_memory=2**30), pose, velocity, offline=True, recording=True)
    assert not _conditions_on_previous_action(auto, pose, gym.spaces.Discrete(2), offline=True, recording=True)
    assert _conditions_on_previous_action(on, pose, velocity, offline=False)
    assert not _conditions_on_previous_action(off, positions, targets, offline=True)
    with pytest.raises(ConfigError, match="previous_action is for Box observations and actions, not Box and Discrete"):
        _conditions_on_previous_action(on, pose, gym.spaces.Discrete(2), offline=True)
    with pytest.raises(ConfigError, match="previous_action must be one of auto, on, off, got 'yes'"):
        BCConfig(previous_action="yes").validate(continuous=True)


def test_auto_tells_a_recording_from_a_simulators_demos(testdata: Path, tmp_path: Path) -> None:
    """Offline, a bag's velocity commands (the demos keep its clock) get the previous action; the
    bundled Pendulum demos, a simulator expert's actions of the state, do not (bench/RESULTS.md,
    issue 51: it made their held-out scores worse)."""
    bag, demos = testdata / "ros1" / "plotjuggler_example.bag", tmp_path / "turtle.mcap"
    converted, turtle, pendulum = run_cli_many([
        ["convert", bag, "--map", write_map(tmp_path, TURTLE_MAP), "--out", demos, "--quiet"],
        ["train", "bc", "--demos", demos, "--epochs", "1", "--hidden", "16", "--quiet", "--json", "--out", tmp_path / "turtle"],
        ["train", "bc", "--demos", DATASETS / "Pendulum-v1.mcap", "--epochs", "1", "--hidden", "16", "--quiet", "--json",
         "--out", tmp_path / "pendulum"],
    ])
    assert converted.returncode == 0, converted.stderr
    assert last_json(turtle)["previous_action"] is True and last_json(turtle)["offline"] is True
    assert last_json(pendulum)["previous_action"] is False and last_json(pendulum)["offline"] is True


def test_a_policy_of_the_previous_action_trains_evaluates_and_films_in_an_env_and_is_no_expert(tmp_path: Path) -> None:
    run = tmp_path / "bc"
    demos = str(DATASETS / "Pendulum-v1.mcap")
    train, evaluate, record, cartpole = run_cli_many([
        ["train", "bc", "--env", "Pendulum-v1", "--demos", demos, "--previous-action", "on", "--epochs", "3",
         "--hidden", "16", "--quiet", "--json", "--out", run],
        ["eval", "policy", run, "--env", "Pendulum-v1", "--episodes", "2", "--video", tmp_path / "episode.gif", "--json"],
        ["record", "--env", "Pendulum-v1", "--expert", run, "--episodes", "1", "--out", tmp_path / "demos.mcap"],
        ["train", "bc", "--env", "CartPole-v1", "--demos", str(DATASETS / "CartPole-v1.mcap"), "--previous-action", "on",
         "--out", tmp_path / "cartpole"],
    ])
    assert train.returncode == 0, train.stderr
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["previous_action"] is True and metrics["eval"]["episodes"] == 10
    assert load_policy(run).config.previous_action
    assert evaluate.returncode == 0, evaluate.stderr
    assert last_json(evaluate)["episodes"] == 2 and last_json(evaluate)["video"]["frames"] == 201
    assert_one_line_error(record, f"--expert {run}: the policy acts on the previous action as well as the state")
    assert_one_line_error(cartpole, "--previous-action is for Box observations and actions, not Box and Discrete")
    assert not (tmp_path / "demos.mcap").exists() and not (tmp_path / "cartpole").exists()

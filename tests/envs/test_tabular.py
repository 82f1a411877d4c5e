"""The tabular MDPs: registered ids, well-formed dynamics, exact H-step episodes, the expert."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import imitation.envs  # noqa: F401  (registers the ids)
from imitation.envs.rollout import play_episode
from imitation.envs.tabular import TabularMDP, cliff_world, gridworld, random_mdp, tabular_mdp_of
from imitation.envs.tabular_planning import Dynamics, expected_return, soft_optimal_policy
from imitation.errors import ImitationError
from imitation.experts.load import load_expert

TABULAR_IDS = ["imitation/GridWorld8x8-v0", "imitation/GridWorld8x8Slippery-v0", "imitation/CliffWorld-v0", "imitation/RandomMDP-v0"]


@pytest.mark.parametrize("env_id", TABULAR_IDS)
def test_registered_tabular_env_runs_exactly_the_horizon(env_id: str) -> None:
    env = gym.make(env_id)
    mdp = tabular_mdp_of(env, where="test")
    assert env.observation_space == gym.spaces.Discrete(mdp.n_states)
    assert np.allclose(mdp.transition.sum(-1), 1.0) and np.isclose(mdp.initial.sum(), 1.0)
    _, length = play_episode(env, lambda observation: env.action_space.sample(), seed=3)
    assert length == mdp.horizon


def test_grid_moves_deterministic_and_slippery() -> None:
    deterministic, slippery = gridworld(), gridworld(slip=0.2)
    # From the start (0, 0), "right" reaches (0, 1); slipping turns it up (wall: stay) or down.
    assert deterministic.transition[0, 1, 1] == 1.0
    assert slippery.transition[0, 1, 1] == pytest.approx(0.8)
    assert slippery.transition[0, 1, 0] == pytest.approx(0.1) and slippery.transition[0, 1, 8] == pytest.approx(0.1)
    goal = 63
    assert np.all(deterministic.transition[goal, :, goal] == 1.0), "the goal is absorbing"
    assert Dynamics.of(deterministic.transition).is_deterministic and not Dynamics.of(slippery.transition).is_deterministic


def test_env_reward_is_the_state_reward_of_the_state_left() -> None:
    env = gym.make("imitation/GridWorld8x8-v0")
    env.reset(seed=0)
    mdp = tabular_mdp_of(env, where="test")
    state = env.unwrapped.state
    _, reward, _, _, _ = env.step(2)
    assert reward == mdp.reward[state]


def test_expert_returns_match_the_exact_expected_return() -> None:
    env = gym.make("imitation/GridWorld8x8Slippery-v0")
    mdp = tabular_mdp_of(env, where="test")
    expert = load_expert("scripted", env, seed=0)
    returns = [play_episode(env, expert, seed=seed)[0] for seed in range(300)]
    exact = expected_return(Dynamics.of(mdp.transition), mdp, soft_optimal_policy(mdp))
    assert np.mean(returns) == pytest.approx(exact, abs=4 * np.std(returns) / np.sqrt(len(returns)))
    uniform = np.full((mdp.horizon, mdp.n_states, mdp.n_actions), 1.0 / mdp.n_actions)
    assert exact > expected_return(Dynamics.of(mdp.transition), mdp, uniform) + 10


def test_random_mdp_is_reproducible_and_sparse() -> None:
    a, b = random_mdp(seed=4), random_mdp(seed=4)
    assert np.array_equal(a.transition, b.transition) and np.array_equal(a.reward, b.reward)
    assert ((a.transition > 0).sum(-1) == 4).all()
    assert cliff_world().grid_shape == (4, 7)


def test_malformed_mdp_and_non_tabular_env_are_refused() -> None:
    good = gridworld()
    with pytest.raises(ImitationError, match="sum to 1"):
        TabularMDP(transition=good.transition * 0.5, initial=good.initial, features=good.features, reward=good.reward, horizon=30)
    with pytest.raises(ImitationError, match="not a tabular MDP"):
        tabular_mdp_of(gym.make("CartPole-v1"), where="--method mce")

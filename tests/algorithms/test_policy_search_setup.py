"""A policy search's setup (imitation.algorithms.policy_search.PolicySearch.__init__): the policy it
builds from the config (its layers, activation and seeded start, torch's threads), scores that do not
depend on the number of env copies, a budget of exactly one full-length generation, and
observations it cannot search over refused naming it."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from torch import nn

from imitation.algorithms.policy_search import PolicySearch, SearchConfig, actor_vector
from imitation.errors import ImitationError
from imitation.policies import make_policy


class DictObservationEnv(gym.Env):
    observation_space = gym.spaces.Dict({"position": gym.spaces.Box(-1.0, 1.0, (1,), np.float32)})
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return {"position": np.zeros(1, np.float32)}, {}

    def step(self, action):
        return self.reset()[0], 0.0, True, False, {}


def test_the_policy_is_the_configs_network_seeded_by_the_run() -> None:
    """Hidden [4] with ReLU on CartPole: 4 × 4 + 4 trunk and 2 × 4 + 2 head parameters, drawn as
    make_policy draws them after torch.manual_seed(seed); torch runs on the config's threads."""
    threads = torch.get_num_threads()
    try:
        search = PolicySearch(
            SearchConfig(
                env_id="CartPole-v1",
                population=2,
                n_envs=3,
                total_steps=2_000,
                seed=11,
                hidden_sizes=[4],
                activation="relu",
                threads=2,
            )
        )
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(threads)
    search.close()
    assert [type(layer) for layer in search.policy.actor_trunk] == [nn.Linear, nn.ReLU]
    assert search.dimension == 4 * 4 + 4 + 2 * 4 + 2
    env = gym.make("CartPole-v1")
    torch.manual_seed(11)
    expected = make_policy(env.observation_space, env.action_space, hidden_sizes=[4], activation="relu")
    np.testing.assert_array_equal(actor_vector(search.policy), actor_vector(expected))


def test_a_budget_of_one_full_length_generation_is_enough() -> None:
    """3 policies × 1 episode × 500 steps: 1,500 steps run one generation, 1,499 none."""
    search = PolicySearch(SearchConfig(env_id="CartPole-v1", population=2, n_envs=3, total_steps=1_500))
    search.close()
    assert (search.generation_limit, search.done, search.total) == (1_500, False, 1)
    with pytest.raises(ImitationError, match="total_steps 1499 is less than one generation at full episode length"):
        PolicySearch(SearchConfig(env_id="CartPole-v1", population=2, n_envs=3, total_steps=1_499))


def test_dict_observations_are_refused_in_one_line_naming_policy_search() -> None:
    gym.register(id="imitation-tests/SearchDictObservation-v0", entry_point=DictObservationEnv)
    try:
        with pytest.raises(ImitationError, match=r"^policy search takes Box or Discrete observations, not "):
            PolicySearch(SearchConfig(env_id="imitation-tests/SearchDictObservation-v0", total_steps=10))
    finally:
        gym.registry.pop("imitation-tests/SearchDictObservation-v0")


def test_the_number_of_env_copies_changes_no_score() -> None:
    """One copy runs the (policy, episode) pairs in turn, three side by side: the same rows."""
    rows = []
    for n_envs in (1, 3):
        search = PolicySearch(SearchConfig(env_id="CartPole-v1", population=2, n_envs=n_envs, total_steps=6_000, seed=4))
        rows.append([{k: v for k, v in search.step().items() if k != "steps_per_second"} for _ in range(2)])
        search.close()
    assert rows[0] == rows[1] and rows[0][-1]["episodes"] == 6.0

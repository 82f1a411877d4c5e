"""A policy search (imitation.algorithms.policy_search) at its edges: its checkpoint taken before
the first generation, its counters refused by name when out of range, a damaged part named, the
projected total it resumes with, CMA-ES's replayed history (its row's σ, and the history a resumed
run saves again); the action a searched policy takes, and the elites among tied scores."""

from __future__ import annotations

import re

import gymnasium as gym
import numpy as np
import pytest
import torch

from imitation.algorithms.policy_search import PolicySearch, SearchConfig, elite_indices, mode
from imitation.checkpoints import snapshot
from imitation.errors import ImitationError
from imitation.policies import make_policy


def search(method: str = "cmaes") -> PolicySearch:
    return PolicySearch(SearchConfig(env_id="CartPole-v1", method=method, population=2, n_envs=3, total_steps=2_100, seed=5))


def test_a_checkpoint_before_the_first_generation_resumes_from_the_start() -> None:
    fresh, resumed, whole = search(), search(), search()
    resumed.load_state_dict(snapshot(*fresh.state_dict()))
    assert (resumed.generations, resumed.global_step, resumed.total) == (0, 0, fresh.total)
    timeless = [{k: v for k, v in learner.step().items() if k != "steps_per_second"} for learner in (resumed, whole)]
    assert timeless[0] == timeless[1]
    for learner in (fresh, resumed, whole):
        learner.close()


def test_a_resumed_search_projects_the_total_the_interrupted_one_had() -> None:
    first = search("cem")
    for _ in range(2):
        first.step()
    resumed = search("cem")
    resumed.load_state_dict(snapshot(*first.state_dict()))
    assert resumed.total == first.total and resumed.total > resumed.generations
    first.close()
    resumed.close()


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"global_step": 2_101}, "the checkpoint's env step is 2101, outside 0..2100"),
        ({"generation": 5, "global_step": 4}, "the checkpoint's next generation is 5, outside 0..4"),
    ],
)
def test_a_checkpoints_counters_out_of_range_are_refused_by_name(changes: dict, message: str) -> None:
    learner = search()
    tensors, state = snapshot(*learner.state_dict())
    with pytest.raises(ImitationError, match=message):
        learner.load_state_dict((tensors, state | changes))
    learner.close()


def test_cmaes_reports_its_step_size_and_a_resumed_run_saves_the_history_it_replayed() -> None:
    first = search()
    rows = [first.step() for _ in range(2)]
    assert rows[-1]["sigma"] == float(first.search.es.sigma) and rows[0]["sigma"] != rows[1]["sigma"]
    tensors, state = snapshot(*first.state_dict())
    resumed = search()
    resumed.load_state_dict((tensors, state))
    assert resumed.state_dict()[1]["search"] == state["search"]
    assert len(state["search"]["told"]) == 2 and all(len(losses) == 2 for losses in state["search"]["told"])
    assert torch.equal(torch.as_tensor(resumed.search.centre()), torch.as_tensor(first.search.centre()))
    first.close()
    resumed.close()


@pytest.mark.parametrize(
    "action_space",
    [gym.spaces.Discrete(3), gym.spaces.MultiDiscrete([3, 2, 4]), gym.spaces.Box(-1.0, 1.0, (2,), np.float32)],
    ids=["discrete", "multidiscrete", "box"],
)
def test_the_searched_policys_action_is_its_mode_component_by_component(action_space: gym.Space) -> None:
    torch.manual_seed(0)
    policy = make_policy(gym.spaces.Box(-1.0, 1.0, (3,), np.float32), action_space, hidden_sizes=[5])
    features = policy.encode(torch.randn(6, 3))
    with torch.no_grad():
        outputs = policy.action_head(policy.actor_trunk(features))
        assert torch.equal(mode(policy, outputs), policy.act(features, deterministic=True))


def test_elites_among_tied_scores_are_the_first_candidates() -> None:
    """40 candidates, the first 20 tied for best in shuffled positions: the 10 elites are the
    earliest-listed of them (numpy's default sort is not stable past 16 elements)."""
    best = np.random.default_rng(0).permutation(40)[:20]
    scores = np.zeros(40)
    scores[best] = 1.0
    assert elite_indices(scores, 0.25).tolist() == sorted(best)[:10]


def test_a_damaged_checkpoint_names_the_part_that_does_not_fit() -> None:
    """CartPole's linear actor has 4 × 2 weights and 2 biases: a CEM mean of 3 values, or a
    CMA-ES generation of 3 scores where the population is 2, is refused saying so."""
    cem = search("cem")
    tensors, state = snapshot(*cem.state_dict())
    expected = "the checkpoint does not fit this CEM run (ValueError: a parameter vector of shape (3,), not (10,))"
    with pytest.raises(ImitationError, match=re.escape(expected)):
        cem.load_state_dict((tensors | {"search.mean": torch.zeros(3, dtype=torch.float64)}, state))
    cem.close()
    cmaes = search("cmaes")
    tensors, state = snapshot(*cmaes.state_dict())
    damaged = state | {"search": {"told": [[0.0, 1.0, 2.0]]}}
    expected = "the checkpoint does not fit this CMA-ES run (ValueError: a generation of 3 scores, not 2)"
    with pytest.raises(ImitationError, match=re.escape(expected)):
        cmaes.load_state_dict((tensors, damaged))
    cmaes.close()

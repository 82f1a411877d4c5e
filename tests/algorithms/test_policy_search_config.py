"""A policy search's settings (imitation.algorithms.policy_search.SearchConfig.validate): each one
out of range is refused with a message naming it and its config class, and each range's edges are
accepted."""

from __future__ import annotations

import math

import pytest

from imitation.algorithms.policy_search import SearchConfig
from imitation.errors import ConfigError

AT_LEAST_ONE = ("total_steps", "population", "episodes_per_candidate", "n_envs", "extra_noise_generations")
POSITIVE = ("sigma", "sigma_min", "sigma_max", "success_factor", "failure_factor")

REFUSED = [
    ({"method": "es"}, "method", "must be one of hill-climb, cem, cmaes, got 'es'"),
    *[({name: 0}, name, "must be at least 1, got 0") for name in AT_LEAST_ONE],
    ({"method": "cmaes", "population": 1}, "population", "must be at least 2 for CMA-ES, got 1"),
    ({"elite_fraction": 0.0}, "elite_fraction", "must be in (0, 1], got 0.0"),
    ({"elite_fraction": 1.5}, "elite_fraction", "must be in (0, 1], got 1.5"),
    *[({name: 0.0}, name, "must be a positive finite number, got 0.0") for name in POSITIVE],
    *[({name: math.inf}, name, "must be a positive finite number, got inf") for name in POSITIVE],
    ({"extra_noise": -0.1}, "extra_noise", "must be a finite number ≥ 0, got -0.1"),
    ({"extra_noise": math.inf}, "extra_noise", "must be a finite number ≥ 0, got inf"),
    ({"sigma_min": 2.5, "sigma_max": 2.0}, "sigma_min", "2.5 is above sigma_max 2.0: the clamp is empty"),
]


@pytest.mark.parametrize(("changes", "field", "problem"), REFUSED, ids=[f"{row[1]}={row[0]}" for row in REFUSED])
def test_a_setting_out_of_range_is_refused_naming_it(changes: dict, field: str, problem: str) -> None:
    with pytest.raises(ConfigError) as caught:
        SearchConfig(env_id="CartPole-v1", **changes).validate()
    assert (caught.value.field, caught.value.owner, str(caught.value)) == (field, "SearchConfig", f"{field} {problem}")


@pytest.mark.parametrize(
    "changes",
    [
        {name: 1 for name in AT_LEAST_ONE} | {"method": "hill-climb"},
        {"method": "cem", "population": 1},
        {"method": "cmaes", "population": 2},
        {"elite_fraction": 1.0},
        {"elite_fraction": 1e-9},
        {"extra_noise": 0.0},
        {"sigma_min": 0.5, "sigma_max": 0.5},
        {name: 1e-300 for name in POSITIVE},
    ],
    ids=["ones", "cem-of-one", "cmaes-of-two", "all-elite", "tiny-elite", "no-extra-noise", "sigma-pinned", "tiny-positive"],
)
def test_the_edges_of_each_range_are_accepted(changes: dict) -> None:
    SearchConfig(env_id="CartPole-v1", **changes).validate()

"""Gradient-free policy search (imitation/algorithms/policy_search.py): CEM's refit against
elites worked by hand, hill climbing's keep-if-better and σ adaptation, CMA-ES (the cma library)
on a known function and its replayed checkpoint, the batched actor against the policy itself,
the vector-env scoring against episodes run one by one, resume against an uninterrupted run, and
short CartPole searches that learn. The acceptance figures (CartPole and Pendulum, three seeds)
are slow tests: `pytest -m slow`."""

from __future__ import annotations

import dataclasses
import math

import gymnasium as gym
import numpy as np
import pytest
import torch

from imitation.algorithms.policy_search import (
    CMAES,
    CrossEntropy,
    HillClimbing,
    PolicySearch,
    SearchConfig,
    actor_outputs,
    actor_vector,
    adapt_sigma,
    cem_refit,
    elite_indices,
    extra_variance,
    hill_climb_choice,
    load_actor_vector,
)
from imitation.checkpoints import snapshot
from imitation.envs.make import make_env
from imitation.errors import ConfigError, ImitationError
from imitation.jobs.loop import run
from imitation.policies import make_policy

# ------------------------------------------------------------------------------------------------
# The formulas


def test_cem_refit_matches_the_elites_worked_by_hand() -> None:
    samples = np.array([[0.0, 0.0], [1.0, 2.0], [3.0, -2.0], [2.0, 4.0], [-1.0, 1.0]])
    scores = np.array([1.0, 5.0, 3.0, 4.0, 0.0])
    # ρ = 0.4 of 5: the 2 best, rows 1 (5.0) and 3 (4.0): μ = (1.5, 3), σ² = (0.25, 1) (divided by 2, not 1), + Z = 0.1.
    mean, variance = cem_refit(samples, scores, 0.4, 0.1)
    np.testing.assert_allclose(mean, [1.5, 3.0])
    np.testing.assert_allclose(variance, [0.35, 1.1])
    # ρ = 0.6: rows 1, 3, 2: μ = (2, 4/3), σ² = ((1 + 0 + 1)/3, ((2/3)² + (8/3)² + (10/3)²)/3).
    mean, variance = cem_refit(samples, scores, 0.6, 0.0)
    np.testing.assert_allclose(mean, [2.0, 4.0 / 3.0])
    np.testing.assert_allclose(variance, [2.0 / 3.0, (4 / 9 + 64 / 9 + 100 / 9) / 3])


def test_elites_are_the_ceiling_of_the_fraction_best_first() -> None:
    scores = np.arange(16.0)
    assert list(elite_indices(scores, 0.2)) == [15, 14, 13, 12]  # ⌈3.2⌉
    assert len(elite_indices(np.arange(25.0), 0.28)) == 7  # 0.28 · 25 is 7.000000000000001 in floating point
    assert list(elite_indices(np.array([1.0, 1.0, 0.0]), 0.1)) == [0]  # at least one; ties: the first
    assert list(elite_indices(np.array([2.0, 7.0, 7.0]), 1.0)) == [1, 2, 0]


def test_extra_noise_decreases_linearly_to_zero() -> None:
    assert extra_variance(0, 0.5, 10) == 0.5
    assert extra_variance(5, 0.5, 10) == pytest.approx(0.25)
    assert extra_variance(10, 0.5, 10) == 0.0
    assert extra_variance(30, 0.5, 10) == 0.0


def test_hill_climbing_keeps_only_strict_improvements() -> None:
    assert hill_climb_choice(3.0, np.array([1.0, 3.0, 2.0])) is None  # a tie does not displace the incumbent
    assert hill_climb_choice(3.0, np.array([1.0, 4.0, 5.0])) == 2
    assert hill_climb_choice(-math.inf, np.array([-7.0])) == 0


def test_sigma_shrinks_on_success_grows_on_failure_within_the_clamp() -> None:
    config = SearchConfig(env_id="CartPole-v1", sigma_min=0.1, sigma_max=1.0)
    assert adapt_sigma(0.4, True, config) == pytest.approx(0.2)
    assert adapt_sigma(0.4, False, config) == pytest.approx(0.8)
    assert adapt_sigma(0.15, True, config) == 0.1
    assert adapt_sigma(0.8, False, config) == 1.0
    one_fifth = SearchConfig(env_id="CartPole-v1", success_factor=1.5, failure_factor=0.9)
    assert adapt_sigma(0.4, True, one_fifth) == pytest.approx(0.6)


def test_hill_climbing_strategy_moves_only_to_a_better_candidate() -> None:
    config = SearchConfig(env_id="CartPole-v1", method="hill-climb", population=3, sigma=0.5)
    search = HillClimbing(config, np.zeros(2))
    centre, candidates = search.propose(np.random.default_rng(0))
    assert np.array_equal(centre, np.zeros(2)) and candidates.shape == (3, 2)
    noise = np.random.default_rng(0).standard_normal((3, 2))
    np.testing.assert_allclose(candidates, 0.5 * noise)  # θ + σε
    row = search.tell(candidates, 10.0, np.array([9.0, 10.0, 8.0]))
    assert np.array_equal(search.centre(), np.zeros(2)) and search.sigma == 1.0 and row["improved"] == 0.0
    row = search.tell(candidates, 10.0, np.array([9.0, 12.0, 11.0]))
    assert np.array_equal(search.centre(), candidates[1]) and search.sigma == 0.5 and row["improved"] == 1.0


def test_cem_strategy_samples_its_gaussian_and_refits() -> None:
    config = SearchConfig(
        env_id="CartPole-v1", method="cem", population=4, sigma=2.0, extra_noise=0.3, extra_noise_generations=2
    )
    search = CrossEntropy(config, np.array([1.0, -1.0]))
    narrow = CrossEntropy(dataclasses.replace(config, sigma=0.5), np.zeros(3))
    assert (narrow.mean.tolist(), narrow.variance.tolist(), narrow.generation) == ([0.0] * 3, [0.25] * 3, 0)  # σ₀²
    _, candidates = search.propose(np.random.default_rng(3))
    np.testing.assert_allclose(candidates, np.array([1.0, -1.0]) + 2.0 * np.random.default_rng(3).standard_normal((4, 2)))
    scores = np.array([0.0, 3.0, 1.0, 2.0])
    row = search.tell(candidates, 0.0, scores)
    expected_mean, expected_variance = cem_refit(candidates, scores, 0.2, 0.3)
    np.testing.assert_allclose(search.mean, expected_mean)
    np.testing.assert_allclose(search.variance, expected_variance)
    assert row == {"sigma": pytest.approx(np.sqrt(expected_variance).mean()), "extra_noise": 0.3}
    search.tell(candidates, 0.0, scores)  # generation 1: Z = 0.15
    np.testing.assert_allclose(search.variance, cem_refit(candidates, scores, 0.2, 0.15)[1])
    # Generation 2 reaches t_Z: no extra variance, σ the elite's (one of 4 at ρ = 0.2: σ² = 0).
    row = search.tell(candidates, 0.0, scores)
    assert search.generation == 3 and row == {"sigma": 0.0, "extra_noise": 0.0}


def test_cmaes_through_cma_minimises_a_sphere() -> None:
    config = SearchConfig(env_id="CartPole-v1", method="cmaes", population=8, sigma=1.0, seed=4)
    search = CMAES(config, np.full(5, 3.0))
    rng = np.random.default_rng(0)
    for _ in range(60):
        _, candidates = search.propose(rng)
        search.tell(candidates, 0.0, -(candidates**2).sum(axis=1))  # Ĵ = −‖θ‖²
    assert np.linalg.norm(search.centre()) < 1e-2 < np.linalg.norm(np.full(5, 3.0))


def test_cmaes_checkpoint_replays_to_the_same_strategy() -> None:
    config = SearchConfig(env_id="CartPole-v1", method="cmaes", population=6, sigma=0.7, seed=2)
    search = CMAES(config, np.linspace(-1, 1, 4))
    rng = np.random.default_rng(1)
    for _ in range(7):
        _, candidates = search.propose(rng)
        search.tell(candidates, 0.0, -np.abs(candidates - 0.3).sum(axis=1))
    tensors, state = snapshot(*search.state())
    restored = CMAES(config, np.linspace(-1, 1, 4))
    restored.restore(tensors, state)
    np.testing.assert_array_equal(restored.centre(), search.centre())
    assert restored.es.sigma == search.es.sigma
    np.testing.assert_array_equal(restored.es.C, search.es.C)
    np.testing.assert_array_equal(restored.propose(rng)[1], search.propose(rng)[1])  # the next generation too


# ------------------------------------------------------------------------------------------------
# The searched vector and the scoring


@pytest.mark.parametrize(("env_id", "hidden"), [("CartPole-v1", []), ("Pendulum-v1", [5, 3])])
def test_batched_actors_act_as_the_policy_holding_each_vector(env_id: str, hidden: list[int]) -> None:
    torch.manual_seed(0)
    env = make_env(env_id)
    policy = make_policy(env.observation_space, env.action_space, hidden_sizes=hidden)
    dimension = len(actor_vector(policy))
    vectors = torch.randn(4, dimension, dtype=torch.float64).float()
    observations = torch.randn(4, env.observation_space.shape[0])
    outputs = actor_outputs(policy, vectors, policy.encode(observations))
    for row in range(4):
        load_actor_vector(policy, vectors[row].double().numpy())
        with torch.no_grad():
            expected = policy.action_head(policy.actor_trunk(policy.encode(observations[row : row + 1])))
        torch.testing.assert_close(outputs[row : row + 1], expected)
        np.testing.assert_allclose(actor_vector(policy), vectors[row].double().numpy())


def _episode_return(policy, env: gym.Env, seed: int) -> tuple[float, int]:
    observation, _ = env.reset(seed=seed)
    total, steps, done = 0.0, 0, False
    while not done:
        observation, reward, terminated, truncated, _ = env.step(policy.predict(observation[None])[0])
        total, steps, done = total + float(reward), steps + 1, terminated or truncated
    return total, steps


def test_scores_are_mean_returns_of_the_episodes_run_one_by_one() -> None:
    """5 policies × 2 episode starts dealt to 3 env copies: each score is the policy's mean
    return over those starts, and every step of every episode is counted once."""
    search = PolicySearch(SearchConfig(env_id="CartPole-v1", method="cem", n_envs=3, total_steps=20_000))
    rng = np.random.default_rng(0)
    vectors = rng.normal(0.0, 1.0, (5, search.dimension))
    seeds = [11, 12]
    scores = search.evaluate(vectors, seeds)
    env = make_env("CartPole-v1")
    expected, steps = [], 0
    for vector in vectors:
        load_actor_vector(search.policy, vector)
        episodes = [_episode_return(search.policy, env, seed) for seed in seeds]
        expected.append(np.mean([ret for ret, _ in episodes]))
        steps += sum(length for _, length in episodes)
    np.testing.assert_allclose(scores, expected)
    assert len(set(scores)) > 1  # the policies differ, so the test can tell them apart
    assert search.global_step == steps and search.episodes == 10
    search.close()


def test_a_non_finite_observation_stops_the_search() -> None:
    pytest.importorskip("nan_envs")
    search = PolicySearch(
        SearchConfig(env_id="nan_envs:NaNObservation-v0", method="cem", n_envs=2, population=3, total_steps=1000)
    )
    with pytest.raises(ImitationError, match="non-finite observation .* CEM needs finite observations"):
        run(search)
    search.close()


def test_config_errors_name_the_field() -> None:
    with pytest.raises(ConfigError, match="method must be one of"):
        SearchConfig(env_id="CartPole-v1", method="es").validate()
    with pytest.raises(ConfigError, match="elite_fraction must be in"):
        SearchConfig(env_id="CartPole-v1", elite_fraction=0.0).validate()
    with pytest.raises(ConfigError, match="population must be at least 2 for CMA-ES"):
        SearchConfig(env_id="CartPole-v1", method="cmaes", population=1).validate()
    with pytest.raises(ConfigError, match="sigma must be a positive finite number"):
        SearchConfig(env_id="CartPole-v1", sigma=-1.0).validate()
    with pytest.raises(ConfigError, match="total_steps 1000 is less than one generation"):
        PolicySearch(SearchConfig(env_id="CartPole-v1", total_steps=1000))


# ------------------------------------------------------------------------------------------------
# The learner: budget, resume, learning


@pytest.mark.parametrize("method", ["hill-climb", "cem", "cmaes"])
def test_resume_equals_an_uninterrupted_run(method: str) -> None:
    # Full-length generations would take 3 × 500 steps: the budget stops the search after 600 steps.
    config = SearchConfig(env_id="CartPole-v1", method=method, population=2, n_envs=3, total_steps=2_100, seed=5)
    whole = PolicySearch(config)
    rows = run(whole)
    first = PolicySearch(config)
    head = [first.step() for _ in range(3)]
    checkpoint = snapshot(*first.state_dict())
    first.close()
    resumed = PolicySearch(config)
    resumed.load_state_dict(checkpoint)
    tail = run(resumed)
    assert len(tail) >= 2, "the budget must leave generations after the checkpoint"
    drop = {"steps_per_second"}
    assert [{k: v for k, v in r.items() if k not in drop} for r in head + tail] == [
        {k: v for k, v in r.items() if k not in drop} for r in rows
    ]
    np.testing.assert_array_equal(actor_vector(resumed.policy), actor_vector(whole.policy))
    # The budget: no generation may pass it, the last one stopped short of a full-length one.
    assert whole.global_step <= config.total_steps < whole.global_step + whole.generation_limit
    whole.close()
    resumed.close()


def test_a_damaged_checkpoint_is_one_line() -> None:
    config = SearchConfig(env_id="CartPole-v1", method="cem", population=4, n_envs=4, total_steps=6_000)
    search = PolicySearch(config)
    tensors, state = snapshot(*search.state_dict())
    tensors["search.mean"] = torch.zeros(3, dtype=torch.float64)
    with pytest.raises(ImitationError, match="the checkpoint does not fit this CEM run"):
        search.load_state_dict((tensors, state))
    search.close()


@pytest.mark.parametrize("method", ["cem", "hill-climb"])
def test_a_short_cartpole_search_learns(method: str) -> None:
    """The initial linear policy (seed 1) balances for 28 steps on the evaluation starts. A 12k
    budget, of which a full-length generation (17 × 500 steps) is held in reserve, takes CEM and
    hill climbing (seed 1) far beyond that on the held-out evaluation starts. The slow tests
    below are the full figures."""
    from imitation.evaluation.policy import evaluate_policy
    from imitation.jobs.search import search_config
    from imitation.policies import SingleObservationPolicy

    search = PolicySearch(search_config("CartPole-v1", method, total_steps=12_000, seed=1))
    before = evaluate_policy(SingleObservationPolicy(search.policy), make_env("CartPole-v1"), episodes=5, seed=0)[
        "mean_return"
    ]
    rows = run(search)
    after = evaluate_policy(SingleObservationPolicy(search.policy), make_env("CartPole-v1"), episodes=5, seed=0)["mean_return"]
    search.close()
    assert before < 50 and after > 150, (before, after)
    assert rows[-1]["return"] > rows[0]["return"]


# ------------------------------------------------------------------------------------------------
# Acceptance figures (slow): `eval policy`'s default evaluation (10 episodes, seeds 0–9) of the run directory


def _searched(tmp_path, env_id: str, method: str, seed: int) -> tuple[dict, float]:
    from imitation.jobs.evaluate_policy import eval_policy_job
    from imitation.jobs.search import search_config, search_job

    result = search_job(search_config(env_id, method, seed=seed), tmp_path / f"{method}-{seed}", progress=False)
    return result, eval_policy_job(result["run"], env_id)["mean_return"]


@pytest.mark.slow
def test_cem_balances_cartpole_within_50k_steps_on_every_seed(tmp_path) -> None:
    for seed in range(3):
        result, score = _searched(tmp_path, "CartPole-v1", "cem", seed)
        assert result["steps"] <= 50_000 and score >= 475, (seed, result["steps"], score)


@pytest.mark.slow
def test_hill_climbing_balances_cartpole_within_50k_steps_on_two_of_three_seeds(tmp_path) -> None:
    scores = []
    for seed in range(3):
        result, score = _searched(tmp_path, "CartPole-v1", "hill-climb", seed)
        assert result["steps"] <= 50_000
        scores.append(score)
    assert sum(score >= 475 for score in scores) >= 2, scores


@pytest.mark.slow
def test_cem_swings_pendulum_up_within_500k_steps_on_two_of_three_seeds(tmp_path) -> None:
    scores = []
    for seed in range(3):
        result, score = _searched(tmp_path, "Pendulum-v1", "cem", seed)
        assert result["steps"] <= 500_000
        scores.append(score)
    assert sum(score >= -400 for score in scores) >= 2, scores

"""One generation of a policy search (imitation.algorithms.policy_search.PolicySearch) against
episodes run one by one: its row (the centre's return, the candidates' mean and best, the steps
and episodes counted, the progress fields), scoring with fewer (policy, episode) pairs than env
copies (and where they start), non-finite rewards, and the generations the budget is projected
to last, worked by hand."""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np
import pytest

from imitation.algorithms.policy_search import HillClimbing, PolicySearch, SearchConfig, actor_vector, load_actor_vector
from imitation.checkpoints import snapshot
from imitation.envs.make import make_env
from imitation.errors import ImitationError
from imitation.policies import ActorCritic, make_policy


def one_by_one(env_id: str, vectors: np.ndarray, seeds: list[int]) -> tuple[list[float], int]:
    """Each vector's mean return over episodes started from `seeds`, its linear policy acting by
    its mode, and the steps all the episodes took."""
    env = make_env(env_id)
    policy = make_policy(env.observation_space, env.action_space, hidden_sizes=[])
    assert isinstance(policy, ActorCritic)
    means, steps = [], 0
    for vector in vectors:
        load_actor_vector(policy, vector)
        returns = []
        for seed in seeds:
            observation, _ = env.reset(seed=seed)
            total, done = 0.0, False
            while not done:
                observation, reward, terminated, truncated, _ = env.step(policy.predict(observation[None])[0])
                total, steps, done = total + float(reward), steps + 1, terminated or truncated
            returns.append(total)
        means.append(float(np.mean(returns)))
    env.close()
    return means, steps


def test_a_generations_row_restates_its_scores_on_the_generations_episode_starts() -> None:
    """Generation 0 of seed 1 draws its candidates, then its 2 episode seeds, from a generator
    seeded (1, 0): the centre and 3 candidates, run one by one from those starts, give the row's
    returns; 4 policies × 2 episodes of Pendulum's 200 steps were counted, every step once.
    Pendulum's return is continuous in its start, so any other episode seed would show."""
    config = SearchConfig(
        env_id="Pendulum-v1", method="hill-climb", population=3, episodes_per_candidate=2, n_envs=3, total_steps=20_000, seed=1
    )
    search = PolicySearch(config)
    rng = np.random.default_rng([1, 0])
    centre, candidates = HillClimbing(config, actor_vector(search.policy)).propose(rng)
    seeds = [int(seed) for seed in rng.integers(0, 2**31 - 1, 2)]
    scores, steps = one_by_one("Pendulum-v1", np.vstack([centre[None], candidates]), seeds)
    started = time.perf_counter()
    row = search.step()
    elapsed = time.perf_counter() - started
    # 1,600 steps of 20,000 spent, 1,600 held back: 1 + ⌊16,800 / 1,600⌋ + 1 generations projected.
    assert (search.completed, search.total) == (1, 12)
    assert search.step()["generation"] == 2.0 and search.completed == 2
    search.close()
    assert len({scores[0], float(np.mean(scores[1:])), max(scores[1:])}) == 3  # the test can tell them apart
    improved = max(scores[1:]) > scores[0]
    # The search acts on 3 envs at once, this test on one: float32 products of a batch of 3 and of 1
    # round differently on some CPUs' kernels, and Pendulum's 200 steps grow that (an Intel Xeon's:
    # up to 9e-9 relative), far below what another episode start changes (whole units of return).
    same = {"rel": 1e-6}
    assert row == {
        "step": float(steps),
        "generation": 1.0,
        "return": pytest.approx(scores[0], **same),
        "population_return": pytest.approx(float(np.mean(scores[1:])), **same),
        "best_return": pytest.approx(max(scores[1:]), **same),
        "episodes": 8.0,
        "steps_per_second": row["steps_per_second"],
        "sigma": 0.25 if improved else 1.0,
        "improved": float(improved),
    }
    assert row["steps_per_second"] >= steps / elapsed  # the clock ran within the step
    assert search.progress(row) == {"ret": f"{scores[0]:.1f}", "best": f"{max(scores[1:]):.1f}", "step": str(steps)}


def test_fewer_pairs_than_env_copies_score_as_episodes_run_one_by_one() -> None:
    """2 policies × 1 episode on 5 copies: three copies idle from the start, and their steps and
    episodes are not counted."""
    search = PolicySearch(SearchConfig(env_id="CartPole-v1", method="cem", population=4, n_envs=5, total_steps=20_000))
    vectors = np.random.default_rng(3).normal(0.0, 1.0, (2, search.dimension))
    scores = search.evaluate(vectors, [21])
    expected, steps = one_by_one("CartPole-v1", vectors, [21])
    search.close()
    np.testing.assert_allclose(scores, expected)
    assert expected[0] != expected[1] and (search.global_step, search.episodes) == (steps, 2)


@pytest.mark.parametrize(
    ("generation", "global_step", "total", "done"),
    [
        (0, 0, 6, False),  # 1 + ⌊(10,000 - 1,500) / 1,500⌋ at full episode length
        (4, 1_000, 35, False),  # 250 steps a generation so far: 4 + ⌊7,500 / 250⌋ + 1
        (4, 5, 6_801, False),  # 1.25 a generation: 4 + ⌊8,495 / 1.25⌋ + 1
        (3, 10, 2_551, False),  # 3 + ⌊8,490 · 3 / 10⌋ + 1: 8,490 // (10 / 3) in floats gave 2,546
        (30, 8_500, 31, False),  # the last full-length generation just fits: one more
        (30, 8_501, 30, True),  # it would not: done, the total is the generations run
        (30, 10_000, 30, True),
    ],
)
def test_the_projected_total_and_done_from_a_checkpoints_counters(
    generation: int, global_step: int, total: int, done: bool
) -> None:
    """CartPole's episodes end by step 500, so a generation of 3 policies × 1 episode takes at most
    1,500 steps; none starts that could pass the 10,000-step budget."""
    search = PolicySearch(SearchConfig(env_id="CartPole-v1", method="cem", population=2, n_envs=3, total_steps=10_000))
    assert search.generation_limit == 1_500
    tensors, state = snapshot(*search.state_dict())
    search.load_state_dict((tensors, state | {"generation": generation, "global_step": global_step}))
    search.close()
    assert (search.total, search.done) == (total, done)


def test_episodes_without_a_time_limit_reserve_one_step_of_the_budget() -> None:
    """With no episode limit a generation's length is unknown: the budget is spent when no step of
    it is left, and the projection assumes one step a generation until there is a mean."""
    env_id = "TestPolicySearchUnlimited-v0"
    gym.register(env_id, entry_point="gymnasium.envs.classic_control.cartpole:CartPoleEnv", max_episode_steps=None)
    try:
        search = PolicySearch(SearchConfig(env_id=env_id, method="cem", population=2, n_envs=3, total_steps=1_000))
        assert search.generation_limit is None and search.total == 1_001  # 0 + ⌊1,000 / 1⌋ + 1
        tensors, state = snapshot(*search.state_dict())
        for global_step, total, done in [(999, 2, False), (1_000, 1, True)]:
            search.load_state_dict((tensors, state | {"generation": 1, "global_step": global_step}))
            assert (search.total, search.done) == (total, done)
        search.close()
    finally:
        del gym.registry[env_id]


def test_one_policy_scores_beside_idle_copies() -> None:
    """`evaluate` of a single vector over one episode start on 3 copies: the idle two act with
    that only policy, and the score is its episode's return."""
    search = PolicySearch(SearchConfig(env_id="CartPole-v1", method="cem", population=2, n_envs=3, total_steps=20_000))
    vector = np.random.default_rng(5).normal(0.0, 1.0, (1, search.dimension))
    scores = search.evaluate(vector, [8])
    search.close()
    expected, steps = one_by_one("CartPole-v1", vector, [8])
    assert scores.tolist() == expected and (search.global_step, search.episodes) == (steps, 1)


def test_a_non_finite_reward_stops_the_search_naming_it() -> None:
    """tests/nan_envs.py: each copy's 290th step returns a NaN reward (episodes of 50 steps)."""
    pytest.importorskip("nan_envs")
    search = PolicySearch(
        SearchConfig(env_id="nan_envs:NaNReward-v0", method="cem", n_envs=2, population=3, total_steps=1_000)
    )
    with pytest.raises(
        ImitationError, match=r"^nan_envs:NaNReward-v0: the environment returned a non-finite reward by env step"
    ):
        while not search.done:
            search.step()
    search.close()


class NaNStartAtSeedZero(gym.Env):
    """Starts from NaN when reset with seed 0, from finite states otherwise; episodes of 5 steps."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.t = 0
        return np.full(2, np.nan if seed == 0 else 0.5, np.float32), {}

    def step(self, action):
        self.t += 1
        return np.zeros(2, np.float32), 1.0, False, self.t >= 5, {}


@pytest.mark.filterwarnings("ignore:.*not within the observation space")  # the NaN start, on purpose
def test_idle_copies_start_from_seed_0_and_their_first_observation_is_checked() -> None:
    """2 (policy, episode) pairs from seed 5 on 3 copies: the idle third starts from seed 0, where
    this env returns NaN, and the search stops before any step."""
    env_id = "imitation-tests/SearchNaNStartAtSeedZero-v0"
    gym.register(env_id, entry_point=NaNStartAtSeedZero)
    try:
        search = PolicySearch(SearchConfig(env_id=env_id, method="cem", population=2, n_envs=3, total_steps=100))
        with pytest.raises(ImitationError, match="returned a non-finite observation by env step 0 "):
            search.evaluate(np.zeros((2, search.dimension)), [5])
        search.close()
    finally:
        gym.registry.pop(env_id)

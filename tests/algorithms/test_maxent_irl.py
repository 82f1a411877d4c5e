"""Tabular MaxEnt / MCE IRL: the two passes, the gradient of notes §5.3.3, recovery from demos."""

from __future__ import annotations

import dataclasses
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch

import imitation.envs  # noqa: F401  (registers the ids)
from imitation.algorithms.maxent_irl import MaxEntIRL, MaxEntIRLConfig, demo_visitation
from imitation.data.dataset import DemoDataset
from imitation.data.mcap.writer import DemoWriter
from imitation.data.recorder import RecordEpisodes, run_episodes
from imitation.data.types import Episode, episodes_to_transitions
from imitation.envs.tabular import TabularMDP, gridworld, random_mdp
from imitation.envs.tabular_planning import (
    DenseDynamics, Dynamics, SparseDynamics, _logsumexp, _logsumexp_rows, expected_return, soft_optimal_policy, soft_value_iteration,
    state_visitation,
)
from imitation.errors import ConfigError, ImitationError
from imitation.experts.load import load_expert
from imitation.jobs.loop import run
from imitation.rewards import all_state_rewards, make_reward_model


def _model(mdp: TabularMDP, hidden_sizes: list[int] = ()) -> torch.nn.Module:
    torch.manual_seed(0)
    return make_reward_model(gym.spaces.Discrete(mdp.n_states), gym.spaces.Discrete(mdp.n_actions), feature_table=mdp.features, hidden_sizes=list(hidden_sizes))


def _exact_expert_visitation(mdp: TabularMDP, discount: float = 1.0) -> np.ndarray:
    return state_visitation(Dynamics.of(mdp.transition), mdp.initial, soft_optimal_policy(mdp, discount=discount), horizon=mdp.horizon, discount=discount)


@pytest.mark.parametrize("discount", [1.0, 0.99, 0.9, 0.5])
def test_visitation_sums_to_the_discounted_horizon_plus_one(discount: float) -> None:
    mdp = random_mdp(seed=1)
    dynamics = Dynamics.of(mdp.transition)
    policy, _ = soft_value_iteration(dynamics, mdp.reward, horizon=mdp.horizon, discount=discount)
    assert np.allclose(policy.sum(-1), 1.0)
    occupancy = state_visitation(dynamics, mdp.initial, policy, horizon=mdp.horizon, discount=discount)
    expected = mdp.horizon + 1 if discount == 1.0 else (1 - discount ** (mdp.horizon + 1)) / (1 - discount)
    assert occupancy.sum() == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("discount", [0.9, 0.5])
def test_infinite_horizon_visitation_sums_to_one_over_one_minus_discount(discount: float) -> None:
    mdp = random_mdp(seed=2)
    dynamics = Dynamics.of(mdp.transition)
    policy, _ = soft_value_iteration(dynamics, mdp.reward, horizon=None, discount=discount)
    assert policy.shape == (mdp.n_states, mdp.n_actions)
    assert state_visitation(dynamics, mdp.initial, policy, horizon=None, discount=discount).sum() == pytest.approx(1 / (1 - discount), rel=1e-9)


def test_infinite_horizon_without_discount_is_refused() -> None:
    mdp = random_mdp(seed=0)
    with pytest.raises(ImitationError, match="infinite horizon needs a discount below 1"):
        soft_value_iteration(Dynamics.of(mdp.transition), mdp.reward, horizon=None, discount=1.0)
    with pytest.raises(ImitationError, match="infinite horizon"):
        run(MaxEntIRL(
            TabularMDP(transition=mdp.transition, initial=mdp.initial, features=mdp.features, reward=mdp.reward, horizon=None),
            np.ones(mdp.n_states), _model(mdp), MaxEntIRLConfig(),
        ))


def test_dense_dynamics_compute_in_float64_whatever_they_are_given() -> None:
    mdp = random_mdp(seed=4)
    values = np.random.default_rng(0).normal(size=mdp.n_states)
    single, double = DenseDynamics(mdp.transition.astype(np.float32)), DenseDynamics(mdp.transition.astype(np.float32).astype(np.float64))
    assert np.array_equal(single.expectation(values), double.expectation(values))
    assert np.array_equal(single.log_expectation_of_exp(values), double.log_expectation_of_exp(values))


def test_dense_and_sparse_dynamics_agree() -> None:
    mdp = random_mdp(seed=3, n_states=300)
    dense, sparse = DenseDynamics(mdp.transition), SparseDynamics(mdp.transition, width=4)
    values = np.random.default_rng(0).normal(size=mdp.n_states)
    assert np.allclose(dense.expectation(values), sparse.expectation(values))
    assert np.allclose(dense.log_expectation_of_exp(values), sparse.log_expectation_of_exp(values))
    mass = np.random.default_rng(1).random((mdp.n_states, mdp.n_actions))
    assert np.allclose(dense.propagate(mass), sparse.propagate(mass))
    assert isinstance(Dynamics.of(mdp.transition), SparseDynamics) and isinstance(Dynamics.of(gridworld().transition), DenseDynamics)


def test_log_sum_exp_rows_hold_far_apart_scales() -> None:
    """log Σ_a exp q(s, a) per row, each shifted by its own maximum: rows around -1000 and +1000
    would under- or overflow with one shift for the whole array."""
    values = np.array([[-1000.0, -1001.0, -1002.0], [1000.0, 999.0, 1001.0]] * 3000)
    expected = values.max(1) + np.log(np.exp(values - values.max(1, keepdims=True)).sum(1))
    np.testing.assert_allclose(_logsumexp_rows(values), expected, rtol=1e-12)  # the large-array path
    np.testing.assert_allclose(_logsumexp_rows(values[:2]), expected[:2], rtol=1e-12)
    np.testing.assert_allclose(_logsumexp(values.T, axis=0), expected, rtol=1e-12)
    np.testing.assert_allclose(_logsumexp(values[:2], axis=1), expected[:2], rtol=1e-12)


def test_sparse_dynamics_are_marked_deterministic_only_when_every_move_is() -> None:
    assert SparseDynamics(gridworld().transition, width=3).is_deterministic
    assert not SparseDynamics(gridworld(slip=0.2).transition, width=3).is_deterministic
    assert DenseDynamics(gridworld().transition).is_deterministic and not DenseDynamics(gridworld(slip=0.2).transition).is_deterministic


def test_expected_return_pays_for_the_h_states_acted_in() -> None:
    """Σ_{t<H} E[r(s_t)]: two states, stay or swap, H = 2, start in s0 and always swap: r(s0) + r(s1)."""
    transition = np.array([[[1.0, 0.0], [0.0, 1.0]], [[0.0, 1.0], [1.0, 0.0]]])
    swap = np.tile([0.0, 1.0], (2, 2, 1))
    mdp = TabularMDP(transition=transition, initial=np.array([1.0, 0.0]), features=np.eye(2), reward=np.array([1.0, 10.0]), horizon=2)
    assert expected_return(Dynamics.of(transition), mdp, swap) == pytest.approx(11.0)


def test_backward_pass_by_hand() -> None:
    """Two states, two actions, H = 1: action 0 stays, action 1 swaps; r = (0, 1); start in s0.
    V_1 = r; Q_0(s0, ·) = r(s0) + (V_1(s0), V_1(s1)) = (0, 1); π_0(·|s0) = softmax(0, 1)."""
    transition = np.array([[[1.0, 0.0], [0.0, 1.0]], [[0.0, 1.0], [1.0, 0.0]]])
    dynamics = Dynamics.of(transition)
    policy, values = soft_value_iteration(dynamics, np.array([0.0, 1.0]), horizon=1, discount=1.0)
    assert np.allclose(policy[0, 0], np.exp([0, 1]) / np.exp([0, 1]).sum())
    assert values[0] == pytest.approx(np.log(1 + np.e))
    occupancy = state_visitation(dynamics, np.array([1.0, 0.0]), policy, horizon=1, discount=1.0)
    assert np.allclose(occupancy, [1 + 1 / (1 + np.e), np.e / (1 + np.e)])


def test_maxent_and_mce_coincide_on_deterministic_dynamics() -> None:
    mdp = gridworld()
    dynamics = Dynamics.of(mdp.transition)
    mce, _ = soft_value_iteration(dynamics, mdp.reward, horizon=mdp.horizon, discount=1.0, method="mce")
    maxent, _ = soft_value_iteration(dynamics, mdp.reward, horizon=mdp.horizon, discount=1.0, method="maxent")
    assert np.allclose(mce, maxent)
    slippery = Dynamics.of(gridworld(slip=0.2).transition)
    assert not np.allclose(
        soft_value_iteration(slippery, mdp.reward, horizon=mdp.horizon, discount=1.0, method="mce")[0],
        soft_value_iteration(slippery, mdp.reward, horizon=mdp.horizon, discount=1.0, method="maxent")[0],
    )


def test_the_gradient_is_demo_minus_learner_feature_counts_and_that_of_the_likelihood() -> None:
    """Notes §5.3.3: ∇L(w) = μ̃ - Σ_s D(s) x(s); L(w) = μ̃ᵀr - E_ρ₀[V_0] (the causal log-likelihood up
    to terms free of w), checked against finite differences."""
    mdp = random_mdp(seed=5)
    dynamics = Dynamics.of(mdp.transition)
    target = _exact_expert_visitation(mdp)
    w = np.random.default_rng(0).normal(size=mdp.features.shape[1])

    def likelihood(weights: np.ndarray) -> float:
        reward = mdp.features @ weights
        _, values = soft_value_iteration(dynamics, reward, horizon=mdp.horizon, discount=1.0)
        return float(target @ reward - mdp.initial @ values)

    policy, _ = soft_value_iteration(dynamics, mdp.features @ w, horizon=mdp.horizon, discount=1.0)
    learner = state_visitation(dynamics, mdp.initial, policy, horizon=mdp.horizon, discount=1.0)
    analytic = target @ mdp.features - learner @ mdp.features
    step = 1e-6
    numeric = np.array([(likelihood(w + step * e) - likelihood(w - step * e)) / (2 * step) for e in np.eye(len(w))])
    assert np.allclose(analytic, numeric, atol=1e-5)


@pytest.mark.parametrize(("slip", "method"), [(0.0, "maxent"), (0.0, "mce"), (0.2, "mce")])
def test_linear_reward_matches_the_experts_exact_occupancy(slip: float, method: str) -> None:
    mdp = gridworld(slip=slip)
    target = _exact_expert_visitation(mdp)
    learner = MaxEntIRL(mdp, target, _model(mdp), MaxEntIRLConfig(method=method, iterations=1000, learning_rate=0.2, tolerance=1e-3))
    history = run(learner)
    assert np.abs(learner.occupancy - target).max() <= 1e-3
    assert history[-1]["occupancy_error"] <= 1e-3 and len(history) < 1000


def test_maxent_on_stochastic_dynamics_is_refused() -> None:
    mdp = gridworld(slip=0.2)
    with pytest.raises(ImitationError, match="deterministic dynamics.*use mce"):
        run(MaxEntIRL(mdp, _exact_expert_visitation(mdp), _model(mdp), MaxEntIRLConfig(method="maxent")))


def _record(env_id: str, path, episodes: int = 50) -> DemoDataset:
    env = gym.make(env_id)
    with DemoWriter(path, env_id=env_id, observation_space=env.observation_space, action_space=env.action_space) as writer:
        run_episodes(RecordEpisodes(env, writer), load_expert("scripted", env, seed=0), episodes=episodes, seed=0, progress=False)
    return DemoDataset([path])


@pytest.mark.parametrize(("env_id", "hidden_sizes"), [
    ("imitation/GridWorld8x8-v0", []), ("imitation/GridWorld8x8Slippery-v0", []), ("imitation/GridWorld8x8Slippery-v0", [32, 32]),
])
def test_reward_from_50_recorded_episodes_earns_nine_tenths_of_the_experts_return(env_id: str, hidden_sizes: list[int], tmp_path) -> None:
    env = gym.make(env_id)
    mdp = env.unwrapped.mdp
    dataset = _record(env_id, tmp_path / "demos.mcap")
    target = demo_visitation(dataset.read_episodes(), n_states=mdp.n_states, horizon=mdp.horizon, discount=1.0)
    model = _model(mdp, hidden_sizes)
    run(MaxEntIRL(mdp, target, model, MaxEntIRLConfig(iterations=300)))
    learned = all_state_rewards(model, mdp.n_states).detach().double().numpy()
    dynamics = Dynamics.of(mdp.transition)
    returns = [expected_return(dynamics, mdp, policy) for policy in (
        soft_optimal_policy(mdp, learned), soft_optimal_policy(mdp), np.full((mdp.horizon, mdp.n_states, mdp.n_actions), 0.25),
    )]
    assert (returns[0] - returns[2]) / (returns[1] - returns[2]) >= 0.9


def test_episodes_transitions_and_a_loader_give_the_same_demo_visitation(tmp_path) -> None:
    mdp = gridworld()
    dataset = _record("imitation/GridWorld8x8-v0", tmp_path / "demos.mcap", episodes=7)
    episodes = dataset.read_episodes()
    from_episodes = demo_visitation(episodes, n_states=mdp.n_states, horizon=mdp.horizon, discount=1.0)
    from_transitions = demo_visitation(episodes_to_transitions(episodes), n_states=mdp.n_states, horizon=mdp.horizon, discount=1.0)
    from_loader = demo_visitation(iter(dataset), n_states=mdp.n_states, horizon=mdp.horizon, discount=1.0)
    assert np.allclose(from_episodes, from_transitions) and np.allclose(from_episodes, from_loader)
    assert from_episodes.sum() == pytest.approx(mdp.horizon + 1)
    with pytest.raises(ImitationError, match="no time index"):
        demo_visitation(episodes_to_transitions(episodes), n_states=mdp.n_states, horizon=mdp.horizon, discount=0.9)


def test_one_demo_episode_is_enough_and_none_is_refused(tmp_path) -> None:
    mdp = gridworld()
    (episode,) = _record("imitation/GridWorld8x8-v0", tmp_path / "one.mcap", episodes=1).read_episodes()
    visitation = demo_visitation([episode], n_states=mdp.n_states, horizon=mdp.horizon, discount=0.9)
    expected = np.zeros(mdp.n_states)
    np.add.at(expected, np.asarray(episode.observations).astype(int), 0.9 ** np.arange(mdp.horizon + 1))
    np.testing.assert_allclose(visitation, expected)
    with pytest.raises(ImitationError, match="no demo episodes"):
        demo_visitation([], n_states=mdp.n_states, horizon=mdp.horizon, discount=1.0)


def test_unvisited_high_states_keep_their_zero_and_bad_states_are_named() -> None:
    """Visitation has one entry per state, also past the highest state visited (transitions and
    the sparse forward pass alike); a state outside the MDP is named with where it came from."""
    episode = Episode(observations=np.array([0, 1, 1]), actions=np.array([0, 0]), rewards=np.zeros(2), terminated=False, truncated=True)
    transitions = episodes_to_transitions([episode])
    np.testing.assert_allclose(demo_visitation(transitions, n_states=5, horizon=2, discount=1.0), [1, 2, 0, 0, 0])
    mdp = random_mdp(seed=3, n_states=300)
    unreachable = mdp.transition.copy()
    unreachable[..., -1] = 0.0
    unreachable /= unreachable.sum(-1, keepdims=True)
    sparse = Dynamics.of(unreachable)
    assert isinstance(sparse, SparseDynamics)
    mass = sparse.propagate(np.full((300, mdp.n_actions), 1.0 / (300 * mdp.n_actions)))
    assert mass.shape == (300,) and mass[-1] == 0.0
    with pytest.raises(ImitationError, match="transitions: observation 7 is not a state"):
        demo_visitation(episodes_to_transitions([dataclasses.replace(episode, observations=np.array([0, 7, 1]))]), n_states=5, horizon=2, discount=1.0)
    with pytest.raises(ImitationError, match="demo episode 1: observation 9 is not a state"):
        demo_visitation([episode, dataclasses.replace(episode, observations=np.array([9, 1, 1]))], n_states=5, horizon=2, discount=1.0)
    # State indices run 0 … S - 1: S itself is out, as an episode's state or a final next-observation.
    one_past = dataclasses.replace(episode, observations=np.array([0, 1, 5]))
    with pytest.raises(ImitationError, match="demo episode 0: observation 5 is not a state of an MDP with 5 states"):
        demo_visitation([one_past], n_states=5, horizon=2, discount=1.0)
    with pytest.raises(ImitationError, match="transitions: observation 5 is not a state of an MDP with 5 states"):
        demo_visitation(episodes_to_transitions([one_past]), n_states=5, horizon=2, discount=1.0)


def test_demo_episodes_of_the_wrong_length_are_refused(tmp_path) -> None:
    episodes = _record("imitation/GridWorld8x8-v0", tmp_path / "demos.mcap", episodes=2).read_episodes()
    with pytest.raises(ImitationError, match="demo episode 0 has 30 steps, but the MDP's horizon is 20"):
        demo_visitation(episodes, n_states=64, horizon=20, discount=1.0)


def _finite_difference_of_start_value(dynamics: Dynamics, initial: np.ndarray, reward: np.ndarray, states, *, horizon, discount, method) -> np.ndarray:
    """∂(ρ₀·V_0)/∂r(s) by central differences, for each s in `states`."""
    gradient = np.empty(len(states))
    for i, s in enumerate(states):
        step = np.zeros(len(reward))
        step[s] = 1e-5
        high = initial @ soft_value_iteration(dynamics, reward + step, horizon=horizon, discount=discount, method=method)[1]
        low = initial @ soft_value_iteration(dynamics, reward - step, horizon=horizon, discount=discount, method=method)[1]
        gradient[i] = (high - low) / 2e-5
    return gradient


@pytest.mark.parametrize("horizon", [12, None])
@pytest.mark.parametrize(("method", "slip"), [("mce", 0.2), ("mce", 0.0), ("maxent", 0.0)])
def test_discounted_visitation_is_the_gradient_of_the_soft_start_value(horizon: int | None, method: str, slip: float) -> None:
    """At γ = 0.9, ∂(ρ₀·V_0)/∂r(s) = D(s) = Σ_t γ^t D_t(s) of the soft-optimal policy: the identity
    behind ∇L = D̃ - D_θ, which holds only if the backward and forward passes discount alike."""
    mdp = gridworld(slip=slip, horizon=12)
    dynamics = Dynamics.of(mdp.transition)
    reward = np.random.default_rng(0).normal(size=mdp.n_states)
    policy, _ = soft_value_iteration(dynamics, reward, horizon=horizon, discount=0.9, method=method)
    visitation = state_visitation(dynamics, mdp.initial, policy, horizon=horizon, discount=0.9)
    states = np.argsort(-visitation)[:12]  # the most visited, where a wrong discount shows most
    gradient = _finite_difference_of_start_value(dynamics, mdp.initial, reward, states, horizon=horizon, discount=0.9, method=method)
    np.testing.assert_allclose(gradient, visitation[states], atol=1e-6)
    # The undiscounted occupancy is another vector: the test tells γ from no γ.
    if horizon is not None:
        undiscounted = state_visitation(dynamics, mdp.initial, policy, horizon=horizon, discount=1.0)
        assert np.abs(undiscounted - visitation).max() > 0.1


def _stay_or_swap(horizon: int = 1, initial: tuple[float, float] = (1.0, 0.0)) -> TabularMDP:
    """Two states, action 0 stays and action 1 swaps, start in s0 (by default); one-hot features."""
    transition = np.array([[[1.0, 0.0], [0.0, 1.0]], [[0.0, 1.0], [1.0, 0.0]]])
    return TabularMDP(
        transition=transition, initial=np.array(initial), features=np.eye(2), reward=np.array([0.0, 1.0]), horizon=horizon
    )


def _linear_model(
    mdp: TabularMDP, weights: list[float], bias: float = 0.0, dtype: torch.dtype = torch.float32
) -> torch.nn.Module:
    """r(s) = w·x(s) + b with the weights given."""
    model = _model(mdp).to(dtype)
    with torch.no_grad():
        model.net[0].weight.copy_(torch.tensor([weights], dtype=torch.float64))
        model.net[0].bias.fill_(bias)
    return model


@pytest.mark.parametrize(("changes", "field"), [
    ({"iterations": 0}, "iterations"),
    ({"learning_rate": 0.0}, "learning_rate"),
    ({"learning_rate": 1e30}, "learning_rate"),
    ({"learning_rate": float("nan")}, "learning_rate"),
    ({"method": "soft"}, "method"),
])
def test_config_out_of_range_is_refused_naming_the_field(changes: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=f"^{field} ") as raised:
        MaxEntIRLConfig(**changes).validate()
    assert raised.value.owner == "MaxEntIRLConfig"


def test_config_at_the_edges_of_its_ranges_is_accepted() -> None:
    MaxEntIRLConfig(iterations=1, learning_rate=1e29).validate()
    MaxEntIRLConfig(learning_rate=1e-30).validate()


def test_one_iteration_by_hand() -> None:
    """Stay-or-swap, H = 1, r = (0, 1), demos D̃ = (1, 1). By hand (test_backward_pass_by_hand):
    V_0(s0) = log(1 + e), D = (1 + 1/(1+e), e/(1+e)); so the loss ρ₀·V_0 - D̃·r = log(1 + e) - 1, the
    error max |D - D̃| = 1/(1+e), and the gradient of (D - D̃)·r_θ is 1/(1+e)·(1, -1) for w and 0 for
    the bias. A fresh learner has not converged and has no policy or occupancy yet; a one-iteration
    run takes no Adam step, so the reward stays the one the row was computed for."""
    mdp = _stay_or_swap()
    model = _linear_model(mdp, [0.0, 1.0])
    learner = MaxEntIRL(mdp, np.array([1.0, 1.0]), model, MaxEntIRLConfig(iterations=1, learning_rate=0.5))
    assert learner.converged is False and learner.policy is None and learner.occupancy is None and not learner.done
    row = learner.step()
    p = 1 / (1 + np.e)
    expected = {"iteration": 1.0, "loss": np.log(1 + np.e) - 1, "occupancy_error": p, "gradient_norm": np.sqrt(2) * p}
    assert row == pytest.approx(expected, rel=1e-6)
    np.testing.assert_allclose(learner.occupancy, [1 + p, 1 - p], rtol=1e-6)
    assert learner.done and not learner.converged
    np.testing.assert_array_equal(all_state_rewards(model, 2).detach().numpy(), [0.0, 1.0])
    assert learner.progress(row) == {"error": f"{p:.2e}", "loss": f"{np.log(1 + np.e) - 1:.3f}"}


def test_visitation_matched_exactly_converges_even_at_zero_tolerance() -> None:
    """r = 0: the uniform policy visits (1, 0) then (½, ½), D = (1.5, 0.5) exactly; demos with that
    visitation are matched at the first iteration, error 0 ≤ tolerance 0."""
    mdp = _stay_or_swap()
    learner = MaxEntIRL(mdp, np.array([1.5, 0.5]), _linear_model(mdp, [0.0, 0.0]), MaxEntIRLConfig(tolerance=0.0))
    assert run(learner)[-1]["occupancy_error"] == 0.0
    assert learner.converged and learner.done and learner.completed == 1


@pytest.mark.parametrize(
    "demo_occupancy",
    [
        pytest.param([0.5, 3.5], id="the soft values overflow"),
        pytest.param([3.5, 0.5], id="the loss overflows too"),
    ],
)
def test_overflowing_reward_stops_as_diverged_without_numpy_warnings(demo_occupancy: list[float]) -> None:
    """A float64 reward near the largest double overflows the soft values (r + V = inf, then
    inf - inf in π = exp(Q - V)): the run stops with the divergence error, and numpy's overflow
    warnings stay silent. With the demos spread, D̃·r and ρ₀·V raise no warning themselves; with
    them on the rewarding state, D̃·r = 3.5e308 overflows too and the loss is inf - inf."""
    mdp = _stay_or_swap(horizon=3, initial=(0.5, 0.5))
    model = _linear_model(mdp, [1e308, 0.0], dtype=torch.float64)
    learner = MaxEntIRL(mdp, np.array(demo_occupancy), model, MaxEntIRLConfig())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ImitationError, match="iteration 1: the loss is .*diverged"):
            learner.step()


def test_a_non_finite_gradient_alone_stops_the_run() -> None:
    """Features of 3e38 with w = (1e-38, 0): r = (3, 0) and the loss are finite, but the float32
    gradient (D - D̃)·x overflows to ±inf; the run stops there rather than step Adam with it."""
    mdp = dataclasses.replace(_stay_or_swap(), features=np.eye(2) * 3e38)
    learner = MaxEntIRL(mdp, np.array([0.0, 2.0]), _linear_model(mdp, [1e-38, 0.0]), MaxEntIRLConfig())
    with pytest.raises(ImitationError, match=r"iteration 1: the loss is -?\d[\d.e+-]* and the gradient norm (inf|nan) \(diverged"):
        learner.step()


def test_checkpoint_counter_from_a_fresh_start_to_a_finished_run_and_no_further() -> None:
    """The checkpoint holds the next iteration, 1 (fresh) … iterations + 1 (finished); outside that
    range the checkpoint is refused, naming the counter and the range."""
    mdp = _stay_or_swap()

    def learner() -> MaxEntIRL:
        return MaxEntIRL(mdp, np.array([1.0, 1.0]), _linear_model(mdp, [0.0, 1.0]), MaxEntIRLConfig(iterations=3))

    tensors, state = learner().state_dict()
    assert state["iteration"] == 1
    for next_iteration, completed in [(1, 0), (4, 3)]:
        resumed = learner()
        resumed.load_state_dict((tensors, state | {"iteration": next_iteration}))
        assert resumed.completed == completed and resumed.done == (completed == 3)
    for bad in (0, 5):
        with pytest.raises(ImitationError, match=rf"the checkpoint's next iteration is {bad}, outside 1\.\.4 for this run"):
            learner().load_state_dict((tensors, state | {"iteration": bad}))


def test_states_given_as_a_column_count_as_a_flat_array() -> None:
    """Observations shaped (T + 1, 1), as a Box(1,) of state indices gives them, are flattened:
    the same visitation as from the flat array, from episodes and from transitions alike."""
    flat = Episode(
        observations=np.array([0, 1, 1]), actions=np.array([0, 0]), rewards=np.zeros(2), terminated=False, truncated=True
    )
    column = dataclasses.replace(flat, observations=flat.observations[:, None])
    expected = [1, 2, 0, 0, 0]
    np.testing.assert_allclose(demo_visitation([column], n_states=5, horizon=2, discount=1.0), expected)
    np.testing.assert_allclose(demo_visitation([column], n_states=5, horizon=2, discount=0.5), [1, 0.5 + 0.25, 0, 0, 0])
    from_transitions = demo_visitation(episodes_to_transitions([column]), n_states=5, horizon=2, discount=1.0)
    np.testing.assert_allclose(from_transitions, expected)

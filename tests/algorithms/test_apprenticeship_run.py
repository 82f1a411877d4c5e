"""What an apprenticeship run records and reports (imitation.algorithms.apprenticeship): the
tabular reward w·φ(s) it saves, the member `eval policy` gets, the mixture's summary in
metrics.json and the progress bar's fields, on the bundled gridworld demos."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from support import DATASETS

from imitation.algorithms.apprenticeship import (
    Apprenticeship,
    ApprenticeshipConfig,
    TabularSolver,
    mixture_summary,
    projection_step,
    reward_weights,
    set_reward_weights,
    tabular_feature_reward,
)
from imitation.algorithms.maxent_irl import demo_visitation
from imitation.checkpoints import snapshot
from imitation.data.dataset import DemoDataset
from imitation.envs.make import make_env
from imitation.envs.tabular import TabularMDP, tabular_mdp_of

ENV_ID = "imitation/GridWorld8x8Slippery-v0"


def learned() -> Apprenticeship:
    mdp = tabular_mdp_of(make_env(ENV_ID), where="test")
    episodes = DemoDataset([DATASETS / "GridWorld8x8Slippery-v0.mcap"]).read_episodes()
    mu_expert = demo_visitation(episodes, n_states=mdp.n_states, horizon=mdp.horizon, discount=1.0) @ mdp.features
    learner = Apprenticeship(TabularSolver(mdp, 1.0), mu_expert, ApprenticeshipConfig(iterations=4, tolerance=0.0))
    while not learner.done:
        row = learner.step()
    assert learner.progress(row) == {"distance": f"{row['relative_distance']:.3f}", "alpha": f"{row['alpha']:.2f}"}
    return learner


def test_the_tabular_reward_is_w_dot_phi_of_each_state() -> None:
    env = make_env(ENV_ID)
    mdp = tabular_mdp_of(env, where="test")
    reward = tabular_feature_reward(env.observation_space, env.action_space, mdp.features)
    states = torch.arange(mdp.n_states)
    actions = torch.zeros(mdp.n_states, dtype=torch.long)
    assert torch.equal(reward.rewards_of(states, actions, states), torch.zeros(mdp.n_states))  # w starts at 0
    weights = np.linspace(-1.0, 2.0, mdp.features.shape[1])
    set_reward_weights(reward, weights)
    expected = torch.as_tensor(mdp.features @ weights, dtype=torch.float32)
    torch.testing.assert_close(reward.rewards_of(states, actions, states), expected)


def test_the_member_eval_policy_gets_is_the_solvers_policy_nearest_mu_e_and_the_summary_is_the_mixture() -> None:
    learner = learned()
    distances = np.linalg.norm(learner.mus - learner.mu_expert, axis=1)
    assert learner.closest() == 1 + int(np.argmin(distances[1:]))  # never π^(0), the random policy
    summary = mixture_summary(learner)
    assert summary == {
        "lambdas": learner.lambdas.tolist(),
        "feature_expectations": learner.mus.tolist(),
        "reward_weights": learner.weights.tolist(),
        "mixture_feature_expectations": learner.mu_bar.tolist(),
        "expert_feature_expectations": learner.mu_expert.tolist(),
    }
    assert len(summary["lambdas"]) == len(summary["feature_expectations"]) == 5 and len(summary["reward_weights"]) == 4


def test_the_random_policy_is_never_the_member_chosen_even_when_nearest() -> None:
    learner = learned()
    learner.mus[0] = learner.mu_expert  # π^(0) exactly at μ_E
    learner.mus[2] = learner.mu_expert + 1e-3
    assert learner.closest() == 2


def two_state_mdp(horizon: int | None) -> TabularMDP:
    transition = np.zeros((2, 2, 2))
    transition[:, 0, 0] = transition[:, 1, 1] = 1.0  # action a moves to state a
    return TabularMDP(
        transition=transition, initial=np.array([1.0, 0.0]), features=np.eye(2), reward=np.array([0.0, 1.0]), horizon=horizon
    )


@pytest.mark.parametrize(("horizon", "discount", "shape"), [(None, 0.9, (2, 2)), (3, 1.0, (3, 2, 2))])
def test_the_tabular_solvers_checkpoint_round_trips_before_and_after_its_first_policy(
    horizon: int | None, discount: float, shape: tuple[int, ...]
) -> None:
    """A checkpoint taken before any policy (a run stopped at once) holds none; later ones hold
    each policy, stationary (S, A) without a horizon and (H, S, A) with one."""
    solver = TabularSolver(two_state_mdp(horizon), discount)
    empty = snapshot(*solver.state_dict())
    assert empty[0]["policies"].shape == (0, *shape)
    restored = TabularSolver(two_state_mdp(horizon), discount)
    restored.load_state_dict(empty)
    assert restored.policies == []
    solver.random_policy()
    solver.solve(np.array([0.0, 1.0]))
    restored.load_state_dict(snapshot(*solver.state_dict()))
    assert [policy.shape for policy in restored.policies] == [shape, shape]
    np.testing.assert_array_equal(np.stack(restored.policies), np.stack(solver.policies))
    np.testing.assert_array_equal(restored.policies[1][..., 0, :], np.tile([0.0, 1.0], (*shape[:-2], 1)))  # go to state 1


def test_a_checkpoint_for_another_mdps_shape_is_refused_naming_both_shapes() -> None:
    other = TabularSolver(two_state_mdp(3), 1.0)
    other.random_policy()
    with pytest.raises(ValueError, match=r"policies of shape \(3, 2, 2\), the MDP's are \(2, 2\)"):
        TabularSolver(two_state_mdp(None), 0.9).load_state_dict(snapshot(*other.state_dict()))


def test_a_resumed_run_counts_its_training_time_on_from_the_checkpoints() -> None:
    first = learned()
    tensors, state = snapshot(*first.state_dict())
    resumed = Apprenticeship(first.solver, first.mu_expert, first.config)
    resumed.load_state_dict((tensors, state))
    assert resumed.state_dict()[1]["seconds"] >= state["seconds"] > 0


def test_small_distances_and_steps_are_normalised_and_projected_too() -> None:
    weights, distance = reward_weights(np.array([0.3, 0.4]), np.zeros(2))
    assert distance == pytest.approx(0.5) and weights.tolist() == pytest.approx([0.6, 0.8])
    # μ̄ = 0, μ = (0.1, 0), μ_E = (0.05, 1): α = (0.1 · 0.05) / 0.01 = 0.5.
    mu_bar, alpha = projection_step(np.zeros(2), np.array([0.1, 0.0]), np.array([0.05, 1.0]))
    assert alpha == pytest.approx(0.5) and mu_bar.tolist() == pytest.approx([0.05, 0.0])
    ApprenticeshipConfig(iterations=1).validate()


@pytest.mark.parametrize("why", ["converged", "stalled"])
def test_a_run_stopped_early_stays_stopped_when_resumed_from_its_last_checkpoint(why: str) -> None:
    """A run that converged (or stalled) before its iteration budget, interrupted after its last
    checkpoint (during the final evaluation): the resumed run is done, as the uninterrupted one
    was, and reports the same reason."""
    if why == "converged":
        mdp = tabular_mdp_of(make_env(ENV_ID), where="test")
        episodes = DemoDataset([DATASETS / "GridWorld8x8Slippery-v0.mcap"]).read_episodes()
        mu_expert = demo_visitation(episodes, n_states=mdp.n_states, horizon=mdp.horizon, discount=1.0) @ mdp.features
        config = ApprenticeshipConfig(iterations=50, tolerance=0.05)
    else:  # μ_E = (0, 3) in the two-state MDP: the policy that stays in state 0 is all a reward can ask for
        mdp, mu_expert, config = two_state_mdp(3), np.array([0.0, 3.0]), ApprenticeshipConfig(iterations=50, tolerance=0.0)
    whole = Apprenticeship(TabularSolver(mdp, 1.0), mu_expert, config)
    while not whole.done:
        whole.step()
    assert whole.iterations < 50 and (whole.converged, whole.stalled) == (why == "converged", why == "stalled")
    resumed = Apprenticeship(TabularSolver(mdp, 1.0), mu_expert, config)
    resumed.load_state_dict(snapshot(*whole.state_dict()))
    assert resumed.done and (resumed.converged, resumed.stalled) == (whole.converged, whole.stalled)


@pytest.mark.parametrize("mu_expert", [(0.3, 0.4), (0.0, 0.0), (2.0, 1.0)], ids=["short", "zero", "long"])
def test_each_iterations_row_restates_the_projection(mu_expert: tuple[float, float]) -> None:
    """The row of iteration i: t = ‖μ_E − μ̄‖ before it (the margin), α, ‖μ_E − μ̄‖ after it, that
    over ‖μ_E‖ (or itself when μ_E = 0), and the new policy's own distance ‖μ^(i) − μ_E‖."""
    target = np.array(mu_expert)
    learner = Apprenticeship(TabularSolver(two_state_mdp(3), 1.0), target, ApprenticeshipConfig(iterations=3, tolerance=0.0))
    scale = float(np.linalg.norm(target))
    for i in range(1, 4):
        before = learner.mu_bar.copy() if i > 1 else None
        row = learner.step()
        if before is None:
            before = learner.mus[0]
        distance = float(np.linalg.norm(target - learner.mu_bar))
        assert row == pytest.approx(
            {
                "iteration": float(i),
                "distance": distance,
                "relative_distance": distance / scale if scale else distance,
                "margin": float(np.linalg.norm(target - before)),
                "alpha": learner.lambdas[-1],
                "policy_distance": float(np.linalg.norm(learner.mus[-1] - target)),
            }
        )
        if learner.done:
            break


def test_a_distance_exactly_at_the_tolerance_has_converged() -> None:
    """‖μ_E‖ = 1, so the tolerance is the distance itself; features ¼ keep μ within reach of it."""
    mdp = two_state_mdp(3)
    mdp = TabularMDP(transition=mdp.transition, initial=mdp.initial, features=mdp.features / 4, reward=mdp.reward, horizon=3)
    target = np.array([0.0, 1.0])
    probe = Apprenticeship(TabularSolver(mdp, 1.0), target, ApprenticeshipConfig(iterations=1, tolerance=0.0))
    probe.step()
    learner = Apprenticeship(TabularSolver(mdp, 1.0), target, ApprenticeshipConfig(iterations=5, tolerance=probe.distance))
    learner.step()
    assert learner.distance == probe.distance > 0 and learner.converged and learner.done

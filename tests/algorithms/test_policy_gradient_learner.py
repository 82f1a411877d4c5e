"""The policy-gradient learner's critic wiring (imitation.algorithms.policy_gradient): the weights
of a batch bootstrap from V(s_{t+1}) of the state that followed each step (the next step's state
inside an episode, the true final state where a time limit or a rollout's end cut it) and from
nothing after a termination. Checked on a hand-made batch against numbers worked by hand, and on
batches CartPole-v1 (which terminates) really produced, against a per-step restatement."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from imitation.algorithms.policy_gradient import Batch, PGConfig, PolicyGradient
from imitation.checkpoints import snapshot, unprefixed
from imitation.errors import ImitationError
from imitation.policies import ActorCritic, PolicyConfig

GAMMA = 0.5


def learner_with_critic_s0(**options) -> PolicyGradient:
    """A CartPole learner whose linear critic reads V(s) = s₀."""
    config = PGConfig(
        env_id="CartPole-v1", estimator="actor-critic", gamma=GAMMA, n_envs=1, batch_steps=5, hidden_sizes=[], **options
    )
    learner = PolicyGradient(config)
    with torch.no_grad():
        learner.policy.value_head.weight.copy_(torch.tensor([[1.0, 0.0, 0.0, 0.0]]))
        learner.policy.value_head.bias.zero_()
    return learner


def hand_batch() -> Batch:
    """Episode A: s₀ = 1, 2, 3, terminated; episode B: s₀ = 4, 5, truncated in the state s₀ = 7.
    Every reward 1."""
    features = torch.zeros(5, 4)
    features[:, 0] = torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0])
    final = torch.zeros(5, 4)
    final[4, 0] = 7.0
    return Batch(
        features=features,
        actions=torch.zeros(5, dtype=torch.long),
        rewards=torch.ones(5),
        terminated=torch.tensor([False, False, True, False, False]),
        truncated=torch.tensor([False, False, False, False, True]),
        final_features=final,
        episode_returns=[3.0, 2.0],
        pieces=2,
    )


@pytest.mark.parametrize(
    ("options", "advantages"),
    [
        # TD(0): δ_t = r_t + γ (1 − d_t) V(s_{t+1}) − V(s_t).
        # A: 1 + ½·2 − 1, 1 + ½·3 − 2, 1 − 3;  B: 1 + ½·5 − 4, 1 + ½·7 − 5.
        ({"gae_lambda": 0.0}, [1.0, 0.5, -2.0, -0.5, -0.5]),
        ({"n_step": 1}, [1.0, 0.5, -2.0, -0.5, -0.5]),
        # Two steps: r_t + γ r_{t+1} + γ² V(s_{t+2}), cut by the episode's end.
        # A: 1 + ½ + ¼·3 − 1, 1 + ½ − 2, 1 − 3;  B: 1 + ½ + ¼·7 − 4, 1 + ½·7 − 5.
        ({"n_step": 2}, [1.25, -0.5, -2.0, -0.75, -0.5]),
    ],
    ids=["gae-0", "td0", "2-step"],
)
def test_the_critic_bootstraps_from_the_next_state_and_not_after_a_termination(options: dict, advantages: list[float]) -> None:
    learner = learner_with_critic_s0(**options)
    try:
        weights, targets, values = learner.weights(hand_batch())
    finally:
        learner.close()
    assert values.tolist() == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert weights.tolist() == pytest.approx(advantages)
    assert targets.tolist() == pytest.approx([a + v for a, v in zip(advantages, [1.0, 2.0, 3.0, 4.0, 5.0])])


def td0_by_step(learner: PolicyGradient, batch: Batch) -> torch.Tensor:
    """δ_t of every step, one step at a time from the batch's flags."""
    value = learner.policy.value
    deltas = []
    with torch.no_grad():
        for t in range(len(batch.rewards)):
            following = 0.0
            if batch.truncated[t]:
                following = value(batch.final_features[t][None])[0]
            elif not batch.terminated[t]:
                following = value(batch.features[t + 1][None])[0]
            deltas.append(batch.rewards[t] + learner.config.gamma * following - value(batch.features[t][None])[0])
    return torch.stack([torch.as_tensor(delta, dtype=torch.float32) for delta in deltas])


@pytest.mark.parametrize("rollout_steps", [None, 30], ids=["episodes", "rollouts"])
def test_cartpole_batches_are_weighted_by_td0_of_the_state_each_step_reached(rollout_steps: int | None) -> None:
    """Whole episodes (CartPole-v1's random-policy episodes terminate) and 30-step rollouts of 4
    copies (pieces cut at the rollout's end are truncated and bootstrapped from where they got to)."""
    config = PGConfig(
        env_id="CartPole-v1",
        estimator="actor-critic",
        gae_lambda=0.0,
        gamma=0.9,
        n_envs=4,
        batch_steps=120,
        rollout_steps=rollout_steps,
        total_steps=2000,
        hidden_sizes=[8],
    )
    learner = PolicyGradient(config)
    try:
        for _ in range(2):  # the second batch with a critic that has been fitted once
            batch = learner.collect()
            assert batch.terminated.any()
            assert batch.truncated.any() == (rollout_steps is not None)
            weights, targets, values = learner.weights(batch)
            torch.testing.assert_close(weights, td0_by_step(learner, batch), rtol=1e-5, atol=1e-5)
            torch.testing.assert_close(targets, weights + values)
            learner.step()
    finally:
        learner.close()


def test_progress_shows_the_return_and_steps_and_a_config_reads_back_from_its_json() -> None:
    learner = learner_with_critic_s0(n_step=2)
    try:
        assert learner.progress({"return": 12.345, "step": 1024.0}) == {"ret": "12.3", "steps": "1024"}
    finally:
        learner.close()
    config = learner.config
    saved = dataclasses.asdict(config) | {"written_by": "a later version"}
    assert PGConfig.from_json(saved) == config


def test_the_checkpoint_alone_rebuilds_the_policy_and_a_damaged_one_is_one_line_naming_the_learner() -> None:
    learner = learner_with_critic_s0(n_step=2)
    try:
        learner.step()
        tensors, state = snapshot(*learner.state_dict())
        policy = ActorCritic(PolicyConfig.from_json(state["policy"]))
        policy.load_state_dict(unprefixed("policy", tensors))
        features = torch.randn(3, 4)
        assert torch.equal(policy.value(features), learner.policy.value(features))
        with pytest.raises(ImitationError, match=r"^the checkpoint's next batch is 1000000000, outside 0\.\.\d+ for this run"):
            learner.load_state_dict((tensors, state | {"batch": 10**9}))
        with pytest.raises(ImitationError, match=r"^the checkpoint does not fit this policy gradient run \(RuntimeError: Error\(s\) in loading"):
            learner.load_state_dict(({name: t for name, t in tensors.items() if name != "policy.value_head.weight"}, state))
    finally:
        learner.close()

"""Behavioural cloning: the loss is the one in the notes, early stopping keeps the best weights,
and short runs on the bundled demos clone the expert."""

from __future__ import annotations

import copy
import math
import time

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS

from imitation.algorithms.bc import SMALL_DATA, BCConfig, BehaviouralCloning, bc_loss, policy_options
from imitation.checkpoints import snapshot
from imitation.data.loader import TransitionTensors, load_transitions, transitions_to_torch
from imitation.data.mcap.reader import DemoFile
from imitation.envs.make import make_env
from imitation.errors import ConfigError, ImitationError
from imitation.evaluation.policy import evaluate_policy
from imitation.jobs.loop import run
from imitation.policies import SingleObservationPolicy, make_policy
from imitation.runs import read_checkpoint, save_checkpoint

BOX4 = gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)


def batch_of(observations: torch.Tensor, actions: torch.Tensor) -> TransitionTensors:
    n = len(observations)
    return TransitionTensors(
        observations=observations,
        actions=actions,
        rewards=torch.zeros(n),
        next_observations=None,
        terminated=torch.zeros(n, dtype=torch.bool),
        truncated=torch.zeros(n, dtype=torch.bool),
        episode_index=torch.zeros(n, dtype=torch.long),
    )


def test_discrete_loss_is_cross_entropy_and_regularisers_add_up() -> None:
    torch.manual_seed(0)
    policy = make_policy(BOX4, gym.spaces.Discrete(3), hidden_sizes=[8])
    torch.nn.init.normal_(policy.action_head.weight)  # so that the head's share of the L2 term shows
    batch = batch_of(torch.randn(10, 4), torch.randint(0, 3, (10,)))
    logits = policy.action_head(policy.actor_trunk(policy.encode(batch.observations)))
    cross_entropy = torch.nn.functional.cross_entropy(logits, batch.actions)
    loss, parts = bc_loss(policy, batch, BCConfig(l2_coef=0.0))  # unregularised (the default has a little weight decay)
    assert loss.item() == pytest.approx(cross_entropy.item(), rel=1e-5)
    entropy = torch.distributions.Categorical(logits=logits).entropy().mean()
    l2 = sum((p**2).sum() for n, p in policy.named_parameters() if n.startswith(("actor_trunk", "action_head")))
    regularised, _ = bc_loss(policy, batch, BCConfig(entropy_coef=0.1, l2_coef=0.01))
    assert regularised.item() == pytest.approx((cross_entropy - 0.1 * entropy + 0.01 * l2).item(), rel=1e-5)


def test_continuous_mse_loss_fits_the_mean() -> None:
    policy = make_policy(BOX4, gym.spaces.Box(-1, 1, (2,), np.float32), hidden_sizes=[8])
    batch = batch_of(torch.randn(6, 4), torch.randn(6, 2))
    mean = policy.action_head(policy.actor_trunk(policy.encode(batch.observations)))
    loss, _ = bc_loss(policy, batch, BCConfig(loss="mse", l2_coef=0.0))
    assert loss.item() == pytest.approx(((mean - batch.actions) ** 2).sum(-1).mean().item(), rel=1e-5)
    with pytest.raises(ImitationError, match="mse is for continuous"):
        BCConfig(loss="mse").validate(continuous=False)


def test_early_stopping_keeps_the_best_epoch() -> None:
    torch.manual_seed(0)
    # Labels unrelated to the inputs: validation loss can only get worse as training memorises noise.
    train = batch_of(torch.randn(64, 4), torch.randint(0, 2, (64,)))
    validation = batch_of(torch.randn(64, 4), torch.randint(0, 2, (64,)))
    policy = make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[64, 64])
    learner = BehaviouralCloning(
        policy, train, validation, BCConfig(epochs=200, patience=5, batch_size=16, learning_rate=1e-2)
    )
    history = run(learner)
    assert len(history) < 200
    best = min(history, key=lambda row: row["validation_loss"])
    assert learner.best_epoch == best["epoch"] and len(history) == learner.best_epoch + 5
    with torch.no_grad():
        final, _ = bc_loss(learner.policy, validation, BCConfig(l2_coef=0.0))
    assert final.item() == pytest.approx(best["validation_loss"], rel=1e-4)


@pytest.mark.parametrize(("env_id", "minimum"), [("CartPole-v1", 475.0)])
def test_short_bc_clones_the_bundled_expert(env_id: str, minimum: float) -> None:
    env = make_env(env_id)
    config = BCConfig(epochs=30, patience=30, seed=0)
    policy = make_policy(env.observation_space, env.action_space, **policy_options(config))
    data = transitions_to_torch(load_transitions(DATASETS / f"{env_id}.mcap", next_observations=False))
    learner = BehaviouralCloning(policy, data, None, config)
    run(learner)
    trained = learner.policy
    assert evaluate_policy(SingleObservationPolicy(trained), env, episodes=5, seed=0)["mean_return"] >= minimum


def test_short_bc_on_the_bundled_pendulum_demos_reaches_eight_tenths_of_the_expert() -> None:
    """The default suite's continuous learning check: 60 epochs of the default BC (seed 0) in a
    few seconds, normalised between uniform random actions (0) and the demos (1)."""
    env = make_env("Pendulum-v1")
    demos = DATASETS / "Pendulum-v1.mcap"
    env.action_space.seed(0)
    random_return = evaluate_policy(lambda o: env.action_space.sample(), env, episodes=10, seed=10_000)["mean_return"]
    expert_return = float(np.mean([f.episode_return for f in DemoFile(demos).episodes]))
    config = BCConfig(epochs=60, patience=60, seed=0)
    policy = make_policy(env.observation_space, env.action_space, **policy_options(config))
    learner = BehaviouralCloning(policy, transitions_to_torch(load_transitions(demos, next_observations=False)), None, config)
    run(learner)
    trained = learner.policy
    learned = evaluate_policy(SingleObservationPolicy(trained), env, episodes=10, seed=0)["mean_return"]
    assert (learned - random_return) / (expert_return - random_return) >= 0.8


@pytest.mark.slow
def test_acceptance_pendulum_normalised_return() -> None:
    env = make_env("Pendulum-v1")
    data = transitions_to_torch(load_transitions(DATASETS / "Pendulum-v1.mcap", next_observations=False))
    random_return = evaluate_policy(lambda o: env.action_space.sample(), env, episodes=20, seed=10_000)["mean_return"]
    expert_return = float(np.mean([f.episode_return for f in DemoFile(DATASETS / "Pendulum-v1.mcap").episodes]))
    config = BCConfig(seed=0)
    policy = make_policy(env.observation_space, env.action_space, **policy_options(config))
    learner = BehaviouralCloning(policy, data, None, config)
    run(learner)
    trained = learner.policy
    learned = evaluate_policy(SingleObservationPolicy(trained), env, episodes=10, seed=0)["mean_return"]
    assert (learned - random_return) / (expert_return - random_return) >= 0.9


@pytest.mark.parametrize(
    ("settings", "field"),
    [
        ({"epochs": 1, "batch_size": 1, "patience": 1, "learning_rate": 1e-29}, None),  # the smallest allowed
        ({"epochs": 0}, "epochs"),
        ({"batch_size": 0}, "batch_size"),
        ({"patience": 0}, "patience"),
        ({"learning_rate": 0.0}, "learning_rate"),
        ({"learning_rate": 1e30}, "learning_rate"),  # the bound itself is out
        ({"learning_rate": float("nan")}, "learning_rate"),
    ],
)
def test_bc_config_accepts_counts_from_one_and_a_learning_rate_strictly_between_zero_and_1e30(
    settings: dict, field: str | None
) -> None:
    config = BCConfig(**settings)
    if field is None:
        config.validate(continuous=True)
    else:
        with pytest.raises(ConfigError, match=f"^{field} must be"):
            config.validate(continuous=True)


def learnable_batch(n: int, seed: int) -> TransitionTensors:
    """Action 1 exactly when the first observation is positive: a rule a small MLP learns fast."""
    observations = torch.randn(n, 4, generator=torch.Generator().manual_seed(seed))
    return batch_of(observations, (observations[:, 0] > 0).long())


def test_without_validation_the_lowest_training_loss_picks_the_weights_kept() -> None:
    torch.manual_seed(0)
    policy = make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[16])
    initial = copy.deepcopy(policy.state_dict())
    learner = BehaviouralCloning(
        policy,
        learnable_batch(64, 0),
        None,
        BCConfig(epochs=4, patience=4, batch_size=16, epoch_samples=64, learning_rate=1e-2),
    )
    history = run(learner)
    assert all(np.isnan(row["validation_loss"]) for row in history)
    assert learner.best_epoch == min(history, key=lambda row: row["train_loss"])["epoch"] > 0
    assert learner.best_loss == pytest.approx(min(row["train_loss"] for row in history))
    assert any(not torch.equal(learner.policy.state_dict()[name], tensor) for name, tensor in initial.items()), (
        "trained weights kept"
    )


def test_a_validation_loss_that_stops_changing_is_no_improvement_and_ends_the_run_after_patience_epochs() -> None:
    """A learning rate of 1e-29 moves no float32 weight, so every epoch's validation loss equals
    the first's exactly: a tie is not a new best, and the run stops `patience` epochs later."""
    torch.manual_seed(0)
    policy = make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[8])
    config = BCConfig(epochs=10, patience=2, batch_size=16, epoch_samples=32, learning_rate=1e-29)
    learner = BehaviouralCloning(policy, learnable_batch(32, 0), learnable_batch(16, 1), config)
    history = run(learner)
    assert len({row["validation_loss"] for row in history}) == 1
    assert (len(history), learner.best_epoch) == (3, 1)


def test_evaluate_gets_the_policy_in_eval_mode_every_few_epochs_and_at_the_last() -> None:
    torch.manual_seed(0)
    policy = make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[8])
    calls = []

    def evaluate(evaluated) -> float:
        calls.append((evaluated is policy, evaluated.training))
        return 7.0

    config = BCConfig(epochs=3, patience=3, batch_size=16, epoch_samples=16)
    learner = BehaviouralCloning(policy, learnable_batch(16, 0), None, config, evaluate=evaluate, evaluate_every=2)
    history = run(learner)
    np.testing.assert_array_equal([row["return"] for row in history], [np.nan, 7.0, 7.0])
    assert calls == [(True, False), (True, False)]
    assert learner.progress(history[1]) == {"train": f"{history[1]['train_loss']:.3f}", "val": "nan", "ret": "7.0"}


def test_bc_checkpoint_round_trip_restores_every_field_and_refuses_counters_outside_the_run(tmp_path) -> None:
    """Through the files, as a run does: the weights, the best weights so far (kept apart from the
    current ones), the best loss (inf before the first epoch, written as null), the counters and
    the clock come back; a next epoch outside 1 … epochs + 1 is refused, and so is a checkpoint
    of something else, as one line naming BC."""
    train, validation = learnable_batch(64, 0), learnable_batch(32, 1)
    config = BCConfig(epochs=4, patience=4, batch_size=16, epoch_samples=64, hidden_sizes=[8], learning_rate=0.05)

    def learner(seed: int) -> BehaviouralCloning:
        torch.manual_seed(seed)
        return BehaviouralCloning(make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[8]), train, validation, config)

    def through_files(original: BehaviouralCloning, folder: str):
        (tmp_path / folder).mkdir()
        save_checkpoint(tmp_path / folder, *snapshot(*original.state_dict()))
        return read_checkpoint(tmp_path / folder)

    fresh = learner(0)
    restored = learner(1)
    restored.load_state_dict(through_files(fresh, "fresh"))
    assert (restored.best_loss, restored.best_epoch, restored.epochs, restored.samples) == (float("inf"), 0, 0, 0)

    original = learner(0)
    for _ in range(2):
        original.step()
    original.best_state = {name: tensor + 1.0 for name, tensor in original.best_state.items()}  # unlike the current weights
    checkpoint = through_files(original, "trained")
    restored = learner(1)
    restored.load_state_dict(checkpoint)
    for name, tensor in original.policy.state_dict().items():
        assert torch.equal(restored.policy.state_dict()[name], tensor), name
    assert restored.best_state.keys() == original.best_state.keys()
    for name, tensor in original.best_state.items():
        assert torch.equal(restored.best_state[name], tensor), name
    assert np.isfinite(original.best_loss)
    assert (restored.best_loss, restored.best_epoch, restored.epochs, restored.samples) == (
        original.best_loss,
        original.best_epoch,
        2,
        original.samples,
    )
    tensors, state = checkpoint
    for epoch in (1, 5):  # the first epoch, and a finished run
        learner(1).load_state_dict((tensors, state | {"epoch": epoch}))
    for epoch in (0, 6):
        with pytest.raises(ImitationError, match=f"the checkpoint's next epoch is {epoch}, outside 1..5"):
            learner(1).load_state_dict((tensors, state | {"epoch": epoch}))
    with pytest.raises(ImitationError, match="does not fit this BC run"):
        learner(1).load_state_dict(({}, {}))


@pytest.mark.parametrize(
    ("transitions", "activation"),
    [(None, "relu"), (0, "tanh"), (SMALL_DATA - 1, "tanh"), (SMALL_DATA, "relu"), (10 * SMALL_DATA, "relu")],
)
def test_policy_options_resolve_auto_to_tanh_below_small_data_and_normalise_both_sides(
    transitions: int | None, activation: str
) -> None:
    config = BCConfig(hidden_sizes=[32, 16])
    assert policy_options(config, transitions) == {
        "hidden_sizes": [32, 16],
        "activation": activation,
        "normalize_observations": True,
        "normalize_actions": True,
        "history": 1,
        "chunk": 1,
        "execute": None,
        "ensemble": None,
        "angles": [],
        "denoising_steps": 100,
        "sampling_steps": 10,
        "sampling_noise": 1.0,
        "prediction": "sample",
        "members": 1,
    }
    assert policy_options(BCConfig(activation="elu"), transitions)["activation"] == "elu"  # a named one stays


def test_a_continuous_policy_takes_the_mse_loss_and_gets_its_action_normaliser_fitted_to_the_training_actions() -> None:
    torch.manual_seed(0)
    box2 = gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)
    policy = make_policy(BOX4, box2, hidden_sizes=[8], normalize_actions=True)
    actions = torch.tensor([[1.0, 10.0], [3.0, 10.0], [5.0, 10.0], [7.0, 10.0], [9.0, 10.0]])
    BehaviouralCloning(policy, batch_of(torch.randn(5, 4), actions), None, BCConfig(loss="mse", epochs=1))
    assert torch.allclose(policy.action_mean, torch.tensor([5.0, 10.0]))
    assert torch.allclose(policy.action_scale, torch.tensor([math.sqrt(8.0), 1.0]))  # a still dimension keeps 1
    discrete = make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[8])
    with pytest.raises(ConfigError, match="mse is for continuous"):
        BehaviouralCloning(discrete, learnable_batch(4, 0), None, BCConfig(loss="mse", epochs=1))


def test_an_epoch_goes_through_at_least_epoch_samples_in_whole_passes_and_reports_samples_per_second() -> None:
    """24 transitions and epoch_samples 40: two passes (48 samples, three batches of 16) an epoch;
    the rate is the samples so far over the training seconds so far."""
    torch.manual_seed(0)
    policy = make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[8])
    config = BCConfig(epochs=2, patience=2, batch_size=16, epoch_samples=40)
    learner = BehaviouralCloning(policy, learnable_batch(24, 0), None, config)
    started = time.perf_counter()
    rows = [learner.step(), learner.step()]
    elapsed = time.perf_counter() - started
    assert learner.state_dict()[1]["samples"] == 96
    assert 0 < elapsed < 1  # so that samples · seconds cannot pass for samples / seconds
    assert rows[1]["samples_per_second"] >= 96 / elapsed
    assert rows[0]["samples_per_second"] >= 48 / elapsed


def test_the_seed_decides_the_minibatch_order() -> None:
    """BC draws nothing else at random once the policy is built: from the same weights and data,
    the same seed repeats an epoch exactly and another seed shuffles it differently."""
    torch.manual_seed(0)
    policy = make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[8])
    data = learnable_batch(64, 0)

    def one_epoch(seed: int) -> dict[str, torch.Tensor]:
        config = BCConfig(epochs=1, batch_size=8, epoch_samples=64, learning_rate=0.05, seed=seed)
        learner = BehaviouralCloning(copy.deepcopy(policy), data, None, config)
        learner.step()
        return learner.policy.state_dict()

    first, again, other = one_epoch(1), one_epoch(1), one_epoch(0)
    assert all(torch.equal(first[name], again[name]) for name in first)
    assert not all(torch.equal(first[name], other[name]) for name in first)


def test_evaluate_runs_every_five_epochs_by_default_and_progress_shows_no_return_without_one() -> None:
    torch.manual_seed(0)
    policy = make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[8])
    config = BCConfig(epochs=7, patience=7, batch_size=16, epoch_samples=16)
    learner = BehaviouralCloning(policy, learnable_batch(16, 0), None, config, evaluate=lambda p: 3.0)
    history = run(learner)
    assert [row["epoch"] for row in history if np.isfinite(row["return"])] == [5.0, 7.0]
    assert learner.progress(history[0]) == {"train": f"{history[0]['train_loss']:.3f}", "val": "nan"}


@pytest.mark.parametrize(
    ("action_space", "options"),
    [
        (gym.spaces.Discrete(2), {}),
        (gym.spaces.MultiDiscrete([2, 3]), {}),
        (gym.spaces.Box(-1, 1, (2,), np.float32), {}),
        (gym.spaces.Box(-1, 1, (2,), np.float32), {"normalize_actions": True}),
    ],
    ids=["categorical", "multi-categorical", "gaussian", "normalised gaussian"],
)
def test_a_diverging_run_stops_with_one_line_naming_the_epoch_whatever_the_head(action_space, options) -> None:
    """A learning rate of 1e29 throws the weights to ±1e29 in one Adam step, so the next batch's
    distribution has non-finite parameters: that is the loss check's to report (torch's argument
    validation, were it on, would raise its own ValueError first)."""
    torch.manual_seed(0)
    policy = make_policy(BOX4, action_space, hidden_sizes=[8], activation="relu", **options)
    observations = torch.randn(64, 4, generator=torch.Generator().manual_seed(0))
    action_space.seed(0)
    actions = torch.from_numpy(np.stack([action_space.sample() for _ in range(64)]))
    config = BCConfig(epochs=3, batch_size=16, epoch_samples=64, learning_rate=1e29, l2_coef=0.0)
    learner = BehaviouralCloning(policy, batch_of(observations, actions), None, config)
    with pytest.raises(
        ImitationError, match=r"^BC epoch 1: the loss is (nan|inf|-inf) \(diverged; try a lower learning rate\)$"
    ):
        run(learner)

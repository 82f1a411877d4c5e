"""The policy heads against closed forms; save/load round trip; env action mapping."""

from __future__ import annotations

import math
import re

import gymnasium as gym
import numpy as np
import pytest
import torch

from imitation.errors import ImitationError
from imitation.mlp import check_layer_widths
from imitation.policies import (
    PolicyConfig,
    RunningMeanStd,
    SingleObservationPolicy,
    check_policy_fits_env,
    make_policy,
    policy_tensors,
)
from imitation.policy_kinds import load_policy
from imitation.runs import RunWriter

BOX4 = gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)


def test_categorical_log_prob_and_entropy_match_softmax() -> None:
    torch.manual_seed(0)
    policy = make_policy(BOX4, gym.spaces.Discrete(3), hidden_sizes=[8])
    torch.nn.init.normal_(policy.action_head.weight)  # leave the near-uniform initial policy
    features = torch.randn(5, 4)
    logits = policy.action_head(policy.actor_trunk(features))
    probabilities = torch.softmax(logits, -1)
    actions = torch.tensor([0, 1, 2, 1, 0])
    log_prob, entropy = policy.log_prob_and_entropy(policy.distribution(features), actions)
    assert torch.allclose(log_prob, torch.log(probabilities[torch.arange(5), actions]))
    assert torch.allclose(entropy, -(probabilities * probabilities.log()).sum(-1))


def test_gaussian_log_prob_and_entropy_match_closed_form() -> None:
    torch.manual_seed(0)
    policy = make_policy(BOX4, gym.spaces.Box(-1, 1, (2,), np.float32), hidden_sizes=[8], log_std_init=-0.3)
    with torch.no_grad():
        policy.log_std.copy_(torch.tensor([-0.3, 0.4]))
    features, actions = torch.randn(6, 4), torch.randn(6, 2)
    mean = policy.action_head(policy.actor_trunk(features))
    sigma = torch.tensor([math.exp(-0.3), math.exp(0.4)])
    expected_log_prob = (-((actions - mean) ** 2) / (2 * sigma**2) - sigma.log() - 0.5 * math.log(2 * math.pi)).sum(-1)
    expected_entropy = (0.5 * math.log(2 * math.pi * math.e) + sigma.log()).sum()
    log_prob, entropy = policy.log_prob_and_entropy(policy.distribution(features), actions)
    assert torch.allclose(log_prob, expected_log_prob, atol=1e-5)
    assert torch.allclose(entropy, expected_entropy.expand(6), atol=1e-6)


def test_rollout_samples_carry_the_gaussian_log_density_of_the_unclipped_action() -> None:
    """`sample` writes the log-density out by hand: -(a-μ)²/2σ² - log σ - ½ log 2π per dim, of
    the unclipped sample, also where the env receives it clipped to the bounds."""
    torch.manual_seed(0)
    policy = make_policy(BOX4, gym.spaces.Box(-0.5, 0.5, (2,), np.float32), hidden_sizes=[8])
    with torch.no_grad():
        policy.log_std.copy_(torch.tensor([0.7, -0.4]))
    features = torch.randn(500, 4)
    action, log_prob, mean = policy.sample(features)
    sigma = torch.tensor([math.exp(0.7), math.exp(-0.4)])
    expected = (-((action - mean) ** 2) / (2 * sigma**2) - sigma.log() - 0.5 * math.log(2 * math.pi)).sum(-1)
    assert torch.allclose(log_prob, expected, atol=1e-5)
    assert torch.allclose(log_prob, policy.log_prob(policy.distribution(features), action), atol=1e-5)
    clipped = (action.abs() > 0.5).any(-1)
    assert clipped.sum() > 100 and (np.abs(policy.to_env_action(action)) <= 0.5).all()
    # The samples are N(μ, σ²): their spread is σ per dim.
    assert torch.allclose((action - mean).std(0), sigma, rtol=0.1)


def test_multi_discrete_head_is_independent_categoricals_over_class_indices() -> None:
    torch.manual_seed(0)
    space = gym.spaces.MultiDiscrete([3, 2], start=[1, -1])
    policy = make_policy(BOX4, space, hidden_sizes=[8])
    torch.nn.init.normal_(policy.action_head.weight)
    features = torch.randn(400, 4)
    logits = policy.action_head(policy.actor_trunk(features))
    first, second = torch.log_softmax(logits[:, :3], -1), torch.log_softmax(logits[:, 3:], -1)
    indices = torch.stack([torch.randint(0, 3, (400,)), torch.randint(0, 2, (400,))], -1)
    expected = first.gather(-1, indices[:, :1]).squeeze(-1) + second.gather(-1, indices[:, 1:]).squeeze(-1)
    distribution = policy.distribution(features)
    log_prob, entropy = policy.log_prob_and_entropy(distribution, indices)
    assert torch.allclose(log_prob, expected, atol=1e-6)
    assert torch.allclose(entropy, -(first.exp() * first).sum(-1) - (second.exp() * second).sum(-1), atol=1e-6)
    action, sampled_log_prob, parameters = policy.sample(features)
    assert torch.allclose(sampled_log_prob, policy.log_prob(distribution, action), atol=1e-6)
    assert torch.allclose(parameters, torch.cat([first, second], -1), atol=1e-6)
    # Env actions are index + start, and back.
    env_actions = policy.to_env_action(action)
    assert env_actions.dtype == space.dtype and all(a in space for a in env_actions)
    assert torch.equal(policy.from_env_action(torch.as_tensor(env_actions)), action)
    assert torch.allclose(policy.env_action_log_prob(distribution, torch.as_tensor(env_actions)), sampled_log_prob, atol=1e-6)
    assert (policy.predict(features[:5].numpy()) == (distribution.mode[:5] + torch.tensor([1, -1])).numpy()).all()


def test_shifted_discrete_actions_reach_the_env_as_index_plus_start() -> None:
    policy = make_policy(BOX4, gym.spaces.Discrete(3, start=1), hidden_sizes=[4])
    assert policy.to_env_action(torch.tensor([0, 1, 2])).tolist() == [1, 2, 3]
    assert policy.from_env_action(torch.tensor([1, 2, 3])).tolist() == [0, 1, 2]


def test_gaussian_env_actions_are_clipped_to_the_bounds() -> None:
    policy = make_policy(BOX4, gym.spaces.Box(np.array([-2.0], np.float32), np.array([1.0], np.float32)))
    env_actions = policy.to_env_action(torch.tensor([[-5.0], [0.5], [7.0]]))
    assert env_actions.dtype == np.float32 and env_actions[:, 0].tolist() == [-2.0, 0.5, 1.0]


def test_env_action_log_prob_is_the_censored_gaussian_at_the_bounds_and_the_density_inside() -> None:
    torch.manual_seed(0)
    policy = make_policy(
        BOX4,
        gym.spaces.Box(np.array([-2.0, -1.0]), np.array([2.0, 1.0]), dtype=np.float32),
        hidden_sizes=[8],
        log_std_init=-0.5,
    )
    features = torch.randn(3, 4)
    distribution = policy.distribution(features)
    mean, sigma = distribution.mean, distribution.stddev
    actions = torch.tensor([[2.0, 0.3], [-2.0, -1.0], [0.5, 1.0]])
    normal = torch.distributions.Normal(mean, sigma)
    expected = torch.stack(
        [
            torch.log(1 - normal.cdf(torch.tensor([2.0, 1.0])))[0, 0] + normal.log_prob(actions)[0, 1],  # high bound: P(a ≥ 2)
            torch.log(normal.cdf(torch.tensor([-2.0, -1.0])))[1].sum(),  # both at the low bound: P(a ≤ low)
            normal.log_prob(actions)[2, 0] + torch.log(1 - normal.cdf(torch.tensor([2.0, 1.0])))[2, 1],
        ]
    )
    assert torch.allclose(policy.env_action_log_prob(distribution, actions), expected, atol=1e-5)
    # Inside the bounds it is the policy's own log-density.
    inside = torch.tensor([[0.1, -0.2], [1.9, 0.99], [-1.5, 0.0]])
    assert torch.allclose(policy.env_action_log_prob(distribution, inside), policy.log_prob(distribution, inside))
    discrete = make_policy(BOX4, gym.spaces.Discrete(3, start=1), hidden_sizes=[8])
    categorical = discrete.distribution(features)
    assert torch.allclose(
        discrete.env_action_log_prob(categorical, torch.tensor([1, 3, 2])),
        discrete.log_prob(categorical, torch.tensor([0, 2, 1])),
    )


def test_discrete_observations_are_one_hot_over_the_whole_space() -> None:
    """Discrete(5, start=2): value v is one-hot at v - 2 in 5 columns, whichever values a batch holds."""
    policy = make_policy(gym.spaces.Discrete(5, start=2), gym.spaces.Discrete(2), hidden_sizes=[4])
    assert policy.encode(torch.tensor([2, 3])).tolist() == [[1, 0, 0, 0, 0], [0, 1, 0, 0, 0]]


def test_discrete_observations_are_one_hot() -> None:
    policy = make_policy(gym.spaces.Discrete(5, start=1), gym.spaces.Discrete(2))
    assert policy.encode(torch.tensor([1, 5])).tolist() == [[1, 0, 0, 0, 0], [0, 0, 0, 0, 1]]


def test_observation_normaliser_tracks_mean_and_variance() -> None:
    policy = make_policy(BOX4, gym.spaces.Discrete(2), normalize_observations=True)
    data = torch.randn(1000, 4) * torch.tensor([1.0, 2.0, 3.0, 4.0]) + 5.0
    for chunk in data.split(100):
        policy.update_normalizer(chunk)
    assert torch.allclose(policy.obs_rms.mean.float(), data.mean(0), atol=1e-4)
    assert torch.allclose(policy.obs_rms.var.float(), data.var(0, unbiased=False), rtol=1e-3)


def test_a_batch_larger_than_one_piece_updates_the_normaliser_exactly_as_a_whole() -> None:
    """RunningMeanStd folds a batch in pieces of 2^23 numbers (a bounded float64 copy): a batch of
    three and a half pieces must give the whole batch's mean and variance."""
    from imitation.policies import RunningMeanStd

    stats = RunningMeanStd((64,), epsilon=0.0)
    data = torch.randn(7 * 2**16, 64, dtype=torch.float64) * 3.0 + 2.0
    stats.update(data.float())
    assert stats.count.item() == len(data)
    torch.testing.assert_close(stats.mean, data.float().double().mean(0), rtol=0, atol=1e-9)
    torch.testing.assert_close(stats.var, data.float().double().var(0, unbiased=False), rtol=1e-9, atol=0)


def test_normalised_observations_are_standardised_then_clipped_at_ten() -> None:
    """(x - μ) / √(σ² + 1e-8), clipped to ±10; a constant dimension (σ² = 0) stays finite."""
    policy = make_policy(BOX4, gym.spaces.Discrete(2), normalize_observations=True)
    with torch.no_grad():
        policy.obs_rms.mean.copy_(torch.tensor([1.0, -2.0, 0.0, 3.0], dtype=torch.float64))
        policy.obs_rms.var.copy_(torch.tensor([4.0, 0.25, 0.0, 1e-6], dtype=torch.float64))
    x = torch.tensor([[3.0, -2.5, 0.0, 3.001], [-100.0, 100.0, 1.0, 2.0]])
    expected = ((x.double() - policy.obs_rms.mean) / torch.sqrt(policy.obs_rms.var + 1e-8)).clamp(-10, 10).float()
    features = policy.encode(x)
    assert torch.allclose(features, expected, atol=1e-6)
    assert features[0].tolist() == pytest.approx([1.0, -1.0, 0.0, 1.0 / np.sqrt(1.01e-6) * 1e-3], rel=1e-4)
    assert features[1, :2].tolist() == [-10.0, 10.0] and features[1, 2].item() == 10.0


def test_multi_discrete_samples_follow_each_components_probabilities() -> None:
    """Stochastic acting on MultiDiscrete: each component drawn from its own softmax, independently."""
    torch.manual_seed(0)
    policy = make_policy(BOX4, gym.spaces.MultiDiscrete([3, 2]), hidden_sizes=[8])
    with torch.no_grad():
        policy.action_head.weight.zero_()
        policy.action_head.bias.copy_(torch.log(torch.tensor([0.6, 0.3, 0.1, 0.2, 0.8])))
    features = torch.zeros(20_000, 4)
    action = policy.act(features)
    assert action.shape == (20_000, 2)
    first = torch.bincount(action[:, 0], minlength=3) / 20_000
    second = torch.bincount(action[:, 1], minlength=2) / 20_000
    assert torch.allclose(first, torch.tensor([0.6, 0.3, 0.1]), atol=0.015) and torch.allclose(
        second, torch.tensor([0.2, 0.8]), atol=0.015
    )
    sampled = policy.distribution(features[:5]).sample(torch.Size([7]))
    assert sampled.shape == (7, 5, 2)
    deterministic = policy.act(features[:3], deterministic=True)
    assert deterministic.tolist() == [[0, 1]] * 3


def test_saved_policy_acts_identically(tmp_path) -> None:
    policy = make_policy(BOX4, gym.spaces.Box(-1, 1, (2,), np.float32), normalize_observations=True, hidden_sizes=[16, 16])
    policy.update_normalizer(torch.randn(50, 4) * 3)
    run = RunWriter(tmp_path / "run", config={"kind": "ppo", "policy": policy.config.to_json()}, tensorboard=False)
    run.save_weights(policy_tensors(policy))
    run.finish({})
    restored = load_policy(tmp_path / "run")
    observations = np.random.default_rng(0).normal(size=(7, 4)).astype(np.float32)
    np.testing.assert_array_equal(restored.predict(observations), policy.predict(observations))


def test_loading_something_that_is_not_a_policy(tmp_path) -> None:
    with pytest.raises(ImitationError, match="not a run directory"):
        load_policy(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ImitationError, match="not a finished run directory"):
        load_policy(tmp_path / "empty")


def test_action_spaces_without_a_head_are_refused() -> None:
    with pytest.raises(ImitationError, match="policies take Discrete, MultiDiscrete or Box actions, not MultiBinary"):
        make_policy(BOX4, gym.spaces.MultiBinary(3))
    with pytest.raises(ImitationError, match=r"MultiDiscrete actions of one dimension, not of shape \(2, 2\)"):
        make_policy(BOX4, gym.spaces.MultiDiscrete([[2, 3], [4, 5]]))


def test_normalised_actions_are_a_gaussian_in_the_envs_units(tmp_path) -> None:
    """With normalize_actions, the head works in standardised units: π(·|s) = N(m + s·μ_θ(s), (s·σ)²)
    with m, s the training actions' mean and std per dimension (a still dimension keeps s = 1);
    log-probabilities, sampling and the saved policy all speak the env's units."""
    space = gym.spaces.Box(-np.inf, np.inf, (3,), np.float32)
    policy = make_policy(gym.spaces.Box(-1, 1, (2,), np.float32), space, hidden_sizes=[8], normalize_actions=True)
    # Four actions of three numbers (a non-square batch), and σ = 1/2 so that s·σ differs from s/σ.
    actions = torch.tensor([[10.0, -3.0, 7.0], [14.0, -1.0, 7.0], [12.0, -2.0, 7.0], [12.0, -2.0, 7.0]])
    policy.fit_action_normalizer(actions, torch.zeros(4, 2))
    assert torch.allclose(policy.action_mean, torch.tensor([12.0, -2.0, 7.0]))
    assert torch.allclose(policy.action_scale, torch.tensor([np.sqrt(2), np.sqrt(1 / 2), 1.0], dtype=torch.float32))
    with torch.no_grad():
        policy.log_std.fill_(math.log(0.5))
    features = policy.encode(torch.randn(5, 2))
    head = policy.action_head(policy.actor_trunk(features))
    distribution = policy.distribution(features)
    assert torch.allclose(distribution.mean, policy.action_mean + policy.action_scale * head)
    assert torch.allclose(distribution.stddev, (policy.action_scale * 0.5).expand(5, 3))
    expected = torch.distributions.Normal(
        policy.action_mean + policy.action_scale * head, policy.action_scale * policy.log_std.exp()
    )
    assert torch.allclose(policy.log_prob(distribution, actions[:1].expand(5, 3)), expected.log_prob(actions[:1]).sum(-1))
    plain = make_policy(gym.spaces.Box(-1, 1, (2,), np.float32), space, hidden_sizes=[8])
    plain.fit_action_normalizer(actions, torch.zeros(4, 2))  # nothing to fit: its head works in the env's units
    assert not hasattr(plain, "action_mean")

    from imitation.policies import policy_tensors
    from imitation.policy_kinds import load_policy
    from imitation.runs import RunWriter as Writer

    with Writer(
        tmp_path / "run", config={"kind": "bc", "env_id": None, "policy": policy.config.to_json()}, tensorboard=False
    ) as run:
        run.save_weights(policy_tensors(policy))
        run.finish({})
    loaded = load_policy(tmp_path / "run")
    observations = np.random.default_rng(0).normal(size=(4, 2)).astype(np.float32)
    assert np.allclose(loaded.predict(observations), policy.eval().predict(observations))


LAYER_WIDTHS_MESSAGE = "hidden_sizes must be a list of layer widths in [1, 2^20], got "


@pytest.mark.parametrize("widths", [[], [1], [2**20], [1] * 64], ids=["none", "one", "2^20", "64 layers"])
def test_layer_widths_from_1_to_2_to_the_20_in_at_most_64_layers_are_accepted(widths) -> None:
    check_layer_widths(widths)


@pytest.mark.parametrize(
    "widths",
    [(8, 8), "64", [1] * 65, [0], [2**20 + 1], [True], [8, "8"], [8.0]],
    ids=["a tuple", "a string", "65 layers", "zero", "above 2^20", "a boolean", "a string width", "a float width"],
)
def test_layer_widths_read_from_a_file_are_refused_unless_a_short_list_of_widths(widths) -> None:
    with pytest.raises(ValueError, match=re.escape(LAYER_WIDTHS_MESSAGE + str(widths)[:80]) + "$"):
        check_layer_widths(widths)


def test_a_refused_layer_width_list_is_quoted_up_to_80_characters() -> None:
    widths = [2**21] * 20
    with pytest.raises(ValueError, match=re.escape(LAYER_WIDTHS_MESSAGE + str(widths)[:80]) + "$"):
        check_layer_widths(widths)


# (observation space, action space, options, the weight-matrix numbers of both trunks and the
# action and value heads, counted by hand)
PLANNED = {
    "separate trunks": (BOX4, gym.spaces.Discrete(3), {"hidden_sizes": [5, 6, 7]}, 2 * (4 * 5 + 5 * 6 + 6 * 7) + 7 * (3 + 1)),
    "shared trunk": (
        BOX4,
        gym.spaces.Discrete(3),
        {"hidden_sizes": [5, 6, 7], "shared_trunk": True},
        4 * 5 + 5 * 6 + 6 * 7 + 7 * (3 + 1),
    ),
    "no hidden layer": (gym.spaces.Discrete(6), gym.spaces.Box(-1, 1, (2,), np.float32), {"hidden_sizes": []}, 6 * (2 + 1)),
    "multi-discrete": (BOX4, gym.spaces.MultiDiscrete([3, 2]), {"hidden_sizes": [5]}, 2 * 4 * 5 + 5 * (5 + 1)),
}


@pytest.mark.parametrize(("observations", "actions", "options", "planned"), PLANNED.values(), ids=PLANNED.keys())
def test_a_truncated_policy_weights_file_is_refused_before_the_network_is_built(
    tmp_path, observations, actions, options, planned
) -> None:
    """The config's network needs at least its weight matrices: a file with fewer numbers (here
    a one-layer policy's action head, 2 × 1 weights and 2 biases) is refused with both counts,
    before anything that size is allocated."""
    from imitation.data.spaces import space_to_json

    config = PolicyConfig(observation_space=space_to_json(observations), action_space=space_to_json(actions), **options)
    tiny = make_policy(gym.spaces.Box(-1, 1, (1,), np.float32), gym.spaces.Discrete(2), hidden_sizes=[])
    weights = {name: t for name, t in policy_tensors(tiny).items() if "action_head" in name}
    run = RunWriter(tmp_path / "run", config={"kind": "bc", "policy": config.to_json()}, tensorboard=False)
    run.save_weights(weights)
    path = run.finish({})
    expected = f"{path}: its config describes a network of at least {planned} weights, but its weights file holds 4 numbers"
    with pytest.raises(ImitationError, match=re.escape(expected)):
        load_policy(path)


def test_the_observation_count_stays_exact_past_float32s_2_to_the_24() -> None:
    """A long PPO run folds in more than 2^24 observations: the count (float64) keeps counting."""
    stats = RunningMeanStd((1,))
    stats.count.fill_(2**24)
    stats.update(torch.ones(1, 1))
    assert stats.count.item() == 2**24 + 1


def test_a_reset_normaliser_forgets_everything_seen() -> None:
    """After reset_parameters the statistics are a fresh normaliser's, so the next fit is the new data's alone."""
    stats, fresh = RunningMeanStd((2,)), RunningMeanStd((2,))
    stats.update(torch.randn(50, 2) * 7 + 3)
    stats.reset_parameters()
    for name, tensor in fresh.state_dict().items():
        assert torch.equal(stats.state_dict()[name], tensor), name
    data = torch.tensor([[1.0, 2.0], [3.0, 6.0]])
    stats.update(data)
    fresh.update(data)
    assert torch.equal(stats.var, fresh.var) and torch.equal(stats.mean, fresh.mean)


def test_the_single_observation_expert_returns_python_ints_for_discrete_actions() -> None:
    expert = SingleObservationPolicy(make_policy(BOX4, gym.spaces.Discrete(3, start=2), hidden_sizes=[4]))
    action = expert(np.zeros(4, np.float32))
    assert type(action) is int and action in (2, 3, 4)
    box = SingleObservationPolicy(make_policy(BOX4, gym.spaces.Box(-1, 1, (2,), np.float32), hidden_sizes=[4]))
    assert box(np.zeros(4, np.float32)).shape == (2,)


def test_a_stochastic_single_observation_expert_samples_its_policy() -> None:
    """deterministic=False draws from π(·|s): with π = (½, ½) both actions come up, where the mode would repeat one."""
    torch.manual_seed(0)
    policy = make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[4])
    with torch.no_grad():
        policy.action_head.weight.zero_()
        policy.action_head.bias.zero_()
    sampled = {SingleObservationPolicy(policy, deterministic=False)(np.zeros(4, np.float32)) for _ in range(40)}
    assert sampled == {0, 1}
    assert {SingleObservationPolicy(policy)(np.zeros(4, np.float32)) for _ in range(5)} == {0}


@pytest.mark.parametrize(
    ("data", "error", "message"),
    [
        ([], TypeError, "the policy config is a list, not an object"),
        (
            {"activation": 1},
            TypeError,
            "activation must be a name, shared_trunk, normalize_observations/actions and previous_action true or false",
        ),
        ({"shared_trunk": "yes"}, TypeError, "activation must be a name"),
        ({"normalize_observations": 1}, TypeError, "activation must be a name"),
        ({"normalize_actions": "no"}, TypeError, "activation must be a name"),
        ({"previous_action": 1}, TypeError, "activation must be a name"),
        ({"log_std_init": True}, ValueError, "log_std_init must be a finite number, got True"),
        ({"log_std_init": "0.5"}, ValueError, "log_std_init must be a finite number, got '0.5'"),
        ({"log_std_init": math.nan}, ValueError, "log_std_init must be a finite number, got nan"),
        ({"log_std_init": -math.inf}, ValueError, "log_std_init must be a finite number, got -inf"),
        ({"observation_keys": "pixels"}, TypeError, "observation_keys must be a list of names"),
        ({"frame_stack": True}, ValueError, "frame_stack must be an integer in [1, 64], got True"),
        ({"frame_stack": 65}, ValueError, "frame_stack must be an integer in [1, 64], got 65"),
        ({"cnn": []}, TypeError, "the CNN config is a list, not an object"),
        ({"pixels": 5}, ValueError, "a pixel recipe is {'size': [H, W]"),
        ({"denoising_steps": 0}, ValueError, "denoising_steps must be a whole number in [1, 10000], got 0"),
        ({"sampling_steps": 1.5}, ValueError, "sampling_steps must be a whole number in [1, 10000], got 1.5"),
        ({"sampling_steps": 101}, ValueError, "sampling_steps (101) must be at most denoising_steps (100)"),
        ({"sampling_noise": 1.5}, ValueError, "sampling_noise must be a number in [0, 1], got 1.5"),
        ({"sampling_noise": True}, ValueError, "sampling_noise must be a number in [0, 1], got True"),
        ({"prediction": 0}, TypeError, "prediction must be a name, got 0"),
        ({"angles": [4, 4]}, ValueError, "angles must be a list of distinct observation positions, got [4, 4]"),
    ],
    ids=[
        "list", "activation", "shared_trunk", "normalize_observations", "normalize_actions", "previous_action", "bool",
        "str", "nan", "-inf", "observation_keys", "frame_stack bool", "frame_stack 65", "cnn", "pixels",
        "denoising_steps", "sampling_steps float", "sampling_steps over", "sampling_noise over", "sampling_noise bool",
        "prediction", "angles twice",
    ],  # fmt: skip
)
def test_a_policy_config_read_from_a_file_refuses_each_malformed_field_naming_it(data, error, message) -> None:
    valid = make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[4]).config.to_json() | {"log_std_init": -1}
    assert PolicyConfig.from_json(valid).to_json() == valid
    with pytest.raises(error, match=f"^{re.escape(message)}"):
        PolicyConfig.from_json(data if not isinstance(data, dict) else valid | data)


def test_a_policy_for_other_spaces_than_the_envs_is_refused_in_one_line_naming_where_and_whose() -> None:
    policy = make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[4])
    env = gym.make("Pendulum-v1")
    with pytest.raises(ImitationError, match=re.escape("here: the policy's observation space Box(float32, (4,)) does not")):
        check_policy_fits_env(policy, env, where="here")
    check_policy_fits_env(make_policy(env.observation_space, env.action_space, hidden_sizes=[4]), env, where="here")


def test_acting_one_observation_at_a_time_runs_an_mlp_on_one_thread_and_leaves_a_cnn_its_threads() -> None:
    previous = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        image = gym.spaces.Box(0, 255, (36, 36, 1), np.uint8)
        SingleObservationPolicy(make_policy(image, gym.spaces.Discrete(2), hidden_sizes=[4]))
        assert torch.get_num_threads() == 2
        SingleObservationPolicy(make_policy(BOX4, gym.spaces.Discrete(2), hidden_sizes=[4]))
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(previous)


@pytest.mark.parametrize("actions", [gym.spaces.Discrete(3, start=2), gym.spaces.Box(-1.0, 1.0, (2,), np.float32)])
def test_held_out_scores_equal_the_point_action_and_nll_taken_apart(actions: gym.Space) -> None:
    torch.manual_seed(0)
    policy = make_policy(BOX4, actions, hidden_sizes=[8])
    observations = torch.randn(5, 4)
    taken = torch.as_tensor(np.stack([actions.sample() for _ in range(5)]))
    point, nll = policy.held_out(observations, taken)
    assert torch.equal(point, policy.point_action(observations))
    assert torch.allclose(nll, policy.action_nll(observations, taken))

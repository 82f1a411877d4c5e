"""Reward models in process: the run directory round trip, the refusals of load_reward, the
controls (constant and random rewards), relabelling, observation statistics and r(s) of every
state, each against a hand computation."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch

from imitation.envs.rollout import Rollout
from imitation.errors import ImitationError
from imitation.jobs.run_directory import save_reward_run
from imitation.rewards import (
    RewardConfig,
    RewardNet,
    all_state_rewards,
    constant_reward_like,
    load_reward,
    make_reward_model,
    random_reward_like,
    reward_tensors,
)
from imitation.runs import RunWriter

BOX3 = gym.spaces.Box(-np.inf, np.inf, (3,), np.float32)
BOX2_ACTIONS = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)


def _write_run(path: Path, config: dict[str, Any], tensors: dict[str, torch.Tensor]) -> Path:
    """A finished run directory holding exactly this config.json and these weights."""
    with RunWriter(path, config=config, tensorboard=False) as run:
        run.save_weights(tensors)
        return run.finish({})


def _tiny_weights() -> dict[str, torch.Tensor]:
    """The weights of a linear reward on one number: 2 numbers in all (a truncated file for any bigger config)."""
    return reward_tensors(make_reward_model(gym.spaces.Box(-1, 1, (1,), np.float32), BOX2_ACTIONS, hidden_sizes=[]))


def _assert_same_state(got: dict[str, torch.Tensor], expected: dict[str, torch.Tensor]) -> None:
    assert got.keys() == expected.keys()
    for name, tensor in expected.items():
        assert torch.equal(got[name], tensor), name


def _box_sas_model() -> RewardNet:
    torch.manual_seed(0)
    model = make_reward_model(BOX3, BOX2_ACTIONS, inputs="sas", hidden_sizes=[5], normalize_observations=True)
    model.set_observation_statistics(torch.randn(20, 3) * 4 + 1)
    return model


def _tabular_model(width: int, hidden: list[int]) -> RewardNet:
    torch.manual_seed(1)
    table = np.random.default_rng(width).normal(size=(6, width))
    return make_reward_model(gym.spaces.Discrete(6), gym.spaces.Discrete(2), feature_table=table, hidden_sizes=hidden)


def _batch(model: RewardNet, n: int = 7) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(n)
    if isinstance(model.observation_space, gym.spaces.Discrete):
        states = torch.randint(0, int(model.observation_space.n), (n,), generator=generator)
    else:
        states = torch.randn(n, 3, generator=generator) * 5
    if isinstance(model.action_space, gym.spaces.Discrete):
        start = int(model.action_space.start)
        actions = torch.randint(start, start + int(model.action_space.n), (n,), generator=generator)
    else:
        actions = torch.rand(n, 2, generator=generator) * 2 - 1
    return states, actions, states.flip(0)


ROUND_TRIPS = {
    "box s,a,s' normalised": _box_sas_model,
    "box s,a linear, shifted discrete actions": lambda: make_reward_model(
        BOX3, gym.spaces.Discrete(4, start=1), inputs="sa", hidden_sizes=[]
    ),
    "feature table of width 3": lambda: _tabular_model(3, [4]),
    "feature table of width 1": lambda: _tabular_model(1, []),
}


@pytest.mark.parametrize("make", ROUND_TRIPS.values(), ids=ROUND_TRIPS.keys())
def test_a_saved_reward_run_loads_back_the_same_reward_in_eval_mode(tmp_path, make) -> None:
    """save_reward_run writes what the IRL jobs write (config.json's "reward", the weights under
    "reward."); load_reward gives back the config, every weight and buffer, and the same r."""
    model = make()
    path = save_reward_run(model, tmp_path / "run", env_id="Nothing-v0", source="test")
    loaded = load_reward(path)
    assert loaded.config == model.config and not loaded.training
    _assert_same_state(loaded.state_dict(), model.state_dict())
    batch = _batch(model)
    torch.testing.assert_close(loaded(*batch), model(*batch), rtol=0, atol=0)


def test_weights_are_saved_under_the_reward_prefix() -> None:
    model = _tabular_model(3, [4])
    assert reward_tensors(model).keys() == {"reward." + name for name in model.state_dict()}
    assert all(torch.equal(reward_tensors(model)["reward." + name], t) for name, t in model.state_dict().items())


def test_a_config_without_a_kind_but_with_a_reward_loads(tmp_path) -> None:
    """Any run recording a reward config is read as one (its kind is not required)."""
    model = _box_sas_model()
    path = _write_run(tmp_path / "run", {"env_id": None, "reward": model.config.to_json()}, reward_tensors(model))
    _assert_same_state(load_reward(path).state_dict(), model.state_dict())


def test_a_run_of_another_kind_is_not_a_reward_model(tmp_path) -> None:
    path = _write_run(tmp_path / "run", {"kind": "ppo", "env_id": None}, {"policy.x": torch.zeros(3)})
    with pytest.raises(ImitationError, match=re.escape(f"{path}: not a reward model (a 'ppo' run)")):
        load_reward(path)


def test_a_reward_run_without_its_reward_config_is_refused_as_not_matching(tmp_path) -> None:
    path = _write_run(tmp_path / "run", {"kind": "reward", "env_id": None}, _tiny_weights())
    with pytest.raises(ImitationError, match=re.escape(f"{path}: reward weights do not match its config ('reward')")):
        load_reward(path)


def _valid_config() -> dict[str, Any]:
    return make_reward_model(gym.spaces.Discrete(4), gym.spaces.Discrete(2), hidden_sizes=[3]).config.to_json()


# (what to change in a valid config, the TypeError or ValueError message load_reward reports)
MALFORMED = {
    "not an object": (lambda c: [1, 2], "the reward config is a list, not an object"),
    "hidden sizes not a list": (
        lambda c: c | {"hidden_sizes": "64"},
        "hidden_sizes must be a list of layer widths in [1, 2^20], got 64",
    ),
    "inputs not a name": (
        lambda c: c | {"inputs": 3},
        "inputs and activation must be names, output one of linear, softplus, normalize_observations true or false",
    ),
    "unknown output": (
        lambda c: c | {"output": "sigmoid"},
        "inputs and activation must be names, output one of linear, softplus, normalize_observations true or false",
    ),
    "activation not a name": (
        lambda c: c | {"activation": 1},
        "inputs and activation must be names, output one of linear, softplus, normalize_observations true or false",
    ),
    "normalisation not a flag": (
        lambda c: c | {"normalize_observations": "yes"},
        "inputs and activation must be names, output one of linear, softplus, normalize_observations true or false",
    ),
    "feature width a boolean": (
        lambda c: c | {"state_features": True},
        "state_features must be a width in [1, 2^20] or null, got True",
    ),
    "feature width a string": (
        lambda c: c | {"state_features": "3"},
        "state_features must be a width in [1, 2^20] or null, got 3",
    ),
    "feature width a float": (
        lambda c: c | {"state_features": 1.5},
        "state_features must be a width in [1, 2^20] or null, got 1.5",
    ),
    "feature width zero": (lambda c: c | {"state_features": 0}, "state_features must be a width in [1, 2^20] or null, got 0"),
    "feature width above 2^20": (
        lambda c: c | {"state_features": 2**20 + 1},
        "state_features must be a width in [1, 2^20] or null, got 1048577",
    ),
    "observation keys a name": (lambda c: c | {"observation_keys": "pixels"}, "observation_keys must be a list of names"),
    "frame stack zero": (lambda c: c | {"frame_stack": 0}, "frame_stack must be an integer in [1, 64], got 0"),
    "frame stack a long string": (
        lambda c: c | {"frame_stack": "7" * 50},
        "frame_stack must be an integer in [1, 64], got " + "7" * 40,
    ),
    # The message quotes at most 40 characters of the value.
    "feature width a long string": (
        lambda c: c | {"state_features": "x" * 50},
        "state_features must be a width in [1, 2^20] or null, got " + "x" * 40,
    ),
}


@pytest.mark.parametrize(("change", "message"), MALFORMED.values(), ids=MALFORMED.keys())
def test_a_malformed_reward_config_is_refused_naming_the_run(tmp_path, change, message) -> None:
    path = _write_run(tmp_path / "run", {"kind": "reward", "env_id": None, "reward": change(_valid_config())}, _tiny_weights())
    with pytest.raises(ImitationError, match=re.escape(f"{path}: reward weights do not match its config ({message})") + "$"):
        load_reward(path)


# (observation space, action space, options, the weight-matrix numbers (and feature table) counted by hand)
PLANNED = {
    "box s": (BOX3, BOX2_ACTIONS, {"inputs": "s", "hidden_sizes": [5]}, 3 * 5 + 5 * 1),
    "box s,a": (BOX3, BOX2_ACTIONS, {"inputs": "sa", "hidden_sizes": [5]}, (3 + 2) * 5 + 5 * 1),
    "box s,a,s'": (BOX3, BOX2_ACTIONS, {"inputs": "sas", "hidden_sizes": [5, 2]}, (3 + 2 + 3) * 5 + 5 * 2 + 2 * 1),
    "one-hot s,a linear": (gym.spaces.Discrete(4), gym.spaces.Discrete(3), {"inputs": "sa", "hidden_sizes": []}, 4 + 3),
    "one-hot s,a,s'": (
        gym.spaces.Discrete(4),
        gym.spaces.Discrete(3),
        {"inputs": "sas", "hidden_sizes": [2]},
        (4 + 3 + 4) * 2 + 2,
    ),
    "feature table": (
        gym.spaces.Discrete(6),
        gym.spaces.Discrete(3),
        {"state_features": 2, "hidden_sizes": [5]},
        6 * 2 + 2 * 5 + 5,
    ),
    # The widest table allowed passes validation and is then refused for want of weights.
    "widest feature table": (
        gym.spaces.Discrete(4),
        gym.spaces.Discrete(3),
        {"state_features": 2**20, "hidden_sizes": []},
        4 * 2**20 + 2**20,
    ),
}


@pytest.mark.parametrize(("observations", "actions", "options", "planned"), PLANNED.values(), ids=PLANNED.keys())
def test_a_truncated_weights_file_is_refused_before_the_network_is_built(
    tmp_path, observations, actions, options, planned
) -> None:
    """The config's network needs at least its weight matrices (and feature table); a file that
    holds fewer numbers is refused with both counts, before anything that size is allocated."""
    from imitation.data.spaces import space_to_json

    config = RewardConfig(observation_space=space_to_json(observations), action_space=space_to_json(actions), **options)
    path = _write_run(tmp_path / "run", {"kind": "reward", "env_id": None, "reward": config.to_json()}, _tiny_weights())
    expected = f"{path}: its config describes a network of at least {planned} weights, but its weights file holds 2 numbers"
    with pytest.raises(ImitationError, match=re.escape(expected)):
        load_reward(path)


def test_weights_that_fill_the_planned_count_but_miss_the_biases_are_refused_as_not_matching(tmp_path) -> None:
    """The count check refuses only files too small for the network: one holding exactly the
    weight matrices passes it, and loading then reports what is missing."""
    model = make_reward_model(BOX3, BOX2_ACTIONS, hidden_sizes=[5])
    matrices = {name: t for name, t in reward_tensors(model).items() if name.endswith(".weight")}
    assert sum(t.numel() for t in matrices.values()) == 3 * 5 + 5
    path = _write_run(tmp_path / "run", {"kind": "reward", "env_id": None, "reward": model.config.to_json()}, matrices)
    with pytest.raises(
        ImitationError, match=re.escape(f"{path}: reward weights do not match its config (Error(s) in loading")
    ):
        load_reward(path)


CONTROLS = {
    "box s,a,s' normalised": _box_sas_model,
    "feature table": lambda: _tabular_model(3, [4]),
    "linear": lambda: _tabular_model(1, []),
}


def _buffers(model: RewardNet) -> dict[str, torch.Tensor]:
    return {name: t for name, t in model.state_dict().items() if not name.startswith("net.")}


@pytest.mark.parametrize("make", CONTROLS.values(), ids=CONTROLS.keys())
def test_the_constant_control_pays_its_value_everywhere_and_keeps_the_fixed_buffers(make) -> None:
    model = make()
    before = {name: t.clone() for name, t in model.state_dict().items()}
    batch = _batch(model, 9)
    default = constant_reward_like(model)
    assert torch.equal(default(*batch), torch.ones(9))  # the default value is 1
    constant = constant_reward_like(model, -0.25)
    assert torch.equal(constant(*batch), torch.full((9,), -0.25))
    assert constant.config == model.config and not constant.training
    _assert_same_state(_buffers(constant), _buffers(model))
    _assert_same_state(model.state_dict(), before)  # the model itself is untouched


@pytest.mark.parametrize("make", CONTROLS.values(), ids=CONTROLS.keys())
def test_the_random_control_is_a_fresh_network_drawn_by_seed_with_the_fixed_buffers(make) -> None:
    """random_reward_like(model, seed) is the network PyTorch initialises under `seed`, with the
    model's feature table and observation statistics; it leaves the global random state alone."""
    model = make()
    batch = _batch(model, 9)
    state = torch.random.get_rng_state()
    first, again, other = (random_reward_like(model, seed=s) for s in (3, 3, 4))
    assert torch.equal(torch.random.get_rng_state(), state)
    torch.manual_seed(3)
    expected = RewardNet(model.config)
    for name, tensor in first.state_dict().items():
        reference = expected.state_dict()[name] if name.startswith("net.") else model.state_dict()[name]
        assert torch.equal(tensor, reference), name
        assert torch.equal(again.state_dict()[name], tensor), name
    assert not first.training
    assert not torch.allclose(first(*batch), model(*batch)) and not torch.allclose(other(*batch), first(*batch))


def _linear(model: RewardNet, weight: list[float], bias: float) -> RewardNet:
    with torch.no_grad():
        model.net[-1].weight.copy_(torch.tensor([weight]))
        model.net[-1].bias.fill_(bias)
    return model


def test_relabel_gives_r_of_every_step_in_time_by_env_order() -> None:
    """A linear r(s, a, s') = w_s·s + w_a[a - start] + w_s'·s' + b over a (T=3, n_envs=2) rollout."""
    model = _linear(
        make_reward_model(
            gym.spaces.Box(-5, 5, (2,), np.float32), gym.spaces.Discrete(3, start=1), inputs="sas", hidden_sizes=[]
        ),
        [1.0, -2.0, 10.0, 20.0, 30.0, 0.5, 0.25],
        0.125,
    )
    observations = torch.arange(12, dtype=torch.float32).reshape(3, 2, 2)
    env_actions = torch.tensor([[1, 2], [3, 1], [2, 3]])
    next_observations = observations + 1
    zeros = torch.zeros(3, 2)
    rollout = Rollout(
        observations=observations,
        actions=env_actions - 1,
        env_actions=env_actions,
        next_observations=next_observations,
        log_probs=zeros,
        env_rewards=zeros,
        terminated=zeros.bool(),
        truncated=zeros.bool(),
    )
    expected = torch.tensor(
        [
            [
                observations[t, e, 0]
                - 2 * observations[t, e, 1]
                + 10 * env_actions[t, e]
                + 0.5 * next_observations[t, e, 0]
                + 0.25 * next_observations[t, e, 1]
                + 0.125
                for e in range(2)
            ]
            for t in range(3)
        ]
    )
    torch.testing.assert_close(model.relabel(rollout), expected)


def test_observation_statistics_centre_on_the_demos_and_scale_by_half_range_or_the_largest_spread() -> None:
    """Mean: of `observations` alone. Scale: half the range where the bounds are finite, else the
    largest std of `observations` and `others`, floored at 1e-3."""
    space = gym.spaces.Box(np.array([-2.0, -np.inf, -np.inf], np.float32), np.array([4.0, np.inf, np.inf], np.float32))
    model = make_reward_model(space, BOX2_ACTIONS, hidden_sizes=[], normalize_observations=True)
    demos = torch.tensor([[0.0, 1.0, 5.0], [2.0, 3.0, 5.0], [4.0, 8.0, 5.0]])
    others = torch.tensor([[100.0, 0.0, 5.0], [-100.0, 0.0, 5.0]])
    model.set_observation_statistics(demos, others)
    assert model.observation_mean.tolist() == pytest.approx([2.0, 4.0, 5.0])
    # dim 0: (4 - -2) / 2; dim 1: the demos' std, larger than the others' 0; dim 2: never moves.
    assert model.observation_std.tolist() == pytest.approx([3.0, float(torch.tensor([1.0, 3.0, 8.0]).std()), 1e-3])
    _linear(model, [1.0, 1.0, 0.0], 0.0)
    assert model(torch.tensor([[5.0, 4.0, 5.0]]), torch.zeros(1, 2), torch.zeros(1, 3)).item() == pytest.approx(1.0)


def test_bounds_beyond_float32_count_as_unbounded() -> None:
    """The statistics are float32: a float64 Box bound past float32's range (here one bound of
    each dimension) would make a half range of ∞ there, so the spread scales it instead."""
    space = gym.spaces.Box(np.array([-1e300, -1.0]), np.array([1.0, 1e300]), dtype=np.float64)
    model = make_reward_model(space, BOX2_ACTIONS, hidden_sizes=[], normalize_observations=True)
    demos = torch.tensor([[0.0, 0.0], [2.0, 4.0]], dtype=torch.float64)
    model.set_observation_statistics(demos)
    assert model.observation_std.tolist() == pytest.approx([np.sqrt(2.0), np.sqrt(8.0)])


def test_all_state_rewards_are_r_of_each_state_through_its_features() -> None:
    """r(s) = x(s)·w + b for a linear reward on a feature table, and w[s] + b on one-hot states."""
    table = np.array([[1.0, 0.0], [0.0, 1.0], [2.0, -1.0], [0.5, 0.5]])
    model = _linear(
        make_reward_model(gym.spaces.Discrete(4), gym.spaces.Discrete(2), feature_table=table, hidden_sizes=[]),
        [3.0, -1.0],
        0.5,
    )
    assert all_state_rewards(model, 4).tolist() == pytest.approx([3.5, -0.5, 7.5, 1.5])
    one_hot = _linear(
        make_reward_model(gym.spaces.Discrete(3), gym.spaces.Discrete(2), hidden_sizes=[]), [0.25, -2.0, 4.0], 1.0
    )
    assert all_state_rewards(one_hot, 3).tolist() == pytest.approx([1.25, -1.0, 5.0])


@pytest.mark.parametrize("inputs", ["sa", "sas"])
def test_state_rewards_of_a_reward_that_reads_actions_are_refused(inputs: str) -> None:
    """The tabular planner scores states; a reward of (s, a) has no r(s) to give it (it used to be
    called with the state as its action: a raw index error, or r(s, a=s) with no error at all)."""
    model = make_reward_model(gym.spaces.Discrete(9), gym.spaces.Discrete(4), inputs=inputs, hidden_sizes=[])
    with pytest.raises(ImitationError, match=f"need a reward of the state alone .*takes '{inputs}'"):
        all_state_rewards(model, 9)


def test_train_ppo_reads_its_reward_run_once_and_optimises_that_reward(tmp_path, monkeypatch) -> None:
    """`train ppo --reward RUN` read the run directory three times (the observation fields, the
    model, the demos); now once, and the run it writes names the reward it optimised."""
    from imitation import rewards
    from imitation.jobs.ppo import train_ppo

    model = make_reward_model(gym.spaces.Box(-np.inf, np.inf, (4,), np.float32), gym.spaces.Discrete(2), hidden_sizes=[4])
    reward_run = save_reward_run(model, tmp_path / "reward", env_id="CartPole-v1", source="test")
    reads: list[str] = []
    read_run = rewards.read_run
    monkeypatch.setattr(rewards, "read_run", lambda path: reads.append(str(path)) or read_run(path))
    flags = {"total_steps": 256, "n_envs": 2, "seed": 0}
    config, result = train_ppo("CartPole-v1", tmp_path / "ppo", flags, reward_run=str(reward_run), progress=False)
    assert reads == [str(reward_run)]
    assert config.total_steps == 256 and result["steps"] == 256
    saved = json.loads((tmp_path / "ppo" / "config.json").read_text())
    assert saved["reward_run"] == str(reward_run) and saved["source"] == f"--reward {reward_run}"


@pytest.mark.parametrize("inputs", ["sa", "sas"])
def test_a_shaping_potential_of_more_than_the_state_is_refused(tmp_path, inputs: str) -> None:
    """AIRL saves h(s); shaping calls h with states alone, so an h of other inputs in a run
    directory (edited, or another tool's) would be misread: refused naming the run."""
    from imitation.rewards import load_potential, potential_tensors

    g = make_reward_model(BOX3, BOX2_ACTIONS, hidden_sizes=[4])
    h_of_state = make_reward_model(BOX3, BOX2_ACTIONS, hidden_sizes=[4])
    h_of_more = make_reward_model(BOX3, BOX2_ACTIONS, inputs=inputs, hidden_sizes=[4])
    for name, h in (("state", h_of_state), ("more", h_of_more)):
        config = {"kind": "reward", "reward": g.config.to_json(), "potential": h.config.to_json()}
        _write_run(tmp_path / name, config, reward_tensors(g) | potential_tensors(h))
    _assert_same_state(load_potential(tmp_path / "state").state_dict(), h_of_state.state_dict())
    with pytest.raises(ImitationError, match=rf"^{re.escape(str(tmp_path / 'more'))}: its shaping potential h reads inputs '{inputs}'; AIRL's h is a function of the state alone \('s'\)$"):
        load_potential(tmp_path / "more")

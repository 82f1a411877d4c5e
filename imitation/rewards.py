"""Reward models r_φ(s), r_φ(s, a) or r_φ(s, a, s'): linear or MLP, and loading them.

A reward run directory (written by the IRL jobs) holds config.json with
{"kind": "reward", "env_id": ..., "reward": RewardConfig} and model.safetensors with the
weights under "reward." (with a tabular reward's per-state feature table and the fixed
observation statistics, so evaluation sees what training saw). PPO optimises a learned reward
by handing it each rollout to relabel in one batched call (`RewardNet.relabel`): that is the
one way a learned reward enters training.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from imitation.data.spaces import space_from_json, space_to_json
from imitation.envs.rollout import Rollout
from imitation.errors import ImitationError, SpaceError
from imitation.policies import ACTIVATIONS, check_layer_widths, check_weights_cover, mlp_weight_count, observation_size
from imitation.runs import read_run

REWARD_INPUTS = ("s", "sa", "sas")
REWARD_PREFIX = "reward."


@dataclass(kw_only=True)
class RewardConfig:
    observation_space: dict[str, Any]
    action_space: dict[str, Any]
    inputs: str = "s"
    hidden_sizes: list[int] = field(default_factory=lambda: [64, 64])
    activation: str = "relu"
    # Tabular MDPs: r is computed on a per-state feature vector x(s) of this width, looked up
    # in a (states, width) table that is saved with the weights (None: on the state itself).
    state_features: int | None = None
    # Box observations: standardised by fixed statistics (set once, e.g. from the demos, and
    # saved with the weights).
    normalize_observations: bool = False

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_json(data: Any) -> RewardConfig:
        """From config.json's "reward"; TypeError or ValueError for anything malformed."""
        if not isinstance(data, dict):
            raise TypeError(f"the reward config is a {type(data).__name__}, not an object")
        config = RewardConfig(**data)
        check_layer_widths(config.hidden_sizes)
        if (
            not isinstance(config.inputs, str)
            or not isinstance(config.activation, str)
            or not isinstance(config.normalize_observations, bool)
        ):
            raise TypeError("inputs and activation must be names, normalize_observations true or false")
        features = config.state_features
        if features is not None and (
            isinstance(features, bool) or not isinstance(features, int) or not 1 <= features <= 2**20
        ):
            raise ValueError(f"state_features must be a width in [1, 2^20] or null, got {str(features)[:40]}")
        return config


def _planned_weights(config: RewardConfig) -> int:
    """How many numbers a RewardNet of this config holds at least: its feature table and weight matrices."""
    observations, actions = space_from_json(config.observation_space), space_from_json(config.action_space)
    size = observation_size(observations)
    table = 0
    if config.state_features is not None and isinstance(observations, gym.spaces.Discrete):
        table, size = int(observations.n) * config.state_features, config.state_features
    size += (observation_size(actions) if "a" in config.inputs else 0) + (
        observation_size(observations) if config.inputs == "sas" else 0
    )
    return table + mlp_weight_count(size, config.hidden_sizes, 1)


def _one_hot_or_flat(values: torch.Tensor, space: gym.Space) -> torch.Tensor:
    if isinstance(space, gym.spaces.Discrete):
        return nn.functional.one_hot(values.long().reshape(-1) - int(space.start), int(space.n)).float()
    return values.reshape(values.shape[0], -1).float()


class RewardNet(nn.Module):
    """r_φ on the chosen inputs; `hidden_sizes=[]` makes it linear in the features."""

    # Buffers (register_buffer), present with `state_features` or `normalize_observations`; declared
    # for the type checker, which otherwise sees nn.Module.__getattr__.
    state_features: torch.Tensor
    observation_mean: torch.Tensor
    observation_std: torch.Tensor

    def __init__(self, config: RewardConfig) -> None:
        super().__init__()
        if config.inputs not in REWARD_INPUTS:
            raise ImitationError(f"reward inputs must be one of {', '.join(REWARD_INPUTS)}, got {config.inputs!r}")
        self.config = config
        self.observation_space = space_from_json(config.observation_space)
        self.action_space = space_from_json(config.action_space)
        size = observation_size(self.observation_space)
        if config.state_features is not None:
            if not isinstance(self.observation_space, gym.spaces.Discrete) or config.inputs != "s":
                raise ImitationError("a per-state feature table needs Discrete observations and a reward on s alone")
            self.register_buffer("state_features", torch.zeros(int(self.observation_space.n), config.state_features))
            size = config.state_features
        if config.normalize_observations:
            if not isinstance(self.observation_space, gym.spaces.Box):
                raise ImitationError("reward observation normalisation needs Box observations")
            flat = observation_size(self.observation_space)
            self.register_buffer("observation_mean", torch.zeros(flat))
            self.register_buffer("observation_std", torch.ones(flat))
        if "a" in config.inputs:
            size += observation_size(self.action_space)
        if config.inputs == "sas":
            size += observation_size(self.observation_space)
        layers: list[nn.Module] = []
        for hidden in config.hidden_sizes:
            layers += [nn.Linear(size, hidden), ACTIVATIONS[config.activation]()]
            size = hidden
        layers.append(nn.Linear(size, 1))
        self.net = nn.Sequential(*layers)

    def set_observation_statistics(self, observations: torch.Tensor, *others: torch.Tensor) -> None:
        """Centre observations on the mean of `observations`; scale each dimension by half the
        observation space's range where it is finite, else by the largest std of `observations`
        and `others` (floored at 1e-3). Scaled by the demos alone, which span a sliver of the
        space, every state they never visit would sit far out, where a network extrapolates."""

        def flat(tensor: torch.Tensor) -> torch.Tensor:
            return tensor.reshape(tensor.shape[0], -1).float()

        self.observation_mean.copy_(flat(observations).mean(0))
        spreads = torch.stack([flat(t).std(0) for t in (observations, *others)]).max(0).values.clamp_min(1e-3)
        assert isinstance(self.observation_space, gym.spaces.Box)  # normalize_observations requires it (__init__)
        low = torch.as_tensor(self.observation_space.low, dtype=torch.float32).reshape(-1)
        high = torch.as_tensor(self.observation_space.high, dtype=torch.float32).reshape(-1)
        half_range = (high - low) / 2
        self.observation_std.copy_(torch.where(torch.isfinite(half_range), half_range, spreads))

    def _encode_observations(self, observations: torch.Tensor) -> torch.Tensor:
        encoded = _one_hot_or_flat(observations, self.observation_space)
        if self.config.normalize_observations:
            encoded = (encoded - self.observation_mean) / self.observation_std
        return encoded

    def inputs(self, observations: torch.Tensor, actions: torch.Tensor, next_observations: torch.Tensor) -> torch.Tensor:
        """The network's input vector: encoded (normalised, one-hot) s, and a and s' if used."""
        if self.config.state_features is not None:
            assert isinstance(self.observation_space, gym.spaces.Discrete)  # a feature table requires it (__init__)
            return self.state_features[observations.long().reshape(-1) - int(self.observation_space.start)]
        parts = [self._encode_observations(observations)]
        if "a" in self.config.inputs:
            parts.append(_one_hot_or_flat(actions, self.action_space))
        if self.config.inputs == "sas":
            parts.append(self._encode_observations(next_observations))
        return torch.cat(parts, dim=-1)

    def forward(self, observations: torch.Tensor, actions: torch.Tensor, next_observations: torch.Tensor) -> torch.Tensor:
        return self.net(self.inputs(observations, actions, next_observations)).squeeze(-1)

    def relabel(self, rollout: Rollout) -> torch.Tensor:
        """r_φ(s_t, a_t, s_{t+1}) for every step of a rollout, shape (T, n_envs), where the rollout is."""
        steps, n_envs = rollout.env_rewards.shape
        device = next(self.parameters()).device
        inputs = (
            flat_batch(getattr(rollout, name), 2).to(device) for name in ("observations", "env_actions", "next_observations")
        )
        with torch.no_grad():
            rewards = self(*inputs)
        return rewards.reshape(steps, n_envs).to(rollout.env_rewards.device)


def flat_batch(tensor: torch.Tensor, leading_dims: int) -> torch.Tensor:
    """The first `leading_dims` dimensions (e.g. time × envs) merged into one batch dimension."""
    return tensor.reshape(-1, *tensor.shape[leading_dims:])


def all_state_rewards(model: RewardNet, n_states: int) -> torch.Tensor:
    """r_θ(s) for every state s (the model maps a state index to its features itself)."""
    if model.config.inputs != "s":
        raise ImitationError(
            "a tabular MDP's state rewards need a reward of the state alone (inputs 's'); "
            f"this one takes {model.config.inputs!r}"
        )
    states = torch.arange(n_states)
    return model(states, states, states)


def reward_tensors(model: RewardNet) -> dict[str, torch.Tensor]:
    return {REWARD_PREFIX + name: tensor for name, tensor in model.state_dict().items()}


def load_reward(path: str | os.PathLike) -> RewardNet:
    """The reward model of a run directory, on the CPU, in eval mode."""
    config, weights = read_run(path)
    if config.get("kind") != "reward" and "reward" not in config:
        raise ImitationError(
            f"{path}: not a reward model (a {str(config.get('kind', 'unknown'))[:40]!r} run); pass the run directory of "
            "`train irl`"
        )
    state = {name[len(REWARD_PREFIX) :]: t for name, t in weights.items() if name.startswith(REWARD_PREFIX)}
    try:
        reward_config = RewardConfig.from_json(config["reward"])
        check_weights_cover(path, _planned_weights(reward_config), state)
        model = RewardNet(reward_config)
        model.load_state_dict(state)
    except SpaceError as error:
        raise ImitationError(f"{path}: the reward model's {error}") from None
    except (TypeError, KeyError, RuntimeError, ValueError) as error:
        raise ImitationError(
            f"{path}: reward weights do not match its config ({(str(error).splitlines() or [''])[0][:200]})"
        ) from None
    return model.eval()


def make_reward_model(
    observation_space: gym.Space, action_space: gym.Space, *, feature_table: np.ndarray | None = None, **options: Any
) -> RewardNet:
    """A fresh reward model; `feature_table` (states × d) makes r a function of x(s)."""
    if feature_table is not None:
        options["state_features"] = int(feature_table.shape[1])
    model = RewardNet(
        RewardConfig(observation_space=space_to_json(observation_space), action_space=space_to_json(action_space), **options)
    )
    if feature_table is not None:
        model.state_features.copy_(torch.as_tensor(feature_table, dtype=torch.float32))
    return model


def _fresh_like(model: RewardNet) -> RewardNet:
    """A new network of `model`'s configuration with its fixed buffers (feature table,
    observation statistics) and freshly initialised weights."""
    fresh = RewardNet(model.config)
    fresh.load_state_dict(
        {name: tensor for name, tensor in model.state_dict().items() if not name.startswith("net.")}, strict=False
    )
    return fresh.eval()


def random_reward_like(model: RewardNet, *, seed: int) -> RewardNet:
    """A control: `model`'s architecture with random weights (PyTorch's default initialisation under `seed`)."""
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        return _fresh_like(model)


def constant_reward_like(model: RewardNet, value: float = 1.0) -> RewardNet:
    """A control: `model`'s architecture paying `value` everywhere (last layer zero, bias `value`)."""
    constant = _fresh_like(model)
    last = constant.net[-1]
    assert isinstance(last, nn.Linear)
    with torch.no_grad():
        last.weight.zero_()
        last.bias.fill_(value)
    return constant

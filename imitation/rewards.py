"""Reward models r_φ(s), r_φ(s, a) or r_φ(s, a, s'): linear or MLP, and loading them.

Image observations (uint8 frames or frame stacks, and Dicts holding them beside vectors) are read
as the policies read them (`imitation.observation_encoding`, `ObservationConfig`): each image leaf,
scaled to [0, 1], through its own CNN (`imitation.encoders.ImageEncoder`, shared by s and s'), the other
leaves flattened (one-hot for Discrete), and the MLP on their concatenation,

    r_φ(s, a, s') = MLP([CNN_1(s_1), …, CNN_m(s_m), CNN_1(s'_1), …, vec(s), vec(s'), a]),

with the parts the inputs ("s", "sa", "sas") leave out omitted.

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
from imitation.encoders import ImageEncoder, cnn_weight_count, conv_output_sides
from imitation.envs.rollout import Rollout
from imitation.errors import ImitationError, SpaceError
from imitation.mlp import ACTIVATIONS, check_layer_widths, check_weights_cover, mlp_weight_count
from imitation.observation_encoding import (
    ObservationConfig,
    ObservationLayout,
    leaf_frames,
    observation_size,
    one_hot_or_flat,
    vector_leaves,
)
from imitation.runs import read_run
from imitation.tensors import tree_map

REWARD_INPUTS = ("s", "sa", "sas")
# The network's last linear output as the reward, or its softplus log(1 + e^x) = −log(1 − σ(x)):
# GAIL's reward of its discriminator's logit.
REWARD_OUTPUTS = ("linear", "softplus")


@dataclass(kw_only=True)
class RewardConfig(ObservationConfig):
    """Everything needed to rebuild a reward model before loading its weights: its spaces and
    inputs, the network, and how it reads observations (`ObservationConfig`)."""

    observation_space: dict[str, Any]
    action_space: dict[str, Any]
    inputs: str = "s"
    hidden_sizes: list[int] = field(default_factory=lambda: [64, 64])
    activation: str = "relu"
    output: str = "linear"
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
            or config.output not in REWARD_OUTPUTS
            or not isinstance(config.normalize_observations, bool)
        ):
            raise TypeError(
                f"inputs and activation must be names, output one of {', '.join(REWARD_OUTPUTS)}, normalize_observations "
                "true or false"
            )
        features = config.state_features
        if features is not None and (
            isinstance(features, bool) or not isinstance(features, int) or not 1 <= features <= 2**20
        ):
            raise ValueError(f"state_features must be a width in [1, 2^20] or null, got {str(features)[:40]}")
        config.check_observation_fields()
        return config


def reward_layout(config: RewardConfig) -> ObservationLayout | None:
    """How an image or Dict observation is read (None for a plain Box or Discrete one)."""
    return config.layout(space_from_json(config.observation_space))


def _state_size(config: RewardConfig, layout: ObservationLayout | None) -> int:
    """The width of one encoded state: the CNNs' features and the vector leaves, or the flat state."""
    if layout is None:
        return observation_size(space_from_json(config.observation_space))
    return config.cnn_config().features * len(layout.images) + layout.vector_size


def _planned_weights(config: RewardConfig) -> int:
    """How many numbers a RewardNet of this config holds at least: its feature table and weight matrices."""
    observations, actions = space_from_json(config.observation_space), space_from_json(config.action_space)
    layout = reward_layout(config)
    state = size = _state_size(config, layout)
    table = 0
    if config.state_features is not None and isinstance(observations, gym.spaces.Discrete):
        table, size = int(observations.n) * config.state_features, config.state_features
    size += (observation_size(actions) if "a" in config.inputs else 0) + (state if config.inputs == "sas" else 0)
    cnn = config.cnn_config()
    encoders = sum(
        cnn_weight_count(leaf.frames * leaf.channels, leaf.height, leaf.width, cnn)
        for leaf in (layout.images if layout else [])
    )
    return table + encoders + mlp_weight_count(size, config.hidden_sizes, 1)


# Samples per forward pass of `RewardNet.rewards_of`: bounds the activations' memory.
_CHUNK = 4096


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
        if config.output not in REWARD_OUTPUTS:
            raise ImitationError(f"reward output must be one of {', '.join(REWARD_OUTPUTS)}, got {config.output!r}")
        self.config = config
        self.observation_space = space_from_json(config.observation_space)
        self.action_space = space_from_json(config.action_space)
        self.layout = reward_layout(config)
        self.encoders = nn.ModuleList(self._image_encoders())
        state = size = _state_size(config, self.layout)
        if self.layout is not None and (config.state_features is not None or config.normalize_observations):
            raise ImitationError("a reward on image or Dict observations has no feature table and no observation statistics")
        if config.state_features is not None:
            if not isinstance(self.observation_space, gym.spaces.Discrete) or config.inputs != "s":
                raise ImitationError("a per-state feature table needs Discrete observations and a reward on s alone")
            self.register_buffer("state_features", torch.zeros(int(self.observation_space.n), config.state_features))
            size = config.state_features
        if config.normalize_observations:
            if not isinstance(self.observation_space, gym.spaces.Box):
                raise ImitationError("reward observation normalisation needs Box observations")
            self.register_buffer("observation_mean", torch.zeros(state))
            self.register_buffer("observation_std", torch.ones(state))
        if "a" in config.inputs:
            size += observation_size(self.action_space)
        if config.inputs == "sas":
            size += state
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

    def _image_encoders(self) -> list[ImageEncoder]:
        if self.layout is None:
            return []
        cnn = self.config.cnn_config()
        for leaf in self.layout.images:
            if min(conv_output_sides(leaf.height, leaf.width, cnn)) < 1:
                raise ImitationError(
                    f"{leaf.height}×{leaf.width} frames are too small for the reward's CNN (kernels {cnn.kernels}, strides "
                    f"{cnn.strides}): give larger frames or smaller kernels"
                )
        return [ImageEncoder(leaf.frames, leaf.height, leaf.width, leaf.channels, cnn) for leaf in self.layout.images]

    def _encode_observations(self, observations: torch.Tensor) -> torch.Tensor:
        encoded = one_hot_or_flat(observations, self.observation_space)
        if self.config.normalize_observations:
            encoded = (encoded - self.observation_mean) / self.observation_std
        return encoded

    def prepare(self, observations: Any, actions: torch.Tensor, next_observations: Any) -> list[torch.Tensor]:
        """The float tensors r_φ is a differentiable function of (`score`): the input vector of a
        flat reward; for an image reward each image leaf of s (then of s') as (batch, k, H, W, C)
        scaled to [0, 1], then the vector of the other parts."""
        if self.layout is None:
            return [self._flat_inputs(observations, actions, next_observations)]
        states = [observations, next_observations] if self.config.inputs == "sas" else [observations]
        frames = [leaf_frames(state, leaf).float() / 255.0 for state in states for leaf in self.layout.images]
        rest = [vector_leaves(state, self.layout) for state in states if self.layout.vectors]
        if "a" in self.config.inputs:
            rest.append(one_hot_or_flat(actions, self.action_space))
        return [*frames, torch.cat(rest, dim=-1)] if rest else frames

    def features(self, prepared: list[torch.Tensor]) -> torch.Tensor:
        """The MLP's input vector from `prepare`'s tensors: image leaves through their CNNs."""
        if self.layout is None:
            return prepared[0]
        images = len(self.layout.images)
        encoded = [self.encoders[i % images](part) for i, part in enumerate(prepared) if part.dim() == 5]
        return torch.cat([*encoded, *(part for part in prepared if part.dim() != 5)], dim=-1)

    def net_output(self, prepared: list[torch.Tensor]) -> torch.Tensor:
        """The network's last linear output for `prepare`'s tensors, one per sample."""
        return self.net(self.features(prepared)).squeeze(-1)

    def score(self, prepared: list[torch.Tensor]) -> torch.Tensor:
        """r_φ of `prepare`'s tensors, one per sample: the output, through softplus if so configured."""
        output = self.net_output(prepared)
        return nn.functional.softplus(output) if self.config.output == "softplus" else output

    def inputs(self, observations: Any, actions: torch.Tensor, next_observations: Any) -> torch.Tensor:
        """The MLP's input vector: encoded (normalised, one-hot, CNN-read) s, and a and s' if used."""
        return self.features(self.prepare(observations, actions, next_observations))

    def _flat_inputs(self, observations: torch.Tensor, actions: torch.Tensor, next_observations: torch.Tensor) -> torch.Tensor:
        if self.config.state_features is not None:
            assert isinstance(self.observation_space, gym.spaces.Discrete)  # a feature table requires it (__init__)
            return self.state_features[observations.long().reshape(-1) - int(self.observation_space.start)]
        parts = [self._encode_observations(observations)]
        if "a" in self.config.inputs:
            parts.append(one_hot_or_flat(actions, self.action_space))
        if self.config.inputs == "sas":
            parts.append(self._encode_observations(next_observations))
        return torch.cat(parts, dim=-1)

    def forward(self, observations: Any, actions: torch.Tensor, next_observations: Any) -> torch.Tensor:
        return self.score(self.prepare(observations, actions, next_observations))

    def rewards_of(self, observations: Any, actions: torch.Tensor, next_observations: Any) -> torch.Tensor:
        """r_φ of a batch of any size, without gradients, `_CHUNK` samples at a time (a CNN's
        activations for a whole demo set would not fit in memory), where the model is."""
        device = next(self.parameters()).device
        chunks = []
        with torch.no_grad():
            for start in range(0, len(actions), _CHUNK):
                rows = slice(start, start + _CHUNK)
                chunks.append(self(*(tree_index(part, rows, device) for part in (observations, actions, next_observations))))
        return torch.cat(chunks)

    def relabel(self, rollout: Rollout) -> torch.Tensor:
        """r_φ(s_t, a_t, s_{t+1}) for every step of a rollout, shape (T, n_envs), where the rollout is."""
        steps, n_envs = rollout.env_rewards.shape
        inputs = (flat_batch(getattr(rollout, name), 2) for name in ("observations", "env_actions", "next_observations"))
        return self.rewards_of(*inputs).reshape(steps, n_envs).to(rollout.env_rewards.device)


def airl_shaped_reward(
    g: torch.Tensor, potential: torch.Tensor, next_potential: torch.Tensor, terminated: torch.Tensor, gamma: float
) -> torch.Tensor:
    """f = g + γ (1 − d) h(s') − h(s): AIRL's reward shaped by its potential h (`imitation.algorithms.airl`)."""
    return g + gamma * (1.0 - terminated) * next_potential - potential


class ShapedReward:
    """f = g + γ (1 − d) h(s') − h(s) of every step of a rollout, from the g and h an AIRL run saved.

    A potential-based shaping of g (Ng, Harada & Russell 1999): an episode's discounted return of
    f is g's plus γ^T h(s_T) − h(s_0), so both rewards rank policies alike (γ^T ≈ 0 over long
    horizons; h(s_0) does not depend on the policy). h, AIRL's estimate of the expert's soft value,
    pays at once for what g pays later; the optimum it leads to is g's.
    """

    def __init__(self, reward: RewardNet, potential: RewardNet, *, gamma: float) -> None:
        self.reward = reward
        self.potential = potential
        self.gamma = gamma

    def relabel(self, rollout: Rollout) -> torch.Tensor:
        steps, n_envs = rollout.env_rewards.shape
        observations, actions, next_observations = (
            flat_batch(getattr(rollout, name), 2) for name in ("observations", "env_actions", "next_observations")
        )
        g = self.reward.rewards_of(observations, actions, next_observations)
        potential = self.potential.rewards_of(observations, actions, observations)
        next_potential = self.potential.rewards_of(next_observations, actions, next_observations)
        terminated = rollout.terminated.reshape(-1).to(device=g.device, dtype=g.dtype)
        shaped = airl_shaped_reward(g, potential, next_potential, terminated, self.gamma)
        return shaped.reshape(steps, n_envs).to(rollout.env_rewards.device)


def tree_index(tree: Any, index: Any, device: torch.device | str | None = None) -> Any:
    """tree[index], leaf by leaf (moved to `device` when given)."""
    return tree_map(lambda tensor: tensor[index] if device is None else tensor[index].to(device), tree)


def flat_batch(tree: Any, leading_dims: int) -> Any:
    """The first `leading_dims` dimensions (e.g. time × envs) of every leaf merged into one batch dimension."""
    return tree_map(lambda tensor: tensor.reshape(-1, *tensor.shape[leading_dims:]), tree)


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
    return _net_tensors(model, "reward")


def potential_tensors(model: RewardNet) -> dict[str, torch.Tensor]:
    """AIRL's shaping potential h, saved beside its reward g."""
    return _net_tensors(model, "potential")


def _net_tensors(model: RewardNet, key: str) -> dict[str, torch.Tensor]:
    """`model`'s weights under "`key`.", the prefix `_saved_net` reads them back from."""
    return {f"{key}.{name}": tensor for name, tensor in model.state_dict().items()}


@dataclass(frozen=True)
class RewardRun:
    """A reward run directory (`train irl`'s), read once: its config.json, its reward model (on
    the CPU, in eval mode) and the weights AIRL's shaping potential h is built from on demand."""

    path: str
    config: dict[str, Any]
    reward: RewardNet
    weights: dict[str, torch.Tensor]

    def potential(self) -> RewardNet:
        """AIRL's shaping potential h, saved beside its reward g."""
        if "potential" not in self.config:
            raise ImitationError(
                f"{self.path}: holds no shaping potential h (a {str(self.config.get('kind', 'unknown'))[:40]!r} run); "
                "only `train irl --method airl` saves one"
            )
        potential = _saved_net(self.path, self.config, self.weights, "potential", "shaping potential")
        if potential.config.inputs != "s":
            # AIRL learns h(s) alone; shaping calls h with states only, so another h would be misread.
            raise ImitationError(
                f"{self.path}: its shaping potential h reads inputs {potential.config.inputs!r}; AIRL's h is a function "
                "of the state alone ('s')"
            )
        return potential

    @staticmethod
    def of(path: str | os.PathLike, config: dict[str, Any], weights: dict[str, torch.Tensor]) -> RewardRun:
        """The reward run of the run directory `path` whose config and weights were read
        (`read_run`); one-line errors for any other run or a damaged one."""
        if config.get("kind") != "reward" and "reward" not in config:
            raise ImitationError(
                f"{path}: not a reward model (a {str(config.get('kind', 'unknown'))[:40]!r} run); pass the run directory "
                "of `train irl`"
            )
        return RewardRun(str(path), config, _saved_net(path, config, weights, "reward", "reward model"), weights)


def read_reward_run(path: str | os.PathLike) -> RewardRun:
    """The reward run directory `path` (`RewardRun.of`)."""
    return RewardRun.of(path, *read_run(path))


def load_reward(path: str | os.PathLike) -> RewardNet:
    """The reward model of a run directory, on the CPU, in eval mode."""
    return read_reward_run(path).reward


def load_potential(path: str | os.PathLike) -> RewardNet:
    """AIRL's shaping potential h of a reward run directory, on the CPU, in eval mode."""
    return read_reward_run(path).potential()


def _saved_net(
    path: str | os.PathLike, config: dict[str, Any], weights: dict[str, torch.Tensor], key: str, net: str
) -> RewardNet:
    """The RewardNet of config.json's `key` section with the weights saved under "`key`.", checked
    against each other; `net` names it in the errors."""
    prefix = key + "."
    state = {name[len(prefix) :]: t for name, t in weights.items() if name.startswith(prefix)}
    try:
        reward_config = RewardConfig.from_json(config[key])
        check_weights_cover(path, _planned_weights(reward_config), state)
        model = RewardNet(reward_config)
        model.load_state_dict(state)
    except SpaceError as error:
        raise ImitationError(f"{path}: the {net}'s {error}") from None
    except (TypeError, KeyError, RuntimeError, ValueError) as error:
        raise ImitationError(
            f"{path}: {key} weights do not match its config ({(str(error).splitlines() or [''])[0][:200]})"
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
    fresh.load_state_dict(dict(model.named_buffers()), strict=False)
    return fresh.eval()


def random_reward_like(model: RewardNet, *, seed: int) -> RewardNet:
    """A control: `model`'s architecture with random weights (PyTorch's default initialisation under `seed`)."""
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        return _fresh_like(model)


def constant_reward_like(model: RewardNet, value: float = 1.0) -> RewardNet:
    """A control: `model`'s architecture paying `value` (> 0 for a softplus output) everywhere:
    last layer zero, bias `value` or, through softplus, its inverse log(e^value − 1)."""
    constant = _fresh_like(model)
    last = constant.net[-1]
    assert isinstance(last, nn.Linear)
    with torch.no_grad():
        last.weight.zero_()
        last.bias.fill_(value if model.config.output == "linear" else float(np.log(np.expm1(value))))
    return constant

"""Reward models r_φ(s), r_φ(s, a) or r_φ(s, a, s'): linear or MLP; save/load; the env wrapper.

A reward run directory (written by the IRL learners) holds config.json with
{"kind": "reward", "env_id": ..., "reward": RewardConfig} and model.safetensors with the
weights under "reward.". `LearnedReward` swaps an env's reward for the model's and keeps the
true one in info["true_reward"], so training on a recovered reward still reports true returns.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from imitation.data.spaces import check_spaces_fit, space_from_json, space_to_json
from imitation.errors import ImitationError
from imitation.policies import ACTIVATIONS, observation_size
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

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def _one_hot_or_flat(values: torch.Tensor, space: gym.Space) -> torch.Tensor:
    if isinstance(space, gym.spaces.Discrete):
        return nn.functional.one_hot(values.long().reshape(-1) - int(space.start), int(space.n)).float()
    return values.reshape(values.shape[0], -1).float()


class RewardNet(nn.Module):
    """r_φ on the chosen inputs; `hidden_sizes=[]` makes it linear in the features."""

    def __init__(self, config: RewardConfig) -> None:
        super().__init__()
        if config.inputs not in REWARD_INPUTS:
            raise ImitationError(f"reward inputs must be one of {', '.join(REWARD_INPUTS)}, got {config.inputs!r}")
        self.config = config
        self.observation_space = space_from_json(config.observation_space)
        self.action_space = space_from_json(config.action_space)
        size = observation_size(self.observation_space)
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

    def forward(self, observations: torch.Tensor, actions: torch.Tensor, next_observations: torch.Tensor) -> torch.Tensor:
        parts = [_one_hot_or_flat(observations, self.observation_space)]
        if "a" in self.config.inputs:
            parts.append(_one_hot_or_flat(actions, self.action_space))
        if self.config.inputs == "sas":
            parts.append(_one_hot_or_flat(next_observations, self.observation_space))
        return self.net(torch.cat(parts, dim=-1)).squeeze(-1)


def reward_tensors(model: RewardNet) -> dict[str, torch.Tensor]:
    return {REWARD_PREFIX + name: tensor for name, tensor in model.state_dict().items()}


def load_reward(path: str | os.PathLike) -> RewardNet:
    """The reward model of a run directory, on the CPU, in eval mode."""
    config, weights = read_run(path)
    if config.get("kind") != "reward" and "reward" not in config:
        raise ImitationError(f"{path}: not a reward model (a {config.get('kind', 'unknown')!r} run); pass the run directory of `train irl`")
    try:
        model = RewardNet(RewardConfig(**config["reward"]))
        model.load_state_dict({name[len(REWARD_PREFIX) :]: t for name, t in weights.items() if name.startswith(REWARD_PREFIX)})
    except (TypeError, KeyError, RuntimeError) as error:
        raise ImitationError(f"{path}: reward weights do not match its config ({str(error).splitlines()[0]})") from None
    return model.eval()


class LearnedReward(gym.Wrapper):
    """Replaces the env's reward by r_φ(s, a, s') and keeps the true reward in info["true_reward"]."""

    def __init__(self, env: gym.Env, model: RewardNet, *, where: str = "--reward") -> None:
        super().__init__(env)
        check_spaces_fit("reward model's", model.observation_space, model.action_space, env, where=where)
        self.model = model
        self._observation: Any = None

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self._observation, info = self.env.reset(**kwargs)
        return self._observation, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        next_observation, true_reward, terminated, truncated, info = self.env.step(action)
        with torch.no_grad():
            learned = self.model(
                torch.as_tensor(np.asarray(self._observation)[None]),
                torch.as_tensor(np.asarray(action)[None]),
                torch.as_tensor(np.asarray(next_observation)[None]),
            ).item()
        self._observation = next_observation
        return next_observation, learned, terminated, truncated, {**info, "true_reward": float(true_reward)}


def make_reward_model(observation_space: gym.Space, action_space: gym.Space, **options: Any) -> RewardNet:
    return RewardNet(RewardConfig(observation_space=space_to_json(observation_space), action_space=space_to_json(action_space), **options))

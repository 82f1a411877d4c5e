"""stable-baselines3 experts, read from their zips without unpickling (`imitation.experts.sb3_zip`).

Each algorithm's expert acts as SB3's `predict(deterministic=True)` does:

- PPO and A2C `MlpPolicy`: an `ActorCritic`, the policy this toolkit trains (so it can also be
  fine-tuned or evaluated as a run): the categorical's most likely action, or the Gaussian's mean
  clipped to the bounds; a gSDE policy acts by its mean too;
- SAC and TQC: a = low + (tanh μ(s) + 1)(high − low)/2, with μ the squashed Gaussian's mean
  (clipped to ±clip_mean first under gSDE, as SB3 does);
- TD3 and DDPG: a = low + (μ(s) + 1)(high − low)/2, with μ's last layer a tanh;
- DQN: a = argmax_a Q(s, a); QR-DQN: a = argmax_a mean_k θ_k(s, a) over its k quantiles.

Observations go in as SB3's MlpPolicy takes them: Box flattened to floats, Discrete one-hot.
Refused, in one line naming the algorithm: CNN and MultiInput policies (a feature extractor with
weights), image observations (SB3 scales them by 1/255 inside the policy), and PPO/A2C actor and
critic networks of different sizes. VecNormalize statistics are not in the zip but in a separate
pickle (`vecnormalize.pkl`) and are not loaded: an expert trained with VecNormalize sees
unnormalised observations here and will act badly.
"""

from __future__ import annotations

import os
import re
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from imitation.errors import ImitationError
from imitation.experts.sb3_zip import SB3Zip, read_activation, read_sb3_zip, read_space
from imitation.mlp import ACTIVATIONS
from imitation.observation_encoding import observation_size
from imitation.policies import ActorCritic, action_logits_size, make_policy

# SB3 module names → ours. The trunks are nn.Sequential(Linear, activation, ...) in both, so
# hidden-layer indices carry over unchanged.
HEADS = {
    "action_net.weight": "action_head.weight",
    "action_net.bias": "action_head.bias",
    "value_net.weight": "value_head.weight",
    "value_net.bias": "value_head.bias",
    "log_std": "log_std",
}
HIDDEN_LAYER = re.compile(r"mlp_extractor\.(policy_net|value_net|shared_net)\.(\d+)\.(weight|bias)")
# Where each off-policy algorithm keeps the network its expert acts with: the hidden layers'
# prefix and the output layer's (None: the last layer under the same prefix).
NETWORKS = {
    "SAC": ("actor.latent_pi.", "actor.mu."),
    "TQC": ("actor.latent_pi.", "actor.mu."),
    "TD3": ("actor.mu.", None),
    "DQN": ("q_net.q_net.", None),
    "QR-DQN": ("quantile_net.quantile_net.", None),
}
SAC_CLIP_MEAN = 2.0  # SB3's default for SAC's and TQC's gSDE actors
LINEAR = re.compile(r"(\d+)\.(weight|bias)")


def load_sb3_expert(path: str | os.PathLike) -> tuple[ActorCritic | OffPolicyExpert, str]:
    """The expert in an SB3 zip of any supported algorithm, on the CPU in eval mode, and the
    algorithm's name."""
    model = read_sb3_zip(path)
    if model.algorithm == "PPO/A2C":
        return _actor_critic(model), model.algorithm
    return _off_policy_expert(model), model.algorithm


def load_sb3_policy(path: str | os.PathLike) -> ActorCritic:
    """The policy in an SB3 PPO/A2C zip, as an ActorCritic on the CPU in eval mode."""
    model = read_sb3_zip(path)
    if model.algorithm != "PPO/A2C":
        raise ImitationError(
            f"{model.where}: not a PPO/A2C actor-critic; use it as an expert (imitation.experts.sb3.load_sb3_expert)"
        )
    return _actor_critic(model)


def _spaces(model: SB3Zip) -> tuple[gym.Space, gym.Space]:
    """The zip's spaces, refused when the policy class or the observations need a CNN."""
    if model.policy_class in ("CnnPolicy", "MultiInputPolicy", "ActorCriticCnnPolicy", "MultiInputActorCriticPolicy"):
        raise ImitationError(
            f"{model.where}: a {model.policy_class} is not supported (only MlpPolicy: no feature extractor with weights)"
        )
    observation_space, action_space = read_space(model, "observation_space"), read_space(model, "action_space")
    if (
        isinstance(observation_space, gym.spaces.Box)
        and observation_space.dtype == np.uint8
        and len(observation_space.shape) == 3
    ):
        raise ImitationError(
            f"{model.where}: image observations are not supported (SB3 scales them by 1/255 inside the policy)"
        )
    return observation_space, action_space


def _actor_critic(model: SB3Zip) -> ActorCritic:
    file = model.where
    observation_space, action_space = _spaces(model)
    hidden_sizes, shared, state = _rename_weights(file, model.weights, sde=bool(model.data.get("use_sde")))
    head = state.get("action_head.weight")
    if head is not None and head.dim() == 2 and head.shape[0] != action_logits_size(action_space):
        # Checked before the network is built: a forged space could otherwise ask for a huge head.
        details = f"its action head has {head.shape[0]} outputs, the action space needs {action_logits_size(action_space)}"
        raise ImitationError(f"{file}: policy.pth does not fit the zip's spaces ({details})")
    policy = make_policy(
        observation_space, action_space, hidden_sizes=hidden_sizes, activation=read_activation(model), shared_trunk=shared
    )
    # Ours and SB3's differ in what they keep in the module: the action bounds (SB3 keeps them in
    # the action space, read above) and, under gSDE, the state-independent log σ (SB3's is a
    # matrix of noise weights; an expert acts by its mean, so ours stays at its initial value).
    kept = ("action_low", "action_high", "log_std") if model.data.get("use_sde") else ("action_low", "action_high")
    state.update({name: tensor for name, tensor in policy.state_dict().items() if name in kept})
    try:
        policy.load_state_dict(state)
    except RuntimeError as error:
        details = "; ".join(line.strip() for line in str(error).splitlines()[1:]) or str(error)
        raise ImitationError(f"{file}: policy.pth does not fit the zip's spaces ({details})") from None
    return policy.eval()


class OffPolicyExpert(nn.Module):
    """An off-policy algorithm's network read out as its deterministic action (see the module
    docstring): an MLP on the encoded observation, `net`, whose outputs are SAC's and TQC's
    squashed mean, TD3's pre-tanh action, DQN's Q-values or QR-DQN's quantiles."""

    low: torch.Tensor  # Box action bounds (buffers)
    high: torch.Tensor

    def __init__(
        self,
        algorithm: str,
        observation_space: gym.Space,
        action_space: gym.Space,
        sizes: list[int],
        activation: str,
        *,
        clip_mean: float | None = None,
    ) -> None:
        super().__init__()
        self.algorithm, self.observation_space, self.action_space, self.clip_mean = (
            algorithm,
            observation_space,
            action_space,
            clip_mean,
        )
        layers: list[nn.Module] = []
        for inputs, outputs in zip(sizes[:-1], sizes[1:]):
            layers += [nn.Linear(inputs, outputs), ACTIVATIONS[activation]()]
        self.net = nn.Sequential(*layers[:-1])  # no activation after the output layer
        if isinstance(action_space, gym.spaces.Box):
            self.register_buffer("low", torch.as_tensor(action_space.low, dtype=torch.float32).reshape(-1))
            self.register_buffer("high", torch.as_tensor(action_space.high, dtype=torch.float32).reshape(-1))

    def encode(self, observations: torch.Tensor) -> torch.Tensor:
        if isinstance(self.observation_space, gym.spaces.Discrete):
            index = observations.long().reshape(-1) - int(self.observation_space.start)
            return nn.functional.one_hot(index, int(self.observation_space.n)).float()
        return observations.reshape(len(observations), -1).float()

    def predict(self, observations: Any, *, deterministic: bool = True) -> np.ndarray:
        """Env actions for a batch of raw observations (always the deterministic ones)."""
        with torch.no_grad():
            outputs = self.net(self.encode(torch.as_tensor(np.asarray(observations))))
            if isinstance(self.action_space, gym.spaces.Discrete):
                if self.algorithm == "QR-DQN":
                    outputs = outputs.reshape(len(outputs), -1, int(self.action_space.n)).mean(1)
                return (outputs.argmax(-1) + int(self.action_space.start)).numpy()
            if self.clip_mean is not None:
                outputs = outputs.clamp(-self.clip_mean, self.clip_mean)
            scaled = torch.tanh(outputs)  # SAC's and TQC's squashing; TD3's last layer
            action = self.low + 0.5 * (scaled + 1.0) * (self.high - self.low)
            assert self.action_space.shape is not None
            return action.reshape(len(action), *self.action_space.shape).numpy()


def _off_policy_expert(model: SB3Zip) -> OffPolicyExpert:
    file = model.where
    observation_space, action_space = _spaces(model)
    continuous = model.algorithm in ("SAC", "TQC", "TD3")
    if continuous != isinstance(action_space, gym.spaces.Box) or not isinstance(
        action_space, (gym.spaces.Box, gym.spaces.Discrete)
    ):
        raise ImitationError(f"{file}: its action space {action_space} is not one {model.algorithm} acts in")
    hidden, output = NETWORKS[model.algorithm]
    layers = _linear_layers(file, model.weights, hidden)
    if output is not None:
        head = _linear_layers(file, model.weights, output)
        if len(head) != 1:
            raise ImitationError(f"{file}: {output}* holds {len(head)} linear layers, where the actor's mean is one")
        layers += head
    sizes = [int(layers[0][0].shape[1])] + [int(weight.shape[0]) for weight, _ in layers]
    if sizes[0] != observation_size(observation_space):
        raise ImitationError(
            f"{file}: policy.pth takes {sizes[0]} inputs, the observation space gives {observation_size(observation_space)}"
        )
    actions = int(np.prod(action_space.shape)) if isinstance(action_space, gym.spaces.Box) else int(action_space.n)
    quantiles, remainder = divmod(sizes[-1], actions)
    if remainder or (quantiles != 1 and model.algorithm != "QR-DQN"):
        raise ImitationError(f"{file}: policy.pth has {sizes[-1]} outputs, which do not fit {actions} actions")
    sde_mean = model.algorithm in ("SAC", "TQC") and f"{output}0.weight" in model.weights
    clip_mean = _clip_mean(model) if sde_mean else None
    expert = OffPolicyExpert(
        model.algorithm, observation_space, action_space, sizes[:], read_activation(model), clip_mean=clip_mean
    )
    state = {
        f"net.{2 * i}.{name}": tensor for i, layer in enumerate(layers) for name, tensor in zip(("weight", "bias"), layer)
    }
    state |= {name: tensor for name, tensor in expert.state_dict().items() if name in ("low", "high")}
    try:
        expert.load_state_dict(state)
    except RuntimeError as error:
        details = "; ".join(line.strip() for line in str(error).splitlines()[1:]) or str(error)
        raise ImitationError(f"{file}: policy.pth does not fit the zip's spaces ({details})") from None
    return expert.eval()


def _linear_layers(file: str, weights: dict[str, torch.Tensor], prefix: str) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """(weight, bias) of the Linear layers under `prefix`, in order: at indices 0, 2, 4, ... of an
    nn.Sequential with activations between (a gSDE mean is `mu.0`, its Hardtanh `mu.1`), or the
    one nn.Linear the prefix names."""
    found: dict[int, dict[str, torch.Tensor]] = {}
    for name, tensor in weights.items():
        if not name.startswith(prefix):
            continue
        rest = name[len(prefix) :]
        if rest in ("weight", "bias"):  # one nn.Linear, not a Sequential (SAC's mean without gSDE)
            found.setdefault(0, {})[rest] = tensor
        elif match := LINEAR.fullmatch(rest):
            found.setdefault(int(match[1]), {})[match[2]] = tensor
    indices = sorted(found)
    if not indices or indices != list(range(0, 2 * len(indices), 2)):
        raise ImitationError(
            f"{file}: policy.pth has no linear layers under {prefix}* at indices 0, 2, 4, ... (found {indices})"
        )
    layers = []
    for i in indices:
        weight, bias = found[i].get("weight"), found[i].get("bias")
        if weight is None or bias is None or weight.dim() != 2 or bias.shape != weight.shape[:1]:
            raise ImitationError(f"{file}: {prefix}{i} is not a linear layer (a 2-D weight and a bias of its rows)")
        layers.append((weight, bias))
    for (previous, _), (weight, _) in zip(layers, layers[1:]):
        if weight.shape[1] != previous.shape[0]:
            raise ImitationError(
                f"{file}: {prefix}* layers do not chain ({previous.shape[0]} outputs into {weight.shape[1]} inputs)"
            )
    return layers


def _clip_mean(model: SB3Zip) -> float:
    """SAC's and TQC's gSDE clip of the mean: policy_kwargs' readable `clip_mean`, else SB3's default."""
    kwargs = model.data.get("policy_kwargs")
    value = kwargs.get("clip_mean", SAC_CLIP_MEAN) if isinstance(kwargs, dict) else SAC_CLIP_MEAN
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < float("inf"):
        raise ImitationError(f"{model.where}: policy_kwargs' clip_mean is {str(value)[:40]}, not a positive number")
    return float(value)


def _rename_weights(
    file: str, weights: dict[str, torch.Tensor], *, sde: bool
) -> tuple[list[int], bool, dict[str, torch.Tensor]]:
    """Hidden sizes, whether the trunk is shared, and the weights under our module names."""
    layers: dict[str, dict[int, dict[str, torch.Tensor]]] = {"policy_net": {}, "value_net": {}, "shared_net": {}}
    state: dict[str, torch.Tensor] = {}
    for name, tensor in weights.items():
        if name == "log_std" and sde:
            continue  # gSDE's noise weights, (latent, actions): an expert acts by the mean
        if name in HEADS:
            state[HEADS[name]] = tensor
        elif match := HIDDEN_LAYER.fullmatch(name):
            layers[match[1]].setdefault(int(match[2]), {})[match[3]] = tensor
        else:
            raise ImitationError(
                f"{file}: policy.pth holds {name!r}, which an SB3 PPO/A2C MlpPolicy does not have "
                "(CNN, MultiInput and custom feature extractors are not supported)"
            )
    sizes = {net: _hidden_sizes(file, net, found) for net, found in layers.items()}
    if sizes["shared_net"] and (sizes["policy_net"] or sizes["value_net"]):
        raise ImitationError(f"{file}: a shared network followed by separate actor/critic layers is not supported")
    if sizes["shared_net"]:
        trunks: dict[str, tuple[str, ...]] = {"shared_net": ("actor_trunk", "critic_trunk")}
    elif sizes["policy_net"] != sizes["value_net"]:
        raise ImitationError(
            f"{file}: actor hidden sizes {sizes['policy_net']} differ from critic hidden sizes {sizes['value_net']}, which "
            "is not supported"
        )
    else:
        trunks = {"policy_net": ("actor_trunk",), "value_net": ("critic_trunk",)}
    for net, ours in trunks.items():
        for index, params in layers[net].items():
            for param, tensor in params.items():
                state.update({f"{trunk}.{index}.{param}": tensor for trunk in ours})
    return sizes["shared_net"] or sizes["policy_net"], bool(sizes["shared_net"]), state


def _hidden_sizes(file: str, net: str, found: dict[int, dict[str, torch.Tensor]]) -> list[int]:
    """Output sizes of an MLP's Linear layers, which sit at indices 0, 2, 4, ... (activations between)."""
    indices = sorted(found)
    linear = all(set(found[i]) == {"weight", "bias"} and found[i]["weight"].dim() == 2 for i in indices)
    if indices != list(range(0, 2 * len(indices), 2)) or not linear:
        raise ImitationError(
            f"{file}: mlp_extractor.{net} is not Linear layers alternating with activations (layers {indices})"
        )
    return [int(found[i]["weight"].shape[0]) for i in indices]

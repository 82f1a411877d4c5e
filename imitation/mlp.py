"""MLPs as policies and reward models build them, and the checks on their sizes that come before
any weight is allocated: widths read from a file, the weights a config plans against those a
weights file holds. Hidden layers are orthogonal with gain √2 (tanh or ReLU between them)."""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import nn

from imitation.errors import ImitationError

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU}


def check_layer_widths(hidden_sizes: Any) -> None:
    """Hidden-layer widths read from a file: a list of at most 64 widths in [1, 2^20]."""
    if not (
        isinstance(hidden_sizes, list)
        and len(hidden_sizes) <= 64
        and all(isinstance(h, int) and not isinstance(h, bool) and 1 <= h <= 2**20 for h in hidden_sizes)
    ):
        raise ValueError(f"hidden_sizes must be a list of layer widths in [1, 2^20], got {str(hidden_sizes)[:80]}")


def mlp_weight_count(inputs: int, hidden_sizes: list[int], outputs: int) -> int:
    """How many numbers the weight matrices of such an MLP hold (its biases not counted)."""
    sizes = [inputs, *hidden_sizes, outputs]
    return sum(a * b for a, b in zip(sizes, sizes[1:]))


def check_weights_cover(path: Any, planned: int, weights: dict[str, torch.Tensor]) -> None:
    """Refuse, before allocating it, a network bigger than the weights file could fill: every
    parameter must be in the file, so a config asking for more is wrong (or crafted)."""
    held = sum(tensor.numel() for tensor in weights.values())
    if planned > held:
        raise ImitationError(
            f"{path}: its config describes a network of at least {planned} weights, but its weights file holds {held} numbers"
        )


def orthogonal_linear(inputs: int, outputs: int, gain: float) -> nn.Linear:
    """A linear layer with orthogonal weights of the given gain and zero biases."""
    linear = nn.Linear(inputs, outputs)
    nn.init.orthogonal_(linear.weight, gain)
    nn.init.zeros_(linear.bias)
    return linear


def hidden_layers(inputs: int, hidden_sizes: list[int], activation: str) -> nn.Sequential:
    """The hidden layers of an MLP trunk, each orthogonal with gain √2 and followed by `activation`."""
    layers: list[nn.Module] = []
    for size in hidden_sizes:
        layers += [orthogonal_linear(inputs, size, math.sqrt(2)), ACTIVATIONS[activation]()]
        inputs = size
    return nn.Sequential(*layers)

"""Tensor and device helpers shared by the learners, the reward models and the loaders: the device
a run asks for, and trees of tensors (an observation of a Dict space is a dict of batches)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch

from imitation.errors import ConfigError

TensorTree = torch.Tensor | dict[str, Any]


def resolve_device(device: str | torch.device = "auto") -> torch.device:
    """'auto' → CUDA when available, else CPU; anything else is passed to torch.device."""
    if isinstance(device, torch.device):
        return device
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        resolved = torch.device(device)
    except RuntimeError as error:
        raise ConfigError("device", f"{device!r}: {error}") from None
    if resolved.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device", f"{device}: CUDA is not available on this machine")
    return resolved


def tree_map(fn: Callable[[Any], Any], tree: Any) -> Any:
    """`fn` applied to every leaf of a tree (a tensor or array, or a dict of trees; None stays None), the tree kept."""
    if tree is None:
        return None
    if isinstance(tree, dict):
        return {key: tree_map(fn, sub) for key, sub in tree.items()}
    return fn(tree)


def tree_cat(*trees: Any) -> Any:
    """Batches (tensors, or dicts of them alike) one after the other."""
    if isinstance(trees[0], dict):
        return {key: tree_cat(*(tree[key] for tree in trees)) for key in trees[0]}
    return torch.cat(trees)

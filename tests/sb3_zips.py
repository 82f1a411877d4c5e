"""The parts of a stable-baselines3 zip as SB3 2.x writes them, for tests that build zips."""

from __future__ import annotations

from typing import Any, Sequence

import gymnasium as gym
import torch

# base64 of "not opened": stands in for the pickle SB3 writes, which the loader must never open.
OPAQUE = "bm90IG9wZW5lZA=="


def space_entry(space: gym.Space, serialized: str = OPAQUE) -> dict[str, Any]:
    """A space as SB3 2.x writes it into `data`: an opaque pickle plus readable attributes, with
    numpy values as their str() (so Discrete's n is "3", Box bounds are '[-2. -2.]')."""
    entry = {":type:": f"<class '{type(space).__module__}.{type(space).__name__}'>", ":serialized:": serialized, "_shape": list(space.shape)}
    if isinstance(space, gym.spaces.Discrete):
        return entry | {"n": str(space.n), "start": str(space.start), "dtype": "int64"}
    if isinstance(space, gym.spaces.Box):
        return entry | {"dtype": str(space.dtype), "low": str(space.low), "high": str(space.high)}
    return entry


def sb3_weights(obs_size: int, actions: int, *, pi: Sequence[int], vf: Sequence[int], shared: Sequence[int] = (), box: bool = False) -> dict[str, torch.Tensor]:
    """A random state dict with the names and shapes of SB3's ActorCriticPolicy."""
    weights: dict[str, torch.Tensor] = {}
    width = obs_size
    for net, sizes in (("shared_net", shared), ("policy_net", pi), ("value_net", vf)):
        inputs = width
        for i, size in enumerate(sizes):
            weights[f"mlp_extractor.{net}.{2 * i}.weight"] = torch.randn(size, inputs)
            weights[f"mlp_extractor.{net}.{2 * i}.bias"] = torch.randn(size)
            inputs = size
        if net == "shared_net":
            width = inputs
    pi_out, vf_out = (pi or shared or [obs_size])[-1], (vf or shared or [obs_size])[-1]
    weights |= {"action_net.weight": torch.randn(actions, pi_out), "action_net.bias": torch.randn(actions)}
    weights |= {"value_net.weight": torch.randn(1, vf_out), "value_net.bias": torch.randn(1)}
    if box:
        weights["log_std"] = torch.randn(actions)
    return weights

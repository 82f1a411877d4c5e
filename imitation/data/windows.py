"""Sequence windows over flat transitions, for policies that read a history of observations and
predict a chunk of actions (action chunking, diffusion policies). For transition t of an episode
that spans rows [b, e], with a history of n observations and a chunk of H actions,

    o_{t,j} = s_{clamp(t − n + 1 + j)},   observation pad_{t,j} = (t − n + 1 + j < b),   j = 0 … n − 1
    a_{t,k} = a_{clamp(t + k)},           action pad_{t,k}      = (t + k > e),           k = 0 … H − 1

with clamp to [b, e]: before the episode's start its first observation is repeated, past its end
its last action, and the masks say which entries were repeated, as LeRobot's `delta_timestamps`
(its `*_is_pad` masks) and the Diffusion Policy code's sequence sampler pad them. A window never
crosses into another episode.

The index of every window is computed once (`window_index`, from the rows' episode ids); a
minibatch's windows are gathered from the transitions when it is drawn (`gather_windows`), so that
the data is held once however long the windows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from imitation.data.loader import TransitionTensors
from imitation.errors import ImitationError
from imitation.tensors import TensorTree, tree_map

MAX_WINDOW = 1024  # steps of history or of a chunk: beyond any policy's, and a bound on the index's memory


@dataclass(frozen=True)
class WindowSpec:
    """How many observations a window holds (the current one and those before it) and how many
    actions (the current one and those after it)."""

    observations: int = 1
    actions: int = 1

    def __post_init__(self) -> None:
        for name in ("observations", "actions"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_WINDOW:
                raise ImitationError(f"a window's {name} must be a whole number in [1, {MAX_WINDOW}], got {value!r:.40}")


@dataclass(frozen=True)
class WindowIndex:
    """Per transition (rows) and window position (columns): the row each entry is read from, and
    whether it repeats the episode's edge (pad)."""

    observation_rows: np.ndarray
    observation_pad: np.ndarray
    action_rows: np.ndarray
    action_pad: np.ndarray

    def __len__(self) -> int:
        return len(self.observation_rows)


def window_index(episode_index: np.ndarray, spec: WindowSpec) -> WindowIndex:
    """The windows of transitions whose episode ids are `episode_index` (one per row, each
    episode's rows contiguous and in step order, as `load_transitions` lays them out)."""
    episodes = np.asarray(episode_index)
    if episodes.ndim != 1:
        raise ImitationError(f"episode ids must be one per transition, got an array of shape {episodes.shape}")
    rows = np.arange(len(episodes), dtype=np.int64)
    new = np.ones(len(episodes), dtype=bool)
    new[1:] = episodes[1:] != episodes[:-1]
    starts = np.flatnonzero(new)
    if len(np.unique(episodes[starts])) != len(starts):
        raise ImitationError("an episode's transitions must be contiguous rows; one episode id appears in two places")
    run = np.cumsum(new) - 1
    ends = np.append(starts[1:], len(episodes)) - 1
    first, last = starts[run][:, None], ends[run][:, None]
    observed = rows[:, None] + np.arange(1 - spec.observations, 1, dtype=np.int64)
    acted = rows[:, None] + np.arange(spec.actions, dtype=np.int64)
    return WindowIndex(
        observation_rows=np.clip(observed, first, last),
        observation_pad=observed < first,
        action_rows=np.clip(acted, first, last),
        action_pad=acted > last,
    )


@dataclass(frozen=True)
class WindowBatch:
    """Windows of a minibatch: observations (batch, n, …) per leaf, actions (batch, H, …), and
    their pad masks (batch, n) and (batch, H)."""

    observations: TensorTree
    observation_pad: torch.Tensor
    actions: torch.Tensor
    action_pad: torch.Tensor

    def __len__(self) -> int:
        return len(self.action_pad)

    def to(self, device: str | torch.device) -> WindowBatch:
        return WindowBatch(
            observations=tree_map(lambda tensor: tensor.to(device), self.observations),
            observation_pad=self.observation_pad.to(device),
            actions=self.actions.to(device),
            action_pad=self.action_pad.to(device),
        )


def gather_windows(data: TransitionTensors, index: WindowIndex, rows: np.ndarray) -> WindowBatch:
    """The windows of transitions `rows` of `data` (whose windows `index` describes)."""
    if not isinstance(data.actions, torch.Tensor):
        raise ImitationError("windows take Box or Discrete actions, not Dict ones")
    device = data.device

    def gather(tensor: torch.Tensor, at: np.ndarray) -> torch.Tensor:
        flat = torch.as_tensor(at.reshape(-1), device=tensor.device)
        return tensor[flat].reshape(*at.shape, *tensor.shape[1:])

    observation_rows, action_rows = index.observation_rows[rows], index.action_rows[rows]
    return WindowBatch(
        observations=tree_map(lambda tensor: gather(tensor, observation_rows), data.observations),
        observation_pad=torch.as_tensor(index.observation_pad[rows], device=device),
        actions=gather(data.actions, action_rows),
        action_pad=torch.as_tensor(index.action_pad[rows], device=device),
    )

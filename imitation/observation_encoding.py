"""How an observation becomes a network's input, shared by policies (`imitation.policies`) and reward
models (`imitation.rewards`): a Box or Discrete observation read flat (Discrete one-hot); a Dict
or image observation by its `ObservationLayout`, each image leaf (a stack of `frame_stack`
frames) as frames for a CNN (`imitation.encoders`) and the other leaves flattened side by side,
in key order. `ObservationConfig` holds the fields that say so, embedded in both configs; the
checks on those fields of a config read from a file, and on a CNN's size before it is built, sit
here too."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from imitation.encoders import CNNConfig, cnn_weight_count
from imitation.envs.pixels import PixelRecipe, is_image_space
from imitation.errors import ImitationError
from imitation.limits import LIMITS


def check_image_fields(observation_keys: Any, frame_stack: Any, cnn: Any, pixels: Any) -> None:
    """The image fields a policy or reward config read from a file holds: the leaves read, the
    frames per image leaf, the CNN and how the env renders. TypeError or ValueError naming the
    malformed one."""
    if observation_keys is not None and not (
        isinstance(observation_keys, list) and all(isinstance(key, str) for key in observation_keys)
    ):
        raise TypeError("observation_keys must be a list of names")
    if isinstance(frame_stack, bool) or not isinstance(frame_stack, int) or not 1 <= frame_stack <= 64:
        raise ValueError(f"frame_stack must be an integer in [1, 64], got {str(frame_stack)[:40]}")
    if cnn is not None:
        CNNConfig.from_json(cnn)
    if pixels is not None:
        PixelRecipe.from_json(pixels)


def check_cnn_size(layout: ObservationLayout, cnn: CNNConfig) -> None:
    """Refuse, before any weight is allocated, CNNs on the layout's image leaves that hold more
    than `LIMITS.policy_parameters` weights: their last linear layer grows with the frames' area
    (the default CNN on 480×640 frames holds 139 million weights, on 96×96 2 million)."""
    weights = sum(cnn_weight_count(leaf.frames * leaf.channels, leaf.height, leaf.width, cnn) for leaf in layout.images)
    if weights > LIMITS.policy_parameters:
        sides = ", ".join(sorted({f"{leaf.height}×{leaf.width}" for leaf in layout.images}))
        raise ImitationError(
            f"the CNN on {sides} frames would hold {weights} weights, more than the limit policy_parameters="
            f"{LIMITS.policy_parameters}: train on smaller frames (train bc --image-size 96x96 resizes them as they load) "
            "or raise the limit with `imitation --limit policy_parameters=N`"
        )


def check_angles(angles: list[int], size: int) -> None:
    """The observation positions read as angles lie within an observation of `size` numbers."""
    if outside := [index for index in angles if not 0 <= index < size]:
        raise ImitationError(f"--angles {outside[0]}: the observation holds {size} numbers (positions 0 to {size - 1})")


def with_angles(observations: torch.Tensor, angles: torch.Tensor) -> torch.Tensor:
    """Flat observations (…, d) with each angle θ at the positions `angles` (a LongTensor) read as
    (cos θ, sin θ): cos θ in its place, sin θ appended, so that a turn through 0 (or 2π) is not a
    jump of 2π."""
    if not len(angles):
        return observations
    radians = observations[..., angles]
    return torch.cat([observations.index_copy(-1, angles, radians.cos()), radians.sin()], -1)


def observation_size(space: gym.Space) -> int:
    if isinstance(space, gym.spaces.Box):
        return int(np.prod(space.shape))
    if isinstance(space, gym.spaces.Discrete):
        return int(space.n)
    raise ImitationError(f"policies take Box or Discrete observations, not {type(space).__name__}")


@dataclass(frozen=True)
class ImageLeaf:
    """A leaf of the observation read as frames: its path, and (k, H, W, C) per sample."""

    path: tuple[str, ...]
    frames: int
    height: int
    width: int
    channels: int


@dataclass(frozen=True)
class ObservationLayout:
    """How a Dict or image observation becomes features: image leaves through CNNs, the other
    leaves read flattened (Discrete ones one-hot) into one vector, in key order."""

    images: list[ImageLeaf]
    vectors: list[tuple[tuple[str, ...], gym.Space]]

    @property
    def vector_size(self) -> int:
        return sum(observation_size(space) for _, space in self.vectors)


def observation_layout(space: gym.Space, keys: list[str] | None, frame_stack: int) -> ObservationLayout | None:
    """The layout of a Dict or image observation space (None for a plain Box or Discrete one,
    read as before). With `frame_stack` k > 1 an image leaf is a (k, H, W, C) stack."""

    def image(path: tuple[str, ...], sub: gym.Space) -> ImageLeaf | None:
        if not isinstance(sub, gym.spaces.Box) or sub.dtype != np.uint8:
            return None
        shape = sub.shape
        if frame_stack > 1:
            if len(shape) == 4 and shape[0] == frame_stack and shape[-1] in (1, 3, 4):
                return ImageLeaf(path, frame_stack, shape[1], shape[2], shape[3])
            return None
        if not is_image_space(sub):
            return None
        return ImageLeaf(path, 1, shape[0], shape[1], shape[2] if len(shape) == 3 else 1)

    if not isinstance(space, gym.spaces.Dict):
        leaf = image((), space)
        return ObservationLayout([leaf], []) if leaf is not None else None
    unknown = sorted(set(keys or []) - set(space.spaces))
    if unknown:
        raise ImitationError(f"observation keys {unknown} are not in the observation space's {sorted(space.spaces)}")
    images: list[ImageLeaf] = []
    vectors: list[tuple[tuple[str, ...], gym.Space]] = []
    for key, sub in space.spaces.items():
        if keys is not None and key not in keys:
            continue
        leaf = image((key,), sub)
        if leaf is not None:
            images.append(leaf)
        elif isinstance(sub, (gym.spaces.Box, gym.spaces.Discrete)):
            vectors.append(((key,), sub))
        else:
            raise ImitationError(f"policies read Box, Discrete and image leaves of a Dict observation, not {key!r}: {sub}")
    if not images and not vectors:
        raise ImitationError("the policy reads no observation leaf")
    return ObservationLayout(images, vectors)


def _leaf(tree: Any, path: tuple[str, ...]) -> Any:
    for key in path:
        tree = tree[key]
    return tree


def leaf_frames(observations: Any, leaf: ImageLeaf) -> torch.Tensor:
    """An image leaf of a batch as (batch, k, H, W, C)."""
    frames = _leaf(observations, leaf.path)
    return frames.reshape(frames.shape[0], leaf.frames, leaf.height, leaf.width, leaf.channels)


def one_hot_or_flat(values: torch.Tensor, space: gym.Space) -> torch.Tensor:
    """A batch of one leaf as float rows: Discrete values one-hot, others flattened."""
    if isinstance(space, gym.spaces.Discrete):
        return nn.functional.one_hot(values.long().reshape(-1) - int(space.start), int(space.n)).float()
    return values.reshape(values.shape[0], -1).float()


def vector_leaves(observations: Any, layout: ObservationLayout) -> torch.Tensor:
    """The non-image leaves of a batch, flattened (Discrete ones one-hot) side by side."""
    return torch.cat([one_hot_or_flat(_leaf(observations, path), space) for path, space in layout.vectors], dim=1)


@dataclass(kw_only=True)
class ObservationConfig:
    """How a network reads its observations, the fields `PolicyConfig` and `RewardConfig` share
    (flat in their JSON): the top-level leaves read (None: all), frames per image leaf, the CNN on
    image leaves (`encoders.CNNConfig` JSON; None: the Nature CNN), and how the acting env renders
    its frames (`PixelRecipe` JSON; None: the env's own observations), so that a policy acting, or
    PPO on a learnt reward, sees what training saw."""

    observation_keys: list[str] | None = None
    frame_stack: int = 1
    cnn: dict[str, Any] | None = None
    pixels: dict[str, Any] | None = None

    def check_observation_fields(self) -> None:
        """Of a config read from a file: TypeError or ValueError naming a malformed field."""
        check_image_fields(self.observation_keys, self.frame_stack, self.cnn, self.pixels)

    def layout(self, space: gym.Space) -> ObservationLayout | None:
        """How observations of `space` are read (None for a plain Box or Discrete one)."""
        return observation_layout(space, self.observation_keys, self.frame_stack)

    def cnn_config(self) -> CNNConfig:
        return CNNConfig.from_json(self.cnn or {})

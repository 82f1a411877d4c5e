"""A learner's crop and target size for camera frames (`train bc --crop T,L,H,W --image-size HxW`).

`FrameTransform` is applied once to every image leaf of an observation (`is_image_leaf`: uint8,
(H, W) or (H, W, C)), where frames are decoded: keep the rectangle `crop` (top, left, height,
width), then resize to `size` (height, width) with the toolkit's one resize
(`imitation.data.image_resize`: area averaging). The policy carries it (`PolicyConfig`'s
`image_transform`), and the env it acts in applies it to every frame it observes, so a policy
sees in evaluation exactly what it learnt from (`TransformFrames`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.data.image_resize import MAX_SIDE, resized
from imitation.data.mcap.images import is_image_leaf
from imitation.data.spaces import space_leaves
from imitation.errors import ImitationError


@dataclass(frozen=True)
class FrameTransform:
    """Crop, then resize, every image leaf (the module docstring); None leaves that step out."""

    size: tuple[int, int] | None = None  # height, width
    crop: tuple[int, int, int, int] | None = None  # top, left, height, width

    def shape(self, shape: tuple[int, ...]) -> tuple[int, ...]:
        """An image leaf's shape after the transform (channels kept)."""
        height, width = self.size or (self.crop[2:] if self.crop is not None else shape[:2])
        return (height, width, *shape[2:])

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        if self.crop is not None:
            top, left, height, width = self.crop
            frame = frame[top : top + height, left : left + width]
        return resized(frame, self.size) if self.size is not None else np.ascontiguousarray(frame)

    def check(self, space: gym.Space, where: str) -> None:
        """Refuse a crop outside a frame of `space`, or a space without frames; `where` names the data."""
        leaves = [(path, shape) for path, dtype, shape in space_leaves(space) if is_image_leaf(dtype, shape)]
        if not leaves:
            raise ImitationError(f"{where}: --image-size and --crop resize camera frames, and the observations hold none")
        for path, shape in leaves:
            if self.crop is not None:
                top, left, height, width = self.crop
                if top + height > shape[0] or left + width > shape[1]:
                    raise ImitationError(
                        f"{where}: --crop {','.join(map(str, self.crop))} (top, left, height, width) reaches outside the "
                        f"{shape[0]}×{shape[1]} frames of {'/'.join(path) or 'the observation'}"
                    )

    def space(self, space: gym.Space) -> gym.Space:
        """`space` with each image leaf at its transformed shape."""
        if isinstance(space, gym.spaces.Dict):
            return gym.spaces.Dict({key: self.space(sub) for key, sub in space.spaces.items()})
        if isinstance(space, gym.spaces.Box) and is_image_leaf(space.dtype, space.shape):
            return gym.spaces.Box(0, 255, self.shape(space.shape), dtype=np.uint8)
        return space

    def observation(self, observation: Any) -> Any:
        """One observation (an array, or a dict of them) with each image leaf transformed."""
        if isinstance(observation, dict):
            return {key: self.observation(value) for key, value in observation.items()}
        array = np.asarray(observation)
        return self(array) if is_image_leaf(array.dtype, array.shape) else observation

    def row_bytes(self, space: gym.Space) -> int:
        """Bytes of one observation of `space` once transformed."""
        return sum(dtype.itemsize * math.prod(shape) for _, dtype, shape in space_leaves(self.space(space)))

    def describe(self) -> str:
        crop = f"cropped to {self.crop[2]}×{self.crop[3]} at ({self.crop[0]}, {self.crop[1]})" if self.crop else ""
        size = f"resized to {self.size[0]}×{self.size[1]}" if self.size else ""
        return ", ".join(part for part in (crop, size) if part)

    def to_json(self) -> dict[str, Any]:
        return {
            **({"size": list(self.size)} if self.size is not None else {}),
            **({"crop": list(self.crop)} if self.crop is not None else {}),
        }

    @staticmethod
    def from_json(data: Any) -> FrameTransform:
        """From `to_json`'s output read from a file; ValueError for anything else."""
        size = data.get("size") if isinstance(data, dict) else None
        crop = data.get("crop") if isinstance(data, dict) else None
        if not (
            isinstance(data, dict)
            and set(data) <= {"size", "crop"}
            and (size is None or _integers(size, 2, 1))
            and (crop is None or (_integers(crop, 4, 0) and min(crop[2:]) >= 1))
        ):
            raise ValueError(
                "an image transform is {'size': [H, W], 'crop': [top, left, height, width]} with sides up to "
                f"{MAX_SIDE}, got {str(data)[:80]}"
            )
        return FrameTransform(
            (size[0], size[1]) if size is not None else None,
            (crop[0], crop[1], crop[2], crop[3]) if crop is not None else None,
        )


def _integers(values: Any, count: int, low: int) -> bool:
    return (
        isinstance(values, list)
        and len(values) == count
        and all(isinstance(n, int) and not isinstance(n, bool) and low <= n <= MAX_SIDE for n in values)
    )


class TransformFrames(gym.ObservationWrapper):
    """Every image leaf of the observations cropped and resized by `transform`, as a policy
    trained with `train bc --crop/--image-size` learnt from them (`FrameTransform`)."""

    def __init__(self, env: gym.Env, transform: FrameTransform) -> None:
        super().__init__(env)
        name = env.spec.id if env.spec else type(env.unwrapped).__name__
        transform.check(env.observation_space, f"environment {name}")
        self.transform = transform
        self.observation_space = transform.space(env.observation_space)

    def observation(self, observation: Any) -> Any:
        return self.transform.observation(observation)

"""Pixel observations: an environment's rendered frames as what a policy sees, and frame stacks.

- `PixelRecipe(size=(H, W), grayscale, crop)` says how a frame is made: `env.render()` (the env is
  made with render_mode="rgb_array"), cropped to the rectangle (top, left, height, width) if one is
  given (a camera's region of interest), resized to H×W by area averaging (cv2.INTER_AREA, which keeps
  thin lines such as CartPole's pole visible), and, if asked, converted to luma
  Y = 0.299 R + 0.587 G + 0.114 B. Frames are uint8 (H, W, C), C = 1 or 3.
- `PixelObservation`: observations {"pixels": frame, "state": the env's own observation}. The
  state rides along for experts that act on it (DAgger's scripted expert) and for evaluation;
  pixel policies read "pixels" alone (`PolicyConfig.observation_keys`). An env whose observation
  already is an image gives {"pixels": that image, resized}.
- `StackFrames(env, k)`: every image leaf becomes its last k frames, (k, H, W, C) oldest first,
  with the reset frame repeated before the first step (gymnasium's FrameStackObservation with
  padding "reset"); other leaves pass through unchanged. `stack_frames` builds the same stacks
  from stored episodes, so that a policy learns offline from exactly what it will see acting.
"""

from __future__ import annotations

import os
import re
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, SupportsFloat

import cv2
import gymnasium as gym
import numpy as np

from imitation.errors import ImitationError

PIXELS_KEY = "pixels"
STATE_KEY = "state"
_SIZE = re.compile(r"^([1-9][0-9]{0,3})x([1-9][0-9]{0,3})$")


def parse_crop(text: str) -> tuple[int, int, int, int]:
    """(top, left, height, width) from "T,L,H,W" as given to `--crop`."""
    parts = text.split(",")
    if len(parts) != 4 or not all(part.strip().isdigit() for part in parts):
        raise ImitationError(f"--crop {text!r}: give the rectangle as TOP,LEFT,HEIGHT,WIDTH in pixels, e.g. 120,150,200,300")
    top, left, height, width = (int(part) for part in parts)
    if height < 1 or width < 1:
        raise ImitationError(f"--crop {text!r}: the rectangle's height and width must be at least 1")
    return top, left, height, width


def is_image_space(space: gym.Space) -> bool:
    """A uint8 Box of shape (H, W) or (H, W, C) with C in {1, 3, 4}: a frame (channels last)."""
    if not isinstance(space, gym.spaces.Box) or space.dtype != np.uint8:
        return False
    shape = space.shape
    return len(shape) == 2 or (len(shape) == 3 and shape[-1] in (1, 3, 4))


def image_keys(space: gym.Space) -> list[str]:
    """The top-level keys of a Dict space that hold images (`[""]` for a bare image space)."""
    if isinstance(space, gym.spaces.Dict):
        return [key for key, sub in space.spaces.items() if is_image_space(sub)]
    return [""] if is_image_space(space) else []


@dataclass(frozen=True)
class PixelRecipe:
    """How frames are rendered for a pixel observation (see the module docstring)."""

    height: int
    width: int
    grayscale: bool = False
    crop: tuple[int, int, int, int] | None = None  # top, left, height, width of the rendered image

    @staticmethod
    def parse(size: str, *, grayscale: bool = False, crop: str | None = None) -> PixelRecipe:
        """From "HxW" as given to `--pixels` (e.g. "84x84") and "T,L,H,W" as given to `--crop`."""
        match = _SIZE.match(size.strip())
        if not match:
            raise ImitationError(f"--pixels {size!r}: give the frame size as HEIGHTxWIDTH, e.g. 84x84")
        box = parse_crop(crop) if crop is not None else None
        return PixelRecipe(int(match[1]), int(match[2]), grayscale, box)

    def to_json(self) -> dict[str, Any]:
        crop = {"crop": list(self.crop)} if self.crop is not None else {}
        return {"size": [self.height, self.width], "grayscale": self.grayscale, **crop}

    @staticmethod
    def from_json(data: Any) -> PixelRecipe:
        """From `to_json`'s output as read from a file; ValueError for anything else."""
        size = data.get("size") if isinstance(data, dict) else None
        crop = data.get("crop") if isinstance(data, dict) else None
        if not (
            _integers(size, 2, 1)
            and isinstance(data.get("grayscale", False), bool)
            and (crop is None or (_integers(crop, 4, 0) and min(crop[2:]) >= 1))
        ):
            raise ValueError(
                "a pixel recipe is {'size': [H, W], 'grayscale': bool, 'crop': [top, left, height, width]} with sizes in "
                f"[1, 4096], got {str(data)[:80]}"
            )
        assert isinstance(size, list)  # checked above
        box = (crop[0], crop[1], crop[2], crop[3]) if crop is not None else None
        return PixelRecipe(size[0], size[1], data.get("grayscale", False), box)

    @property
    def channels(self) -> int:
        return 1 if self.grayscale else 3

    def frame(self, image: np.ndarray) -> np.ndarray:
        """An RGB (or mono) uint8 image → this recipe's (H, W, C) frame."""
        image = np.asarray(image, dtype=np.uint8)
        if self.crop is not None:
            top, left, height, width = self.crop
            if top + height > image.shape[0] or left + width > image.shape[1]:
                raise ImitationError(
                    f"crop {list(self.crop)} (top, left, height, width) reaches outside the {image.shape[0]}×{image.shape[1]} "
                    "rendered image"
                )
            image = image[top : top + height, left : left + width]
        if image.ndim == 2:
            image = image[:, :, None]
        if image.shape[:2] != (self.height, self.width):
            image = cv2.resize(image, (self.width, self.height), interpolation=cv2.INTER_AREA)
            if image.ndim == 2:
                image = image[:, :, None]
        if self.grayscale and image.shape[2] >= 3:
            image = cv2.cvtColor(np.ascontiguousarray(image[:, :, :3]), cv2.COLOR_RGB2GRAY)[:, :, None]
        elif not self.grayscale and image.shape[2] == 1:
            image = np.repeat(image, 3, axis=2)
        elif image.shape[2] == 4:
            image = image[:, :, :3]
        return np.ascontiguousarray(image)

    def space(self) -> gym.spaces.Box:
        return gym.spaces.Box(0, 255, (self.height, self.width, self.channels), dtype=np.uint8)


def _integers(values: Any, count: int, low: int) -> bool:
    return (
        isinstance(values, list)
        and len(values) == count
        and all(isinstance(n, int) and not isinstance(n, bool) and low <= n <= 4096 for n in values)
    )


def recorded_pixels(
    metadata: Mapping[str, Any], source: str, *, frame_stack: int | None = None
) -> tuple[PixelRecipe | None, int]:
    """How a demo file's frames were rendered, from its user `metadata` (`record --pixels` writes
    the recipe and its `frame_stack` under "pixels"; None for other demos), and the frames per
    stack: `frame_stack` when the caller sets it (the recorded number is then not read, so a
    damaged one can be overridden), else as recorded (1 when none). One-line errors name `source`."""
    recorded = metadata.get(PIXELS_KEY)
    if recorded is None:
        return None, frame_stack or 1
    try:
        recipe = PixelRecipe.from_json(recorded)
    except ValueError as error:
        raise ImitationError(f"{source}: user metadata 'pixels': {error}") from None
    if frame_stack is not None:
        return recipe, frame_stack
    stack = recorded.get("frame_stack", 1)
    if isinstance(stack, bool) or not isinstance(stack, int) or not 1 <= stack <= 64:
        raise ImitationError(f"{source}: user metadata 'pixels': frame_stack must be in [1, 64], got {stack!r:.40}")
    return recipe, stack


def make_pixel_env(env_id: str, recipe: PixelRecipe, **kwargs: Any) -> gym.Env:
    """`env_id` made to render frames, observed through `PixelObservation`."""
    from imitation.envs.make import make_env

    env = make_env(env_id, render_mode="rgb_array", **kwargs)
    return PixelObservation(env, recipe)


class PixelObservation(gym.ObservationWrapper):
    """Observations {"pixels": frame, "state": the env's observation}, or {"pixels": frame} for an
    env whose observation is the image itself."""

    def __init__(self, env: gym.Env, recipe: PixelRecipe) -> None:
        super().__init__(env)
        # pygame's renderers need no display for rgb_array frames; without these it complains on stderr.
        os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
        os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
        warnings.filterwarnings("ignore", message="pkg_resources is deprecated")  # raised by importing pygame; harmless
        self.recipe = recipe
        self._from_observation = is_image_space(env.observation_space)
        if not self._from_observation and env.render_mode != "rgb_array":
            raise ImitationError(
                f"environment {env.spec.id if env.spec else env}: pixel observations need render_mode='rgb_array', "
                f"it has {env.render_mode!r}"
            )
        spaces: dict[str, gym.Space] = {PIXELS_KEY: recipe.space()}
        if not self._from_observation:
            spaces[STATE_KEY] = env.observation_space
        self.observation_space = gym.spaces.Dict(spaces)

    def observation(self, observation: Any) -> dict[str, Any]:
        if self._from_observation:
            return {PIXELS_KEY: self.recipe.frame(observation)}
        rendered = self.env.render()
        if not isinstance(rendered, np.ndarray):
            raise ImitationError(f"environment {self.env.spec.id if self.env.spec else self.env}: render() gave no frame")
        return {PIXELS_KEY: self.recipe.frame(rendered), STATE_KEY: observation}


def expert_on_state(expert: Callable[[Any], Any], env: PixelObservation) -> Callable[[Any], Any]:
    """An expert of the env's own observations (a scripted controller), acting on `env`'s pixel
    observations through their "state" leaf."""
    assert isinstance(env.observation_space, gym.spaces.Dict)
    if STATE_KEY not in env.observation_space.spaces:
        return expert  # the env's observation is the image itself: the expert acts on frames
    return lambda observation: expert(observation[STATE_KEY])


def stacked_space(space: gym.Space, frames: int) -> gym.Space:
    """`space` with every image leaf (top-level) replaced by a stack of `frames` of it."""

    def stacked(sub: gym.Space) -> gym.Space:
        assert isinstance(sub, gym.spaces.Box)
        return gym.spaces.Box(0, 255, (frames, *sub.shape), dtype=np.uint8)

    if isinstance(space, gym.spaces.Dict):
        return gym.spaces.Dict({key: stacked(sub) if is_image_space(sub) else sub for key, sub in space.spaces.items()})
    return stacked(space) if is_image_space(space) else space


class StackFrames(gym.Wrapper):
    """Each image leaf observed as its last k frames (see the module docstring)."""

    def __init__(self, env: gym.Env, frames: int) -> None:
        super().__init__(env)
        self.frames = frames
        self.keys = image_keys(env.observation_space)
        if not self.keys:
            raise ImitationError(f"frame stacking needs image observations, and {env.observation_space} holds none")
        self.observation_space = stacked_space(env.observation_space, frames)
        self._history: dict[str, list[np.ndarray]] = {}

    def _stacked(self, observation: Any) -> Any:
        if not isinstance(observation, dict):
            return np.stack(self._history[""])
        return {key: np.stack(self._history[key]) if key in self._history else value for key, value in observation.items()}

    def _images(self, observation: Any) -> dict[str, np.ndarray]:
        return {key: np.asarray(observation[key] if key else observation) for key in self.keys}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        observation, info = self.env.reset(seed=seed, options=options)
        self._history = {key: [image] * self.frames for key, image in self._images(observation).items()}
        return self._stacked(observation), info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        for key, image in self._images(observation).items():
            self._history[key] = [*self._history[key][1:], image]
        return self._stacked(observation), reward, terminated, truncated, info


def frame_stack_index(episode_index: np.ndarray, frames: int) -> np.ndarray:
    """(rows, frames) row numbers of each row's stack, oldest first, within its own episode
    (rows in episode and time order); before an episode's first row, its first row again."""
    rows = np.arange(len(episode_index))
    starts = np.ones(len(episode_index), dtype=bool)
    starts[1:] = episode_index[1:] != episode_index[:-1]
    first = np.maximum.accumulate(np.where(starts, rows, 0))
    offsets = np.arange(frames - 1, -1, -1)
    return np.maximum(rows[:, None] - offsets[None, :], first[:, None])


def stack_frames(observations: Any, episode_index: np.ndarray, frames: int, keys: list[str]) -> Any:
    """Stored observations (rows in episode and time order) → what `StackFrames` shows a policy:
    the image leaves `keys` (`image_keys` of the space) stacked, the others unchanged."""
    index = frame_stack_index(episode_index, frames)
    if not isinstance(observations, dict):
        return observations[index]
    return {key: value[index] if key in keys else value for key, value in observations.items()}

"""LeRobot camera features (dtype "video" or "image") as image leaves of the observation.

A camera becomes a uint8 Box(0, 255) of shape (H, W, C), channels last, whatever order info.json
declares its shape in (lerobot writes (H, W, C) with names height/width/channel; older datasets
(C, H, W) with names channels/height/width). Video features are decoded from their mp4 files
(`imitation.data.convert.video`); image features hold one PNG (or JPEG) per frame in the
parquet, decoded with Pillow. A camera given a `size` stores its frames resized to it, each
resized once as it is decoded (`imitation.data.image_resize`). An image feature's frames that
are not resized keep their pictures (`KeptFrames`) where Pillow opens them in the mode the leaf
holds (RGB, L, RGBA), so a demo file of their codec stores the parquet's bytes.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.data.image_resize import resized
from imitation.data.jpeg_scans import excess_scans
from imitation.data.kept_frames import KeptFrames
from imitation.errors import ImitationError
from imitation.limits import LIMITS, over_limit

_MODES = {1: "L", 3: "RGB", 4: "RGBA"}  # Pillow's mode for each channel count
_PICTURES = {"PNG": "png", "JPEG": "jpeg"}  # formats a demo file's image channel stores as they are


@dataclass(frozen=True)
class Camera:
    """One camera feature: its LeRobot name, "video" or "image", its frames' (H, W, C), and the
    (height, width) they are stored at when not their own."""

    key: str
    dtype: str
    shape: tuple[int, int, int]
    size: tuple[int, int] | None = None

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """A stored frame's (H, W, C)."""
        return (*self.size, self.shape[2]) if self.size is not None else self.shape

    @property
    def space(self) -> gym.spaces.Box:
        return gym.spaces.Box(0, 255, shape=self.frame_shape, dtype=np.uint8)


def camera_for(info_path: Path, key: str, feature: dict[str, Any]) -> Camera | str:
    """The camera info.json describes, or why it is skipped (a warning). A frame larger than the
    limit `sample_elements` is refused: each frame is allocated whole."""
    dtype, shape, names = feature.get("dtype"), feature.get("shape"), feature.get("names")
    if not (isinstance(shape, list | tuple) and len(shape) == 3 and all(_size(n) for n in shape)):
        return f"{info_path}: {dtype} feature {key!r} skipped (its shape {str(shape)[:40]} is not that of a frame)"
    channels_first = isinstance(names, list | tuple) and len(names) == 3 and str(names[0]).startswith("channel")
    height, width, channels = (shape[1], shape[2], shape[0]) if channels_first else tuple(shape)
    if math.prod(shape) > LIMITS.sample_elements:
        raise over_limit(f"{info_path}: {dtype} feature {key!r}: numbers per frame", math.prod(shape), "sample_elements")
    video_info = feature.get("info") or feature.get("video_info") or {}
    if dtype == "video" and isinstance(video_info, dict) and video_info.get("video.is_depth_map"):
        return f"{info_path}: video feature {key!r} skipped (depth-map videos are not supported)"
    if channels not in _MODES or (dtype == "video" and channels != 3):
        return f"{info_path}: {dtype} feature {key!r} skipped ({channels} channels; cameras of 1, 3 or 4 are, videos of 3)"
    return Camera(key, str(dtype), (height, width, channels))


def _size(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value > 0


def decoded_images(blobs: list[Any], camera: Camera, what: str) -> np.ndarray:
    """The frames of an image feature: `blobs` holds each frame's encoded bytes (None where the
    parquet row has none). `what` names the dataset and episode in errors."""
    from PIL import Image, UnidentifiedImageError

    out = np.empty((len(blobs), *camera.frame_shape), dtype=np.uint8)
    pictures: list[tuple[str, bytes] | None] = []
    for row, blob in enumerate(blobs):
        try:
            if not isinstance(blob, bytes):
                raise ValueError("the row holds no image bytes")
            with Image.open(io.BytesIO(blob)) as image:
                # Image.open reads the header alone: a frame of another size is refused before it is decompressed.
                if image.size != (camera.shape[1], camera.shape[0]):
                    raise ValueError(f"the image is {image.size[0]}x{image.size[1]}")
                if image.format in ("JPEG", "MPO") and (problem := excess_scans(blob)) is not None:
                    raise ImitationError(f"{what}: image feature {camera.key!r}, frame {row}: {problem}")
                codec = _PICTURES.get(str(image.format)) if image.mode == _MODES[camera.shape[2]] else None
                pixels = np.asarray(image.convert(_MODES[camera.shape[2]]))
            pixels = pixels.reshape(pixels.shape[:2] + (-1,))
            out[row] = resized(pixels, camera.size) if camera.size is not None else pixels
            pictures.append((codec, blob) if codec is not None else None)
        except (OSError, ValueError, UnidentifiedImageError, Image.DecompressionBombError) as error:
            raise ImitationError(
                f"{what}: image feature {camera.key!r}, frame {row}: cannot decode it as a "
                f"{camera.shape[1]}x{camera.shape[0]} image with {camera.shape[2]} channels "
                f"({type(error).__name__}: {str(error)[:120]})"
            ) from None
    codecs = {picture[0] for picture in pictures if picture is not None}
    if camera.size is not None or len(codecs) != 1:
        return out
    codec = codecs.pop()
    return KeptFrames.of(out, codec, [picture[1] if picture and picture[0] == codec else None for picture in pictures])

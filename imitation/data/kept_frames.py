"""Decoded camera frames that keep the compressed pictures they were decoded from.

A converter that decodes a source's JPEG or PNG frames (a ROS CompressedImage, a LeRobot image
feature) hands on `KeptFrames`: the pixels, for everything that reads an observation, and each
row's picture, which a demo file whose image codec is that picture's stores as it is (the
source's bytes exactly: no second lossy generation, no time spent encoding).

A picture is kept only with the pixels it decodes to (the converter checks that the reader
decodes it the same way: same codec, Pillow mode and size). That holds while the pixels are not
changed, so the array is read-only, and every array made from it (a copy, a cast, a reshape, an
index other than a slice of whole rows) is a `KeptFrames` without pictures: its frames are
encoded like any others.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


class KeptFrames(np.ndarray):
    """Frames (N, H, W[, C]) with `pictures[i]` the encoded picture of row i (None where the row
    has none) in `codec` ("jpeg" or "png"); both None once the array is derived from."""

    codec: str | None
    pictures: tuple[bytes | None, ...] | None

    @staticmethod
    def of(pixels: np.ndarray, codec: str, pictures: Sequence[bytes | None]) -> KeptFrames:
        if len(pictures) != len(pixels):
            raise ValueError(f"{len(pictures)} pictures for {len(pixels)} frames")
        frames = pixels.view(KeptFrames)
        frames.flags.writeable = False
        frames.codec, frames.pictures = codec, tuple(pictures)
        return frames

    def __array_finalize__(self, obj: Any) -> None:
        self.codec, self.pictures = None, None

    def __getitem__(self, key: Any) -> Any:
        out = super().__getitem__(key)
        if isinstance(key, slice) and isinstance(out, KeptFrames) and self.pictures is not None:
            out.codec, out.pictures = self.codec, self.pictures[key]
        return out

    def picture(self, row: int, codec: str) -> bytes | None:
        """Row `row`'s picture if it is one of `codec`, else None."""
        if self.pictures is None or self.codec != codec:
            return None
        return self.pictures[row]

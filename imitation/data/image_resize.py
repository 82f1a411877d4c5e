"""Camera frames resized to a target height and width, and the `HxW` text that names one.

One filter for every place that resizes stored frames: OpenCV's area averaging
(`cv2.INTER_AREA`, the filter `record --pixels` renders with). Shrinking, each output pixel is
the mean of the source pixels it covers, so fine texture averages out instead of aliasing;
enlarging, OpenCV interpolates bilinearly. The aspect ratio is not kept: a frame becomes exactly
H×W (crop first to keep it). A frame keeps its dtype (uint8 or uint16) and channel count.
"""

from __future__ import annotations

import re

import numpy as np

from imitation.errors import ImitationError

RESIZE_FILTER = "area (cv2.INTER_AREA)"
MAX_SIDE = 2**16  # pixels: a larger side is a typo


def parse_image_size(text: str, what: str) -> tuple[int, int]:
    """(height, width) from `HxW` text such as "96x96"; ImitationError naming `what` (the flag) otherwise."""
    match = re.fullmatch(r"\s*(\d{1,6})\s*[xX×]\s*(\d{1,6})\s*", text)
    if match is None or not all(0 < int(side) <= MAX_SIDE for side in match.groups()):
        raise ImitationError(f"{what} {text[:40]}: give HEIGHTxWIDTH in pixels, each 1 to {MAX_SIDE}, e.g. 96x96")
    return int(match[1]), int(match[2])


def resized(frame: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """`frame` ((H, W) or (H, W, C), C from 1 to 4) as `size` (height, width), same dtype and channels."""
    import cv2

    if frame.shape[:2] == size:
        return frame
    out = cv2.resize(np.ascontiguousarray(frame), (size[1], size[0]), interpolation=cv2.INTER_AREA)
    return out.reshape(size + frame.shape[2:])  # OpenCV drops a single channel's axis

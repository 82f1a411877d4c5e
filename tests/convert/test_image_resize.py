"""The one resize every conversion (and a learner's target size) applies to stored frames."""

from __future__ import annotations

import numpy as np
import pytest

from imitation.data.image_resize import parse_image_size, resized
from imitation.errors import ImitationError


def test_shrinking_by_a_whole_factor_averages_each_block() -> None:
    rng = np.random.default_rng(0)
    for frame in (rng.integers(0, 256, (8, 12, 3), dtype=np.uint8), rng.integers(0, 60000, (8, 12), dtype=np.uint16),
                  rng.integers(0, 256, (8, 12, 1), dtype=np.uint8), rng.integers(0, 256, (8, 12, 4), dtype=np.uint8)):
        small = resized(frame, (4, 3))
        assert small.dtype == frame.dtype and small.shape == (4, 3, *frame.shape[2:])
        blocks = frame.reshape(4, 2, 3, 4, -1).astype(np.float64).mean(axis=(1, 3)).reshape(small.shape)
        assert np.abs(small.astype(np.float64) - blocks).max() <= 0.5  # the block's mean, rounded
    frame = rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)
    assert resized(frame, (5, 7)) is frame and resized(frame, (10, 14)).shape == (10, 14, 3)


def test_sizes_are_height_by_width() -> None:
    assert parse_image_size("96x128", "--image-size") == (96, 128)
    for text in ("96", "0x5", "96x", "96x70000", "axb"):
        with pytest.raises(ImitationError, match=rf"^--image-size {text}: give HEIGHTxWIDTH in pixels, each 1 to 65536, e\.g\. 96x96$"):
            parse_image_size(text, "--image-size")

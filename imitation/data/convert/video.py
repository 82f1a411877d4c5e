"""Video frames at given timestamps, decoded with PyAV, as uint8 (N, H, W, 3) RGB arrays.

Frames are chosen as lerobot's own PyAV decoder (`lerobot.datasets.video_utils.
decode_video_frames_pyav`) chooses them: seek to the keyframe at or before the first timestamp,
decode forward until the last one is passed, and give each timestamp the decoded frame nearest
to it, provided it lies within `tolerance_s`; pixels are PyAV's `rgb24` conversion, as there.
Unlike lerobot's decoder, only the frames some timestamp wants are converted and kept, so a
window of a long shared video costs memory for its wanted frames alone; given a `size`, each is
resized to it as it is converted (`imitation.data.image_resize`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from imitation.data.image_resize import resized
from imitation.errors import ImitationError
from imitation.limits import ImageBudget


def frames_at(
    path: Path,
    timestamps: np.ndarray,
    *,
    tolerance_s: float,
    shape: tuple[int, int, int],
    what: str,
    budget: ImageBudget,
    hint: str = "",
    size: tuple[int, int] | None = None,
) -> np.ndarray:
    """The frames of the video at `path` nearest to each of `timestamps` (seconds), of `shape`
    (H, W, 3). `what` names the frames in errors (the feature and episode); every failure is one
    ImitationError naming the file: a video PyAV cannot read or whose frames have another size
    ("cannot decode"), or a timestamp no frame is near ("no video frame within", followed by
    `hint`). `size` (height, width) resizes the frames returned. Every frame
    decoded, wanted or passed over on the way, is counted in `budget` (image_expansion_ratio) as
    it comes: a small video of thousands of frames that barely change stops at the bound."""
    import av

    wanted = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    out = np.empty((len(wanted), *(size or shape[:2]), shape[2]), dtype=np.uint8)
    if not len(wanted):
        return out
    order = np.argsort(wanted, kind="stable")
    ordered = wanted[order]
    best = np.full(len(wanted), np.inf)  # distance to the nearest frame decoded so far, per timestamp
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise ValueError("the file holds no video stream")
            stream = container.streams.video[0]
            base = stream.time_base
            if base is None:
                raise ValueError("the video stream has no time base to place its frames by")
            if stream.codec_context is None:
                raise ValueError("the video stream names no codec PyAV can decode")
            stream.thread_type = "AUTO"  # frame threads: same pixels, faster where the codec has no threads of its own
            decoded = (stream.codec_context.height, stream.codec_context.width)
            if decoded != shape[:2]:
                raise ValueError(f"frames are {decoded[1]}x{decoded[0]}, the dataset declares {shape[1]}x{shape[0]}")
            # As lerobot: the nearest keyframe at or before the first timestamp, with one tick of margin.
            container.seek(round(ordered[0] / base) - 1, backward=True, any_frame=False, stream=stream)
            for frame in container.decode(stream):
                budget.take(shape[0] * shape[1] * shape[2])
                if frame.pts is None:
                    continue
                at = float(frame.pts * base)
                near = slice(
                    np.searchsorted(ordered, at - tolerance_s, "right"), np.searchsorted(ordered, at + tolerance_s, "left")
                )
                closer = np.abs(ordered[near] - at) < best[near]
                if closer.any():
                    pixels = frame.to_ndarray(format="rgb24")
                    pixels = resized(pixels, size) if size is not None else pixels
                    rows = order[near][closer]
                    out[rows] = pixels
                    best[near.start : near.stop][closer] = np.abs(ordered[near][closer] - at)
                if at >= ordered[-1]:
                    break
    except (av.error.FFmpegError, OSError, ValueError) as error:
        raise ImitationError(f"{path}: {what}: cannot decode the video ({type(error).__name__}: {str(error)[:200]})") from None
    missing = np.flatnonzero(np.isinf(best))
    if len(missing):
        raise ImitationError(
            f"{path}: {what}: no video frame within {tolerance_s} s of frame {missing[0]} (at {wanted[missing[0]]:.6f} s)"
            + (f" and {len(missing) - 1} more" if len(missing) > 1 else "")
            + hint
        )
    return out

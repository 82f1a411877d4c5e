"""Image observations as Foxglove image messages (docs/FORMAT.md §6.6).

An *image leaf* is an observation leaf of dtype uint8 and shape (H, W) or (H, W, C) with C in
{1, 3, 4}. Its channel carries one protobuf message per frame (row) instead of blocks, so that
Foxglove and other MCAP tools show it as a video:

- codec `png` (lossless), `jpeg` and `webp` (lossy; WebP's is VP8's intra coding, about a third
  of JPEG's bytes at the same PSNR on camera frames): `foxglove.CompressedImage` {timestamp,
  data, format "png" | "jpeg" | "webp"};
- codec `raw` (lossless; the chunk compression does the work): `foxglove.RawImage` {timestamp,
  width, height, encoding "mono8" | "rgb8" | "rgba8", step = W × C, data: the rows, C order}.

The schema record holds a serialized FileDescriptorSet of the message (and of
google/protobuf/timestamp.proto, which it imports). Pillow encodes and decodes the pictures;
decoding checks every frame's header against the channel's declared shape, and a JPEG's count of
scans against the limit `jpeg_scans` (a WebP's count of frames against 1), before any pixel is
decoded, so a hostile frame costs no more memory or time than an honest one. Frames that come
as `KeptFrames` with pictures of the channel's codec are stored as those pictures, unencoded.
"""

from __future__ import annotations

import functools
import io
import math
import os
import warnings
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Protocol

import numpy as np

from imitation.data.jpeg_scans import excess_scans
from imitation.data.kept_frames import KeptFrames

IMAGE_ENCODING = "protobuf"
CODECS = ("png", "jpeg", "raw", "webp")
DEFAULT_JPEG_QUALITY = 95
# WebP at 85: a demo file of 1.7 times the bytes of lerobot's AV1 videos of 224x224 cameras, at
# 45.5 dB PSNR to their decoded frames; JPEG at 95 takes 5.5 times (bench/RESULTS.md, issue 51).
DEFAULT_WEBP_QUALITY = 85
_SCHEMA_NAMES = {
    "png": "foxglove.CompressedImage",
    "jpeg": "foxglove.CompressedImage",
    "webp": "foxglove.CompressedImage",
    "raw": "foxglove.RawImage",
}
_PIL_FORMATS = {"png": "PNG", "jpeg": "JPEG", "webp": "WEBP"}
_PIL_MODES = {1: "L", 3: "RGB", 4: "RGBA"}
_RAW_ENCODINGS = {1: "mono8", 3: "rgb8", 4: "rgba8"}
_JPEG_FORMATS = ("JPEG", "MPO")  # Pillow opens a JPEG with a multi-picture segment as MPO
# Pillow's zlib level 3 encodes a rendered frame as fast as level 1 and a little smaller; level 6
# halves the size again at 1.7× the time.
_PNG_LEVEL = 3
# Pillow releases the GIL while it encodes and decodes, so an episode's frames go through threads.
_THREADS = min(os.cpu_count() or 1, 8)


class FrameError(ValueError):
    """One frame that does not decode to its channel's declared image; the message names the
    topic, episode and step, and the reader prefixes the file."""


class FrameLimitError(FrameError):
    """A frame refused by a resource limit (`jpeg_scans`): not damage, so a salvage scan stops
    on it rather than keeping the episodes before it."""


def is_image_leaf(dtype: np.dtype | None, shape: tuple[int, ...]) -> bool:
    """Whether a leaf is stored as images: uint8, (H, W) or (H, W, C) with C in {1, 3, 4}, H, W ≥ 1."""
    if dtype is None or dtype != np.uint8 or len(shape) not in (2, 3) or min(shape[:2]) < 1:
        return False
    return len(shape) == 2 or shape[2] in _PIL_MODES


def channels_of(shape: tuple[int, ...]) -> int:
    return 1 if len(shape) == 2 else shape[2]


def schema_name(codec: str) -> str:
    return _SCHEMA_NAMES[codec]


@functools.cache
def schema_data(codec: str) -> bytes:
    """The schema record's data: a FileDescriptorSet of the codec's message, imports first."""
    from google.protobuf import descriptor_pb2

    descriptors = descriptor_pb2.FileDescriptorSet()
    added: set[str] = set()

    def add(file: Any) -> None:
        if file.name in added:
            return
        for dependency in file.dependencies:
            add(dependency)
        added.add(file.name)
        file.CopyToProto(descriptors.file.add())

    add(_message_class(codec).DESCRIPTOR.file)
    return descriptors.SerializeToString()


def _message_class(codec: str) -> Any:
    if codec == "raw":
        from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

        return RawImage
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

    return CompressedImage


def encode_frames(
    codec: str, frames: np.ndarray, times: np.ndarray, *, jpeg_quality: int, webp_quality: int = DEFAULT_WEBP_QUALITY
) -> list[bytes]:
    """The messages of `frames` (uint8, (N, H, W[, C])), frame i stamped `times[i]` ns; a row of
    `KeptFrames` with a picture of `codec` is stored as that picture."""
    kept = frames if isinstance(frames, KeptFrames) else None

    def message(i: int) -> bytes:
        picture = kept.picture(i, codec) if kept is not None else None
        if picture is not None:
            return _message_class(codec)(timestamp=_timestamp(int(times[i])), format=codec, data=picture).SerializeToString()
        return encode_frame(codec, frames[i], int(times[i]), jpeg_quality=jpeg_quality, webp_quality=webp_quality)

    return _map(message, len(frames))


def _timestamp(time_ns: int) -> Any:
    from google.protobuf.timestamp_pb2 import Timestamp

    return Timestamp(seconds=time_ns // 10**9, nanos=time_ns % 10**9)


def encode_frame(
    codec: str, frame: np.ndarray, time_ns: int, *, jpeg_quality: int, webp_quality: int = DEFAULT_WEBP_QUALITY
) -> bytes:
    timestamp = _timestamp(time_ns)
    height, width = frame.shape[:2]
    pixels = np.ascontiguousarray(frame.reshape(height, width, -1))
    channels = pixels.shape[2]
    if codec == "raw":
        return _message_class(codec)(
            timestamp=timestamp,
            width=width,
            height=height,
            encoding=_RAW_ENCODINGS[channels],
            step=width * channels,
            data=pixels.tobytes(),
        ).SerializeToString()
    from PIL import Image

    picture = Image.fromarray(pixels[:, :, 0] if channels == 1 else pixels)
    out = io.BytesIO()
    if codec == "png":
        picture.save(out, format="PNG", compress_level=_PNG_LEVEL)
    elif codec == "webp":
        picture.save(out, format="WEBP", quality=webp_quality)
    else:
        picture.save(out, format="JPEG", quality=jpeg_quality)
    return _message_class(codec)(timestamp=timestamp, format=codec, data=out.getvalue()).SerializeToString()


class FrameMap(Protocol):
    """What is done to each frame as it is decoded (`imitation.data.frame_transform.FrameTransform`:
    a crop and a resize), and the shape it makes of a frame's."""

    def shape(self, shape: tuple[int, ...]) -> tuple[int, ...]: ...

    def __call__(self, frame: np.ndarray) -> np.ndarray: ...


def decode_frames(
    codec: str,
    shape: tuple[int, ...],
    frames: Sequence[bytes | memoryview],
    *,
    topic: str,
    episode: int,
    transform: FrameMap | None = None,
) -> np.ndarray:
    """The frames of one episode's channel as a uint8 array (len(frames), *shape); frame i is step i.
    With `transform`, each frame as it makes it, one at a time (the episode is never held at `shape`).

    Raises FrameError for a frame that does not parse, decode, or match `shape`."""
    out = np.empty((len(frames), *(transform.shape(shape) if transform is not None else shape)), dtype=np.uint8)

    def decode(step: int) -> None:
        try:
            frame = decode_frame(codec, shape, frames[step])
            out[step] = transform(frame) if transform is not None else frame
        except FrameError as error:
            raise type(error)(f"{topic}, episode {episode}, step {step}: {error}") from None

    _map(decode, len(frames))
    return out


def decode_frame(codec: str, shape: tuple[int, ...], message: bytes | memoryview) -> np.ndarray:
    """One frame message as a uint8 array of `shape`; FrameError if it is anything else.

    A raw frame's array is a view of `message`'s pixels: copy it to keep it past that buffer."""
    from google.protobuf.message import DecodeError

    if codec not in CODECS:
        raise FrameError(f"unknown image codec {codec[:40]!r} (this reader knows {', '.join(CODECS)})")
    parsed = _message_class(codec)()
    # The pixels are parsed out of the message by hand, as a view (no copy of a raw frame's
    # megabyte, twice); the rest of the message goes through protobuf, so every other field
    # is read, and refused, exactly as before. A message this cannot split takes protobuf whole.
    split = _split_data(message, _DATA_FIELD[codec])
    try:
        if split is None:
            parsed.ParseFromString(bytes(message))
            data: bytes | memoryview = parsed.data
        else:
            rest, data = split
            parsed.ParseFromString(rest)
    except DecodeError as error:
        raise FrameError(f"not a {schema_name(codec)} message ({_one_line(error)})") from None
    height, width, channels = shape[0], shape[1], channels_of(shape)
    if codec == "raw":
        return _raw_pixels(parsed, data, height, width, channels).reshape(shape)
    if parsed.format != codec:
        raise FrameError(f"format {parsed.format[:40]!r}, but the channel's codec is {codec!r}")
    return _compressed_pixels(codec, data, height, width, channels).reshape(shape)


# The `bytes data` field of each codec's message (RawImage: 6, CompressedImage: 2).
_DATA_FIELD = {"raw": 6, "png": 2, "jpeg": 2, "webp": 2}


def _split_data(message: bytes | memoryview, number: int) -> tuple[bytes, memoryview] | None:
    """(the message without field `number`, that field's bytes as a view of `message`) when the
    field occurs exactly once, length-delimited, in a message of well-formed top-level fields
    (wire types 0, 1, 2 and 5); None for anything else (groups, a truncated or repeated field,
    an over-long varint), which the caller hands to protobuf whole. Removing one
    length-delimited field leaves every other field's bytes, and so protobuf's reading of them,
    as they were."""
    view = memoryview(message).cast("B")
    end = len(view)
    position = 0
    found: tuple[int, int, int] | None = None  # (field start, data start, data end)
    while position < end:
        start = position
        key, position = _varint(view, position)
        if key < 0:
            return None
        wire = key & 7
        if wire == 0:
            _, position = _varint(view, position)
            if position < 0:
                return None
        elif wire == 1:
            position += 8
        elif wire == 5:
            position += 4
        elif wire == 2:
            length, position = _varint(view, position)
            if length < 0:
                return None
            if key >> 3 == number:
                if found is not None:
                    return None
                found = (start, position, position + length)
            position += length
        else:
            return None
        if position > end or (key >> 3 == number and wire != 2):
            return None
    if found is None:
        return None
    start, data_start, data_end = found
    return bytes(view[:start]) + bytes(view[data_end:]), view[data_start:data_end]


def _varint(view: memoryview, position: int) -> tuple[int, int]:
    """The varint at `position` and the position after it; (-1, -1) when it runs past the end or 10 bytes."""
    value = shift = 0
    for i in range(position, min(position + 10, len(view))):
        byte = view[i]
        value |= (byte & 0x7F) << shift
        if byte < 0x80:
            return value, i + 1
        shift += 7
    return -1, -1


def _raw_pixels(parsed: Any, data: bytes | memoryview, height: int, width: int, channels: int) -> np.ndarray:
    expected = (width, height, _RAW_ENCODINGS[channels], width * channels)
    found = (parsed.width, parsed.height, parsed.encoding[:40], parsed.step)
    if found != expected:
        raise FrameError(
            f"a {found[0]}x{found[1]} {found[2]} image (step {found[3]}), but the channel declares {width}x{height} "
            f"{expected[2]}"
        )
    if len(data) != height * width * channels:
        raise FrameError(
            f"{len(data)} bytes of pixels, but a {width}x{height} {expected[2]} image has {height * width * channels}"
        )
    return np.frombuffer(data, dtype=np.uint8)


def _compressed_pixels(codec: str, data: bytes | memoryview, height: int, width: int, channels: int) -> np.ndarray:
    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            picture = Image.open(io.BytesIO(data), formats=[_PIL_FORMATS[codec]])
    except Exception as error:  # a hostile header can make Pillow raise nearly anything
        raise FrameError(f"does not decode as {codec} ({_one_line(error)})") from None
    # The header is checked before a single pixel is decoded: a frame claiming 10^5 × 10^5 pixels allocates nothing.
    if picture.size != (width, height) or picture.mode != _PIL_MODES[channels]:
        raise FrameError(
            f"a {picture.size[0]}x{picture.size[1]} {picture.mode} picture, but the channel declares {width}x{height} "
            f"{_PIL_MODES[channels]}"
        )
    if picture.format in _JPEG_FORMATS and (problem := excess_scans(data)) is not None:
        raise FrameLimitError(problem)
    frames = getattr(picture, "n_frames", 1)
    if codec == "webp" and frames != 1:  # the writer stores one picture per step
        raise FrameError(f"an animation of {frames} frames, not one picture")
    try:
        picture.load()  # here, not inside np.asarray, which would swallow its errors
        pixels = np.asarray(picture)
    except Exception as error:
        raise FrameError(f"does not decode as {codec} ({_one_line(error)})") from None
    if pixels.dtype != np.uint8 or pixels.size != height * width * channels:
        raise FrameError(f"decodes to {pixels.dtype} {list(pixels.shape)}, not uint8 {[height, width, channels]}")
    return pixels


def _map(function: Any, count: int) -> list[Any]:
    """`function(i)` for i < count, on threads when there is enough to share."""
    if count < 4 or _THREADS == 1:
        return [function(i) for i in range(count)]
    # A pool per call, not one for the process: a process forked later (DataLoader workers)
    # would inherit a pool whose threads it does not have.
    with ThreadPoolExecutor(max_workers=min(_THREADS, math.ceil(count / 2))) as pool:
        return list(pool.map(function, range(count)))


def _one_line(error: BaseException) -> str:
    return " ".join(str(error).split())[:120] or type(error).__name__

"""Camera frames of ROS bags: sensor_msgs/Image and sensor_msgs/CompressedImage messages →
arrays (H, W, C), channel-last.

Colour is stored as RGB (C=3) whatever order the camera sent: bgr8 and bgra8 are swapped, and the
alpha of rgba8/bgra8 is dropped (cameras send it opaque). Grey is one channel: mono8 and 8UC1 as
uint8, mono16 and 16UC1 as uint16 — kept at 16 bits, since depth cameras count millimetres in
them and scaling to 8 bits would lose all but the coarsest. A raw frame's `step` (its row stride,
padding included) and `is_bigendian` are honoured.

Compressed frames are JPEG or PNG, image_transport's `compressed` formats ("jpeg", "png",
"bgr8; jpeg compressed bgr8", "mono16; png compressed mono16"), decoded with Pillow. A decoder
returns RGB whatever channel order the encoder was handed, so the format only names the codec;
mono or colour is read from the file itself. compressedDepth (PNG behind a private header) is
refused, as is a 16-bit colour PNG, which Pillow would narrow to 8 bits. A JPEG or PNG that
Pillow opens as RGB or 8-bit grey decodes, in a demo file's image channel of its codec, to the
very pixels it decodes to here: its `picture` says so, and the bytes can be stored as they are.

Checking a frame (`frame_of`) reads its header only — size, channels, that the bytes hold what
the header claims, and a JPEG's count of scans (`jpeg_scans`) — and allocates nothing: the size
limits are applied to what it returns before any pixel is decoded. `decode` produces the pixels,
only for the frames a resampling grid shows, so what is held meanwhile is the bag's (compressed)
bytes, not a decoded copy of every frame.
"""

from __future__ import annotations

import io
import warnings
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from imitation.data.jpeg_scans import excess_scans

IMAGE = "Image"
COMPRESSED = "CompressedImage"


class ImageError(ValueError):
    """A frame that cannot become an array; the text says why (the caller adds where)."""


class _Encoding(NamedTuple):
    sent: int  # channels per pixel in the message
    dtype: np.dtype
    rgb: tuple[int, ...] | None  # the sent channels to keep, in RGB order; None: all, as sent


_U8, _U16 = np.dtype(np.uint8), np.dtype(np.uint16)
_ENCODINGS = {
    "rgb8": _Encoding(3, _U8, None),
    "bgr8": _Encoding(3, _U8, (2, 1, 0)),
    "rgba8": _Encoding(4, _U8, (0, 1, 2)),
    "bgra8": _Encoding(4, _U8, (2, 1, 0)),
    "mono8": _Encoding(1, _U8, None),
    "8UC1": _Encoding(1, _U8, None),
    "mono16": _Encoding(1, _U16, None),
    "16UC1": _Encoding(1, _U16, None),
}
ENCODINGS = tuple(_ENCODINGS)

# Pillow's modes for what JPEG and PNG hold → (channels, dtype) stored.
_MODES: dict[str, tuple[int, np.dtype]] = {
    "1": (1, _U8),
    "L": (1, _U8),
    "LA": (1, _U8),
    "I;16": (1, _U16),
    "I;16B": (1, _U16),
    "I": (1, _U16),  # 16-bit grey PNG on Pillow versions that widen it to int32
    "RGB": (3, _U8),
    "RGBA": (3, _U8),
    "P": (3, _U8),
    "PA": (3, _U8),
    "CMYK": (3, _U8),
    "YCbCr": (3, _U8),
}
_PNG_COLOUR_TYPES = (2, 6)  # IHDR colour types RGB and RGBA
# (Pillow's format, mode) of the pictures a demo file's image channel decodes as they are.
_KEPT = {("JPEG", "RGB"): "jpeg", ("JPEG", "L"): "jpeg", ("PNG", "RGB"): "png", ("PNG", "L"): "png"}
_DECODE_ERRORS = (OSError, ValueError, SyntaxError, EOFError, IndexError, MemoryError)


def image_kind(msgtype: str) -> str | None:
    """IMAGE or COMPRESSED for sensor_msgs' image types (ROS 1 or ROS 2 spelling), else None."""
    package, _, name = msgtype.partition("/")
    name = name.removeprefix("msg/")
    return name if package == "sensor_msgs" and name in (IMAGE, COMPRESSED) else None


@dataclass(frozen=True)
class Frame:
    """A checked frame, not yet decoded: its stored shape and dtype, and what decoding needs."""

    height: int
    width: int
    channels: int
    dtype: np.dtype
    source: str  # the message's encoding or format, as sent
    data: Any  # the message's bytes (bytes, or a numpy uint8 array)
    step: int = 0  # raw frames: bytes per row
    big_endian: bool = False  # raw frames
    codec: str | None = None  # compressed frames: "JPEG" or "PNG"
    picture: str | None = None  # "jpeg" or "png" where `data` can be stored as it is (see the module's docstring)

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.height, self.width, self.channels

    def describe(self) -> str:
        """E.g. "640x480 RGB uint8", "640x480 grey uint16"."""
        return f"{self.width}x{self.height} {'RGB' if self.channels == 3 else 'grey'} {self.dtype.name}"


def frame_of(message: Any, kind: str) -> Frame:
    """Check a decoded message of `kind` (IMAGE or COMPRESSED) without decoding its pixels."""
    return _raw_frame(message) if kind == IMAGE else _compressed_frame(message)


def decode(frame: Frame) -> np.ndarray:
    """The frame's pixels, (H, W, C) of `frame.dtype`; ImageError if they do not decode."""
    return _decode_raw(frame) if frame.codec is None else _decode_compressed(frame)


def _raw_frame(message: Any) -> Frame:
    encoding = str(message.encoding)
    spec = _ENCODINGS.get(encoding)
    if spec is None:
        raise ImageError(f"unknown encoding {encoding[:40]!r} (known: {', '.join(ENCODINGS)})")
    height, width, step = int(message.height), int(message.width), int(message.step)
    if height <= 0 or width <= 0:
        raise ImageError(f"an empty image ({width}x{height})")
    row = width * spec.sent * spec.dtype.itemsize
    if step < row:
        raise ImageError(f"step {step} is shorter than a row of {width} {encoding} pixels ({row} bytes)")
    size = len(message.data)
    if size != step * height:
        raise ImageError(f"data holds {size} bytes; step × height is {step} × {height} = {step * height}")
    channels = len(spec.rgb) if spec.rgb is not None else spec.sent
    return Frame(height, width, channels, spec.dtype, encoding, message.data, step=step, big_endian=bool(message.is_bigendian))


def _decode_raw(frame: Frame) -> np.ndarray:
    spec = _ENCODINGS[frame.source]
    row = frame.width * spec.sent * spec.dtype.itemsize
    rows = np.frombuffer(frame.data, dtype=np.uint8, count=frame.step * frame.height).reshape(frame.height, frame.step)
    wire = spec.dtype.newbyteorder(">" if frame.big_endian else "<")
    pixels: np.ndarray = rows[:, :row].view(wire).reshape(frame.height, frame.width, spec.sent)
    if spec.rgb is not None:
        pixels = pixels[..., list(spec.rgb)]
    return pixels.astype(spec.dtype)  # a native-order copy, free of the message's padding


def _codec(text: str) -> tuple[str, ...]:
    """The codecs a CompressedImage format allows: its name, or either when it names none."""
    lower = text.lower()
    if "compresseddepth" in lower:
        raise ImageError(f"format {text[:60]!r}: compressedDepth is not supported (use the raw depth topic)")
    named = tuple(codec for codec, words in (("JPEG", ("jpeg", "jpg")), ("PNG", ("png",))) if any(w in lower for w in words))
    if len(named) == 1:
        return named
    if not lower.strip():
        return ("JPEG", "PNG")  # some drivers leave the format empty: the bytes say which
    raise ImageError(f"unknown format {text[:60]!r} (JPEG or PNG, e.g. 'jpeg' or 'bgr8; png compressed bgr8')")


def _open(data: Any, codecs: tuple[str, ...]) -> Any:
    from PIL import Image

    with warnings.catch_warnings():
        # Pillow warns of "decompression bombs" by pixel count; our own limits judge the size.
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        try:
            return Image.open(io.BytesIO(bytes(data)), formats=list(codecs))
        except Image.DecompressionBombError as error:
            raise ImageError(str(error)) from None
        except Image.UnidentifiedImageError:
            start = bytes(data[:8]).hex(" ") or "nothing"
            raise ImageError(f"not a {' or '.join(codecs)} image (its bytes start {start})") from None
        except _DECODE_ERRORS as error:
            raise ImageError(f"not a {' or '.join(codecs)} image ({type(error).__name__}: {str(error)[:120]})") from None


def _compressed_frame(message: Any) -> Frame:
    text = str(message.format)
    codecs = _codec(text)
    data = message.data
    image = _open(data, codecs)
    layout = _MODES.get(image.mode)
    if layout is None:
        raise ImageError(f"a {image.format} image of mode {image.mode!r}, which has no place in an RGB or grey array")
    if image.format == "PNG" and len(data) > 25 and data[24] == 16 and data[25] in _PNG_COLOUR_TYPES:
        raise ImageError("a 16-bit colour PNG is not supported (it would be narrowed to 8 bits)")
    width, height = image.size
    if height <= 0 or width <= 0:
        raise ImageError(f"an empty image ({width}x{height})")
    if image.format in ("JPEG", "MPO") and (problem := excess_scans(data)) is not None:
        raise ImageError(problem)
    channels, dtype = layout
    return Frame(height, width, channels, dtype, text, data, codec=image.format, picture=_KEPT.get((image.format, image.mode)))


def _decode_compressed(frame: Frame) -> np.ndarray:
    assert frame.codec is not None  # set for every compressed frame
    image = _open(frame.data, (frame.codec,))
    try:
        image.load()
        if frame.dtype == _U16:
            pixels = np.asarray(image)
            if pixels.dtype != _U16 and (pixels.min() < 0 or pixels.max() > 65535):
                raise ImageError(f"a 16-bit grey {frame.codec} whose values run {pixels.min()}..{pixels.max()}")
        else:
            mode = "L" if frame.channels == 1 else "RGB"
            pixels = np.asarray(image if image.mode == mode else image.convert(mode))
    except ImageError:  # a ValueError, like the decoders' own: ours already says why
        raise
    except _DECODE_ERRORS as error:
        raise ImageError(f"does not decode as {frame.codec} ({type(error).__name__}: {str(error)[:120]})") from None
    if pixels.shape[:2] != (frame.height, frame.width):
        raise ImageError(f"decodes to {pixels.shape[1]}x{pixels.shape[0]}; its header says {frame.width}x{frame.height}")
    return pixels.reshape(frame.shape).astype(frame.dtype, copy=False)

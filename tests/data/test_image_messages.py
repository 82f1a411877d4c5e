"""Image frames as Foxglove messages (imitation.data.mcap.images), field by field: each message's
timestamp is the frame's time to the nanosecond (seconds and nanos apart), a raw frame's
geometry and encoding are its own, and a message decodes back to the frame."""

from __future__ import annotations

import io
import struct
import threading
import time
import zlib

import numpy as np
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf.message import DecodeError
from PIL import Image

from imitation.data.frame_transform import FrameTransform
from imitation.data.kept_frames import KeptFrames
from imitation.data.mcap import images
from imitation.data.mcap.images import (
    FrameError,
    _map,
    _one_line,
    _split_data,
    _varint,
    channels_of,
    decode_frame,
    decode_frames,
    encode_frame,
    encode_frames,
    is_image_leaf,
)

TIMES = np.array([0, 999_999_999, 1_000_000_000, 1_700_000_123_456_789_012], dtype=np.int64)


def frames(shape: tuple[int, ...]) -> np.ndarray:
    return np.random.default_rng(0).integers(0, 256, (len(TIMES), *shape), dtype=np.uint8)


@pytest.mark.parametrize("codec", ["png", "jpeg", "raw"])
def test_each_message_is_stamped_with_its_frames_time_to_the_nanosecond(codec: str) -> None:
    messages = encode_frames(codec, frames((3, 5, 3)), TIMES, jpeg_quality=90)
    kind = RawImage if codec == "raw" else CompressedImage
    stamps = [(message.timestamp.seconds, message.timestamp.nanos) for message in map(kind.FromString, messages)]
    assert stamps == [(0, 0), (0, 999_999_999), (1, 0), (1_700_000_123, 456_789_012)]


@pytest.mark.parametrize(
    ("shape", "encoding"), [((3, 5), "mono8"), ((3, 5, 1), "mono8"), ((3, 5, 3), "rgb8"), ((3, 5, 4), "rgba8")]
)
def test_a_raw_message_holds_the_frames_rows_and_geometry(shape: tuple[int, ...], encoding: str) -> None:
    frame = frames(shape)[0]
    message = RawImage.FromString(encode_frame("raw", frame, 5, jpeg_quality=90))
    channels = 1 if len(shape) == 2 else shape[2]
    assert (message.width, message.height, message.encoding, message.step) == (5, 3, encoding, 5 * channels)
    assert message.data == frame.tobytes()
    assert np.array_equal(decode_frame("raw", shape, encode_frame("raw", frame, 5, jpeg_quality=90)), frame)


@pytest.mark.parametrize("codec", ["png", "jpeg"])
@pytest.mark.parametrize("shape", [(4, 6), (4, 6, 3)])
def test_a_compressed_message_names_its_format_and_decodes_to_the_frame(codec: str, shape: tuple[int, ...]) -> None:
    frame = np.full(shape, 120, dtype=np.uint8)
    frame[1:3, 2:4] = 30
    data = encode_frame(codec, frame, 5, jpeg_quality=95)
    assert CompressedImage.FromString(data).format == codec
    decoded = decode_frame(codec, shape, data)
    assert decoded.shape == shape and decoded.dtype == np.uint8
    if codec == "png":
        assert np.array_equal(decoded, frame)
    else:
        assert np.abs(decoded.astype(int) - frame).max() <= 8


def test_jpeg_quality_is_what_the_encoder_is_given() -> None:
    frame = frames((32, 32, 3))[0]
    sizes = [len(encode_frame("jpeg", frame, 0, jpeg_quality=quality)) for quality in (10, 95)]
    assert sizes[0] < sizes[1] / 2


def test_a_raw_frame_of_another_geometry_is_refused_naming_both() -> None:
    message = RawImage(width=4, height=2, encoding="y" * 50, step=12, data=bytes(24)).SerializeToString()
    with pytest.raises(FrameError) as error:
        decode_frame("raw", (3, 5, 3), message)
    assert str(error.value) == f"a 4x2 {'y' * 40} image (step 12), but the channel declares 5x3 rgb8"
    short = RawImage(width=5, height=3, encoding="mono8", step=5, data=bytes(14)).SerializeToString()
    with pytest.raises(FrameError, match=r"^14 bytes of pixels, but a 5x3 mono8 image has 15$"):
        decode_frame("raw", (3, 5), short)


def test_a_decoders_error_is_quoted_on_one_line_of_at_most_120_characters_or_by_its_type() -> None:
    assert _one_line(ValueError("broken\n   header  here")) == "broken header here"
    assert _one_line(ValueError("x" * 300)) == "x" * 120
    assert _one_line(OSError()) == "OSError"


def _compressed(codec: str, data: bytes) -> bytes:
    return CompressedImage(format=codec, data=data).SerializeToString()


def _png_chunks(*chunks: tuple[bytes, bytes]) -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return b"\x89PNG\r\n\x1a\n" + b"".join(chunk(kind, data) for kind, data in chunks) + chunk(b"IEND", b"")


def _rgb_png(width: int, height: int, pixels: bytes, *before_data: tuple[bytes, bytes]) -> bytes:
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return _png_chunks((b"IHDR", header), *before_data, (b"IDAT", zlib.compress(pixels)))


def test_a_webp_message_decodes_to_its_rgb_or_rgba_frame() -> None:
    for shape in ((4, 6, 3), (4, 6, 4)):
        frame = np.full(shape, 120, dtype=np.uint8)
        message = encode_frame("webp", frame, 7, webp_quality=100, jpeg_quality=10)
        assert CompressedImage.FromString(message).format == "webp"
        assert np.array_equal(decode_frame("webp", shape, message), frame)  # a flat picture is exact at 100


def test_an_animated_webp_frame_is_refused_naming_its_frame_count() -> None:
    frame = np.full((4, 6, 3), 120, dtype=np.uint8)
    out = io.BytesIO()
    Image.fromarray(frame).save(
        out,
        format="WEBP",
        save_all=True,
        append_images=[Image.fromarray(255 - frame), Image.fromarray(frame // 2)],
        duration=50,
    )
    with pytest.raises(FrameError, match=r"^an animation of 3 frames, not one picture$"):
        decode_frame("webp", (4, 6, 3), _compressed("webp", out.getvalue()))


def test_a_picture_of_another_format_than_the_codec_is_refused_even_when_pillow_reads_it() -> None:
    frame = np.full((4, 6, 3), 120, dtype=np.uint8)
    for codec, other in (("png", "BMP"), ("png", "JPEG"), ("jpeg", "PNG"), ("webp", "PNG")):
        out = io.BytesIO()
        Image.fromarray(frame).save(out, format=other)
        with pytest.raises(FrameError, match=rf"^does not decode as {codec} \(cannot identify image file"):
            decode_frame(codec, (4, 6, 3), _compressed(codec, out.getvalue()))


def test_a_png_whose_header_passes_pillows_bomb_warning_is_refused_by_it() -> None:
    # 10^8 pixels: past Pillow's warning (89,478,485) but short of its error (twice that).
    with pytest.raises(
        FrameError, match=r"^does not decode as png \(Image size \(100000000 pixels\) exceeds limit of 89478485"
    ):
        decode_frame("png", (4, 6, 3), _compressed("png", _rgb_png(10_000, 10_000, b"")))


def test_a_png_pillow_warns_about_but_reads_decodes_to_its_picture() -> None:
    # An acTL chunk claiming 0 frames: Pillow warns that the APNG is invalid and reads the PNG's
    # own picture, which is the frame.
    frame = np.random.default_rng(1).integers(0, 256, (4, 6, 3), dtype=np.uint8)
    rows = b"".join(b"\0" + row.tobytes() for row in frame)
    data = _rgb_png(6, 4, rows, (b"acTL", struct.pack(">II", 0, 0)))
    with pytest.warns(UserWarning, match="Invalid APNG"):
        assert np.array_equal(decode_frame("png", (4, 6, 3), _compressed("png", data)), frame)


def _threads_used(count: int, meet: int) -> list[int]:
    """The thread each of `_map`'s `count` calls ran on, in call order. Every `meet` calls wait for
    each other, so that they run at once on `meet` threads or time out, then stay a while, so
    that a pool allowed more threads starts more for the calls still queued."""
    barrier = threading.Barrier(meet, timeout=5)

    def call(i: int) -> tuple[int, int]:
        if meet > 1:
            barrier.wait()
            time.sleep(0.02)
        return i, threading.get_ident()

    results = _map(call, count)
    assert [i for i, _ in results] == list(range(count))
    return [ident for _, ident in results]


def test_frames_are_shared_over_threads_only_from_four_and_on_at_most_half_as_many_threads(monkeypatch) -> None:
    main = threading.get_ident()
    monkeypatch.setattr(images, "_THREADS", 8)
    assert _threads_used(3, 1) == [main] * 3  # too few to share: the calling thread does them
    four = _threads_used(4, 2)
    assert main not in four and len(set(four)) == 2  # ⌈4/2⌉ threads
    eight = _threads_used(8, 4)
    assert main not in eight and len(set(eight)) == 4  # ⌈8/2⌉ threads, fewer than _THREADS
    assert len(set(_threads_used(24, 8))) == 8  # at most _THREADS, short of ⌈24/2⌉
    monkeypatch.setattr(images, "_THREADS", 2)
    assert len(set(_threads_used(6, 2)) - {main}) == 2
    monkeypatch.setattr(images, "_THREADS", 1)
    assert _threads_used(8, 1) == [main] * 8  # one thread: no pool


def _field(number: int, wire: int, payload: bytes) -> bytes:
    """A protobuf field: its key, then `payload` (a length-delimited field's length varint included)."""
    return _varint_bytes(number << 3 | wire) + payload


def _varint_bytes(value: int) -> bytes:
    out = bytearray()
    while True:
        out.append(value & 0x7F | (0x80 if value > 0x7F else 0))
        value >>= 7
        if not value:
            return bytes(out)


def _delimited(number: int, payload: bytes) -> bytes:
    return _field(number, 2, _varint_bytes(len(payload)) + payload)


def test_a_varint_is_read_to_its_last_byte_and_at_most_ten_bytes() -> None:
    cases = {
        b"\x00": (0, 1),
        b"\x7f": (127, 1),
        b"\x80\x01": (128, 2),
        b"\xac\x02": (300, 2),
        b"\xff" * 9 + b"\x01": (2**64 - 1, 10),
        b"\x80" * 9 + b"\x00": (0, 10),
    }
    for data, expected in cases.items():
        assert _varint(memoryview(data), 0) == expected, data
        assert _varint(memoryview(b"\x05\x07" + data + b"\x01"), 2) == (expected[0], expected[1] + 2), data
    for data in (b"", b"\x80", b"\xff\xff", b"\xff" * 10 + b"\x01", b"\x80" * 10 + b"\x00"):
        assert _varint(memoryview(data), 0) == (-1, -1), data  # runs past the end or ten bytes


def test_the_data_field_is_cut_out_of_a_message_of_every_wire_type_as_a_view() -> None:
    pixels = bytes(range(256)) * 2  # a length of two varint bytes
    before = _delimited(1, b"") + _field(4, 0, _varint_bytes(300)) + _field(5, 1, bytes(range(8)))
    after = _field(7, 5, b"\x01\x02\x03\x04") + _delimited(3, b"png") + _field(8, 0, b"\x00")
    message = before + _delimited(2, pixels) + after
    split = _split_data(message, 2)
    assert split is not None
    rest, data = split
    assert rest == before + after and bytes(data) == pixels
    assert np.shares_memory(np.frombuffer(data, np.uint8), np.frombuffer(message, np.uint8))
    # The data field first or last, and alone.
    for whole, expected_rest in (
        (_delimited(2, b"xy") + after, after),
        (before + _delimited(2, b"xy"), before),
        (_delimited(2, b"xy"), b""),
    ):
        split = _split_data(whole, 2)
        assert split is not None and split[0] == expected_rest and bytes(split[1]) == b"xy"
    # A message holding an empty timestamp (time 0) and a raw frame's varint fields splits too.
    raw = encode_frame("raw", np.arange(12, dtype=np.uint8).reshape(2, 2, 3), 0, jpeg_quality=90)
    split = _split_data(raw, 6)
    assert split is not None and bytes(split[1]) == bytes(range(12))
    assert RawImage.FromString(split[0]) == RawImage(width=2, height=2, encoding="rgb8", step=6, timestamp={})


def test_a_message_the_split_cannot_read_is_left_to_protobuf_whole() -> None:
    data = _delimited(2, b"pixels")
    refused = {
        "no data field": _delimited(3, b"png"),
        "data twice": data + data,
        "data as a varint": _field(2, 0, b"\x05"),
        "data as a fixed32 after the real one": data + _field(2, 5, b"\x00" * 4),
        "a group": _field(9, 3, b"") + data,
        "wire type 6": data + _field(9, 6, b""),
        "wire type 7": _field(9, 7, b"") + data,
        "a cut varint field": data + _field(4, 0, b"\x80"),
        "a cut fixed64": data + _field(5, 1, b"\x00" * 7),
        "a cut fixed32": data + _field(7, 5, b"\x00" * 3),
        "a cut length": data + _field(3, 2, b"\x80"),
        "a cut data field": _field(2, 2, b"\x07pixels"),
        "a key over ten bytes": b"\x80" * 10 + b"\x00" + data,
    }
    for name, message in refused.items():
        assert _split_data(message, 2) is None, name


def test_an_unknown_codec_a_message_protobuf_refuses_and_another_format_are_named_in_one_line() -> None:
    with pytest.raises(FrameError) as error:
        decode_frame("gif", (2, 2, 3), b"")
    assert str(error.value) == "unknown image codec 'gif' (this reader knows png, jpeg, raw, webp)"
    with pytest.raises(FrameError) as error:
        decode_frame("g" * 50, (2, 2, 3), b"")
    assert str(error.value) == f"unknown image codec '{'g' * 40}' (this reader knows png, jpeg, raw, webp)"
    garbage = b"\xff\xff\xff\xff not protobuf"
    try:
        CompressedImage.FromString(garbage)
    except DecodeError as refusal:
        reason = " ".join(str(refusal).split())[:120]
    with pytest.raises(FrameError) as error:
        decode_frame("png", (2, 2, 3), garbage)
    assert str(error.value) == f"not a foxglove.CompressedImage message ({reason})"
    png = CompressedImage.FromString(encode_frame("png", np.zeros((2, 2, 3), np.uint8), 0, jpeg_quality=90)).data
    with pytest.raises(FrameError) as error:
        decode_frame("png", (2, 2, 3), _compressed("y" * 50, png))
    assert str(error.value) == f"format '{'y' * 40}', but the channel's codec is 'png'"


def test_frames_decoded_with_a_transform_are_each_frame_transformed_one_at_a_time() -> None:
    rng = np.random.default_rng(3)
    episode = rng.integers(0, 256, (5, 6, 8, 3), dtype=np.uint8)
    messages = encode_frames("png", episode, np.arange(5), jpeg_quality=90)
    transform = FrameTransform(size=(2, 3), crop=(1, 2, 4, 5))
    decoded = decode_frames("png", (6, 8, 3), messages, topic="/camera", episode=0, transform=transform)
    assert decoded.shape == (5, 2, 3, 3) and decoded.dtype == np.uint8
    assert np.array_equal(decoded, np.stack([transform(frame) for frame in episode]))
    cropped = decode_frames(
        "png", (6, 8, 3), messages, topic="/camera", episode=0, transform=FrameTransform(crop=(1, 2, 4, 5))
    )
    assert np.array_equal(cropped, episode[:, 1:5, 2:7])
    assert np.array_equal(decode_frames("png", (6, 8, 3), messages, topic="/camera", episode=0), episode)


def test_a_picture_whose_header_fits_but_whose_pixels_do_not_decode_is_named_with_pillows_reason() -> None:
    rows = b"".join(b"\0" + bytes(18) for _ in range(4))
    cut = _png_chunks((b"IHDR", struct.pack(">IIBBBBB", 6, 4, 8, 2, 0, 0, 0)), (b"IDAT", zlib.compress(rows)[:-6]))
    picture = Image.open(io.BytesIO(cut))
    assert (picture.size, picture.mode) == ((6, 4), "RGB")
    with pytest.raises(OSError) as refusal:
        picture.load()
    with pytest.raises(FrameError) as error:
        decode_frame("png", (4, 6, 3), _compressed("png", cut))
    assert str(error.value) == f"does not decode as png ({' '.join(str(refusal.value).split())[:120]})"


def test_an_image_leaf_is_uint8_of_two_dimensions_or_three_with_one_three_or_four_channels() -> None:
    uint8 = np.dtype(np.uint8)
    leaves = [(4, 6), (4, 6, 1), (4, 6, 3), (4, 6, 4), (1, 1), (1, 1, 3)]
    not_leaves = [(6,), (4, 6, 2), (4, 6, 5), (4, 6, 3, 1), (0, 6), (4, 0, 3), (0, 0), ()]
    assert [is_image_leaf(uint8, shape) for shape in leaves] == [True] * len(leaves)
    assert [is_image_leaf(uint8, shape) for shape in not_leaves] == [False] * len(not_leaves)
    for dtype in (None, np.dtype(np.int8), np.dtype(np.uint16), np.dtype(np.float32)):
        assert not is_image_leaf(dtype, (4, 6, 3)), dtype
    assert [channels_of(shape) for shape in leaves] == [1, 1, 3, 4, 1, 3]


def test_kept_pictures_of_the_codec_are_stored_as_they_are_and_other_rows_encoded() -> None:
    episode = frames((4, 6, 3))
    pictures = []
    for frame in episode:
        out = io.BytesIO()
        Image.fromarray(frame).save(out, format="JPEG", quality=40)
        pictures.append(out.getvalue())
    pictures[1] = None
    kept = KeptFrames.of(episode, "jpeg", pictures)
    messages = [CompressedImage.FromString(message) for message in encode_frames("jpeg", kept, TIMES, jpeg_quality=95)]
    assert [(m.timestamp.seconds, m.timestamp.nanos, m.format) for m in messages] == [
        (0, 0, "jpeg"),
        (0, 999_999_999, "jpeg"),
        (1, 0, "jpeg"),
        (1_700_000_123, 456_789_012, "jpeg"),
    ]
    fresh = CompressedImage.FromString(encode_frame("jpeg", episode[1], int(TIMES[1]), jpeg_quality=95)).data
    assert [m.data for m in messages] == [pictures[0], fresh, pictures[2], pictures[3]]
    # Pictures of another codec than the channel's are not stored: every row is encoded.
    as_png = [CompressedImage.FromString(m).data for m in encode_frames("png", kept, TIMES, jpeg_quality=95)]
    assert as_png == [CompressedImage.FromString(encode_frame("png", f, 0, jpeg_quality=95)).data for f in episode]


@pytest.mark.parametrize("shape", [(5, 7), (5, 7, 1), (5, 7, 3), (5, 7, 4)])
def test_a_compressed_frame_is_pillows_picture_at_the_codecs_settings_byte_for_byte(shape: tuple[int, ...]) -> None:
    frame = frames(shape)[0]
    picture = Image.fromarray(frame.reshape(5, 7, -1)[:, :, 0] if len(shape) == 2 or shape[2] == 1 else frame)
    settings = {"png": {"compress_level": 3}, "jpeg": {"quality": 61}, "webp": {"quality": 37}}
    for codec, options in settings.items():
        channels = 1 if len(shape) == 2 else shape[2]
        if (codec == "jpeg" and channels == 4) or (codec == "webp" and channels == 1):
            continue  # JPEG has no alpha, WebP no grey
        out = io.BytesIO()
        picture.save(out, format=codec.upper(), **options)
        message = CompressedImage.FromString(encode_frame(codec, frame, 12, jpeg_quality=61, webp_quality=37))
        assert (message.format, message.data) == (codec, out.getvalue()), codec


def test_an_episodes_frames_are_encoded_at_the_qualities_given() -> None:
    episode = frames((5, 7, 3))
    for codec in ("jpeg", "webp"):
        messages = encode_frames(codec, episode, TIMES, jpeg_quality=61, webp_quality=37)
        alone = [
            encode_frame(codec, frame, int(time), jpeg_quality=61, webp_quality=37) for frame, time in zip(episode, TIMES)
        ]
        assert messages == alone, codec
        assert messages != encode_frames(codec, episode, TIMES, jpeg_quality=90, webp_quality=90), codec

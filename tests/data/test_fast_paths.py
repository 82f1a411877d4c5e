"""The load path's shortcuts give exactly what the plain paths give: frame messages whose pixels
are split out by hand (raw pixels as a view, no copy) decode to the same arrays, and are refused
with the same errors, as protobuf's whole-message parse; threaded decoding equals serial decoding;
MinibatchLoader's numpy gather gives the batches torch indexing gives, for a fixed seed; and
large_empty arrays behave as np.empty's."""

from __future__ import annotations

import io
import mmap
import re

import numpy as np
import pytest
import torch
from google.protobuf.timestamp_pb2 import Timestamp
from PIL import Image

from imitation.data import columns
from imitation.data.columns import large_empty
from imitation.data.loader import MinibatchLoader, TransitionTensors
from imitation.data.mcap import images
from imitation.data.mcap.images import FrameError, decode_frame, decode_frames, encode_frame

SHAPE = (6, 5, 3)


def _frame(seed: int, shape: tuple[int, ...] = SHAPE) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


def _decode_both(codec: str, message: bytes | memoryview, monkeypatch: pytest.MonkeyPatch) -> tuple[object, object]:
    """decode_frame's outcome (array, or the FrameError's text) with the split path and with protobuf whole."""

    def outcome() -> object:
        try:
            return decode_frame(codec, SHAPE, message)
        except FrameError as error:  # Pillow's messages name the stream's address
            return "FrameError: " + re.sub(r" at 0x[0-9a-f]+", "", str(error))

    fast = outcome()
    with monkeypatch.context() as patch:
        patch.setattr(images, "_split_data", lambda message, number: None)
        whole = outcome()
    return fast, whole


def _same(a: object, b: object) -> bool:
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        return a.shape == b.shape and np.array_equal(a, b)
    return a == b


def _messages(codec: str) -> list[bytes]:
    """A well-formed frame of `codec` and many damaged or unusual variants of it."""
    good = encode_frame(codec, _frame(1), 1_234_567_890, jpeg_quality=90)
    message = images._message_class(codec)()
    message.ParseFromString(good)
    data_number = images._DATA_FIELD[codec]
    variants = [good]
    variants += [good[:cut] for cut in range(len(good))]  # truncated anywhere
    variants += [good[:i] + bytes([good[i] ^ 0xFF]) + good[i + 1 :] for i in range(0, len(good), max(1, len(good) // 97))]
    data_key = bytes([data_number << 3 | 2])
    extra = data_key + bytes([3]) + b"abc"
    variants += [
        good + extra,  # the data field twice: protobuf keeps the last
        extra + good,
        good + bytes([data_number << 3 | 0, 5]),  # the data field's number as a varint
        good + bytes([data_number << 3 | 5]) + b"\x00\x00\x00\x00",  # ... as fixed32
        good + bytes([15 << 3 | 0, 1]) + bytes([16 << 3 | 2, 2]) + b"zz",  # unknown fields
        good + bytes([17 << 3 | 1]) + bytes(8) + bytes([18 << 3 | 5]) + bytes(4),
        good + bytes([19 << 3 | 3, 19 << 3 | 4]),  # an (empty) group
        good + bytes([0 << 3 | 0, 1]),  # field number 0
        good + bytes([20 << 3 | 0]) + b"\xff" * 11,  # an over-long varint
        good + bytes([20 << 3 | 6]),  # wire type 6
        bytes([data_number << 3 | 2]) + b"\xff" * 10 + b"\x01",  # a length beyond any message
        b"",
    ]
    # A string field with invalid UTF-8 (protobuf refuses it), and a corrupt timestamp.
    string_number = 4 if codec == "raw" else 3
    variants.append(good + bytes([string_number << 3 | 2, 2]) + b"\xc3\x28")
    timestamp = Timestamp(seconds=1, nanos=2).SerializeToString()
    variants.append(bytes([1 << 3 | 2, len(timestamp) + 1]) + timestamp + b"\x80" + good)
    return variants


@pytest.mark.parametrize("codec", ["raw", "png", "jpeg"])
def test_split_messages_decode_and_fail_exactly_as_protobuf_whole(codec, monkeypatch) -> None:
    accepted = refused = 0
    for message in _messages(codec):
        for form in (message, memoryview(bytearray(message))):
            fast, whole = _decode_both(codec, form, monkeypatch)
            assert _same(fast, whole), (codec, message, fast, whole)
        accepted += isinstance(fast, np.ndarray)
        refused += isinstance(fast, str)
    assert accepted >= 3 and refused >= 10


def test_the_split_is_taken_for_a_well_formed_frame_and_raw_pixels_are_not_copied() -> None:
    frame = _frame(2)
    message = bytearray(encode_frame("raw", frame, 5, jpeg_quality=90))
    split = images._split_data(message, images._DATA_FIELD["raw"])
    assert split is not None and bytes(split[1]) == frame.tobytes()
    decoded = decode_frame("raw", SHAPE, memoryview(message))
    assert np.array_equal(decoded, frame)
    assert np.shares_memory(decoded, np.frombuffer(message, np.uint8))  # a view, not a copy
    png = encode_frame("png", frame, 5, jpeg_quality=90)
    assert images._split_data(png, images._DATA_FIELD["png"]) is not None


@pytest.mark.parametrize("codec", ["raw", "png", "jpeg"])
def test_threaded_decoding_equals_serial_decoding_and_refuses_the_same_frame(codec, monkeypatch) -> None:
    frames = np.stack([_frame(seed) for seed in range(12)])
    messages: list[bytes | memoryview] = [encode_frame(codec, frame, i, jpeg_quality=90) for i, frame in enumerate(frames)]

    def run(threads: int, batch: list[bytes | memoryview]) -> object:
        with monkeypatch.context() as patch:
            patch.setattr(images, "_THREADS", threads)
            try:
                return decode_frames(codec, SHAPE, batch, topic="/observation", episode=3)
            except FrameError as error:
                return str(error)

    threaded, serial = run(4, messages), run(1, messages)
    assert isinstance(threaded, np.ndarray) and np.array_equal(threaded, serial)
    if codec != "jpeg":
        assert np.array_equal(threaded, frames)
    damaged = list(messages)
    damaged[7] = bytes(messages[7])[:-5]
    threaded, serial = run(4, damaged), run(1, damaged)
    assert isinstance(threaded, str) and threaded == serial and "episode 3, step 7" in threaded


def _tensors(count: int) -> TransitionTensors:
    generator = torch.Generator().manual_seed(0)
    images_ = torch.randint(0, 256, (count, 4, 5, 3), dtype=torch.uint8, generator=generator)
    return TransitionTensors(
        observations={"pixels": images_, "state": torch.randn(count, 2, generator=generator)},
        actions=torch.randint(0, 3, (count,), generator=generator),
        rewards=torch.randn(count, generator=generator, dtype=torch.float64),
        next_observations=None,
        terminated=torch.rand(count, generator=generator) > 0.5,
        truncated=torch.zeros(count, dtype=torch.bool),
        episode_index=torch.arange(count) // 7,
    )


def _assert_same(a: TransitionTensors, b: TransitionTensors) -> None:
    for name in ("actions", "rewards", "terminated", "truncated", "episode_index"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape and torch.equal(x, y), name
    for key in ("pixels", "state"):
        x, y = a.observations[key], b.observations[key]
        assert x.dtype == y.dtype and x.shape == y.shape and torch.equal(x, y), key
    assert a.next_observations is None and b.next_observations is None


def test_select_equals_torch_indexing_and_copies() -> None:
    data = _tensors(30)
    index = torch.tensor([5, 0, 29, -1, 5, 12])
    plain = TransitionTensors(**{name: _apply(lambda t: t[index], getattr(data, name)) for name in _FIELDS})
    selected = data.select(index)
    _assert_same(selected, plain)
    _assert_same(data.select(index.to(torch.int32)), plain)
    selected.observations["pixels"].fill_(0)  # a new tensor: the data is untouched
    assert data.observations["pixels"][5].any()
    with pytest.raises(IndexError):
        data.select(torch.tensor([30]))
    # A transposed (non-contiguous) tensor goes through numpy too; one tracking gradients takes torch's indexing.
    odd = TransitionTensors(
        **{
            **{name: getattr(data, name) for name in _FIELDS},
            "rewards": torch.randn(30, requires_grad=True),
            "actions": torch.randn(2, 30).T,
        }
    )
    taken = odd.select(index)
    assert torch.equal(taken.actions, odd.actions[index]) and torch.equal(taken.rewards, odd.rewards[index])


_FIELDS = ("observations", "actions", "rewards", "next_observations", "terminated", "truncated", "episode_index")


def _apply(fn, tree):  # type: ignore[no-untyped-def]
    if tree is None:
        return None
    if isinstance(tree, dict):
        return {key: fn(value) for key, value in tree.items()}
    return fn(tree)


@pytest.mark.parametrize("passes", [1, 3])
def test_minibatches_for_a_fixed_seed_are_those_of_torch_indexing(passes) -> None:
    data = _tensors(50)
    loader = MinibatchLoader(data, batch_size=16, seed=7, min_samples=passes * 50)
    generator = torch.Generator().manual_seed(7)
    for _epoch in range(2):  # the generator carries on across epochs
        order = torch.cat([torch.randperm(50, generator=generator) for _ in range(passes)])
        batches = list(loader)
        assert len(batches) == len(range(0, len(order), 16))
        for batch, start in zip(batches, range(0, len(order), 16), strict=True):
            index = order[start : start + 16]
            expected = TransitionTensors(
                **{name: _apply(lambda t, index=index: t[index], getattr(data, name)) for name in _FIELDS}
            )
            _assert_same(batch, expected)


def test_large_empty_is_an_ordinary_writable_array(monkeypatch) -> None:
    small = large_empty((3, 4), np.float32)
    assert small.shape == (3, 4) and small.dtype == np.float32 and small.flags.writeable
    monkeypatch.setattr(columns, "_LARGE_BYTES", 1024)
    big = large_empty((64, 8, 3), np.uint8)
    assert big.shape == (64, 8, 3) and big.dtype == np.uint8
    assert big.flags.writeable and big.flags.c_contiguous
    base = big
    while isinstance(base, np.ndarray) and base.base is not None:
        base = base.base
    assert isinstance(base, memoryview) and isinstance(base.obj, mmap.mmap)  # its own mapping, marked for huge pages
    big[...] = 7
    assert int(big.sum()) == 7 * big.size
    tensor = torch.from_numpy(big)
    assert tensor.shape == (64, 8, 3) and int(tensor[63, 7, 2]) == 7
    assert large_empty((0, 5), np.int64).shape == (0, 5)


def test_a_png_of_another_size_is_still_refused_through_the_split() -> None:
    out = io.BytesIO()
    Image.fromarray(_frame(3, (7, 5, 3))).save(out, format="PNG")
    message = images._message_class("png")(format="png", data=out.getvalue()).SerializeToString()
    assert images._split_data(message, images._DATA_FIELD["png"]) is not None
    with pytest.raises(FrameError, match="5x7 RGB picture, but the channel declares 5x6"):
        decode_frame("png", SHAPE, message)

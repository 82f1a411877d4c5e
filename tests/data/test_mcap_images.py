"""Image observations stored as Foxglove image channels (docs/FORMAT.md §6.6): exact png/raw and
close jpeg round trips, one message per frame at its row's time, random access, salvage, standard
tooling, the protobuf schema, and one-line errors for hostile frames."""

from __future__ import annotations

import contextlib
import io
import shutil
import struct
import subprocess
import sys
import zlib
from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from helpers import assert_episodes_equal, rewrite_messages
from mcap.reader import make_reader
from PIL import Image

from imitation.data.columns import read_transitions
from imitation.data.dataset import DemoDataset
from imitation.data.jpeg_scans import scan_count
from imitation.data.loader import load_transitions
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.writer import DemoWriter, write_episodes
from imitation.data.types import Episode
from imitation.errors import DemoFileError, ImitationError
from imitation.limits import LIMITS

H, W = 24, 32
SPACE = gym.spaces.Dict(
    {
        "rgb": gym.spaces.Box(0, 255, (H, W, 3), np.uint8),
        "rgba": gym.spaces.Box(0, 255, (H, W, 4), np.uint8),
        "mono": gym.spaces.Box(0, 255, (H, W), np.uint8),
        "depth": gym.spaces.Box(0, 255, (H, W, 1), np.uint8),
        "state": gym.spaces.Box(-1, 1, (3,), np.float32),
    }
)
NO_ALPHA = gym.spaces.Dict({key: SPACE[key] for key in ("rgb", "mono", "depth", "state")})
ACTIONS = gym.spaces.Discrete(2)
IMAGE_TOPICS = ["/observation/rgb", "/observation/rgba", "/observation/mono", "/observation/depth"]
PYMCAP = Path(sys.executable).parent / "pymcap-cli"


def smooth(rows: int, shape: tuple[int, ...], seed: int) -> np.ndarray:
    """Moving gradients with a little noise: what a camera sees, roughly (jpeg's PSNR is meaningful)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0 : shape[0], 0 : shape[1]]
    channels = shape[2] if len(shape) == 3 else 1
    frames = np.empty((rows, shape[0], shape[1], channels))
    for i in range(rows):
        for c in range(channels):
            frames[i, :, :, c] = 127 + 100 * np.sin(x / (5 + c) + i / 3) * np.cos(y / (7 + c) - i / 5)
    frames += rng.normal(0, 2, frames.shape)
    return np.clip(frames, 0, 255).astype(np.uint8).reshape((rows, *shape))


def episode(space: gym.spaces.Dict, steps: int, seed: int, **extra) -> Episode:
    rng = np.random.default_rng(seed)
    observations = {
        key: smooth(steps + 1, sub.shape, seed)
        if sub.dtype == np.uint8
        else rng.uniform(-1, 1, (steps + 1, 3)).astype(np.float32)
        for key, sub in space.spaces.items()
    }
    return Episode(
        observations=observations,
        actions=rng.integers(0, 2, steps),
        rewards=rng.normal(size=steps),
        terminated=seed % 2 == 0,
        truncated=seed % 2 == 1,
        metadata={"seed": seed},
        **extra,
    )


EPISODES = [episode(SPACE, steps, seed) for seed, steps in enumerate([5, 0, 9, 4])]
NO_ALPHA_EPISODES = [episode(NO_ALPHA, steps, seed) for seed, steps in enumerate([5, 0, 9, 4])]


def write(path: Path, episodes=EPISODES, space=SPACE, **options) -> Path:
    return write_episodes(path, episodes, env_id="Test-v0", observation_space=space, action_space=ACTIONS, dt=0.02, **options)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float("inf") if mse == 0 else 10 * np.log10(255**2 / mse)


@pytest.mark.parametrize("codec", ["png", "raw"])
def test_lossless_codecs_round_trip_exactly(tmp_path, codec) -> None:
    demo = DemoFile(write(tmp_path / "demo.mcap", image_codec=codec, block_steps=4), verify=True)
    assert demo.format_version == 2 and demo.damage is None
    for read, original in zip(demo, EPISODES):
        assert_episodes_equal(read, original)
    # The bulk loader decodes frames straight into their rows.
    batch = read_transitions(DemoDataset(tmp_path / "demo.mcap"), range(len(EPISODES)), next_observations=True)
    assert batch is not None
    np.testing.assert_array_equal(batch.observations["mono"], np.concatenate([e.observations["mono"][:-1] for e in EPISODES]))
    np.testing.assert_array_equal(batch.next_observations["rgb"][-1], EPISODES[-1].observations["rgb"][-1])


def test_jpeg_is_close_on_a_rendered_frame_and_smaller(tmp_path) -> None:
    env = gym.make("CartPole-v1", render_mode="rgb_array")
    env.reset(seed=0)
    frames = []
    for step in range(4):
        frames.append(env.render())
        env.step(step % 2)
    env.close()
    pixels = np.stack(frames)
    space = gym.spaces.Dict({"camera": gym.spaces.Box(0, 255, pixels.shape[1:], np.uint8), "gray": SPACE["mono"]})
    observations = {"camera": pixels, "gray": smooth(4, (H, W), 0)}
    original = Episode(
        observations=observations, actions=np.array([0, 1, 0]), rewards=np.ones(3), terminated=True, truncated=False
    )
    sizes = {}
    for codec in ("jpeg", "png"):
        path = write(tmp_path / f"{codec}.mcap", [original], space, image_codec=codec)
        sizes[codec] = path.stat().st_size
    read = DemoFile(tmp_path / "jpeg.mcap")[0]
    for key in ("camera", "gray"):
        assert read.observations[key].shape == observations[key].shape and read.observations[key].dtype == np.uint8
        assert psnr(read.observations[key], observations[key]) >= 35, key
    assert sizes["jpeg"] < sizes["png"]
    rough = DemoFile(write(tmp_path / "q30.mcap", [original], space, image_codec="jpeg", jpeg_quality=30))[0]
    assert 25 < psnr(rough.observations["camera"], pixels) < psnr(read.observations["camera"], pixels)


def test_one_message_per_frame_at_its_rows_time(tmp_path) -> None:
    """Every frame is its own message at its row's log time, inside its episode's range, and log
    times never decrease in file order though blocks of 2 rows interleave with them."""
    stamped = [episode(SPACE, 5, 7, timestamps=np.array([10, 10, 30, 45, 45, 90]) * 10**6), *EPISODES[:2]]
    path = write(tmp_path / "demo.mcap", stamped, block_steps=2)
    demo = DemoFile(path)
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        messages = [(channel.topic, message.log_time) for _, channel, message in reader.iter_messages(log_time_order=False)]
        channels = {channel.topic: channel for channel in reader.get_summary().channels.values()}
    times = [log_time for _, log_time in messages]
    assert times == sorted(times)
    for facts, original in zip(demo.episodes, stamped):
        inside = [(topic, t) for topic, t in messages if facts.t_start_ns <= t <= facts.t_end_ns]
        expected_times = (
            original.timestamps + facts.time_shift_ns
            if original.timestamps is not None
            else facts.t_start_ns + 20_000_000 * np.arange(facts.length + 1)
        )
        for topic in IMAGE_TOPICS:
            assert [t for name, t in inside if name == topic] == list(expected_times)
    assert channels["/observation/rgb"].message_encoding == "protobuf"
    assert dict(channels["/observation/rgb"].metadata) == {
        "field": "observation",
        "dtype": "|u1",
        "shape": "[24, 32, 3]",
        "codec": "png",
    }
    assert channels["/observation/state"].message_encoding == "imitation.ndarray"
    assert_episodes_equal(demo[0], stamped[0])


def test_random_access_reads_only_episode_k(tmp_path) -> None:
    demo = DemoFile(write(tmp_path / "demo.mcap", durable=True))
    assert (
        len(demo.chunks_of(demo.episodes[2]))
        < len(demo.chunks_of(demo.episodes[0])) + len(demo.chunks_of(demo.episodes[3])) + 1
    )
    assert_episodes_equal(demo[2], EPISODES[2])
    assert_episodes_equal(demo[-1], EPISODES[-1])


def test_killed_writer_keeps_finished_episodes_with_images(tmp_path) -> None:
    path = tmp_path / "demo.mcap"
    writer = DemoWriter(path, env_id="Test-v0", observation_space=SPACE, action_space=ACTIONS, durable=True)
    for original in EPISODES[:3]:
        writer.write(original)
    killed = tmp_path / "killed.mcap.partial"
    shutil.copyfile(writer.partial_path, killed)
    writer.write(EPISODES[3])
    writer.close()
    whole = path.read_bytes()
    # The killed file, and the finished one cut inside its last episode's data.
    (tmp_path / "cut.mcap").write_bytes(whole[: len(killed.read_bytes()) + 300])
    for damaged in (killed, tmp_path / "cut.mcap"):
        with pytest.raises(DemoFileError):
            DemoFile(damaged)
        salvaged = DemoFile(damaged, salvage=True)
        assert len(salvaged) == 3 and salvaged.damage
        for read, original in zip(salvaged, EPISODES):
            assert_episodes_equal(read, original)


def test_files_without_images_are_version_1_byte_for_byte(tmp_path) -> None:
    space = gym.spaces.Dict(
        {"state": SPACE["state"], "grid": gym.spaces.Box(0, 9, (3, 4, 2), np.uint8)}
    )  # 2 channels: no image
    episodes = [episode(space, 4, seed) for seed in range(2)]
    default = write(tmp_path / "default.mcap", episodes, space)
    for codec in ("jpeg", None):
        assert write(tmp_path / f"{codec}.mcap", episodes, space, image_codec=codec).read_bytes() == default.read_bytes()
    assert DemoFile(default).format_version == 1
    blocks = write(tmp_path / "blocks.mcap", EPISODES, image_codec=None)
    assert DemoFile(blocks).format_version == 1
    assert_episodes_equal(DemoFile(blocks)[2], EPISODES[2])


def test_bad_writer_options_are_refused_before_the_file_exists(tmp_path) -> None:
    for options, message in [
        ({"image_codec": "gif"}, "image_codec must be one of png, jpeg, raw, webp or None"),
        ({"image_codec": "jpeg", "jpeg_quality": 0}, "jpeg_quality must be an integer from 1 to 100"),
        ({"image_codec": "jpeg"}, "/observation/rgba: JPEG has no alpha channel"),
    ]:
        with pytest.raises(ImitationError, match=message):
            write(tmp_path / "demo.mcap", **options)
        assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("codec", ["png", "raw"])
def test_schema_is_a_foxglove_descriptor_set_that_decodes_the_frames(tmp_path, codec) -> None:
    path = write(tmp_path / "demo.mcap", NO_ALPHA_EPISODES[:1], NO_ALPHA, image_codec=codec)
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        schema, channel, message = next(reader.iter_messages(topics=["/observation/rgb"]))
    assert (schema.name, schema.encoding) == (f"foxglove.{'RawImage' if codec == 'raw' else 'CompressedImage'}", "protobuf")
    descriptors = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    assert [file.name for file in descriptors.file] == ["google/protobuf/timestamp.proto", f"foxglove/{schema.name[9:]}.proto"]
    pool = descriptor_pool.DescriptorPool()
    for file in descriptors.file:
        pool.Add(file)
    descriptor = pool.FindMessageTypeByName(schema.name)
    numbers = {field.name: field.number for field in descriptor.fields}
    if codec == "raw":
        assert numbers == {"timestamp": 1, "frame_id": 7, "width": 2, "height": 3, "encoding": 4, "step": 5, "data": 6}
    else:
        assert numbers == {"timestamp": 1, "frame_id": 4, "data": 2, "format": 3}
    decoded = message_factory.GetMessageClass(descriptor).FromString(message.data)
    assert decoded.timestamp.seconds * 10**9 + decoded.timestamp.nanos == message.log_time
    if codec == "raw":
        assert (decoded.width, decoded.height, decoded.encoding, decoded.step) == (W, H, "rgb8", 3 * W)
        pixels = np.frombuffer(decoded.data, np.uint8).reshape(H, W, 3)
    else:
        assert decoded.format == "png"
        pixels = np.asarray(Image.open(io.BytesIO(decoded.data)))
    np.testing.assert_array_equal(pixels, EPISODES[0].observations["rgb"][0])


@pytest.mark.parametrize("codec", ["png", "raw"])  # jpeg has png's schema
def test_pymcap_doctor_passes(tmp_path, codec) -> None:
    tool = str(PYMCAP) if PYMCAP.exists() else shutil.which("pymcap-cli")
    if tool is None:
        pytest.skip("pymcap-cli is not installed (it is a dev dependency: pip install -e .[dev])")
    path = write(tmp_path / "demo.mcap", NO_ALPHA_EPISODES, NO_ALPHA, image_codec=codec)
    result = subprocess.run(
        [tool, "doctor", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"},
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "passed MCAP doctor checks" in result.stdout


# -- hostile frames ---------------------------------------------------------------------------


def _png(width: int, height: int, pixels: bytes = b"") -> bytes:
    """A PNG whose header claims `width` × `height` 8-bit RGB, with `pixels` as its (deflated) data."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(pixels)) + chunk(b"IEND", b"")


def _compressed(data: bytes, image_format: str = "png") -> bytes:
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

    return CompressedImage(format=image_format, data=data).SerializeToString()


def _raw(width: int, height: int, data: bytes, encoding: str = "rgb8") -> bytes:
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    return RawImage(
        width=width, height=height, encoding=encoding, step=min(3 * width, 2**32 - 1), data=data
    ).SerializeToString()


def _small_png(shape: tuple[int, ...]) -> bytes:
    out = io.BytesIO()
    Image.fromarray(np.zeros(shape, np.uint8)).save(out, format="PNG")
    return out.getvalue()


def _jpeg_cut() -> bytes:
    out = io.BytesIO()
    Image.fromarray(smooth(1, (H, W, 3), 0)[0]).save(out, format="JPEG")
    return _compressed(out.getvalue()[: len(out.getvalue()) // 2], "jpeg")


HOSTILE = {
    "garbage": ("png", lambda: b"\xff\xff\xff\xff not protobuf", "not a foxglove.CompressedImage message"),
    "not-png": ("png", lambda: _compressed(b"GIF89a" + bytes(40)), "does not decode as png"),
    "corrupt-png": ("png", lambda: _compressed(_small_png((H, W, 3))[:50] + b"\x13" * 40), "does not decode as png"),
    "wrong-shape": (
        "png",
        lambda: _compressed(_small_png((8, 8, 3))),
        "a 8x8 RGB picture, but the channel declares 32x24 RGB",
    ),
    "wrong-mode": ("png", lambda: _compressed(_small_png((H, W))), "a 32x24 L picture, but the channel declares 32x24 RGB"),
    "bomb-png": (
        "png",
        lambda: _compressed(_png(100_000, 100_000)),
        "does not decode as png (Image size (10000000000 pixels) exceeds",
    ),
    "big-png": ("png", lambda: _compressed(_png(5_000, 5_000)), "a 5000x5000 RGB picture, but the channel declares 32x24 RGB"),
    "wrong-format": (
        "png",
        lambda: _compressed(_small_png((H, W, 3)), "jpeg"),
        "format 'jpeg', but the channel's codec is 'png'",
    ),
    "cut-jpeg": ("jpeg", _jpeg_cut, "does not decode as jpeg"),
    "huge-raw": ("raw", lambda: _raw(2**31, 2**31, b"\0" * 12), "a 2147483648x2147483648 rgb8 image"),
    "short-raw": ("raw", lambda: _raw(W, H, b"\0" * 12), "12 bytes of pixels, but a 32x24 rgb8 image has 2304"),
}


@pytest.mark.parametrize("case", list(HOSTILE))
def test_hostile_frame_is_one_line_naming_file_topic_and_frame(tmp_path, case) -> None:
    codec, make_frame, expected = HOSTILE[case]
    good = write(tmp_path / "good.mcap", NO_ALPHA_EPISODES[:3], NO_ALPHA, image_codec=codec)
    episode_start = DemoFile(good).episodes[2].t_start_ns
    bad_time = episode_start + 3 * 20_000_000
    bad = tmp_path / "bad.mcap"
    rewrite_messages(
        good, bad, lambda topic, t, data: (t, make_frame() if (topic, t) == ("/observation/rgb", bad_time) else data)
    )
    demo = DemoFile(bad)
    if codec != "jpeg":
        assert_episodes_equal(demo[0], NO_ALPHA_EPISODES[0])  # the other episodes stay readable
    with pytest.raises(DemoFileError) as caught:
        demo[2]
    message = str(caught.value)
    assert "\n" not in message and message.startswith(f"{bad}: /observation/rgb, episode 2, step 3: "), message
    assert expected in message, message
    # The bulk loader leaves the bad frame to the general path, which names it alike.
    assert read_transitions(DemoDataset(bad), [2], next_observations=False) is None
    with pytest.raises(DemoFileError, match="episode 2, step 3: "):
        load_transitions(bad)
    # The salvage scan keeps the episodes before the bad frame.
    salvaged = DemoFile(bad, salvage=True, verify=True)
    assert len(salvaged) == 2 and "episode 2, step 3" in salvaged.damage


def test_channel_declaring_another_shape_than_the_space_is_refused(tmp_path) -> None:
    good = write(tmp_path / "good.mcap", NO_ALPHA_EPISODES[:1], NO_ALPHA)
    bad = tmp_path / "bad.mcap"
    from mcap.writer import Writer

    with open(good, "rb") as stream, open(bad, "wb") as out:
        reader = make_reader(stream)
        writer = Writer(out)
        writer.start(profile="imitation", library="test")
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        summary = reader.get_summary()
        schemas = {s.id: writer.register_schema(s.name, s.encoding, s.data) for s in summary.schemas.values()}
        ids = {}
        for c in summary.channels.values():
            metadata = dict(c.metadata) | ({"shape": "[2, 2, 3]"} if c.topic == "/observation/rgb" else {})
            ids[c.id] = writer.register_channel(c.topic, c.message_encoding, schemas.get(c.schema_id, 0), metadata)
        for _, channel, message in reader.iter_messages(log_time_order=False):
            writer.add_message(ids[channel.id], log_time=message.log_time, data=message.data, publish_time=message.log_time)
        writer.finish()
    with pytest.raises(
        DemoFileError, match=r"/observation/rgb: an image channel declaring uint8 \[2, 2, 3\], but the space's leaf"
    ):
        DemoFile(bad)[0]


# -- frames cheap to store and dear to decode (imitation/limits.py) ----------------------------


@contextlib.contextmanager
def limits(free_bytes: int | None = None, **values: int) -> Iterator[None]:
    """The block runs with LIMITS' `values` (as `imitation --limit` sets them) and, given, the
    bytes every file may decode to whatever its size."""
    import imitation.limits

    saved = {name: getattr(LIMITS, name) for name in values}, imitation.limits.FREE_EXPANSION_BYTES
    try:
        for name, value in values.items():
            setattr(LIMITS, name, value)
        if free_bytes is not None:
            imitation.limits.FREE_EXPANSION_BYTES = free_bytes
        yield
    finally:
        for name, value in saved[0].items():
            setattr(LIMITS, name, value)
        imitation.limits.FREE_EXPANSION_BYTES = saved[1]


def _progressive(pixels: np.ndarray, scans: int) -> bytes:
    """Pillow's progressive JPEG of `pixels` with its last scan (a refinement of the picture)
    repeated until it has `scans`: libjpeg decodes each scan over the whole picture."""
    out = io.BytesIO()
    Image.fromarray(pixels).save(out, format="JPEG", progressive=True, quality=90)
    data = out.getvalue()
    last, end = data.rindex(b"\xff\xda"), data.rindex(b"\xff\xd9")
    return data[:end] + data[last:end] * (scans - scan_count(data)) + data[end:]


def test_scans_are_counted_from_the_markers() -> None:
    frame = smooth(1, (H, W, 3), 0)[0]
    for options, scans in (({}, 1), ({"progressive": True}, 10)):
        out = io.BytesIO()
        Image.fromarray(frame).save(out, format="JPEG", **options)
        assert scan_count(out.getvalue()) == scans
    grey = io.BytesIO()
    Image.fromarray(frame[..., 0]).save(grey, format="JPEG", progressive=True)
    assert scan_count(grey.getvalue()) == 6
    assert scan_count(_progressive(frame, 250)) == 250
    # A segment's contents are skipped by its length: a whole JPEG inside a comment is not scans.
    inner = _progressive(frame, 40)
    outer = io.BytesIO()
    Image.fromarray(frame).save(outer, format="JPEG", comment=inner)
    assert inner in outer.getvalue() and scan_count(outer.getvalue()) == 1
    assert scan_count(b"not a jpeg") == 0
    # A sequential JPEG whose one scan holds every component is whole after it: libjpeg refuses
    # any scan that follows, so the count stops there (and cameras' frames cost no search).
    baseline = io.BytesIO()
    Image.fromarray(frame).save(baseline, format="JPEG")
    data = baseline.getvalue()
    first, end = data.index(b"\xff\xda"), data.rindex(b"\xff\xd9")
    repeated = data[:end] + data[first:end] * 50 + data[end:]
    assert scan_count(repeated) == 1
    with pytest.raises(OSError):
        Image.open(io.BytesIO(repeated)).load()


def test_a_jpeg_frame_of_more_scans_than_the_limit_is_refused_before_it_is_decoded(tmp_path) -> None:
    good = write(tmp_path / "good.mcap", NO_ALPHA_EPISODES[:3], NO_ALPHA, image_codec="jpeg")
    bad_time = DemoFile(good).episodes[2].t_start_ns + 3 * 20_000_000
    many = _progressive(smooth(1, (H, W, 3), 1)[0], 150)
    bad = tmp_path / "bad.mcap"
    rewrite_messages(
        good, bad, lambda topic, t, data: (t, _compressed(many, "jpeg") if (topic, t) == ("/observation/rgb", bad_time) else data)
    )
    expected = f"{bad}: /observation/rgb, episode 2, step 3: scans of one JPEG frame: 150 is more than the limit jpeg_scans=100"
    for read in (lambda: DemoFile(bad)[2], lambda: load_transitions(bad), lambda: DemoFile(bad, salvage=True, verify=True)):
        with pytest.raises(DemoFileError) as caught:
            read()  # `info`'s salvage scan stops on it too: a limit is not damage to salvage around
        assert str(caught.value).startswith(expected), str(caught.value)
    with limits(jpeg_scans=150):
        frame = DemoFile(bad)[2].observations["rgb"][3]
    assert np.array_equal(frame, np.asarray(Image.open(io.BytesIO(many))))  # raised, the same frame decodes as Pillow decodes it


def test_frames_that_decode_to_far_more_than_the_file_are_refused_when_it_is_opened(tmp_path) -> None:
    """A file whose frames decode to more than image_expansion_ratio times its size (beyond the
    free 64 MiB, lowered here) is refused on opening, through its summary or by the salvage
    scan; raised, the same file reads."""
    black = gym.spaces.Box(0, 255, (64, 64, 3), np.uint8)
    frames = np.zeros((101, 64, 64, 3), np.uint8)  # 1.2 MB decoded, 290 B of PNG each
    path = write_episodes(tmp_path / "black.mcap", [Episode(observations=frames, actions=np.zeros(100, np.int64), rewards=np.zeros(100))],
                          env_id="", observation_space=black, action_space=ACTIONS)
    size = path.stat().st_size
    ratio = frames.nbytes // size
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(path.read_bytes()[:-40])  # no footer: the salvage scan decodes as it reads
    with limits(image_expansion_ratio=ratio - 1, free_bytes=0):
        for read, name in ((lambda: DemoFile(path), path), (lambda: DemoFile(damaged, salvage=True), damaged)):
            with pytest.raises(DemoFileError) as caught:
                read()
            assert str(caught.value).startswith(f"{name}: decoded bytes of its camera frames (from {name.stat().st_size} bytes): "
                                                 f"{frames.nbytes} is more than the limit image_expansion_ratio={ratio - 1}")
    with limits(image_expansion_ratio=2 * ratio, free_bytes=0):
        assert np.array_equal(DemoFile(path)[0].observations, frames)
        assert len(DemoFile(damaged, salvage=True)) == 1

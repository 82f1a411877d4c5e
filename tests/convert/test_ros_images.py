"""Camera topics of ROS bags (sensor_msgs/Image and CompressedImage) become image leaves of a Dict
observation beside the numeric state. Bags are written here with `rosbags`' own writers and
serialisers (ROS 2 MCAP, rosbag2 sqlite, ROS 1), the frames rendered by CartPole."""

from __future__ import annotations

import io
import re
import shutil
import struct
import subprocess
import sys
import zlib
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import gymnasium as gym
import numpy as np
import pytest
from support import run_cli_many, write_map
from test_cli import assert_one_line_error
from test_ros_real_logs import BagWriter

from imitation.data.convert.job import convert
from imitation.data.convert.maps import parse_map
from imitation.data.convert.ros_images import COMPRESSED, IMAGE, ImageError, decode, frame_of
from imitation.data.jpeg_scans import scan_count
from imitation.data.mcap.reader import DemoFile
from imitation.errors import ImitationError

NS = 1_000_000_000
START_NS = 1_700_000_000 * NS
STEPS = 8  # state and command messages, at 10 Hz
HEIGHT, WIDTH = 64, 96
PADDING = 8  # bytes at the end of each row of the raw frames: step > width × 3


def cartpole_frames(count: int) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """`count` rendered frames (RGB, HEIGHT×WIDTH), the states and the actions of one rollout."""
    env = gym.make("CartPole-v1", render_mode="rgb_array")
    state, _ = env.reset(seed=3)
    frames, states, actions = [], [], []
    for step in range(count):
        frame = env.render()
        assert frame is not None
        frames.append(cv2.resize(frame, (WIDTH, HEIGHT), interpolation=cv2.INTER_AREA))
        states.append(state)
        actions.append(step % 2)
        state, *_ = env.step(step % 2)
    env.close()
    return frames, np.asarray(states, dtype=np.float64), np.asarray(actions, dtype=np.float64)


class CameraBagWriter(BagWriter):
    """test_ros_real_logs' bag writer whose topics connect on their first message, with camera messages."""

    def write(self, topic: str, time_ns: int, message: Any) -> None:
        if topic not in self.connections:
            self.topic(topic, message.__msgtype__)
        super().write(topic, time_ns, message)

    def header(self, time_ns: int, frame: str = "camera") -> Any:
        return super().header(time_ns, frame)

    def image(self, time_ns: int, pixels: np.ndarray, encoding: str, *, padding: int = 0, big_endian: bool = False) -> Any:
        """A sensor_msgs/Image of `pixels` (H, W, C) as sent: rows padded by `padding` bytes."""
        height, width = pixels.shape[:2]
        wire = pixels.astype(pixels.dtype.newbyteorder(">" if big_endian else "<")).reshape(height, -1).view(np.uint8)
        rows = np.concatenate([wire, np.full((height, padding), 0xAB, dtype=np.uint8)], axis=1)
        return self.msg(
            "sensor_msgs/msg/Image",
            header=self.header(time_ns),
            height=height,
            width=width,
            encoding=encoding,
            is_bigendian=int(big_endian),
            step=rows.shape[1],
            data=rows.reshape(-1),
        )

    def compressed(self, time_ns: int, data: bytes, format: str) -> Any:
        return self.msg(
            "sensor_msgs/msg/CompressedImage",
            header=self.header(time_ns),
            format=format,
            data=np.frombuffer(data, dtype=np.uint8),
        )

    def joint_state(self, time_ns: int, state: np.ndarray) -> Any:
        return self.msg(
            "sensor_msgs/msg/JointState",
            header=self.header(time_ns),
            name=["cart", "pole"],
            position=np.array([state[0], state[2]]),
            velocity=np.array([state[1], state[3]]),
            effort=np.zeros(0),
        )


def encoded(pixels: np.ndarray, extension: str) -> bytes:
    ok, data = cv2.imencode(extension, pixels, [cv2.IMWRITE_JPEG_QUALITY, 95] if extension == ".jpg" else [])
    assert ok
    return data.tobytes()


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float(10 * np.log10(255.0**2 / mse))


CAMERA_MAP = {
    "rate_hz": 10,
    "observation": [
        {"topic": "/joint_states", "fields": ["position", "velocity"]},
        {"topic": "/camera/image_raw", "image": "front", "size": [HEIGHT, WIDTH]},
        {"topic": "/camera/image_raw/compressed", "image": "front_jpeg"},
        {"topic": "/camera/png", "image": "front_png"},
        {"topic": "/camera/mono", "image": "mono"},
        {"topic": "/depth/image_raw", "image": "depth"},
    ],
    "action": [{"topic": "/cmd", "fields": ["data"]}],
}


def camera_bag(path: Path, kind: str) -> dict[str, Any]:
    """A CartPole rollout as a robot would log it: the joint states and the command at 10 Hz, the
    camera at 20 Hz (raw bgr8 with padded rows, JPEG, PNG), a mono8 camera at 5 Hz and a
    big-endian mono16 "depth" camera at 10 Hz. Returns what was written."""
    frames, states, actions = cartpole_frames(2 * STEPS)
    greys = [cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY) for frame in frames]
    with CameraBagWriter(path, kind) as bag:
        for i, frame in enumerate(frames):  # 20 Hz
            t = START_NS + i * NS // 20
            bgr = np.ascontiguousarray(frame[..., ::-1])
            bag.write("/camera/image_raw", t, bag.image(t, bgr, "bgr8", padding=PADDING))
            bag.write("/camera/image_raw/compressed", t, bag.compressed(t, encoded(bgr, ".jpg"), "rgb8; jpeg compressed bgr8"))
            bag.write("/camera/png", t, bag.compressed(t, encoded(bgr, ".png"), "bgr8; png compressed bgr8"))
            if i % 4 == 0:  # 5 Hz
                bag.write("/camera/mono", t, bag.image(t, greys[i][..., None], "mono8"))
            if i % 2 == 0:  # 10 Hz
                depth = (greys[i].astype(np.uint16) * 257)[..., None]
                bag.write("/depth/image_raw", t, bag.image(t, depth, "mono16", big_endian=True))
        for k in range(STEPS):  # 10 Hz, a millisecond after the frame
            t = START_NS + k * NS // 10 + 1_000_000
            bag.write("/joint_states", t, bag.joint_state(t, states[2 * k]))
            bag.write("/cmd", t + 1_000_000, bag.msg("std_msgs/msg/Float64", data=float(actions[2 * k])))
    return {"frames": frames, "greys": greys, "states": states, "actions": actions}


@pytest.mark.parametrize("kind", ["ros2 mcap", "ros2 sqlite", "ros1"])
def test_cameras_become_image_leaves_beside_the_state(tmp_path: Path, kind: str) -> None:
    bag = tmp_path / ("cartpole.bag" if kind == "ros1" else "cartpole")
    written = camera_bag(bag, kind)
    out = tmp_path / "demos.mcap"
    result = convert(bag, out, map_path=write_map(tmp_path, CAMERA_MAP), progress=False)
    assert result["episodes"] == 1 and result["transitions"] == STEPS
    demo = DemoFile(out)
    space = demo.observation_space
    assert isinstance(space, gym.spaces.Dict)
    assert set(space.spaces) == {"state", "front", "front_jpeg", "front_png", "mono", "depth"}
    assert space["state"] == gym.spaces.Box(-np.inf, np.inf, (4,), np.float64)
    for key in ("front", "front_jpeg", "front_png"):
        assert space[key] == gym.spaces.Box(0, 255, (HEIGHT, WIDTH, 3), np.uint8)
    assert space["mono"] == gym.spaces.Box(0, 255, (HEIGHT, WIDTH, 1), np.uint8)
    assert space["depth"] == gym.spaces.Box(0, 65535, (HEIGHT, WIDTH, 1), np.uint16)  # mono16 is never narrowed
    episode = demo[0]
    observations = episode.observations
    assert observations["front"].shape == (STEPS + 1, HEIGHT, WIDTH, 3) and observations["front"].dtype == np.uint8
    # The grid starts at the first command (2 ms after the first frame) and steps at 10 Hz: step k
    # holds the 20 Hz camera's frame 2k, the 5 Hz one's frame 4⌊k/2⌋; the last, one period past
    # the last command, holds the last frames.
    for k in range(STEPS + 1):
        fast, slow = min(2 * k, 2 * STEPS - 1), min(4 * (k // 2), 2 * STEPS - 4)
        rgb = written["frames"][fast]
        assert np.array_equal(observations["front"][k], rgb)  # bgr8 swapped to RGB, row padding dropped
        assert np.array_equal(observations["front_png"][k], rgb)
        assert psnr(observations["front_jpeg"][k], rgb) > 30
        assert np.array_equal(observations["mono"][k, ..., 0], written["greys"][slow])  # held, not interpolated
        assert np.array_equal(observations["depth"][k, ..., 0], written["greys"][fast].astype(np.uint16) * 257)
    # The JPEG's colours are RGB, not the BGR the encoder was handed.
    jpeg, rgb = observations["front_jpeg"][3], written["frames"][6]
    assert psnr(jpeg, rgb) > psnr(jpeg, rgb[..., ::-1]) + 5
    state = written["states"][: 2 * STEPS : 2]
    assert np.allclose(observations["state"][:STEPS], state[:, [0, 2, 1, 3]])
    assert episode.actions[:, 0].tolist() == written["actions"][: 2 * STEPS : 2].tolist()
    images = demo.user_metadata["observation_images"]
    assert images["front"] == {"topic": "/camera/image_raw", "sent_as": "bgr8"}
    assert images["front_jpeg"]["sent_as"] == "rgb8; jpeg compressed bgr8"
    assert demo.user_metadata["observation_names"][0] == "/joint_states.position[0]"


def test_a_camera_alone_and_the_command_line(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    written = camera_bag(bag, "ros2 mcap")
    only_camera = {**CAMERA_MAP, "observation": [{"topic": "/camera/png", "image": "front"}]}
    out = tmp_path / "demos.mcap"
    (result,) = run_cli_many([["convert", bag, "--map", write_map(tmp_path, only_camera), "--out", out, "--json"]])
    assert result.returncode == 0, result.stderr
    demo = DemoFile(out)
    assert list(demo.observation_space.spaces) == ["front"]  # no numeric entries: no state leaf
    assert np.array_equal(demo[0].observations["front"][1], written["frames"][2])
    pymcap = Path(sys.executable).parent / "pymcap-cli"
    tool = str(pymcap) if pymcap.exists() else shutil.which("pymcap-cli")
    if tool is not None:
        doctor = subprocess.run([tool, "doctor", str(out)], capture_output=True, text=True, timeout=120)
        assert doctor.returncode == 0 and "passed MCAP doctor checks" in doctor.stdout, doctor.stdout + doctor.stderr


def small_bag(path: Path, camera: list[Any], *, kind: str = "ros2 mcap") -> Path:
    """A bag with a 12x8 camera (messages from `camera(bag, i, t)`, None to skip) and a command."""
    with CameraBagWriter(path, kind) as bag:
        for i in range(6):
            t = START_NS + i * NS // 10
            message = camera[i](bag, t) if i < len(camera) else camera[-1](bag, t)
            if message is not None:
                bag.write("/camera", t, message)
            bag.write("/cmd", t + 1_000_000, bag.msg("std_msgs/msg/Float64", data=float(i)))
    return path


PIXELS = np.arange(8 * 12 * 3, dtype=np.uint8).reshape(8, 12, 3)
JPEG = encoded(PIXELS, ".jpg")


def many_scans(pixels: np.ndarray, scans: int) -> bytes:
    """Pillow's progressive JPEG of `pixels` with its last scan repeated until it has `scans`."""
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(pixels).save(out, format="JPEG", progressive=True)
    data = out.getvalue()
    last, end = data.rindex(b"\xff\xda"), data.rindex(b"\xff\xd9")
    return data[:end] + data[last:end] * (scans - scan_count(data)) + data[end:]
SMALL_MAP = {
    "rate_hz": 10,
    "observation": [{"topic": "/camera", "image": "cam"}],
    "action": [{"topic": "/cmd", "fields": ["data"]}],
}


def rgb(bag: BagWriter, t: int) -> Any:
    return bag.image(t, PIXELS, "rgb8")


def jpeg(bag: BagWriter, t: int) -> Any:
    return bag.compressed(t, JPEG, "jpeg")


def png_header(width: int, height: int) -> bytes:
    """A PNG that declares its size and holds no pixels: what a bomb looks like to a header reader."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b"")


def short_data(bag: BagWriter, t: int) -> Any:
    message = bag.image(t, PIXELS, "rgb8")
    message.data = message.data[:-5]
    return message


BAD_BAGS = {
    "truncated jpeg": (
        [jpeg, jpeg, lambda b, t: b.compressed(t, JPEG[:-30], "jpeg"), jpeg],
        SMALL_MAP,
        ["frame 2 (logged at 1700000000200000000 ns)", "does not decode as JPEG"],
    ),
    "not a jpeg": (
        [jpeg, lambda b, t: b.compressed(t, b"\x00" * 40, "jpeg"), jpeg],
        SMALL_MAP,
        ["frame 1 (logged at", "not a JPEG image (its bytes start 00 00 00"],
    ),
    "resolution change": (
        [rgb, rgb, rgb, lambda b, t: b.image(t, PIXELS[:4], "rgb8")],
        SMALL_MAP,
        ["frame 3 (logged at", "a 12x4 RGB uint8 frame", "first was 12x8 RGB uint8", "resolution changes mid-bag"],
    ),
    "unknown encoding": (
        [rgb, lambda b, t: b.image(t, PIXELS[..., :2], "yuv422")],
        SMALL_MAP,
        ["frame 1", "unknown encoding 'yuv422'", "bgr8"],
    ),
    "unknown format": (
        [lambda b, t: b.compressed(t, JPEG, "16UC1; compressedDepth")],
        SMALL_MAP,
        ["frame 0", "compressedDepth is not supported"],
    ),
    "short data": ([rgb, rgb, short_data], SMALL_MAP, ["frame 2", "data holds 283 bytes", "step × height is 36 × 8 = 288"]),
    "a progressive JPEG of 150 scans": (
        [jpeg, lambda b, t: b.compressed(t, many_scans(PIXELS, 150), "jpeg"), jpeg],
        SMALL_MAP,
        ["frame 1 (logged at", "scans of one JPEG frame: 150 is more than the limit jpeg_scans=100"],
    ),
    "a PNG declaring 4000x4000": (
        [lambda b, t: b.compressed(t, png_header(4000, 4000), "png")],
        SMALL_MAP,
        ["/camera frame 0", "4000x4000 RGB uint8 frame: 48000000 is more than the limit sample_elements"],
    ),
    "larger than the map's size": (
        [rgb],
        {**SMALL_MAP, "observation": [{"topic": "/camera", "image": "cam", "size": [4, 12]}]},
        ["frame 0", "a 12x8 RGB uint8 frame; the map's size is [4, 12]"],
    ),
    "not a camera": (
        [rgb],
        {**SMALL_MAP, "observation": [{"topic": "/cmd", "image": "cam"}]},
        ["observation[0] (/cmd)", "needs a sensor_msgs/Image or CompressedImage topic", "it is a std_msgs/msg/Float64"],
    ),
    "pixels as fields": (
        [rgb],
        {**SMALL_MAP, "observation": [{"topic": "/camera", "fields": ["data"]}]},
        ["a camera topic", "image: KEY"],
    ),
}


def test_bad_frames_fail_in_one_line_and_write_nothing(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    cases = []
    for index, (name, (camera, data, fragments)) in enumerate(BAD_BAGS.items()):
        folder = tmp_path / f"case{index}"
        folder.mkdir()
        bag = small_bag(folder / "bag", camera)
        argv = ["convert", bag, "--map", write_map(folder, data), "--out", out / "d.mcap"]
        cases.append((name, argv, [str(bag), *fragments]))
    # The limit on numbers per sample: a 12x8 RGB frame holds 288.
    limited = small_bag(tmp_path / "limited", [rgb])
    cases.append(
        (
            "over the limit",
            [
                "--limit",
                "sample_elements=200",
                "convert",
                limited,
                "--map",
                write_map(tmp_path, SMALL_MAP),
                "--out",
                out / "d.mcap",
            ],
            [str(limited), "/camera frame 0", "288 is more than the limit sample_elements=200"],
        )
    )
    results = run_cli_many([argv for _, argv, _ in cases])
    for (name, _, fragments), result in zip(cases, results):
        try:
            assert_one_line_error(result, *fragments)
        except AssertionError as error:
            raise AssertionError(f"{name}: {error}") from None
    assert list(out.iterdir()) == []  # nothing written, not even a .partial


def test_frames_held_over_many_steps_count_once_per_step(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two frames held over a 100 Hz grid: each step is a decoded frame, counted against
    image_expansion_ratio times the bag's bytes (the free 64 MiB set to 0 for 12x8 frames)
    before the episode's frames are allocated."""
    import imitation.limits

    def nothing(bag: BagWriter, t: int) -> None:
        return None

    bag = small_bag(tmp_path / "bag", [jpeg, nothing, nothing, jpeg, nothing, nothing])
    fast = write_map(tmp_path, {**SMALL_MAP, "rate_hz": 100})
    size = sum(f.stat().st_size for f in bag.iterdir())
    steps = 52  # 0.5 s of commands at 100 Hz, and one period past the last
    monkeypatch.setattr(imitation.limits, "FREE_EXPANSION_BYTES", 0)
    monkeypatch.setattr(imitation.limits.LIMITS, "image_expansion_ratio", steps * PIXELS.nbytes // size)
    with pytest.raises(ImitationError) as caught:
        convert(bag, tmp_path / "d.mcap", map_path=fast, progress=False)
    assert str(caught.value).startswith(
        f"{bag}: decoded bytes of its camera frames (from {size} bytes): {steps * PIXELS.nbytes} is more than the limit image_expansion_ratio="
    )
    assert not (tmp_path / "d.mcap").exists()
    monkeypatch.setattr(imitation.limits.LIMITS, "image_expansion_ratio", steps * PIXELS.nbytes // size + 1)
    assert convert(bag, tmp_path / "d.mcap", map_path=fast, progress=False)["transitions"] == steps - 1


def test_a_640x480_camera_bag_converts_and_trains_within_the_image_bounds(tmp_path: Path) -> None:
    """Real data is not refused by the bounds on decoded frames: a 640x480 JPEG camera at 30 Hz
    (rendered CartPole with a sensor's noise) for 2 s, resampled at 50 Hz (each frame held over
    one or two steps: 92 MB decoded from a 2.4 MB bag, past the free 64 MiB) and at 10 Hz, which
    `train bc` loads whole, frames decoded, and learns from (the state alone: the Nature CNN on
    640x480 frames holds 139M weights, minutes of CPU per epoch)."""
    frames, states, _ = cartpole_frames(60)
    rng = np.random.default_rng(4)
    with CameraBagWriter(tmp_path / "bag", "ros2 mcap") as bag:
        for i, frame in enumerate(frames):
            t = START_NS + i * NS // 30
            big = cv2.resize(frame, (640, 480), interpolation=cv2.INTER_LINEAR).astype(np.int16) + rng.normal(0, 3, (480, 640, 3)).astype(np.int16)
            bag.write("/camera/image_raw/compressed", t, bag.compressed(t, encoded(np.clip(big, 0, 255).astype(np.uint8)[..., ::-1], ".jpg"), "jpeg"))
            if i % 3 == 0:  # the state and the command at 10 Hz
                bag.write("/joint_states", t + 1_000_000, bag.joint_state(t + 1_000_000, states[i]))
                bag.write("/cmd", t + 2_000_000, bag.msg("std_msgs/msg/Float64", data=float(i % 2)))
    camera_map = {"observation": [{"topic": "/joint_states", "fields": ["position"]}, {"topic": "/camera/image_raw/compressed", "image": "front"}],
                  "action": [{"topic": "/cmd", "fields": ["data"]}]}
    held = convert(tmp_path / "bag", tmp_path / "held.mcap", map_path=write_map(tmp_path, {**camera_map, "rate_hz": 50}, "held.yaml"), progress=False)
    assert held["transitions"] == 99  # the 1.97 s from the first command to the last frame, at 50 Hz
    assert DemoFile(tmp_path / "held.mcap").observation_space["front"].shape == (480, 640, 3)
    results = run_cli_many([
        ["convert", tmp_path / "bag", "--map", write_map(tmp_path, {**camera_map, "rate_hz": 10}), "--out", tmp_path / "demos.mcap"],
        ["train", "bc", "--demos", tmp_path / "demos.mcap", "--observation-keys", "state", "--epochs", "1", "--quiet", "--out", tmp_path / "run"],
        ["info", tmp_path / "demos.mcap"],
    ])
    for result in results:
        assert result.returncode == 0, result.stderr[-2000:]
    assert (tmp_path / "run" / "model.safetensors").is_file()


def test_the_ros1_reader_checks_frames_too(tmp_path: Path) -> None:
    bag = small_bag(tmp_path / "cam.bag", [rgb, rgb, lambda b, t: b.image(t, PIXELS[:4], "rgb8")], kind="ros1")
    with pytest.raises(ImitationError, match="frame 2 .* resolution changes mid-bag"):
        convert(bag, tmp_path / "d.mcap", map_path=write_map(tmp_path, SMALL_MAP), progress=False)
    assert not (tmp_path / "d.mcap").exists()


@pytest.mark.parametrize(
    "entry, where, fragment",
    [
        ({"topic": "/camera", "image": "cam", "fields": ["data"]}, "observation", "takes no fields"),
        ({"topic": "/camera", "image": "cam", "default": 0}, "observation", "takes no default"),
        ({"topic": "/camera", "image": "cam", "align": "interpolate"}, "observation", "never interpolated"),
        ({"topic": "/camera", "image": "state"}, "observation", "not 'state'"),
        ({"topic": "/camera", "image": "a/b"}, "observation", "letters, digits"),
        ({"topic": "/camera", "image": "cam", "size": [480]}, "observation", "size must be [height, width]"),
        ({"topic": "/camera", "fields": ["x"], "size": [4, 4]}, "observation", "size is for image entries"),
        ({"topic": "/camera", "image": "cam"}, "action", "images are observations only"),
    ],
)
def test_malformed_image_entries(tmp_path: Path, entry: dict, where: str, fragment: str) -> None:
    raw = {"rate_hz": 10, "observation": [{"topic": "/odom", "fields": ["x"]}], "action": [{"topic": "/cmd", "fields": ["x"]}]}
    raw[where] = [entry]
    with pytest.raises(ImitationError, match=f"map.yaml: {where}\\[0\\] \\(/camera\\): .*{re.escape(fragment)}"):
        parse_map(raw, tmp_path / "map.yaml")


def test_two_cameras_cannot_share_a_key(tmp_path: Path) -> None:
    raw = {
        "rate_hz": 10,
        "observation": [{"topic": "/a", "image": "cam"}, {"topic": "/b", "image": "cam"}],
        "action": [{"topic": "/cmd", "fields": ["x"]}],
    }
    with pytest.raises(ImitationError, match=r"observation\[0\] \(/a\): image key 'cam' is taken"):
        parse_map(raw, tmp_path / "map.yaml")


GREY = np.arange(8 * 12, dtype=np.uint8).reshape(8, 12)
WIDE = GREY.astype(np.uint16) * 300 + 7  # over 8 bits


def raw(pixels: np.ndarray, encoding: str, *, big_endian: bool = False) -> SimpleNamespace:
    wire = pixels.astype(pixels.dtype.newbyteorder(">" if big_endian else "<")).reshape(pixels.shape[0], -1).view(np.uint8)
    return SimpleNamespace(
        height=pixels.shape[0],
        width=pixels.shape[1],
        encoding=encoding,
        is_bigendian=int(big_endian),
        step=wire.shape[1],
        data=wire.tobytes(),
    )


def compressed(pixels: np.ndarray, extension: str, format: str) -> SimpleNamespace:
    return SimpleNamespace(format=format, data=encoded(pixels, extension))


@pytest.mark.parametrize(
    "message, kind, expected",
    [
        (raw(np.dstack([PIXELS, np.full((8, 12), 255, np.uint8)]), "rgba8"), IMAGE, PIXELS),  # alpha dropped
        (raw(np.dstack([PIXELS[..., ::-1], np.full((8, 12), 255, np.uint8)]), "bgra8"), IMAGE, PIXELS),
        (raw(GREY[..., None], "8UC1"), IMAGE, GREY[..., None]),
        (raw(WIDE[..., None], "16UC1"), IMAGE, WIDE[..., None]),
        (raw(WIDE[..., None], "mono16", big_endian=True), IMAGE, WIDE[..., None]),
        (compressed(WIDE, ".png", "mono16; png compressed mono16"), COMPRESSED, WIDE[..., None]),  # 16-bit PNG stays 16-bit
        (compressed(GREY, ".png", "mono8; png compressed mono8"), COMPRESSED, GREY[..., None]),
        (compressed(PIXELS[..., ::-1], ".png", ""), COMPRESSED, PIXELS),  # no format: the bytes say PNG
    ],
    ids=["rgba8", "bgra8", "8UC1", "16UC1", "mono16 big-endian", "16-bit png", "mono png", "empty format"],
)
def test_encodings(message: SimpleNamespace, kind: str, expected: np.ndarray) -> None:
    frame = frame_of(message, kind)
    pixels = decode(frame)
    assert frame.shape == pixels.shape == expected.shape and pixels.dtype == expected.dtype == frame.dtype
    assert np.array_equal(pixels, expected)


def test_a_mono_jpeg_is_one_channel() -> None:
    pixels = decode(frame_of(compressed(GREY, ".jpg", "mono8; jpeg compressed mono8"), COMPRESSED))
    assert pixels.shape == (8, 12, 1) and pixels.dtype == np.uint8 and np.abs(pixels[..., 0].astype(int) - GREY).max() < 8


@pytest.mark.parametrize(
    "message, fragment",
    [
        (compressed(np.dstack([WIDE] * 3), ".png", "bgr16; png compressed bgr16"), "16-bit colour PNG is not supported"),
        (compressed(PIXELS, ".png", "jpeg"), "not a JPEG image (its bytes start 89 50 4e 47"),  # the format names the codec
        (compressed(PIXELS, ".png", "tiff"), "unknown format 'tiff'"),
        (
            SimpleNamespace(**{**vars(raw(PIXELS, "rgb8")), "step": 30}),
            "step 30 is shorter than a row of 12 rgb8 pixels (36 bytes)",
        ),
        (SimpleNamespace(**{**vars(raw(PIXELS, "rgb8")), "height": 0, "data": b""}), "an empty image (12x0)"),
    ],
    ids=["16-bit colour png", "codec mismatch", "tiff", "short step", "empty"],
)
def test_frames_that_cannot_be_arrays(message: SimpleNamespace, fragment: str) -> None:
    kind = COMPRESSED if hasattr(message, "format") else IMAGE
    with pytest.raises(ImageError, match=re.escape(fragment)):
        frame_of(message, kind)

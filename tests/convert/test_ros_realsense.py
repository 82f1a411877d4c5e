"""Issue 51, item 8: librealsense writes 4 bytes after a sensor_msgs/Image's `data` in ROS 1 bags,
which ROS 1's own tools ignore. The bags here are written by `rosbags`' ROS 1 writer from its own
serialiser's bytes, with 4 bytes appended to each camera message as librealsense does."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support import run_cli_many, write_map
from test_cli import assert_one_line_error
from test_ros_real_logs import BagWriter

from imitation.data.convert.job import convert, inspect
from imitation.data.mcap.reader import DemoFile

NS = 1_000_000_000
START_NS = 1_700_000_000 * NS
FRAMES = 6
HEIGHT, WIDTH = 48, 64
COLOR = "/device_0/sensor_1/Color_0/image/data"  # librealsense's topic names
DEPTH = "/device_0/sensor_0/Depth_0/image/data"
TRAILER = b"\x00\x00\x00\x00"


def realsense_bag(path: Path, *, trailer_on_twist: bool = False) -> dict[str, list[np.ndarray]]:
    """Colour (rgb8) and depth (16UC1) frames at 10 Hz, each with 4 bytes after its data, and a
    Twist command; returns the frames written."""
    rng = np.random.default_rng(8)
    written: dict[str, list[np.ndarray]] = {COLOR: [], DEPTH: []}
    with BagWriter(path, "ros1") as bag:
        bag.topic(COLOR, "sensor_msgs/msg/Image")
        bag.topic(DEPTH, "sensor_msgs/msg/Image")
        bag.topic("/cmd_vel", "geometry_msgs/msg/Twist")
        for i in range(FRAMES):
            t = START_NS + i * NS // 10
            color = rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8)
            depth = rng.integers(300, 4000, (HEIGHT, WIDTH), dtype=np.uint16)
            for topic, pixels, encoding, step in ((COLOR, color, "rgb8", WIDTH * 3), (DEPTH, depth, "16UC1", WIDTH * 2)):
                image = bag.msg("sensor_msgs/msg/Image", header=bag.header(t, "camera"), height=HEIGHT, width=WIDTH,
                                encoding=encoding, is_bigendian=0, step=step, data=np.frombuffer(pixels.tobytes(), dtype=np.uint8))
                raw = bytes(bag.store.serialize_ros1(image, "sensor_msgs/msg/Image")) + TRAILER
                bag.writer.write(bag.connections[topic], t, raw)
                written[topic].append(pixels)
            twist = bytes(bag.store.serialize_ros1(bag.twist(0.1 * i, 0.0), "geometry_msgs/msg/Twist"))
            bag.writer.write(bag.connections["/cmd_vel"], t + 1_000_000, twist + (TRAILER if trailer_on_twist else b""))
    return written


CAMERA_MAP = {
    "rate_hz": 10,
    "observation": [{"topic": COLOR, "image": "color"}, {"topic": DEPTH, "image": "depth"}],
    "action": [{"topic": "/cmd_vel", "fields": ["linear.x"], "default": 0}],
}


def test_rosbags_itself_refuses_the_extra_bytes(tmp_path: Path) -> None:
    """The case: rosbags' own reader refuses every camera message of such a bag."""
    from rosbags.highlevel import AnyReader, AnyReaderError

    realsense_bag(tmp_path / "rs.bag")
    with AnyReader([tmp_path / "rs.bag"]) as reader:
        connection, _, raw = next(reader.messages([c for c in reader.connections if c.topic == COLOR]))
        with pytest.raises(AnyReaderError, match="ROS1 message size mismatch"):
            reader.deserialize(raw, connection.msgtype)


def test_realsense_cameras_read_as_ros1_reads_them(tmp_path: Path) -> None:
    bag = tmp_path / "rs.bag"
    written = realsense_bag(bag)
    report = inspect(bag)
    # Before: both cameras "cannot decode" (ROS1 message size mismatch) and were skipped.
    assert all(t["problem"] is None for t in report["topics"]), report["topics"]
    assert sorted(report["warnings"]) == [
        f"{bag}: {topic}: messages carry 4 bytes after a complete sensor_msgs/msg/Image (librealsense writes 4 after an "
        "Image's data); read without them, as ROS 1's tools do" for topic in sorted((COLOR, DEPTH))
    ]
    result = convert(bag, tmp_path / "rs.mcap", map_path=write_map(tmp_path, CAMERA_MAP), progress=False)
    assert len([w for w in result["warnings"] if "4 bytes after a complete" in w]) == 2
    episode = DemoFile(tmp_path / "rs.mcap")[0]
    assert len(episode) == FRAMES  # frames 0…5 at 10 Hz, and one step past the last
    for step in range(FRAMES):
        assert np.array_equal(episode.observations["color"][step], written[COLOR][step])
        assert np.array_equal(episode.observations["depth"][step][..., 0], written[DEPTH][step])
    assert episode.observations["depth"].dtype == np.uint16


def test_extra_bytes_stay_refused_where_rosbags_would_misread(tmp_path: Path) -> None:
    """A Twist does not end with a byte array: bytes after it are damage, as rosbags says; an
    Image cut short is refused whatever follows."""
    realsense_bag(tmp_path / "twist.bag", trailer_on_twist=True)
    short = tmp_path / "short.bag"
    with BagWriter(short, "ros1") as bag:
        bag.topic(COLOR, "sensor_msgs/msg/Image")
        bag.topic("/cmd_vel", "geometry_msgs/msg/Twist")
        image = bag.msg("sensor_msgs/msg/Image", header=bag.header(START_NS, "camera"), height=2, width=2, encoding="rgb8",
                        is_bigendian=0, step=6, data=np.zeros(12, dtype=np.uint8))
        raw = bytes(bag.store.serialize_ros1(image, "sensor_msgs/msg/Image"))
        bag.writer.write(bag.connections[COLOR], START_NS, raw[:-5])  # the data's length says 12; 7 bytes follow
        bag.write("/cmd_vel", START_NS, bag.twist(0.0, 0.0))
    twist_map = {**CAMERA_MAP, "action": [{"topic": "/cmd_vel", "fields": ["linear.x"]}]}
    short_map = {**CAMERA_MAP, "observation": [{"topic": COLOR, "image": "color"}]}
    twist, cut = run_cli_many([
        ["convert", tmp_path / "twist.bag", "--map", write_map(tmp_path, twist_map, "twist.yaml"), "--out", tmp_path / "t.mcap"],
        ["convert", short, "--map", write_map(tmp_path, short_map, "short.yaml"), "--out", tmp_path / "s.mcap"],
    ])
    assert_one_line_error(twist, "action[0]: topic /cmd_vel cannot be read: its messages do not decode as "
                          "geometry_msgs/msg/Twist (SerdeError: ROS1 message size mismatch")
    assert_one_line_error(cut, f"observation[0]: topic {COLOR} cannot be read: its messages do not decode as sensor_msgs/msg/Image")
    assert not list(tmp_path.glob("*.mcap*"))

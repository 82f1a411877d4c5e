"""Issue 17, "Real robot logs, right the first time": float64 fields keep their precision, and the
starter map guesses from message types and rates. Bags here are written by the `rosbags`
library's own writers (ROS 2 MCAP, rosbag2 sqlite, ROS 1), the real bags in ../shared/testdata
are read as they are."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from support import TURTLE_MAP, write_map

from imitation.data.convert.inspect import format_report
from imitation.data.convert.job import convert, inspect
from imitation.data.mcap.reader import DemoFile

NS = 1_000_000_000
START_NS = 1_700_000_000 * NS  # an epoch time, as a real log has
LATITUDE, LONGITUDE = 48.1371234567, 11.5753822234  # Munich, to ten decimals


def _typestore(ros1: bool) -> Any:
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in store.fielddefs:
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    return store


class BagWriter:
    """Topics and messages → a bag, through rosbags' own writers and serialisers."""

    def __init__(self, path: Path, kind: str) -> None:
        from rosbags.rosbag1 import Writer as Writer1
        from rosbags.rosbag2 import StoragePlugin
        from rosbags.rosbag2 import Writer as Writer2

        self.ros1 = kind == "ros1"
        self.store = _typestore(self.ros1)
        if self.ros1:
            self.writer: Any = Writer1(path)
        else:
            plugin = StoragePlugin.MCAP if kind == "ros2 mcap" else StoragePlugin.SQLITE3
            self.writer = Writer2(path, version=9, storage_plugin=plugin)
        self.connections: dict[str, Any] = {}

    def __enter__(self) -> BagWriter:
        self.writer.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.writer.close()

    def topic(self, topic: str, msgtype: str, *, latched: bool = False) -> None:
        if self.ros1:
            self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store, latching=int(latched))
            return
        from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

        never = QosTime(sec=0, nsec=0)
        durability = QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE
        qos = Qos(QosHistory.KEEP_LAST, 10, QosReliability.RELIABLE, durability, never, never, QosLiveliness.AUTOMATIC, never, False)
        self.connections[topic] = self.writer.add_connection(topic, msgtype, typestore=self.store, offered_qos_profiles=[qos])

    def write(self, topic: str, time_ns: int, message: Any) -> None:
        connection = self.connections[topic]
        serialise = self.store.serialize_ros1 if self.ros1 else self.store.serialize_cdr
        self.writer.write(connection, time_ns, serialise(message, connection.msgtype))

    # Messages, built with the typestore's own classes.
    def msg(self, msgtype: str, **values: Any) -> Any:
        return self.store.types[msgtype](**values)

    def header(self, time_ns: int, frame: str = "base_link") -> Any:
        stamp = self.msg("builtin_interfaces/msg/Time", sec=time_ns // NS, nanosec=time_ns % NS)
        if self.ros1:
            return self.msg("std_msgs/msg/Header", seq=0, stamp=stamp, frame_id=frame)
        return self.msg("std_msgs/msg/Header", stamp=stamp, frame_id=frame)

    def vector(self, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> Any:
        return self.msg("geometry_msgs/msg/Vector3", x=x, y=y, z=z)

    def twist(self, linear_x: float, angular_z: float) -> Any:
        return self.msg("geometry_msgs/msg/Twist", linear=self.vector(linear_x), angular=self.vector(z=angular_z))

    def pose(self, x: float = 0.0, y: float = 0.0) -> Any:
        return self.msg(
            "geometry_msgs/msg/Pose",
            position=self.msg("geometry_msgs/msg/Point", x=x, y=y, z=0.0),
            orientation=self.msg("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0),
        )

    def navsatfix(self, time_ns: int, latitude: float, longitude: float, altitude: float) -> Any:
        return self.msg(
            "sensor_msgs/msg/NavSatFix",
            header=self.header(time_ns, "gps"),
            status=self.msg("sensor_msgs/msg/NavSatStatus", status=0, service=1),
            latitude=latitude,
            longitude=longitude,
            altitude=altitude,
            position_covariance=np.full(9, 0.25),
            position_covariance_type=2,
        )


def gps_bag(path: Path, kind: str, seconds: float = 100.0) -> dict[str, np.ndarray]:
    """A velocity command (Twist) and the GPS fix (NavSatFix) of a vehicle driving it at about
    1 m/s, both at 10 Hz: 10 cm a step, finer than float32 resolves at 48° N (0.42 m in
    latitude). Returns what was written."""
    rng = np.random.default_rng(17)
    count = round(seconds * 10)
    speed = 1.0 + 0.1 * np.sin(np.arange(count) / 7.0) + rng.normal(0.0, 1e-3, count)  # m/s
    turn = 0.05 * np.cos(np.arange(count) / 11.0)  # rad/s
    heading = 0.3 + np.cumsum(turn) * 0.1
    north = np.cumsum(speed * np.cos(heading)) * 0.1 + rng.normal(0.0, 0.01, count)  # m, with 1 cm of noise
    east = np.cumsum(speed * np.sin(heading)) * 0.1 + rng.normal(0.0, 0.01, count)
    latitude = LATITUDE + north / 111_320.0
    longitude = LONGITUDE + east / (111_320.0 * math.cos(math.radians(LATITUDE)))
    altitude = 519.123456789 + np.cumsum(rng.normal(0.0, 0.01, count))
    fix_times = START_NS + np.arange(count, dtype=np.int64) * (NS // 10)
    command_times = fix_times + 5_000_000  # 5 ms after each fix
    with BagWriter(path, kind) as bag:
        bag.topic("/gps/fix", "sensor_msgs/msg/NavSatFix")
        bag.topic("/cmd_vel", "geometry_msgs/msg/Twist")
        for i in range(count):
            bag.write("/gps/fix", int(fix_times[i]), bag.navsatfix(int(fix_times[i]), latitude[i], longitude[i], altitude[i]))
            bag.write("/cmd_vel", int(command_times[i]), bag.twist(speed[i], turn[i]))
    return {"fix_times": fix_times, "latitude": latitude, "longitude": longitude, "altitude": altitude,
            "command_times": command_times, "speed": speed, "turn": turn}


GPS_MAP = {
    "rate_hz": 10,
    "observation": [{"topic": "/gps/fix", "fields": ["latitude", "longitude", "altitude"]}],
    "action": [{"topic": "/cmd_vel", "fields": ["linear.x", "angular.z"]}],
}


def hold_values(times: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """The last value at or before each grid time (what `align: hold` must give)."""
    return values[np.searchsorted(times, grid, side="right") - 1]


# 1. float64 fields stay float64 -------------------------------------------------------------

BAG_KINDS = [("ros2 mcap", "gps_mcap", "ros2"), ("sqlite", "gps_sqlite", "ros2"), ("ros1", "gps.bag", "ros1")]


@pytest.mark.parametrize(("kind", "name", "source"), BAG_KINDS, ids=[k[0] for k in BAG_KINDS])
def test_navsatfix_latitudes_come_back_bit_exact(tmp_path: Path, kind: str, name: str, source: str) -> None:
    written = gps_bag(tmp_path / name, kind)
    # The premise: float32 keeps a quarter of these latitudes, 0.21 m apart at worst.
    rounded = written["latitude"].astype(np.float32).astype(np.float64)
    assert len(np.unique(written["latitude"])) == 1000 and len(np.unique(rounded)) < 300
    assert np.max(np.abs(rounded - written["latitude"])) * 111_320 > 0.2

    out = tmp_path / "gps.mcap"
    result = convert(tmp_path / name, out, source=source, map_path=write_map(tmp_path, GPS_MAP), progress=False)
    assert result["observation_space"] == "Box(float64, (3,))" and result["action_space"] == "Box(float64, (2,))"
    demo = DemoFile(out)
    assert demo.observation_space.dtype == np.float64 and demo.action_space.dtype == np.float64
    episode = demo[0]
    assert episode.observations.dtype == np.float64 and episode.actions.dtype == np.float64
    assert len(episode) == 1000  # the grid starts at the first command, 5 ms after the first fix
    grid = np.asarray(episode.timestamps)
    for column, key in enumerate(["latitude", "longitude", "altitude"]):
        expected = hold_values(written["fix_times"], written[key], grid)
        assert np.array_equal(episode.observations[:, column], expected), key  # bit for bit
    assert len(np.unique(episode.observations[:, 0])) == 1000
    for column, key in enumerate(["speed", "turn"]):
        assert np.array_equal(episode.actions[:, column], hold_values(written["command_times"], written[key], grid[:-1]))


def test_declared_types_decide_each_fields_dtype(testdata: Path) -> None:
    """Read from the bags' own definitions, for each reader: ROS 2 MCAP (test_msgs' every
    primitive), ROS 1 and rosbag2 sqlite."""
    from imitation.data.convert.bags import open_bag
    from imitation.data.convert.fields import value_dtype

    bag = open_bag(testdata / "ros2/rosbag2_tests/cdr_test", "ros2")
    try:
        declared = {name: bag.field_type("/test_topic", f"{name}_value") for name in
                    ["bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64"]}
        assert declared == {name: name for name in declared}
        assert bag.field_type("/array_topic", "float32_values") == "float32"
        assert bag.field_type("/array_topic", "basic_types_values[0].float64_value") == "float64"
        assert bag.field_type("/array_topic", "string_values") == "string" and bag.field_type("/array_topic", "nothing") is None
    finally:
        bag.close()
    narrow = {"bool", "byte", "char", "float32", "int8", "uint8", "int16", "uint16"}
    assert {name for name in declared if value_dtype(name) == np.float32} == narrow
    assert value_dtype(None) == np.float64  # a field of unknown type is never narrowed

    turtle = open_bag(testdata / "ros1/plotjuggler_example.bag", "ros1")
    assert turtle.field_type("/turtle1/pose", "theta") == "float32" and turtle.field_type("/turtle1/cmd_vel", "angular.z") == "float64"
    turtle.close()
    sqlite = open_bag(testdata / "ros1/plotjuggler_rosbag2_sqlite", "ros2")
    assert sqlite.field_type("/battery", "voltage") == "float32" and sqlite.field_type("/imu", "orientation.x") == "float64"
    assert sqlite.field_type("/battery", "cell_voltage") == "float32" and sqlite.field_type("/imu", "header.stamp.sec") == "int32"
    sqlite.close()


def test_float32_fields_stay_float32_and_a_mix_gives_float64(testdata: Path, tmp_path: Path) -> None:
    bag = testdata / "ros1/plotjuggler_rosbag2_sqlite"
    battery = {"rate_hz": 25, "observation": [{"topic": "/battery", "fields": ["voltage", "current"]}],
               "action": [{"topic": "/battery", "fields": ["percentage"]}]}
    result = convert(bag, tmp_path / "f32.mcap", map_path=write_map(tmp_path, battery, "f32.yaml"), progress=False)
    assert result["observation_space"] == "Box(float32, (2,))" and result["action_space"] == "Box(float32, (1,))"
    mixed = {**battery, "observation": [*battery["observation"], {"topic": "/imu", "fields": ["orientation.x"]}]}
    result = convert(bag, tmp_path / "mix.mcap", map_path=write_map(tmp_path, mixed, "mix.yaml"), progress=False)
    assert result["observation_space"] == "Box(float64, (3,))" and result["action_space"] == "Box(float32, (1,))"
    narrow, wide = DemoFile(tmp_path / "f32.mcap")[0], DemoFile(tmp_path / "mix.mcap")[0]
    # The float32 voltages sit unchanged in the float64 space, and match the float32 file's.
    assert np.array_equal(wide.observations[:, :2].astype(np.float32), wide.observations[:, :2])
    assert np.array_equal(narrow.observations, wide.observations[:, :2]) and np.array_equal(narrow.actions, wide.actions)
    assert np.any(wide.observations[:, 2].astype(np.float32) != wide.observations[:, 2])  # the Imu's float64 kept


def test_turtlesim_pose_stays_float32(testdata: Path, tmp_path: Path) -> None:
    """The existing conversion, as before for its float32 fields: turtlesim/Pose is float32, the
    Twist command float64 (it used to be narrowed to float32 too)."""
    from rosbags.highlevel import AnyReader

    bag = testdata / "ros1/plotjuggler_example.bag"
    result = convert(bag, tmp_path / "t.mcap", map_path=write_map(tmp_path, TURTLE_MAP), progress=False)
    assert result["observation_space"] == "Box(float32, (5,))" and result["action_space"] == "Box(float64, (2,))"
    episode = DemoFile(tmp_path / "t.mcap")[0]
    with AnyReader([bag]) as reader:
        poses = [(t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages([c for c in reader.connections if c.topic == "/turtle1/pose"])]
    times = np.array([t for t, _ in poses])
    x = np.array([p.x for _, p in poses], dtype=np.float32)
    assert episode.observations.dtype == np.float32 and np.array_equal(episode.observations[:, 0], hold_values(times, x, np.asarray(episode.timestamps)))


# 2. The starter map guesses from types and rates ------------------------------------------------

TRANSFORMS = 120  # /tf_static: one latched message with a robot's worth of fixed frames


def husky_bag(path: Path, kind: str, *, cmd_vel: bool, seconds: float = 10.0) -> None:
    """The reported case: odometry from a topic whose name says "controller", an IMU, a single
    /initialpose, a latched /tf_static with many transforms, and (or not) a /cmd_vel command."""
    with BagWriter(path, kind) as bag:
        bag.topic("/tf_static", "tf2_msgs/msg/TFMessage", latched=True)
        bag.topic("/initialpose", "geometry_msgs/msg/PoseWithCovarianceStamped")
        bag.topic("/husky_velocity_controller/odom", "nav_msgs/msg/Odometry")
        bag.topic("/imu/data", "sensor_msgs/msg/Imu")
        if cmd_vel:
            bag.topic("/cmd_vel", "geometry_msgs/msg/Twist")
        identity = bag.msg("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0)
        transforms = [
            bag.msg("geometry_msgs/msg/TransformStamped", header=bag.header(START_NS, "base_link"), child_frame_id=f"link_{i}",
                    transform=bag.msg("geometry_msgs/msg/Transform", translation=bag.vector(0.01 * i), rotation=identity))
            for i in range(TRANSFORMS)
        ]
        bag.write("/tf_static", START_NS, bag.msg("tf2_msgs/msg/TFMessage", transforms=transforms))
        covariance = bag.msg("geometry_msgs/msg/PoseWithCovariance", pose=bag.pose(1.0, 2.0), covariance=np.zeros(36))
        bag.write("/initialpose", START_NS + NS // 2,
                  bag.msg("geometry_msgs/msg/PoseWithCovarianceStamped", header=bag.header(START_NS, "map"), pose=covariance))
        events = [(START_NS + i * NS // 100, "/imu/data") for i in range(round(seconds * 100))]
        events += [(START_NS + i * NS // 50 + 1_000_000, "/husky_velocity_controller/odom") for i in range(round(seconds * 50))]
        if cmd_vel:
            events += [(START_NS + i * NS // 20 + 3_000_000, "/cmd_vel") for i in range(round(seconds * 20))]
        for time_ns, topic in sorted(events):
            t = (time_ns - START_NS) / NS
            if topic == "/imu/data":
                message = bag.msg(
                    "sensor_msgs/msg/Imu", header=bag.header(time_ns, "imu_link"), orientation=identity,
                    orientation_covariance=np.zeros(9), angular_velocity=bag.vector(z=0.1 * math.sin(t)),
                    angular_velocity_covariance=np.zeros(9), linear_acceleration=bag.vector(z=9.81),
                    linear_acceleration_covariance=np.zeros(9))
            elif topic == "/cmd_vel":
                message = bag.twist(0.5, 0.1 * math.sin(t))
            else:
                twist = bag.msg("geometry_msgs/msg/TwistWithCovariance", twist=bag.twist(0.5, 0.1), covariance=np.zeros(36))
                pose = bag.msg("geometry_msgs/msg/PoseWithCovariance", pose=bag.pose(0.5 * t), covariance=np.zeros(36))
                message = bag.msg("nav_msgs/msg/Odometry", header=bag.header(time_ns, "odom"), child_frame_id="base_link",
                                  pose=pose, twist=twist)
            bag.write(topic, time_ns, message)


def starter(tmp_path: Path, bag: Path, name: str = "starter.yaml") -> tuple[dict[str, Any], dict[str, Any], str]:
    report = inspect(bag, write_map=tmp_path / name)
    text = (tmp_path / name).read_text()
    return report, yaml.safe_load(text), text


HUSKY_KINDS = [("ros2 mcap", "husky", True), ("ros2 mcap", "husky", False), ("ros1", "husky.bag", True), ("ros1", "husky.bag", False)]


@pytest.mark.parametrize(("kind", "name", "cmd_vel"), HUSKY_KINDS, ids=[f"{k}-{'cmd_vel' if c else 'no-command'}" for k, _, c in HUSKY_KINDS])
def test_husky_starter_map(tmp_path: Path, kind: str, name: str, cmd_vel: bool) -> None:
    bag = tmp_path / name
    husky_bag(bag, kind, cmd_vel=cmd_vel)
    report, chosen, text = starter(tmp_path, bag)
    observation = [e["topic"] for e in chosen["observation"]]
    action = [e["topic"] for e in chosen["action"]]
    # Odometry is an observation whatever its topic says; the IMU too; nothing one-shot or latched.
    assert observation == ["/husky_velocity_controller/odom", "/imu/data"]
    assert action == (["/cmd_vel"] if cmd_vel else [])
    assert chosen["rate_hz"] == (20 if cmd_vel else 50)  # the command's rate; without one, the odometry's (the slowest observation)
    roles = {e["topic"]: (e["role"], e["note"]) for e in report["topics"]}
    assert roles["/initialpose"] == (None, "one-shot: 1 message") and roles["/tf_static"] == (None, "transforms")
    assert next(e for e in report["topics"] if e["topic"] == "/tf_static")["latched"]
    odom = chosen["observation"][0]["fields"]
    assert odom == ["pose.pose.position.x", "pose.pose.position.y", "pose.pose.position.z", "pose.pose.orientation.x",
                    "pose.pose.orientation.y", "pose.pose.orientation.z", "pose.pose.orientation.w",
                    "twist.twist.linear.x", "twist.twist.linear.y", "twist.twist.linear.z",
                    "twist.twist.angular.x", "twist.twist.angular.y", "twist.twist.angular.z"]
    if not cmd_vel:
        assert "No command topic was found" in text
        return
    assert chosen["action"][0]["fields"] == ["linear.x", "linear.y", "linear.z", "angular.x", "angular.y", "angular.z"]
    # The starter converts as written: 13 odometry values and 10 IMU values, float64 as declared.
    result = convert(bag, tmp_path / "husky.mcap", map_path=tmp_path / "starter.yaml", progress=False)
    assert result["observation_space"] == "Box(float64, (23,))" and result["action_space"] == "Box(float64, (6,))"
    # From the first odometry (1 ms in; the command has a default) to the last IMU message (9.99 s), at the command's 20 Hz.
    assert result["transitions"] == math.floor((9.99 - 0.001) * 20) + 1 == 200


@pytest.mark.parametrize("kind", ["ros2 mcap", "ros1"])
def test_the_listing_summarises_tf_static(tmp_path: Path, kind: str) -> None:
    bag = tmp_path / ("husky.bag" if kind == "ros1" else "husky")
    husky_bag(bag, kind, cmd_vel=True, seconds=2.0)
    report, _, text = starter(tmp_path, bag)
    listing = format_report(report)
    lines = listing.splitlines()
    # Five topics: a heading each and a few wrapped field lines, not 120 transforms' worth.
    assert len(lines) <= 30 and max(len(line) for line in lines) <= 140 and len(listing) < 3000, listing
    assert listing.count("transforms[") <= 1 and text.count("transforms[") <= 1
    tf_static = lines.index(next(line for line in lines if line.lstrip().startswith("/tf_static")))
    assert "left out: transforms" in lines[tf_static] and "latched" in lines[tf_static]
    assert "not listed" in lines[tf_static + 1] and f"transforms holds {TRANSFORMS}" in lines[tf_static + 1]
    # --json lists the first transform's fields once, with the array's length.
    entry = next(e for e in report["topics"] if e["topic"] == "/tf_static")
    assert entry["arrays"] == [{"field": "transforms", "length": TRANSFORMS}]
    assert 0 < len(entry["fields"]) <= 12 and all(f["field"].startswith("transforms[0].") for f in entry["fields"])
    assert "step at 20 Hz (the command stream, /cmd_vel)" in listing
    assert len(text.splitlines()) <= 50  # the starter map: its commented listing and the entries, velocity commands with their max_age


def test_turtlesim_starter_map(testdata: Path, tmp_path: Path) -> None:
    bag = testdata / "ros1/plotjuggler_example.bag"
    report, chosen, _ = starter(tmp_path, bag)
    action = {e["topic"]: e["fields"] for e in chosen["action"]}
    observation = {e["topic"]: e["fields"] for e in chosen["observation"]}
    assert set(action) == {"/turtle1/cmd_vel", "/turtle2/cmd_vel"}  # the teleop and the follower's commands
    assert action["/turtle1/cmd_vel"] == ["linear.x", "linear.y", "linear.z", "angular.x", "angular.y", "angular.z"]
    assert set(observation) == {"/turtle1/pose", "/turtle2/pose", "/turtle1/color_sensor", "/turtle2/color_sensor"}
    assert observation["/turtle1/pose"] == ["x", "y", "theta", "linear_velocity", "angular_velocity"]
    # The fastest command's average rate: the keyboard teleop's (bursts of about 33 Hz); the follower's is 10 Hz.
    assert chosen["rate_hz"] == 21.4 and report["starter"]["rate_why"] == "the fastest command stream"
    left_out = {e["topic"]: e["note"] for e in report["topics"] if e["role"] is None}
    assert left_out == {"/rosout": "log", "/tf": "transforms", "/tf_static": "transforms"}
    convert(bag, tmp_path / "t.mcap", map_path=tmp_path / "starter.yaml", progress=False)
    demo = DemoFile(tmp_path / "t.mcap")
    assert demo.observation_space.shape == (16,) and demo.action_space.shape == (12,) and demo.dt == pytest.approx(1 / 21.4)


def test_rosbag2_sqlite_starter_map(testdata: Path, tmp_path: Path) -> None:
    report, chosen, text = starter(tmp_path, testdata / "ros1/plotjuggler_rosbag2_sqlite")
    assert [e["topic"] for e in chosen["observation"]] == ["/imu", "/battery", "/pose"] and chosen["action"] == []
    assert chosen["rate_hz"] == 25 and "No command topic was found" in text
    imu = chosen["observation"][0]["fields"]
    assert imu == ["orientation.x", "orientation.y", "orientation.z", "orientation.w", "angular_velocity.x", "angular_velocity.y",
                   "angular_velocity.z", "linear_acceleration.x", "linear_acceleration.y", "linear_acceleration.z"]
    assert "cell_temperature" not in chosen["observation"][1]["fields"]  # empty in the first message: it would not convert
    assert {e["topic"]: e["note"] for e in report["topics"] if e["role"] is None} == {"/parameter_events": "no messages", "/rosout": "no messages"}


@pytest.mark.parametrize(("relative", "observation", "action", "rate"), [
    ("ros2/replay_testing/cmd_vel_only_2.mcap", [], ["/scaled/cmd_vel", "/vehicle/cmd_vel"], 50),
    ("ros2/rosbag2parquet/array_msgs", ["/one_shot/imu", "/one_shot/joint_state"], [], 10),  # single messages: kept, nothing else
    ("ros2/rosbag2parquet/base_msgs", ["/one_shot/vector3"], ["/one_shot/twist"], 10),  # a Twist is a command by type
    ("ros2/rosbag2_tests/talker", [], [], 10),  # a String and the log: nothing to learn from
    ("ros2/rosbag2_tests/cdr_test", ["/test_topic", "/array_topic"], [], 20),  # 19.93 Hz measured
])
def test_ros2_starter_maps(testdata: Path, tmp_path: Path, relative: str, observation: list[str], action: list[str], rate: float) -> None:
    _, chosen, _ = starter(tmp_path, testdata / relative)
    assert [e["topic"] for e in chosen["observation"]] == observation
    assert [e["topic"] for e in chosen["action"]] == action and chosen["rate_hz"] == rate


def test_joint_commands_and_trajectories_are_the_action(tmp_path: Path) -> None:
    """JointState is the observation on /joint_states and the action on /joint_commands; a
    JointTrajectory is a command whatever its topic; a joystick behind them is left out."""
    joints = [f"joint_{i}" for i in range(7)]
    with BagWriter(tmp_path / "arm", "ros2 mcap") as bag:
        bag.topic("/joint_states", "sensor_msgs/msg/JointState")
        bag.topic("/joint_commands", "sensor_msgs/msg/JointState")
        bag.topic("/arm_controller/follow", "trajectory_msgs/msg/JointTrajectory")
        bag.topic("/joy", "sensor_msgs/msg/Joy")
        events = [(START_NS + i * NS // 100, "/joint_states") for i in range(300)]
        events += [(START_NS + i * NS // 50 + 1_000_000, "/joint_commands") for i in range(150)]
        events += [(START_NS + i * NS // 10 + 2_000_000, "/arm_controller/follow") for i in range(30)]
        events += [(START_NS + i * NS // 20 + 3_000_000, "/joy") for i in range(60)]
        for time_ns, topic in sorted(events):
            angles = np.full(7, math.sin((time_ns - START_NS) / NS))
            if topic == "/arm_controller/follow":
                point = bag.msg("trajectory_msgs/msg/JointTrajectoryPoint", positions=angles, velocities=np.zeros(7),
                                accelerations=np.zeros(0), effort=np.zeros(0),
                                time_from_start=bag.msg("builtin_interfaces/msg/Duration", sec=0, nanosec=100_000_000))
                message = bag.msg("trajectory_msgs/msg/JointTrajectory", header=bag.header(time_ns), joint_names=joints, points=[point])
            elif topic == "/joy":
                message = bag.msg("sensor_msgs/msg/Joy", header=bag.header(time_ns), axes=np.zeros(4, dtype=np.float32),
                                  buttons=np.zeros(8, dtype=np.int32))
            else:
                message = bag.msg("sensor_msgs/msg/JointState", header=bag.header(time_ns), name=joints, position=angles,
                                  velocity=np.zeros(7), effort=np.zeros(7))
            bag.write(topic, time_ns, message)
    report, chosen, _ = starter(tmp_path, tmp_path / "arm")
    assert {e["topic"]: e["fields"] for e in chosen["observation"]} == {"/joint_states": ["position", "velocity", "effort"]}
    assert {e["topic"]: e["fields"] for e in chosen["action"]} == {
        "/joint_commands": ["position", "velocity", "effort"],
        "/arm_controller/follow": ["points[0].positions", "points[0].velocities"],  # empty arrays and times left out
    }
    assert chosen["rate_hz"] == 50  # /joint_commands', the fastest command (the trajectory comes at 10 Hz)
    assert next(e for e in report["topics"] if e["topic"] == "/joy")["note"] == "joystick input behind the command topic"
    result = convert(tmp_path / "arm", tmp_path / "arm.mcap", map_path=tmp_path / "starter.yaml", progress=False)
    assert result["observation_space"] == "Box(float64, (21,))" and result["action_space"] == "Box(float64, (35,))"

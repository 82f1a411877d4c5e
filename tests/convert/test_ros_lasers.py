"""Issue 51, items 3 and 5: laser scans, whose beams with no return are +inf (REP 117), and the
starter map of a TurtleBot3-like drive (a 20 Hz command, a 5 Hz laser, AMCL's pose at 0.62 Hz).
Bags are written by `rosbags`' own writers and serialisers (ROS 1 and ROS 2 MCAP)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from support import run_cli_many, write_map
from test_cli import assert_one_line_error
from test_ros_real_logs import BagWriter, starter

from imitation.data.convert.job import convert
from imitation.data.mcap.reader import DemoFile

NS = 1_000_000_000
START_NS = 1_700_000_000 * NS
SECONDS = 69  # the reported drive
BEAMS = 360  # an LDS-01's
RANGE_MIN, RANGE_MAX = 0.12, 3.5
OPEN = slice(150, 211)  # beams through an open door: no return, +inf
TOO_CLOSE = (7, 3)  # (scan, beam): a return closer than range_min, -inf
INVALID = (11, 40)  # (scan, beam): an invalid reading, NaN
AMCL_HZ = 0.62
KINDS = [("ros1", "tb3.bag"), ("ros2 mcap", "tb3")]


def scan_ranges(k: int) -> np.ndarray:
    """The k-th scan's ranges: walls at 0.5 to 2.5 m, the door's beams +inf, two odd beams."""
    angles = np.linspace(-math.pi, math.pi, BEAMS, endpoint=False)
    ranges = (1.5 + np.sin(angles + 0.05 * k)).astype(np.float32)
    ranges[OPEN] = np.inf
    if k == TOO_CLOSE[0]:
        ranges[TOO_CLOSE[1]] = -np.inf
    if k == INVALID[0]:
        ranges[INVALID[1]] = np.nan
    return ranges


def turtlebot_bag(path: Path, kind: str) -> dict[str, np.ndarray]:
    """A 69 s drive: /cmd_vel (Twist) at 20 Hz, /odom at 30 Hz, /scan (LaserScan, 360 beams) at
    5 Hz, /amcl_pose at 0.62 Hz from 1 s on, /tf at 10 Hz. Returns the scans' log times."""
    events = [(START_NS + i * NS // 20 + 2_000_000, "/cmd_vel") for i in range(SECONDS * 20)]
    events += [(START_NS + i * NS // 30, "/odom") for i in range(SECONDS * 30)]
    events += [(START_NS + i * NS // 5 + 1_000_000, "/scan") for i in range(SECONDS * 5)]
    events += [(START_NS + NS + round(i * NS / AMCL_HZ), "/amcl_pose") for i in range(43)]
    events += [(START_NS + i * NS // 10 + 3_000_000, "/tf") for i in range(SECONDS * 10)]
    scans = []
    with BagWriter(path, kind) as bag:
        for topic, msgtype in [("/cmd_vel", "geometry_msgs/msg/Twist"), ("/odom", "nav_msgs/msg/Odometry"),
                               ("/scan", "sensor_msgs/msg/LaserScan"), ("/amcl_pose", "geometry_msgs/msg/PoseWithCovarianceStamped"),
                               ("/tf", "tf2_msgs/msg/TFMessage")]:
            bag.topic(topic, msgtype)
        identity = bag.msg("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0)
        for time_ns, topic in sorted(events):
            t = (time_ns - START_NS) / NS
            if topic == "/cmd_vel":
                message = bag.twist(0.2, 0.3 * math.sin(t / 5))
            elif topic == "/odom":
                message = bag.msg(
                    "nav_msgs/msg/Odometry", header=bag.header(time_ns, "odom"), child_frame_id="base_footprint",
                    pose=bag.msg("geometry_msgs/msg/PoseWithCovariance", pose=bag.pose(0.2 * t), covariance=np.zeros(36)),
                    twist=bag.msg("geometry_msgs/msg/TwistWithCovariance", twist=bag.twist(0.2, 0.0), covariance=np.zeros(36)))
            elif topic == "/scan":
                message = laser(bag, time_ns, scan_ranges(len(scans)))
                scans.append(time_ns)
            elif topic == "/amcl_pose":
                pose = bag.msg("geometry_msgs/msg/PoseWithCovariance", pose=bag.pose(0.2 * t), covariance=np.zeros(36))
                message = bag.msg("geometry_msgs/msg/PoseWithCovarianceStamped", header=bag.header(time_ns, "map"), pose=pose)
            else:
                transform = bag.msg("geometry_msgs/msg/TransformStamped", header=bag.header(time_ns, "odom"), child_frame_id="base_footprint",
                                    transform=bag.msg("geometry_msgs/msg/Transform", translation=bag.vector(0.2 * t), rotation=identity))
                message = bag.msg("tf2_msgs/msg/TFMessage", transforms=[transform])
            bag.write(topic, time_ns, message)
    return {"scans": np.asarray(scans, dtype=np.int64)}


def laser(bag: BagWriter, time_ns: int, ranges: np.ndarray, *, range_max: float = RANGE_MAX) -> Any:
    return bag.msg(
        "sensor_msgs/msg/LaserScan", header=bag.header(time_ns, "base_scan"), angle_min=-math.pi, angle_max=math.pi,
        angle_increment=2 * math.pi / BEAMS, time_increment=0.0, scan_time=0.2, range_min=RANGE_MIN, range_max=range_max,
        ranges=ranges, intensities=np.zeros(0, dtype=np.float32))


@pytest.fixture(scope="module", params=KINDS, ids=[kind for kind, _ in KINDS])
def tb3(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, np.ndarray]]:
    kind, name = request.param
    path = tmp_path_factory.mktemp(kind.replace(" ", "-")) / name
    return path, turtlebot_bag(path, kind)


LASER_MAP = {
    "rate_hz": 20,
    "observation": [{"topic": "/scan", "fields": ["ranges"]}],
    "action": [{"topic": "/cmd_vel", "fields": ["linear.x", "angular.z"], "default": 0, "max_age": 1.0}],
}


def held_scans(times: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """The index of the scan each grid time holds (the last at or before it)."""
    return np.searchsorted(times, grid, side="right") - 1


def test_the_starter_steps_at_the_command_rate_and_takes_the_laser(tb3: tuple[Path, dict], tmp_path: Path) -> None:
    bag, written = tb3
    report, chosen, text = starter(tmp_path, bag)
    # Before: 0.62 Hz (AMCL's pose, the slowest observation) and the scan's constant scalars, 43 transitions.
    assert chosen["rate_hz"] == 20 and report["starter"]["rate_from"] == "/cmd_vel"
    assert [e["topic"] for e in chosen["action"]] == ["/cmd_vel"]
    assert chosen["observation"][1] == {"topic": "/scan", "fields": ["ranges"], "nonfinite": "range_max"}
    assert [e["topic"] for e in chosen["observation"]] == ["/odom", "/scan"]
    amcl = next(e for e in report["topics"] if e["topic"] == "/amcl_pose")
    assert amcl["role"] is None and amcl["note"].startswith("slow: 0.62 Hz, a new value every 32 steps at 20 Hz")
    assert "/amcl_pose  geometry_msgs" in text and "left out: slow: 0.62 Hz" in text
    assert "rate_hz is 20 (the command stream, /cmd_vel)" in text and "nonfinite: range_max clips" in text

    result = convert(bag, tmp_path / "tb3.mcap", map_path=tmp_path / "starter.yaml", progress=False)
    demo = DemoFile(tmp_path / "tb3.mcap")
    episode = demo[0]
    # From the first odometry and scan (the command has a default) to the last message, at 20 Hz.
    last_odometry = (SECONDS * 30 - 1) / 30
    assert result["transitions"] == len(episode) == math.floor((last_odometry - 0.001) * 20) + 1 == 1380
    names = demo.user_metadata["observation_names"]
    scan = [i for i, name in enumerate(names) if name.startswith("/scan.ranges[")]
    assert len(scan) == BEAMS and names[scan[0]] == "/scan.ranges[0]"
    held = held_scans(written["scans"], episode.timestamps)
    clipped = np.stack([scan_ranges(k) for k in range(len(written["scans"]))])
    clipped[np.isposinf(clipped) | np.isnan(clipped)] = RANGE_MAX
    clipped[np.isneginf(clipped)] = RANGE_MIN  # float32, as the message's range_min is
    assert np.array_equal(episode.observations[:, scan], clipped[held])
    assert {TOO_CLOSE[0], INVALID[0]} <= set(held.tolist())
    assert np.isfinite(episode.observations).all()
    # Every scan's door (61 beams), the -inf and the NaN: counted in a warning, never silent.
    replaced = SECONDS * 5 * 61 + 2
    assert any(f"observation[1] (/scan): {replaced} of the {SECONDS * 5 * BEAMS} values read were NaN or ±inf" in w
               for w in result["warnings"]), result["warnings"]


def test_a_laser_without_nonfinite_is_refused_naming_the_topic_and_column(tb3: tuple[Path, dict], tmp_path: Path) -> None:
    bag, written = tb3
    result = run_cli_many([["convert", bag, "--map", write_map(tmp_path, LASER_MAP), "--out", tmp_path / "x.mcap"]])[0]
    # Before: "episode 0, step 0: the observation is inf", naming neither the topic nor the column.
    assert_one_line_error(result, "observation[0] (/scan): column /scan.ranges[150] is inf in the message at "
                          f"{int(written['scans'][0])} ns; {SECONDS * 5} of the topic's {SECONDS * 5} messages hold one there",
                          "nonfinite: range_max, a number or mask on the entry")
    assert not (tmp_path / "x.mcap").exists() and not (tmp_path / "x.mcap.partial").exists()


def test_a_mask_or_a_number_says_what_the_missing_beams_are(tb3: tuple[Path, dict], tmp_path: Path) -> None:
    bag, written = tb3
    masked = {**LASER_MAP, "observation": [{"topic": "/scan", "fields": ["ranges"], "nonfinite": "mask"}]}
    result = convert(bag, tmp_path / "mask.mcap", map_path=write_map(tmp_path, masked, "mask.yaml"), progress=False)
    demo = DemoFile(tmp_path / "mask.mcap")
    names = demo.user_metadata["observation_names"]
    assert result["observation_space"] == f"Box(float32, ({2 * BEAMS},))"
    assert names[:2] == ["/scan.ranges[0]", "/scan.ranges[1]"] and names[BEAMS:BEAMS + 2] == ["finite(/scan.ranges[0])", "finite(/scan.ranges[1])"]
    episode = demo[0]
    held = held_scans(written["scans"], episode.timestamps)
    step = int(np.flatnonzero(held == INVALID[0])[0])  # the scan with the NaN beam
    ranges = scan_ranges(INVALID[0])
    finite = np.isfinite(ranges)
    assert np.array_equal(episode.observations[step, BEAMS:], finite.astype(np.float32))
    assert np.array_equal(episode.observations[step, :BEAMS], np.where(finite, ranges, 0).astype(np.float32))

    constant = {**LASER_MAP, "observation": [{"topic": "/scan", "fields": ["ranges"], "nonfinite": 10}]}
    convert(bag, tmp_path / "ten.mcap", map_path=write_map(tmp_path, constant, "ten.yaml"), progress=False)
    episode = DemoFile(tmp_path / "ten.mcap")[0]
    step = int(np.flatnonzero(held_scans(written["scans"], episode.timestamps) == TOO_CLOSE[0])[0])
    expected = scan_ranges(TOO_CLOSE[0])
    expected[~np.isfinite(expected)] = 10
    assert np.array_equal(episode.observations[step], expected)


def test_nonfinite_is_checked_in_the_map_and_against_the_bag(tmp_path: Path) -> None:
    bag_path = tmp_path / "odd.bag"
    with BagWriter(bag_path, "ros1") as bag:
        bag.topic("/scan", "sensor_msgs/msg/LaserScan")
        bag.topic("/cmd_vel", "geometry_msgs/msg/Twist")
        for i in range(5):
            t = START_NS + i * NS // 5
            # A driver that reports no maximum range: range_max cannot stand for a missing beam.
            bag.write("/scan", t, laser(bag, t, scan_ranges(0), range_max=math.inf))
            bag.write("/cmd_vel", t + 1, bag.twist(0.1, 0.0))

    def case(name: str, **entry: Any) -> list:
        observation = {"topic": "/scan", "fields": ["ranges"], **entry}
        data = {**LASER_MAP, "observation": [observation]}
        return ["convert", bag_path, "--map", write_map(tmp_path, data, f"{name}.yaml"), "--out", tmp_path / f"{name}.mcap"]

    camera = {**LASER_MAP, "observation": [{"topic": "/scan", "image": "cam", "nonfinite": 0}]}
    bad_choice, interpolated, no_limits, inf_limit, camera = run_cli_many([
        case("choice", nonfinite="clip"),
        case("interpolated", nonfinite="mask", align="interpolate"),
        case("twist", topic="/cmd_vel", fields=["linear.x"], nonfinite="range_max"),
        case("inf", nonfinite="range_max"),
        ["convert", bag_path, "--map", write_map(tmp_path, camera, "camera.yaml"), "--out", tmp_path / "camera.mcap"],
    ])
    assert_one_line_error(bad_choice, "observation[0] (/scan): nonfinite must be range_max (the message's own range limits), "
                          "a finite number, or mask", "got 'clip'")
    assert_one_line_error(interpolated, "observation[0] (/scan): nonfinite: mask gives 0/1 columns", "use align: hold")
    assert_one_line_error(no_limits, "observation[0] (/cmd_vel): nonfinite: range_max takes the message's range_max and "
                          "range_min (sensor_msgs/LaserScan) or max_range and min_range (sensor_msgs/Range); a "
                          "geometry_msgs/msg/Twist has neither")
    assert_one_line_error(inf_limit, f"{bag_path}: observation[0] (/scan) at {START_NS} ns: nonfinite: range_max, but the message's "
                          "range_min is 0.12", "range_max inf")
    assert_one_line_error(camera, "an image entry takes no nonfinite")
    assert not list(tmp_path.glob("*.mcap*"))


def test_the_starter_holds_slow_observations_when_nothing_faster_is_left(tmp_path: Path) -> None:
    """A 20 Hz command beside a 1 Hz pose alone: the pose stays (the demos need an observation),
    held between its messages, and the comment says so."""
    with BagWriter(tmp_path / "slow", "ros2 mcap") as bag:
        bag.topic("/cmd_vel", "geometry_msgs/msg/Twist")
        bag.topic("/pose", "geometry_msgs/msg/PoseStamped")
        for i in range(200):
            bag.write("/cmd_vel", START_NS + i * NS // 20, bag.twist(0.1, 0.0))
        for i in range(10):
            t = START_NS + i * NS + 1
            bag.write("/pose", t, bag.msg("geometry_msgs/msg/PoseStamped", header=bag.header(t), pose=bag.pose(0.1 * i)))
    report, chosen, text = starter(tmp_path, tmp_path / "slow")
    assert chosen["rate_hz"] == 20 and [e["topic"] for e in chosen["observation"]] == ["/pose"]
    assert report["starter"]["held"] == ["/pose"] and "# /pose: slower than one value per 10 steps, held" in text
    assert yaml.safe_load(text) == chosen

"""ROS bags → demos on bags other tools wrote (../shared/testdata): ROS 1 .bag, rosbag2 sqlite,
ROS 2 MCAP, and the service-event bag whose schemas no decoder parses."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from support import TURTLE_MAP, write_map

from imitation.data.convert.job import convert, inspect
from imitation.data.mcap.reader import DemoFile
from imitation.errors import ImitationError



def log_times(bag: Path, topic: str) -> np.ndarray:
    """The topic's log times, read independently of our reader (rosbags' AnyReader)."""
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        return np.array([time for _, time, _ in reader.messages(connections)], dtype=np.int64)


def test_ros1_turtle_steps_match_the_time_span_at_10_hz(testdata: Path, tmp_path: Path) -> None:
    bag = testdata / "ros1" / "plotjuggler_example.bag"
    out = tmp_path / "turtle.mcap"
    result = convert(bag, out, source="ros1", map_path=write_map(tmp_path, TURTLE_MAP), progress=False)
    pose, cmd = log_times(bag, "/turtle1/pose"), log_times(bag, "/turtle1/cmd_vel")
    # No default for the command: the demos start at its first message and step at 10 Hz to the
    # last mapped message, plus one step so that the last action has a following observation.
    span_s = (max(pose[-1], cmd[-1]) - max(pose[0], cmd[0])) / 1e9
    demo = DemoFile(out)
    assert result["episodes"] == len(demo) == 1
    assert demo.num_transitions == math.floor(span_s * 10) + 1 == 202
    assert demo.dt == pytest.approx(0.1) and demo.env_id == ""
    episode = demo[0]
    assert np.diff(episode.timestamps).tolist() == [100_000_000] * 202 and episode.truncated
    assert episode.observations.shape == (203, 5) and episode.actions.shape == (202, 2)
    # Hold-last: the action at each grid time is the latest command at or before it.
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        commands = [(t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages([c for c in reader.connections if c.topic == "/turtle1/cmd_vel"])]
    for step in (0, 50, 201):
        t = episode.timestamps[step]
        latest = [message for time, message in commands if time <= t][-1]
        assert episode.actions[step].tolist() == pytest.approx([latest.linear.x, latest.angular.z])
    assert DemoFile(out).user_metadata["action_names"] == ["/turtle1/cmd_vel.linear.x", "/turtle1/cmd_vel.angular.z"]


def test_a_default_lets_the_demos_cover_the_whole_bag(testdata: Path, tmp_path: Path) -> None:
    bag = testdata / "ros1" / "plotjuggler_example.bag"
    data = {**TURTLE_MAP, "action": [{"topic": "/turtle1/cmd_vel", "fields": ["linear.x", "angular.z"], "default": 0, "max_age": 1.0}]}
    convert(bag, tmp_path / "t.mcap", map_path=write_map(tmp_path, data), progress=False)
    pose = log_times(bag, "/turtle1/pose")
    episode = DemoFile(tmp_path / "t.mcap")[0]
    assert len(episode) == math.floor((pose[-1] - pose[0]) / 1e8) + 1 == 215  # 21.5 s of pose at 10 Hz
    assert abs(len(episode) / 10 - 21.7) < 0.25  # the bag's own duration
    assert episode.actions[0].tolist() == [0.0, 0.0]  # before the first command
    assert episode.actions[-1].tolist() == [0.0, 0.0]  # the last command is 3.5 s old by the end: stale


@pytest.mark.parametrize("relative", [
    "ros2/rosbag2parquet/array_msgs", "ros2/rosbag2parquet/base_msgs", "ros2/replay_testing/cmd_vel_only.mcap",
    "ros2/replay_testing/cmd_vel_only_2.mcap", "ros2/rosbag2_tests/cdr_test", "ros2/rosbag2_tests/talker",
    "ros2/rosbag2_tests/bag_with_topics_and_service_events",
])
def test_inspect_every_ros2_file(testdata: Path, relative: str) -> None:
    report = inspect(testdata / relative)
    assert report["from"] == "ros2" and report["topics"]
    metadata = testdata / relative / "metadata.yaml"
    if metadata.is_file():  # rosbag2's own listing agrees with ours
        info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
        expected = {t["topic_metadata"]["name"]: t["message_count"] for t in info["topics_with_message_count"]}
        assert {t["topic"]: t["count"] for t in report["topics"]} == expected
    decodable = [t for t in report["topics"] if not t["problem"]]
    assert all(t["problem"] is None for t in decodable) and len(report["warnings"]) == len(report["topics"]) - len(decodable)


def test_inspect_skips_service_events_with_a_warning(testdata: Path) -> None:
    report = inspect(testdata / "ros2/rosbag2_tests/bag_with_topics_and_service_events")
    problems = {t["topic"] for t in report["topics"] if t["problem"]}
    assert problems == {"/test_service1/_service_event", "/test_service2/_service_event"}
    assert {"/test_topic1", "/test_topic2"} <= {t["topic"] for t in report["topics"] if not t["problem"]}
    assert len(report["warnings"]) == 2 and all("_service_event" in w and "skipped" in w for w in report["warnings"])


def test_inspect_lists_fields_and_writes_a_starter_map_that_converts(testdata: Path, tmp_path: Path) -> None:
    bag = testdata / "ros2/replay_testing/cmd_vel_only_2.mcap"
    report = inspect(bag, write_map=tmp_path / "starter.yaml")
    fields = {t["topic"]: [f["field"] for f in t["fields"]] for t in report["topics"]}
    assert "twist.linear.x" in fields["/vehicle/cmd_vel"] and "header.stamp.sec" in fields["/scaled/cmd_vel"]
    starter = yaml.safe_load((tmp_path / "starter.yaml").read_text())
    assert starter["rate_hz"] == 50 and {e["topic"] for e in starter["action"]} == {"/vehicle/cmd_vel", "/scaled/cmd_vel"}
    # Both topics are commands; make one the observation and the starter converts.
    starter["observation"] = [starter["action"].pop(0)]
    convert(bag, tmp_path / "d.mcap", map_path=write_map(tmp_path, starter), progress=False)
    assert DemoFile(tmp_path / "d.mcap").num_transitions > 0


def test_replay_testing_cmd_vel_at_50_hz(testdata: Path, tmp_path: Path) -> None:
    bag = testdata / "ros2/replay_testing/cmd_vel_only_2.mcap"
    data = {
        "rate_hz": 50,
        "observation": [{"topic": "/vehicle/cmd_vel", "fields": ["twist.linear.x"]}],
        "action": [{"topic": "/scaled/cmd_vel", "fields": ["twist.linear.x"]}],
    }
    result = convert(bag, tmp_path / "cmd.mcap", source="ros2", map_path=write_map(tmp_path, data), progress=False)
    episode = DemoFile(tmp_path / "cmd.mcap")[0]
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(bag, "rb") as stream:
        decoded = {(c.topic, m.log_time): d for _, c, m, d in make_reader(stream, decoder_factories=[DecoderFactory()]).iter_decoded_messages()}
    vehicle = sorted((t, d.twist.linear.x) for (topic, t), d in decoded.items() if topic == "/vehicle/cmd_vel")
    scaled = sorted((t, d.twist.linear.x) for (topic, t), d in decoded.items() if topic == "/scaled/cmd_vel")
    start, end = max(vehicle[0][0], scaled[0][0]), max(vehicle[-1][0], scaled[-1][0])
    assert result["transitions"] == len(episode) == math.floor((end - start) / 2e7) + 1  # 50 Hz
    for step in range(0, len(episode), 7):
        t = episode.timestamps[step]
        assert episode.observations[step, 0] == pytest.approx([x for time, x in vehicle if time <= t][-1])
        assert episode.actions[step, 0] == pytest.approx([x for time, x in scaled if time <= t][-1])
    assert np.any(episode.actions != 0)


def test_rosbag2parquet_joint_state_imu_twist(testdata: Path, tmp_path: Path) -> None:
    # One message per topic: each bag converts into a single step.
    arrays = {
        "rate_hz": 10,
        "observation": [{"topic": "/one_shot/joint_state", "fields": ["position", "velocity", "effort"]},
                        {"topic": "/one_shot/imu", "fields": ["orientation.w", "angular_velocity.x", "orientation_covariance[8]"]}],
        "action": [{"topic": "/one_shot/imu", "fields": ["linear_acceleration.z"]}],
    }
    convert(testdata / "ros2/rosbag2parquet/array_msgs", tmp_path / "a.mcap", map_path=write_map(tmp_path, arrays), progress=False)
    demo = DemoFile(tmp_path / "a.mcap")
    first = demo[0].observations[0]
    assert first[:9].tolist() == pytest.approx([1.5, -0.5, 0.8, 0.1, 0.2, 0.3, 10.1, 10.2, 10.3])
    assert first[9:].tolist() == pytest.approx([1.0, 0.1, 0.9])  # w, angular_velocity.x, orientation_covariance[8]
    assert demo.observation_space.shape == (12,) and demo.user_metadata["observation_names"][0] == "/one_shot/joint_state.position[0]"

    twist = {"rate_hz": 10, "observation": [{"topic": "/one_shot/vector3", "fields": ["x", "y", "z"]}],
             "action": [{"topic": "/one_shot/twist", "fields": ["linear.x", "angular.z"]}]}
    convert(testdata / "ros2/rosbag2parquet/base_msgs", tmp_path / "b.mcap", map_path=write_map(tmp_path, twist, "b.yaml"), progress=False)
    episode = DemoFile(tmp_path / "b.mcap")[0]
    assert episode.observations[0].tolist() == pytest.approx([1.1, 2.2, 3.3]) and episode.actions[0].tolist() == pytest.approx([1.2, -0.6])


def test_rosbag2_sqlite_imu_and_pose_to_battery_voltage(testdata: Path, tmp_path: Path) -> None:
    bag = testdata / "ros1/plotjuggler_rosbag2_sqlite"
    data = {
        "rate_hz": 25,
        "time": "header",
        "align": "interpolate",
        "observation": [{"topic": "/imu", "fields": ["orientation.x", "angular_velocity.z", "linear_acceleration.x"]},
                        {"topic": "/pose", "fields": ["pose.position.x", "pose.orientation.w"]}],
        "action": [{"topic": "/battery", "fields": ["voltage"]}],
        "episodes": {"split": "gap", "seconds": 1.0},
    }
    result = convert(bag, tmp_path / "sqlite.mcap", source="ros2", map_path=write_map(tmp_path, data), progress=False)
    demo = DemoFile(tmp_path / "sqlite.mcap")
    assert result["from"] == "ros2" and demo.source.startswith("rosbag2 sqlite")
    assert demo.observation_space.shape == (5,) and demo.action_space.shape == (1,)
    assert 0.9 * 62.5 * 25 < demo.num_transitions <= 62.6 * 25  # 62.6 s of 25 Hz messages
    voltages = np.concatenate([e.actions[:, 0] for e in demo])
    assert np.all(np.isfinite(voltages)) and voltages.std() > 0


def test_a_message_stamped_beyond_what_a_timestamp_holds_is_one_line(testdata: Path, tmp_path: Path) -> None:
    """A damaged log time (here 2^63 + 5 ns, which MCAP's u64 allows) is refused by name, not
    an overflow deep in numpy (found by tools/fuzz.py)."""
    import shutil

    from mcap.reader import make_reader
    from mcap.writer import Writer

    source = testdata / "ros2/rosbag2parquet/array_msgs"
    bag = tmp_path / "bag"
    bag.mkdir()
    shutil.copy(source / "metadata.yaml", bag / "metadata.yaml")
    with open(source / "array_msgs_0.mcap", "rb") as stream, open(bag / "array_msgs_0.mcap", "wb") as out:
        writer, schemas, channels = Writer(out), {}, {}
        writer.start(profile="ros2", library="test")
        for schema, channel, message in make_reader(stream).iter_messages(log_time_order=True):
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, schemas[schema.id], channel.metadata)
            late = channel.topic == "/one_shot/imu"
            writer.add_message(channels[channel.id], 2**63 + 5 if late else message.log_time, message.data, message.publish_time)
        writer.finish()
    arrays = {"rate_hz": 10, "observation": [{"topic": "/one_shot/joint_state", "fields": ["position"]}],
              "action": [{"topic": "/one_shot/imu", "fields": ["linear_acceleration.z"]}]}
    with pytest.raises(ImitationError, match=r"a message on /one_shot/imu is stamped 9223372036854775813 ns, outside what a timestamp can hold"):
        convert(bag, tmp_path / "out.mcap", map_path=write_map(tmp_path, arrays), progress=False)
    assert not (tmp_path / "out.mcap").exists()


def test_a_damaged_header_stamp_that_stretches_a_bag_over_a_day_is_refused_before_the_grid(testdata: Path, tmp_path: Path) -> None:
    """cmd_vel_only_2 (99 messages in 1 s) with the last /vehicle/cmd_vel header stamp a day late,
    as tools/fuzz.py made it (there 20 days: 44 million steps, 23 s and 3.9 GB for a 7.8 KB bag):
    the 25 Hz grid would hold 2.2 million steps, over 1000 per message, and is refused naming the
    file, the topic and the silence. Split at gaps, the late message is a span of its own."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    bag = tmp_path / "cmd_vel.mcap"
    with open(testdata / "ros2/replay_testing/cmd_vel_only_2.mcap", "rb") as stream, open(bag, "wb") as out:
        records = list(make_reader(stream).iter_messages(log_time_order=True))
        late = max(k for k, (_, channel, _) in enumerate(records) if channel.topic == "/vehicle/cmd_vel")
        writer, schemas, channels = Writer(out), {}, {}
        writer.start(profile="ros2", library="test")
        for k, (schema, channel, message) in enumerate(records):
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, schemas[schema.id], channel.metadata)
            data = message.data
            if k == late:  # CDR little-endian: header.stamp.sec follows the 4-byte encapsulation header
                data = data[:4] + (int.from_bytes(data[4:8], "little") + 86_400).to_bytes(4, "little") + data[8:]
            writer.add_message(channels[channel.id], message.log_time, data, message.publish_time)
        writer.finish()
    twist = {"rate_hz": 25, "time": "header", "observation": [{"topic": "/vehicle/cmd_vel", "fields": ["twist.linear.x", "twist.angular.z"]}],
             "action": [{"topic": "/scaled/cmd_vel", "fields": ["twist.linear.x", "twist.angular.z"]}]}
    with pytest.raises(ImitationError) as refused:
        convert(bag, tmp_path / "out.mcap", map_path=write_map(tmp_path, twist), progress=False)
    assert str(refused.value) == (
        f"{bag}: episode span 0: the 25 Hz grid from 1730467949.015 s to 1730554349.995 s would hold 2160025 steps for "
        "99 messages on /vehicle/cmd_vel, /scaled/cmd_vel; the longest silence is 86400.0 s, from a message on /scaled/cmd_vel "
        "stamped 1730467949.975 s to one on /vehicle/cmd_vel stamped 1730554349.995 s (a damaged timestamp? a real silence "
        "belongs between episodes: `episodes: {split: gap, seconds: S}`); steps per message: 21819 is more than the limit "
        "grid_steps_per_message=1000 (raise it with `imitation --limit grid_steps_per_message=N` if the data is real)"
    )
    assert not (tmp_path / "out.mcap").exists()
    split = {**twist, "episodes": {"split": "gap", "seconds": 1.0}}
    result = convert(bag, tmp_path / "out.mcap", map_path=write_map(tmp_path, split), progress=False)
    assert result["episodes"] == 2 and result["transitions"] == 25 + 1

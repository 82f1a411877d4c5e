"""`--ros-distro` is checked before any bag is opened, whatever the bag (issue 17): it used to be
read only for rosbag2 sqlite bags without message definitions, so a misspelt name passed
unnoticed with every bag in the test data (ROS 1 and MCAP bags carry their definitions)."""

from __future__ import annotations

from pathlib import Path

import pytest
from support import TURTLE_MAP, run_cli_many, write_map
from test_cli import assert_one_line_error, last_json

from imitation.data.convert.bags import open_bag
from imitation.errors import ImitationError

UNKNOWN = "--ros-distro 'hunble': unknown (one of latest, "


def test_an_unknown_distro_is_refused_with_every_kind_of_bag(testdata: Path, tmp_path: Path) -> None:
    turtle = testdata / "ros1" / "plotjuggler_example.bag"
    turtle_map = str(write_map(tmp_path, TURTLE_MAP))
    out = tmp_path / "out"
    out.mkdir()
    refused = [
        ["convert", str(turtle), "--map", turtle_map, "--out", str(out / "ros1.mcap")],  # ROS 1 bag
        ["convert", str(turtle), "--inspect"],
        ["convert", str(testdata / "ros2/replay_testing/cmd_vel_only_2.mcap"), "--inspect"],  # ROS 2 MCAP file
        ["convert", str(testdata / "ros2/rosbag2parquet/array_msgs"), "--inspect"],  # rosbag2 folder (MCAP storage)
        ["convert", str(testdata / "ros1/plotjuggler_rosbag2_sqlite"), "--from", "ros2", "--inspect"],  # sqlite, with definitions
    ]
    accepted = [["convert", str(turtle), "--map", turtle_map, "--out", str(out / "humble.mcap"), "--ros-distro", "humble", "--json", "--quiet"]]
    results = run_cli_many([*(argv + ["--ros-distro", "hunble"] for argv in refused), *accepted])
    for result in results[: len(refused)]:
        assert_one_line_error(result, UNKNOWN, "humble", "jazzy")
    assert last_json(results[-1])["transitions"] == 202  # a known distro changes nothing for a bag with definitions
    assert sorted(p.name for p in out.iterdir()) == ["humble.mcap"], "nothing written for a refused name"


def test_the_name_is_checked_before_the_bag_is_looked_at(tmp_path: Path) -> None:
    with pytest.raises(ImitationError, match="^--ros-distro 'hunble': unknown"):
        open_bag(tmp_path / "absent.bag", "ros1", ros_distro="hunble")
    with pytest.raises(ImitationError, match="no such file"):
        open_bag(tmp_path / "absent.bag", "ros1", ros_distro="humble")

"""`convert`, `export` and offline `train bc` from the command line: the issue's acceptance runs
on third-party files, and one-line errors that leave nothing behind."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from support import DATASETS, TURTLE_MAP, run_cli, write_map
from test_cli import assert_one_line_error, last_json

from imitation.data.mcap.reader import DemoFile



@pytest.mark.parametrize("command", [["convert"], ["export"]])
def test_help(command: list[str]) -> None:
    result = run_cli(*command, "--help")
    assert result.returncode == 0 and "usage: imitation" in result.stdout


def test_convert_help_says_cameras_convert_and_how_a_layout_ends_episodes() -> None:
    text = " ".join(run_cli("convert", "--help").stdout.split())
    assert "skipped" not in text
    assert "Cameras become image observations: LeRobot video and image features, zarr frame arrays, and ROS image topics a map names" in text
    assert "for a layout with ends: terminal_state, where the env's own termination rule first holds" in text


def test_turtle_bag_to_demos_to_offline_bc(testdata: Path, tmp_path: Path) -> None:
    demos = tmp_path / "turtle.mcap"
    converted = last_json(run_cli("convert", str(testdata / "ros1/plotjuggler_example.bag"), "--from", "ros1",
                                  "--map", str(write_map(tmp_path, TURTLE_MAP)), "--out", str(demos), "--json"))
    assert converted["from"] == "ros1" and converted["episodes"] == 1 and converted["transitions"] == 202
    # turtlesim/Pose declares float32 fields, geometry_msgs/Twist float64 ones: each keeps its type.
    assert converted["observation_space"] == "Box(float32, (5,))" and converted["action_space"] == "Box(float64, (2,))"
    info = last_json(run_cli("info", str(demos), "--json"))
    assert info["env_id"] is None and info["dt"] == pytest.approx(0.1) and "/time" in info["channels"]
    run = tmp_path / "bc"
    trained = last_json(run_cli("train", "bc", "--demos", str(demos), "--epochs", "20", "--hidden", "32,32", "--out", str(run), "--json", timeout=300))
    # One recording: the last 20% of its steps are held out, and only the validation loss is reported.
    assert trained["offline"] is True and trained["eval"] is None and trained["env_id"] is None
    assert trained["validation_transitions"] == 40 and trained["train_transitions"] == 162
    assert trained["best_validation_loss"] == pytest.approx(min(float(r["validation_loss"]) for r in _progress(run)))
    assert "return_curve.png" not in {p.name for p in run.iterdir()}
    text = run_cli("train", "bc", "--demos", str(demos), "--epochs", "2", "--out", str(tmp_path / "bc2"), timeout=300)
    assert text.returncode == 0 and "offline" in text.stdout and "validation loss" in text.stdout


def _progress(run: Path) -> list[dict[str, str]]:
    lines = (run / "progress.csv").read_text().splitlines()
    header = lines[0].split(",")
    return [dict(zip(header, line.split(","))) for line in lines[1:]]


def test_inspect_the_service_event_bag(testdata: Path, tmp_path: Path) -> None:
    bag = testdata / "ros2/rosbag2_tests/bag_with_topics_and_service_events"
    result = run_cli("convert", str(bag), "--inspect", "--json")
    report = last_json(result)
    warnings = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(warnings) == 2 and all(line.startswith("warning: /test_service") for line in warnings)
    assert {t["topic"] for t in report["topics"] if not t["problem"]} >= {"/test_topic1", "/test_topic2"}
    text = run_cli("convert", str(bag), "--inspect", "--write-map", str(tmp_path / "starter.yaml"))
    assert text.returncode == 0 and "cannot decode" in text.stdout and (tmp_path / "starter.yaml").is_file()
    assert_one_line_error(run_cli("convert", str(bag), "--inspect", "--write-map", str(tmp_path / "starter.yaml")), "exists")


def test_expert_cartpole_npz_to_bc_to_eval(testdata: Path, tmp_path: Path) -> None:
    demos = tmp_path / "cartpole.mcap"
    converted = last_json(run_cli("convert", str(testdata / "experts/expert_cartpole.npz"), "--env", "CartPole-v1", "--out", str(demos), "--json"))
    assert converted["from"] == "npz" and converted["episodes"] == 100 and converted["action_space"] == "Discrete(2)"
    run = tmp_path / "bc"
    trained = last_json(run_cli("train", "bc", "--demos", str(demos), "--env", "CartPole-v1", "--epochs", "5", "--hidden", "64,64",
                                "--out", str(run), "--json", timeout=300))
    assert trained["offline"] is False and trained["train_transitions"] + trained["validation_transitions"] == converted["transitions"]
    evaluated = last_json(run_cli("eval", "policy", str(run), "--env", "CartPole-v1", "--episodes", "10", "--json"))
    assert evaluated["mean_return"] >= 475


def test_export_from_the_command_line(tmp_path: Path) -> None:
    result = last_json(run_cli("export", str(DATASETS / "CartPole-v1.mcap"), "--to", "foxglove", str(tmp_path / "steps.mcap"), "--json"))
    assert result["to"] == "foxglove" and (tmp_path / "steps.mcap").is_file()
    assert_one_line_error(run_cli("export", str(DATASETS / "CartPole-v1.mcap"), "--to", "rerun", str(tmp_path / "x")), "--to rerun", "unknown format")
    assert_one_line_error(run_cli("export", str(tmp_path / "absent.mcap"), "--to", "lerobot", str(tmp_path / "ds")), "absent.mcap", "cannot open")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["steps.mcap"]


BAD_MAPS = [
    ({**TURTLE_MAP, "observation": [{"topic": "/turtle9/pose", "fields": ["x"]}]}, ["map.yaml", "observation[0]", "/turtle9/pose", "is not in"]),
    ({**TURTLE_MAP, "action": [{"topic": "/rosout", "fields": ["msg"]}]}, ["map.yaml", "action[0] (/rosout)", "'msg' is a string", "not a number"]),
    ({**TURTLE_MAP, "action": [{"topic": "/turtle1/cmd_vel", "fields": ["linear.w"]}]}, ["linear has no field 'w'"]),
    ({key: value for key, value in TURTLE_MAP.items() if key != "action"}, ["map.yaml", "no action"]),
    ({**TURTLE_MAP, "observation": [{"topic": "/a", "fields": ["x"]}], "action": [{"topic": "/b", "fields": ["y"]}]},
     ["plotjuggler_example.bag", "none of the map's topics (/a, /b)", "/turtle1/pose"]),
]


@pytest.mark.parametrize("data, fragments", BAD_MAPS, ids=["unknown topic", "string field", "unknown field", "no action", "no matching topics"])
def test_malformed_maps_fail_in_one_line_and_write_nothing(testdata: Path, tmp_path: Path, data: dict, fragments: list[str]) -> None:
    maps = tmp_path / "maps"
    maps.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    result = run_cli("convert", str(testdata / "ros1/plotjuggler_example.bag"), "--map", str(write_map(maps, data)), "--out", str(out / "d.mcap"))
    assert_one_line_error(result, *fragments)
    assert list(out.iterdir()) == []


def test_bad_sources_fail_in_one_line(testdata: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    not_a_root = tmp_path / "dataset"
    (not_a_root / "data").mkdir(parents=True)
    cases = [
        (["convert", str(not_a_root), "--from", "lerobot"], ["dataset", "not a LeRobot dataset root", "no meta/info.json"]),
        (["convert", str(not_a_root)], ["no meta/info.json"]),
        (["convert", str(testdata / "experts/expert_cartpole.npz"), "--from", "hdf5"], ["--from hdf5", "unknown source", "ros2, ros1, lerobot, npz"]),
        (["convert", str(testdata / "ros1/plotjuggler_example.bag")], ["needs --map"]),
        (["convert", str(testdata / "ros1/plotjuggler_example.bag"), "--from", "ros2", "--map", str(write_map(tmp_path, TURTLE_MAP))], ["not an MCAP file"]),
        (["convert", str(tmp_path / "nothing.bag")], ["nothing.bag", "no such file"]),
        # written by h5py (tools/hdf5_fixture.py): no --from reads it, so the message must not ask for one
        (["convert", str(HDF5)], ["robomimic-layout.hdf5: an HDF5 file, which convert does not read (no --from does)",
                                  "(episodes, steps, columns) array in an .npy file and convert that with --layout"]),
        (["convert", str(testdata / "experts/expert_cartpole.npz"), "--env", "Pendulum-v1"], ["for Pendulum-v1", "do not fit"]),
    ]
    for args, fragments in cases:
        assert_one_line_error(run_cli(*args, "--out", str(out / "d.mcap")), *fragments)
    assert list(out.iterdir()) == []
    assert run_cli("convert", str(not_a_root), "--inspect", "--out", str(out / "d.mcap")).returncode == 2  # usage


def test_lerobot_round_trip_from_the_command_line(tmp_path: Path) -> None:
    dataset = tmp_path / "dataset"
    exported = last_json(run_cli("export", str(DATASETS / "MountainCar-v0.mcap"), "--to", "lerobot", str(dataset), "--json", timeout=300))
    assert exported["codebase_version"] == "v3.0" and json.loads((dataset / "meta" / "info.json").read_text())["total_episodes"] == exported["episodes"]
    back = last_json(run_cli("convert", str(dataset), "--out", str(tmp_path / "back.mcap"), "--json", timeout=300))
    original, restored = DemoFile(DATASETS / "MountainCar-v0.mcap"), DemoFile(tmp_path / "back.mcap")
    assert back["transitions"] == original.num_transitions and restored.env_id == "MountainCar-v0"
    assert [f.episode_return for f in restored.episodes] == [f.episode_return for f in original.episodes]


FIXTURES = Path(__file__).resolve().parent / "fixtures" / "imitation"
HDF5 = Path(__file__).resolve().parent / "fixtures" / "formats" / "robomimic-layout.hdf5"


def test_info_says_how_the_end_flags_were_decided(tmp_path: Path) -> None:
    """imitation's npz (written by imitation 0.3.2) with and without --env, and a recording: what
    `convert` warns and what `info` prints and returns."""
    decided, kept, recorded = tmp_path / "decided.mcap", tmp_path / "kept.mcap", tmp_path / "recorded.mcap"
    converted = last_json(run_cli("convert", str(FIXTURES / "cartpole.npz"), "--env", "CartPole-v1", "--out", str(decided), "--json"))
    assert (converted["terminated"], converted["truncated"]) == (5, 5) and converted["end_flags"]["decided"] == "time_limit"
    info = last_json(run_cli("info", str(decided), "--json"))
    assert info["end_flags"] == {"decided": "time_limit", "source_flag": "terminal", "env_id": "CartPole-v1", "max_episode_steps": 500,
                                 "terminated": 5, "truncated": 5}
    assert (info["terminated"], info["truncated"]) == (5, 5)
    text = run_cli("info", str(decided)).stdout
    assert "episodes:      10  (5 terminated, 5 truncated)" in text
    assert "end flags:     decided from CartPole-v1's 500-step time limit" in text

    result = run_cli("convert", str(FIXTURES / "cartpole.npz"), "--out", str(kept))
    assert result.returncode == 0 and "10 episode(s) marked terminated may have ended at a time limit" in result.stderr
    info = last_json(run_cli("info", str(kept), "--json"))
    assert info["end_flags"]["decided"] == "source" and (info["terminated"], info["truncated"]) == (10, 0)
    assert "end flags:     the source's `terminal`, kept as it is" in run_cli("info", str(kept)).stdout

    assert run_cli("record", "--env", "CartPole-v1", "--expert", "random", "--episodes", "2", "--quiet", "--out", str(recorded)).returncode == 0
    assert last_json(run_cli("info", str(recorded), "--json"))["end_flags"] == {"decided": "env"}
    assert "end flags:     the env's own terminated/truncated signals" in run_cli("info", str(recorded)).stdout
    # A file written before end flags were recorded still reads, and says it does not know.
    assert last_json(run_cli("info", str(DATASETS / "CartPole-v1.mcap"), "--json"))["end_flags"] is None


def test_info_says_a_bags_episodes_are_recordings(testdata: Path, tmp_path: Path) -> None:
    """A ROS bag's episodes stop where the recorder stopped: `info` says so, not that the file is
    too old to tell."""
    demos = tmp_path / "turtle.mcap"
    converted = last_json(run_cli("convert", str(testdata / "ros1/plotjuggler_example.bag"), "--map",
                                  str(write_map(tmp_path, TURTLE_MAP)), "--out", str(demos), "--json"))
    assert converted["end_flags"] == {"decided": "recording", "terminated": 0, "truncated": 1}
    assert last_json(run_cli("info", str(demos), "--json"))["end_flags"] == converted["end_flags"]
    text = run_cli("info", str(demos)).stdout
    assert "end flags:     all 1 truncated: a recording stops where its recorder stopped, not in a terminal state" in text
    assert "not recorded" not in text


def test_a_bare_array_from_the_command_line(tmp_path: Path) -> None:
    import gymnasium as gym
    import numpy as np

    env = gym.make("MountainCar-v0")
    episodes, returns = [], []
    for seed in range(3):
        observation, _ = env.reset(seed=seed)
        rows, done, total = [], False, 0.0
        while not done:
            action = 2 if observation[1] > 0 else 0
            rows.append([*observation, action])
            observation, reward, terminated, truncated, _ = env.step(action)
            total, done = total + reward, terminated or truncated
        episodes.append(np.array([*rows, [*observation, np.nan]]))
        returns.append(total)
    array = np.full((3, 201, 3), np.nan)
    for k, rows in enumerate(episodes):
        array[k, : len(rows)] = rows
    np.save(tmp_path / "human.npy", array)
    (tmp_path / "layout.yaml").write_text("observation: [0, 1]\naction: 2\ndiscrete_action: true\nrows: state\nreward: -1\n")
    out = tmp_path / "human.mcap"
    converted = last_json(run_cli("convert", str(tmp_path / "human.npy"), "--layout", str(tmp_path / "layout.yaml"), "--env", "MountainCar-v0",
                                  "--out", str(out), "--json"))
    assert converted["from"] == "array" and converted["warnings"] == []
    assert [f.episode_return for f in DemoFile(out).episodes] == returns
    assert_one_line_error(run_cli("convert", str(tmp_path / "human.npy"), "--out", str(tmp_path / "x.mcap")), "human.npy", "needs --layout")

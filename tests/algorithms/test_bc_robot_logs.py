"""Offline BC on real robot recordings beats the trivial baselines at default settings, on held-out
steps: the turtlesim bag in ../shared/testdata (a person teleoperating turtle1 from the keyboard; a
controller making turtle2 follow it) and, as a slow test, the Unitree G1 LeRobot dataset. The
baselines are those `train bc` reports: a constant action distribution, the previous action held,
the current state copied where observation and action share a shape."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from support import run_cli, write_map

# A velocity command stream that stops means "stop": turtlesim halts a turtle after 1 s without one.
COMMAND = {"default": 0, "max_age": 1.0}
TELEOP_MAP = {
    "rate_hz": 10,
    "time": "log",
    "observation": [{"topic": "/turtle1/pose", "fields": ["x", "y", "theta", "linear_velocity", "angular_velocity"]}],
    "action": [{"topic": "/turtle1/cmd_vel", "fields": ["linear.x", "angular.z"], **COMMAND}],
    "episodes": {"split": "file"},
}
FOLLOWER_MAP = {
    "rate_hz": 10,
    "time": "log",
    "observation": [
        {"topic": "/turtle2/pose", "fields": ["x", "y", "theta", "linear_velocity", "angular_velocity"]},
        {"topic": "/turtle1/pose", "fields": ["x", "y", "theta"]},
    ],
    "action": [{"topic": "/turtle2/cmd_vel", "fields": ["linear.x", "angular.z"], **COMMAND}],
    "episodes": {"split": "file"},
}


def offline_bc(source: Path, tmp_path: Path, name: str, *convert_args: str) -> tuple[dict, str]:
    demos = tmp_path / f"{name}.mcap"
    converted = run_cli("convert", str(source), *convert_args, "--out", str(demos), "--quiet", timeout=600)
    assert converted.returncode == 0, converted.stderr
    trained = run_cli("train", "bc", "--demos", str(demos), "--out", str(tmp_path / f"bc-{name}"), timeout=3000)
    assert trained.returncode == 0, trained.stderr
    return json.loads((tmp_path / f"bc-{name}" / "metrics.json").read_text()), trained.stderr


@pytest.mark.parametrize(("name", "recording_map"), [("teleop", TELEOP_MAP), ("follower", FOLLOWER_MAP)])
def test_bc_on_the_turtlesim_bag_beats_the_baselines(name: str, recording_map: dict, testdata: Path, tmp_path: Path) -> None:
    bag = testdata / "ros1" / "plotjuggler_example.bag"
    metrics, stderr = offline_bc(bag, tmp_path, name, "--map", str(write_map(tmp_path, recording_map)))
    assert set(metrics["baselines"]) == {"constant", "hold"}, "observation and action differ in shape: no copy-state"
    assert not metrics["previous_action"], "a velocity command beside a pose: auto conditions on the state alone"
    assert metrics["beats_baselines"] == {"constant": True, "hold": True}, metrics
    assert metrics["validation"]["nll"] < metrics["baselines"]["hold"]["nll"] < metrics["baselines"]["constant"]["nll"]
    assert not metrics["warnings"], metrics["warnings"]
    assert f"[BC] epoch {metrics['epochs']}/300" in stderr, "stderr is a pipe here: progress comes as lines"


@pytest.mark.slow
def test_bc_on_the_g1_lerobot_dataset_beats_every_baseline(testdata: Path, tmp_path: Path) -> None:
    """Joint targets beside joint positions, at 30 fps: the default conditions on the previous
    target and predicts its change, and so beats holding it as well as copying the state."""
    metrics, _ = offline_bc(testdata / "lerobot" / "g1_v21", tmp_path, "g1")
    assert metrics["previous_action"] is True
    assert metrics["beats_baselines"] == {"constant": True, "hold": True, "copy_state": True}, metrics
    assert not metrics["warnings"], metrics["warnings"]

"""Offline BC on real robot recordings beats the trivial baselines at default settings, on held-out
steps: the turtlesim bag in ../shared/testdata (a person teleoperating turtle1 from the keyboard; a
controller making turtle2 follow it, at most seeds) and, as a slow test, the Unitree G1 LeRobot dataset. The
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


def offline_bc(source: Path, tmp_path: Path, name: str, *convert_args: str, train_args: tuple[str, ...] = ()) -> tuple[dict, str]:
    tmp_path.mkdir(exist_ok=True)
    demos = tmp_path / f"{name}.mcap"
    converted = run_cli("convert", str(source), *convert_args, "--out", str(demos), "--quiet", timeout=600)
    assert converted.returncode == 0, converted.stderr
    trained = run_cli("train", "bc", "--demos", str(demos), *train_args, "--out", str(tmp_path / f"bc-{name}"), timeout=3000)
    assert trained.returncode == 0, trained.stderr
    return json.loads((tmp_path / f"bc-{name}" / "metrics.json").read_text()), trained.stderr


def test_bc_on_the_teleoperated_turtle_beats_the_baselines(testdata: Path, tmp_path: Path) -> None:
    """A person's velocity commands beside the turtle's pose: a recording, so auto conditions on
    the previous command (bench/RESULTS.md, issue 51: better on both scores at each of 8 seeds)."""
    bag = testdata / "ros1" / "plotjuggler_example.bag"
    metrics, stderr = offline_bc(bag, tmp_path, "teleop", "--map", str(write_map(tmp_path, TELEOP_MAP)))
    assert set(metrics["baselines"]) == {"constant", "hold"}, "observation and action differ in shape: no copy-state"
    assert metrics["previous_action"], "a recorded command stream: auto conditions on the previous command"
    assert metrics["beats_baselines"] == {"constant": True, "hold": True}, metrics
    assert metrics["validation"]["nll"] < metrics["baselines"]["hold"]["nll"] < metrics["baselines"]["constant"]["nll"]
    assert not metrics["warnings"], metrics["warnings"]
    assert f"[BC] epoch {metrics['epochs']}/300" in stderr, "stderr is a pipe here: progress comes as lines"


def _hold_warning(metrics: dict, other: str) -> str:
    scores, hold = metrics["validation"], metrics["baselines"]["hold"]
    sees = "the state alone" if other == "off" else "the previous action, as the hold baseline does"
    return (f"BC does not beat the hold baseline on the held-out transitions (MSE {scores['mse']:.4g} against "
            f"{hold['mse']:.4g}); try --previous-action {other}: the policy then sees {sees}")


def test_bc_on_the_follower_beats_the_baselines_at_most_seeds_and_says_what_lost(testdata: Path, tmp_path: Path) -> None:
    """A controller making turtle2 follow turtle1: 172 training and 43 held-out steps, whose
    scores move with the seed (bench/RESULTS.md, issue 51: conditioned on the previous command,
    BC beats both baselines at 7 of 8 seeds; on the state alone at 5 of 8). Where BC loses to
    holding the command on squared error while its NLL is far lower (seed 0; seed 1 on the state
    alone), the warning quotes the squared error, not the NLL in which BC won, and suggests the
    other --previous-action setting."""
    bag = testdata / "ros1" / "plotjuggler_example.bag"
    recording_map = ["--map", str(write_map(tmp_path, FOLLOWER_MAP))]
    runs = {seed: offline_bc(bag, tmp_path / f"auto-{seed}", "follower", *recording_map, train_args=("--seed", seed))[0]
            for seed in ("0", "1", "2")}
    assert all(metrics["previous_action"] for metrics in runs.values())
    beaten = [seed for seed, metrics in runs.items() if metrics["beats_baselines"] == {"constant": True, "hold": True}]
    assert beaten == ["1", "2"], {seed: (m["validation"], m["baselines"]) for seed, m in runs.items()}
    for seed in ("1", "2"):
        assert not runs[seed]["warnings"], runs[seed]["warnings"]
    off, stderr = offline_bc(bag, tmp_path / "off-1", "follower", *recording_map, train_args=("--previous-action", "off", "--seed", "1"))
    for metrics, other in ((runs["0"], "off"), (off, "on")):
        scores, hold = metrics["validation"], metrics["baselines"]["hold"]
        assert metrics["beats_baselines"] == {"constant": True, "hold": False}, metrics
        assert scores["nll"] < hold["nll"] and scores["mse"] >= hold["mse"], (scores, hold)
        assert metrics["warnings"] == [_hold_warning(metrics, other)]
    assert f"warning: {_hold_warning(off, 'on')}" in stderr


@pytest.mark.slow
def test_bc_on_the_g1_lerobot_dataset_beats_every_baseline(testdata: Path, tmp_path: Path) -> None:
    """Joint targets beside joint positions, at 30 fps: the default conditions on the previous
    target and predicts its change, and so beats holding it as well as copying the state."""
    metrics, _ = offline_bc(testdata / "lerobot" / "g1_v21", tmp_path, "g1")
    assert metrics["previous_action"] is True
    assert metrics["beats_baselines"] == {"constant": True, "hold": True, "copy_state": True}, metrics
    assert not metrics["warnings"], metrics["warnings"]

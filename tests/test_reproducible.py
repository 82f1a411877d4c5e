"""`--seed` reproduces a run: every trainer, run twice in separate processes (each with its own
random torch start seed), writes bit-identical weights."""

from __future__ import annotations

import subprocess
import sys

import pytest
from safetensors.torch import load_file
from support import DATASETS, REPO, run_cli

GRID = "imitation/GridWorld8x8Slippery-v0"
CARTPOLE = str(DATASETS / "CartPole-v1.mcap")
FIXED_HORIZON = str(DATASETS / "CartPoleFixedHorizon-v0.mcap")

TRAINERS = {
    "bc": ["train", "bc", "--demos", CARTPOLE, "--env", "CartPole-v1", "--epochs", "2", "--hidden", "16,16"],
    "dagger": ["train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--rounds", "2", "--episodes-per-round", "1",
               "--epochs", "2", "--hidden", "16,16"],
    "ppo": ["train", "ppo", "--env", "CartPole-v1", "--steps", "1024"],
    "gcl": ["train", "irl", "--method", "gcl", "--env", "imitation/CartPoleFixedHorizon-v0", "--demos", FIXED_HORIZON, "--steps", "1024",
            "--hidden", "16"],
}


def _weights(run) -> dict:
    return load_file(str(run / "model.safetensors"))


def _assert_bit_identical(first: dict, second: dict) -> None:
    assert first.keys() == second.keys()
    different = [name for name in first if (first[name].dtype, first[name].shape, first[name].numpy().tobytes()) != (second[name].dtype, second[name].shape, second[name].numpy().tobytes())]
    assert not different, f"tensors that differ between the two runs: {different}"


def _run_twice(args: list[str], runs: list) -> None:
    """The same command into each of `runs`, side by side: two processes, two torch start seeds."""
    processes = [subprocess.Popen([sys.executable, str(REPO / "cli.py"), *args, "--out", str(run)], stdout=subprocess.DEVNULL,
                                  stderr=subprocess.PIPE, text=True, cwd=REPO) for run in runs]
    for process in processes:
        _, stderr = process.communicate(timeout=300)
        assert process.returncode == 0, stderr[-2000:]


@pytest.mark.parametrize("trainer", sorted(TRAINERS))
def test_two_runs_with_one_seed_write_identical_weights(tmp_path, trainer) -> None:
    runs = [tmp_path / f"run{i}" for i in range(2)]
    _run_twice([*TRAINERS[trainer], "--seed", "3", "--quiet"], runs)
    _assert_bit_identical(_weights(runs[0]), _weights(runs[1]))


@pytest.mark.parametrize(("method", "env_id"), [("maxent", "imitation/GridWorld8x8-v0"), ("mce", GRID)])
def test_tabular_irl_with_one_seed_writes_identical_rewards(tmp_path, method, env_id) -> None:
    demos = tmp_path / "grid.mcap"
    assert run_cli("record", "--env", env_id, "--expert", "scripted", "--episodes", "10", "--quiet", "--out", str(demos)).returncode == 0
    runs = [tmp_path / f"run{i}" for i in range(2)]
    _run_twice(["train", "irl", "--method", method, "--env", env_id, "--demos", str(demos), "--iterations", "30", "--hidden", "8", "--seed", "3",
                "--quiet"], runs)
    _assert_bit_identical(_weights(runs[0]), _weights(runs[1]))

"""`train irl --method` is a registry (imitation/jobs/irl_methods.py): a method registered from
outside the package, with a config of its own, gets its --method choice and its flags (help
labelled with its name), trains through the command line into a reward run that `train ppo
--reward` reads, and a sweep knows its metric."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from support import DATASETS

import cli
from imitation.flags import flag
from imitation.jobs.irl_methods import IRL_METHODS, IRLMethod, IRLRun, register
from imitation.jobs.run_directory import save_reward_run
from imitation.rewards import make_reward_model, read_reward_run


@dataclass(kw_only=True)
class ToyConfig:
    width: int = flag(3, metavar="W", help="the toy reward's hidden width")


def train_toy(run: IRLRun) -> dict[str, Any]:
    """A toy method: an untrained reward network of the configured width on the env's spaces."""
    config = run.config(ToyConfig)
    env = gym.make(run.env_id)
    model = make_reward_model(env.observation_space, env.action_space, hidden_sizes=[config.width])
    save_reward_run(model, run.out, env_id=run.env_id, source=f"toy on {len(run.demos)} demo file(s)")
    return {"run": run.out, "width": config.width}


@pytest.fixture
def toy_method() -> Iterator[None]:
    register(IRLMethod("toy", ((ToyConfig, None),), train_toy, lambda run, result: f"toy reward: {result['run']}", ("loss", "min", "last")))
    yield
    del IRL_METHODS["toy"]


def test_a_registered_method_trains_through_the_command_line(toy_method: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    helps = {option: action.help for action in cli._subcommands(cli._subcommands(cli.make_parser())["train"])["irl"]._actions for option in action.option_strings}
    assert helps["--width"] == "toy: the toy reward's hidden width (default: 3)"
    out = tmp_path / "toy"
    argv = ["train", "irl", "--method", "toy", "--env", "CartPole-v1", "--demos", str(DATASETS / "CartPole-v1.mcap"), "--width", "5", "--out", str(out)]
    assert cli.main([*argv, "--json"]) == 0
    assert json.loads(capsys.readouterr().out.splitlines()[-1]) == {"run": str(out), "width": 5}
    reward = read_reward_run(out)  # as `train ppo --reward` reads it
    assert reward.reward.config.hidden_sizes == [5] and reward.config["env_id"] == "CartPole-v1"
    weights = sum(int(np.prod(tensor.shape)) for tensor in reward.weights.values())
    assert weights == 4 * 5 + 5 + 5 + 1  # CartPole's 4 state features into 5 units, then one output


def test_a_registered_method_refuses_what_it_does_not_do(toy_method: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    base = ["train", "irl", "--method", "toy", "--env", "CartPole-v1", "--demos", str(DATASETS / "CartPole-v1.mcap"), "--out", str(tmp_path / "r")]
    assert cli.main([*base, "--workers", "2"]) == 1
    assert capsys.readouterr().err == "error: --workers: --method toy has no PPO rollouts to spread; use it with gcl, airl or gail\n"
    assert cli.main([*base, "--pool-rollouts", "2"]) == 1
    assert capsys.readouterr().err == "error: --pool-rollouts: sets the training of GAIL's and AIRL's discriminator, and --method toy has none\n"
    assert not (tmp_path / "r").exists()


def test_a_sweep_takes_a_registered_methods_metric(toy_method: None) -> None:
    from imitation.train_commands import default_metric

    assert default_metric("train irl", {"method": "toy"}) == ("loss", "min", "last")

"""Policy kinds are a registry (imitation/policy_kinds.py): a kind registered from outside the
package, with nothing but its `ImitationPolicy` subclass and one entry, trains through `train bc
--policy` and `train dagger --policy`, loads for `eval policy` and `record --expert RUN_DIR`
(which start each episode with its `reset`), and is refused by name where it is unknown."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS
from torch import nn

import cli
from imitation.data.loader import TransitionTensors
from imitation.data.mcap.reader import DemoFile
from imitation.policy_kinds import POLICY_KINDS, PolicyKind, load_policy, register
from imitation.policy_protocol import ImitationObjective, ImitationPolicy, PolicyConfig

CARTPOLE_DEMOS = str(DATASETS / "CartPole-v1.mcap")


def _sizes(config: PolicyConfig) -> tuple[int, int]:
    observations = gym.spaces.Box(-np.inf, np.inf, tuple(config.observation_space["shape"]))
    return int(np.prod(observations.shape)), int(config.action_space["n"])


class LinearSoftmax(ImitationPolicy):
    """A toy kind: logits linear in the raw observation, fitted by cross-entropy; it counts the
    episodes it was told started (across instances: `eval policy` builds its own)."""

    episodes_started = 0

    def __init__(self, config: PolicyConfig) -> None:
        super().__init__(config)
        inputs, outputs = _sizes(config)
        self.linear = nn.Linear(inputs, outputs)

    def _logits(self, observations: Any) -> torch.Tensor:
        return self.linear(observations.float().reshape(len(observations), -1))

    def imitation_loss(self, batch: TransitionTensors, objective: ImitationObjective) -> tuple[torch.Tensor, torch.Tensor]:
        assert isinstance(batch.actions, torch.Tensor)
        fit = nn.functional.cross_entropy(self._logits(batch.observations), batch.actions.long().reshape(-1))
        return fit, fit

    def point_action(self, observations: Any) -> torch.Tensor:
        return self._logits(observations).argmax(-1)

    def predict(self, observations: Any, *, deterministic: bool = True) -> np.ndarray:
        with torch.no_grad():
            return self.point_action(torch.as_tensor(np.array(observations))).numpy()

    def reset(self) -> None:
        LinearSoftmax.episodes_started += 1


def _planned(config: PolicyConfig) -> int:
    inputs, outputs = _sizes(config)
    return (inputs + 1) * outputs


@pytest.fixture
def linear_kind() -> Iterator[None]:
    register(PolicyKind("linear", LinearSoftmax, _planned))
    yield
    del POLICY_KINDS["linear"]


def _main(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, Any]:
    assert cli.main([*argv, "--json"]) == 0, capsys.readouterr().err
    return json.loads(capsys.readouterr().out.splitlines()[-1])


def test_a_registered_kind_trains_evaluates_and_records_through_the_command_line(
    linear_kind: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = tmp_path / "bc"
    trained = _main(capsys, "train", "bc", "--policy", "linear", "--env", "CartPole-v1", "--demos", CARTPOLE_DEMOS, "--epochs", "30", "--out", str(run))
    config = json.loads((run / "config.json").read_text())
    assert config["policy"]["kind"] == "linear" and config["bc"]["policy"] == "linear"
    # Scored by what the kind has: an error rate, no NLL (it has no likelihood).
    assert set(trained["validation"]) == {"error_rate"} and trained["validation"]["error_rate"] < 0.2
    assert trained["beats_baselines"] == {"constant": True}
    assert trained["eval"]["mean_return"] > 100  # a linear rule balances the pole; random play lasts ~22 steps

    before = LinearSoftmax.episodes_started
    evaluated = _main(capsys, "eval", "policy", str(run), "--env", "CartPole-v1", "--episodes", "3")
    assert evaluated["episodes"] == 3
    assert LinearSoftmax.episodes_started - before == 3

    demos = tmp_path / "by-linear.mcap"
    _main(capsys, "record", "--env", "CartPole-v1", "--expert", str(run), "--episodes", "2", "--seed", "3", "--out", str(demos))
    episodes = DemoFile(demos).read_episodes()
    policy = load_policy(run)
    assert isinstance(policy, LinearSoftmax)
    for episode in episodes:
        assert np.array_equal(episode.actions, policy.predict(episode.observations[:-1]))


def test_dagger_trains_a_registered_kind(linear_kind: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "dagger"
    _main(capsys, "train", "dagger", "--policy", "linear", "--env", "CartPole-v1", "--expert", "scripted", "--rounds", "1", "--episodes-per-round", "2", "--epochs", "5", "--out", str(run))
    assert json.loads((run / "config.json").read_text())["policy"]["kind"] == "linear"


def test_an_unknown_kind_is_refused_by_name(linear_kind: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "never"
    assert cli.main(["train", "bc", "--policy", "gaussian-mixture", "--env", "CartPole-v1", "--demos", CARTPOLE_DEMOS, "--out", str(out)]) == 1
    assert capsys.readouterr().err == "error: --policy must be a registered policy kind (actor-critic, chunk, diffusion, linear), got 'gaussian-mixture'\n"
    assert not out.exists() and not Path(f"{out}.partial").exists()


def test_a_run_of_a_kind_not_registered_here_is_refused_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "bc"
    register(PolicyKind("linear", LinearSoftmax, _planned))
    try:
        _main(capsys, "train", "bc", "--policy", "linear", "--demos", CARTPOLE_DEMOS, "--epochs", "2", "--out", str(run))
    finally:
        del POLICY_KINDS["linear"]
    assert cli.main(["eval", "policy", str(run), "--env", "CartPole-v1", "--episodes", "1"]) == 1
    assert capsys.readouterr().err == f"error: {run}: the policy is of kind 'linear', which is not registered here (known: actor-critic, chunk, diffusion)\n"

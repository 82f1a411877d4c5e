"""The action-chunking policy kind (imitation/chunk_policy.py): its masked L1 / squared / cross-
entropy loss against values worked by hand, its receding-horizon execution and reset, and the
kind end to end through the command line (train bc, eval policy, record --expert, train dagger),
with its one-line refusals."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS

import cli
from imitation.algorithms.bc import BCConfig, _mean_loss
from imitation.chunk_policy import ActionChunking
from imitation.data.dataset import DemoDataset
from imitation.data.loader import load_transitions, transitions_to_torch
from imitation.data.mcap.reader import DemoFile
from imitation.data.stream import StreamingLoader
from imitation.data.windows import WindowBatch
from imitation.errors import ImitationError
from imitation.policy_kinds import build_policy, load_policy
from imitation.policy_protocol import ImitationObjective

BOX1 = gym.spaces.Box(-np.inf, np.inf, (1,), np.float32)
CARTPOLE_DEMOS = str(DATASETS / "CartPole-v1.mcap")
PENDULUM = ["--env", "Pendulum-v1", "--demos", str(DATASETS / "Pendulum-v1.mcap")]


def _constant(action_space: gym.Space, outputs: list[float], *, chunk: int, history: int = 1, execute: int | None = None,
              ensemble: float | None = None) -> ActionChunking:
    """A linear chunk policy (no hidden layer) whose head ignores the observation and outputs `outputs`."""
    policy = build_policy("chunk", BOX1, action_space, hidden_sizes=[], chunk=chunk, history=history, execute=execute, ensemble=ensemble)
    assert isinstance(policy, ActionChunking)
    with torch.no_grad():
        policy.head.weight.zero_()
        policy.head.bias.copy_(torch.tensor(outputs))
    return policy


def _windows(actions: list[list[Any]], pad: list[list[bool]]) -> WindowBatch:
    return WindowBatch(
        observations=torch.zeros(len(actions), 1, 1),
        observation_pad=torch.zeros(len(actions), 1, dtype=torch.bool),
        actions=torch.tensor(actions),
        action_pad=torch.tensor(pad),
    )


def test_the_box_loss_is_the_mean_error_over_the_steps_inside_the_episode() -> None:
    policy = _constant(gym.spaces.Box(-5, 5, (1,), np.float32), [0.5, 1.0], chunk=2)
    batch = _windows([[[1.0], [2.0]], [[3.0], [3.0]]], [[False, False], [False, True]])
    _, l1 = policy.imitation_loss(batch, ImitationObjective(loss="nll"))
    assert l1.item() == pytest.approx((0.5 + 1.0 + 2.5) / 3)  # |0.5-1|, |1-2|, |0.5-3|; the padded step left out
    _, squared = policy.imitation_loss(batch, ImitationObjective(loss="mse"))
    assert squared.item() == pytest.approx((0.25 + 1.0 + 6.25) / 3)
    regularised, fit = policy.imitation_loss(batch, ImitationObjective(loss="nll", l2_coef=0.1))
    weights = sum(float((parameter**2).sum()) for parameter in policy.parameters())
    assert regularised.item() == pytest.approx(fit.item() + 0.1 * weights)


def test_the_box_loss_is_in_the_actions_standardised_units() -> None:
    policy = _constant(gym.spaces.Box(-5, 5, (1,), np.float32), [0.0], chunk=1)
    policy.fit_action_normalizer(torch.tensor([[1.0], [3.0]]), None)  # mean 2, std 1
    batch = _windows([[[4.0]]], [[False]])
    assert policy.imitation_loss(batch, ImitationObjective())[1].item() == pytest.approx(2.0)  # |0 - (4-2)/1|
    assert policy.point_action(torch.zeros(1, 1)).tolist() == [[2.0]]  # the head's 0 is the mean action


def test_the_discrete_loss_is_each_steps_cross_entropy() -> None:
    policy = _constant(gym.spaces.Discrete(3, start=1), [0.0, 0.0, math.log(2.0), 0.0, 0.0, 0.0], chunk=2)
    batch = _windows([[3, 1], [2, 2]], [[False, False], [False, True]])
    _, fit = policy.imitation_loss(batch, ImitationObjective())
    # Step 0's logits (0, 0, ln 2): p = (1/4, 1/4, 1/2); step 1's uniform. Actions start at 1.
    expected = (-math.log(0.5) - math.log(1 / 3) - math.log(0.25)) / 3
    assert fit.item() == pytest.approx(expected)
    assert policy.point_action(torch.zeros(2, 1)).tolist() == [3, 3]


def test_observation_noise_adds_sigma_z_to_the_normalised_observations_while_training_only() -> None:
    policy = build_policy("chunk", BOX1, BOX1, hidden_sizes=[], chunk=1)
    with torch.no_grad():  # the head passes the normalised observation through: the chunk is o / √(1 + ε)
        policy.head.weight.fill_(1.0)
        policy.head.bias.zero_()
    batch = WindowBatch(torch.tensor([[[0.5]], [[-1.0]]]), torch.zeros(2, 1, dtype=torch.bool), torch.zeros(2, 1, 1), torch.zeros(2, 1, dtype=torch.bool))
    normalised = policy.observed(batch.observations).reshape(-1)
    objective = ImitationObjective(observation_noise=0.5)
    torch.manual_seed(7)
    _, fit = policy.train().imitation_loss(batch, objective)
    torch.manual_seed(7)
    assert fit.item() == pytest.approx((normalised + 0.5 * torch.randn(2)).abs().mean().item(), rel=1e-6)  # L1 to the zero target
    _, scored = policy.eval().imitation_loss(batch, objective)
    assert scored.item() == pytest.approx(normalised.abs().mean().item(), rel=1e-6)


def test_a_dict_observation_is_read_as_its_vector_leaves_side_by_side_in_key_order() -> None:
    space = gym.spaces.Dict({"b": gym.spaces.Box(-1, 1, (2,), np.float32), "a": gym.spaces.Discrete(3)})
    policy = build_policy("chunk", space, BOX1, hidden_sizes=[], history=2, chunk=2)
    windows = {"a": torch.tensor([[0, 2]]), "b": torch.tensor([[[0.5, -0.5], [0.25, 1.0]]])}  # one window of 2 steps
    expected = torch.tensor([[[1.0, 0.0, 0.0, 0.5, -0.5], [0.0, 0.0, 1.0, 0.25, 1.0]]])  # a one-hot, then b
    assert torch.equal(policy.flat(windows, 2), expected)
    policy.update_normalizer({"a": torch.tensor([0, 2]), "b": torch.tensor([[0.5, -0.5], [0.25, 1.0]])})
    assert torch.allclose(policy.obs_rms.mean, expected[0].mean(0).double(), atol=1e-3)  # beside the statistics' prior count ε
    step = {"a": np.array([2]), "b": np.array([[0.25, 1.0]], dtype=np.float32)}
    with torch.no_grad():
        planned = policy._env_actions(policy._chunk(expected[:, 1:].expand(1, 2, 5)))[:, 0].numpy()
    np.testing.assert_allclose(policy.predict(step), planned, rtol=1e-6)  # the first step stands in for the one before


def test_sequence_kinds_read_a_robots_state_leaf_beside_its_camera(testdata: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    demos = tmp_path / "so101.mcap"
    source = testdata / "lerobot" / "so101_v30"
    assert cli.main(["convert", str(source), "--out", str(demos), "--image-size", "24x32", "--quiet"]) == 0, capsys.readouterr().err
    for kind in ("chunk", "diffusion"):
        flags = ["--policy", kind, "--history", "2", "--chunk", "4", "--observation-keys", "state", "--hidden", "16", "--epochs", "1"]
        assert cli.main(["train", "bc", "--demos", str(demos), *flags, "--out", str(tmp_path / kind), "--quiet"]) == 0, capsys.readouterr().err
        policy = load_policy(tmp_path / kind)
        observation = {"images.wrist": np.zeros((1, 24, 32, 3), np.uint8), "state": np.zeros((1, 6), np.float32)}
        assert policy.predict(observation).shape == (1, 6)


def test_it_executes_k_actions_of_a_chunk_then_plans_again_and_forgets_at_reset() -> None:
    policy = _constant(gym.spaces.Box(-5, 5, (1,), np.float32), [1.0, 2.0, 3.0, 4.0], chunk=4, history=2, execute=3)
    plans = []
    original = policy._chunk

    def counted(history: torch.Tensor) -> torch.Tensor:
        plans.append(history.clone())
        return original(history)

    policy._chunk = counted  # type: ignore[method-assign]
    actions = [float(policy.predict(np.array([[float(step)]]))[0, 0]) for step in range(7)]
    assert actions == [1.0, 2.0, 3.0, 1.0, 2.0, 3.0, 1.0]
    assert [plan[0, :, 0].tolist() for plan in plans] == [[0.0, 0.0], [2.0, 3.0], [5.0, 6.0]]  # first observation repeated
    policy.reset()
    assert float(policy.predict(np.array([[9.0]]))[0, 0]) == 1.0
    assert plans[-1][0, :, 0].tolist() == [9.0, 9.0]


@pytest.mark.parametrize("m", [0.0, math.log(2.0)])
def test_temporal_ensembling_averages_every_plan_that_covers_the_step(m: float) -> None:
    policy = _constant(gym.spaces.Box(-5, 5, (1,), np.float32), [1.0, 2.0, 3.0], chunk=3, ensemble=m)
    actions = [float(policy.predict(np.zeros((1, 1)))[0, 0]) for _ in range(4)]
    w = [math.exp(-m * i) for i in range(3)]  # the i-th oldest plan's weight
    # Step t's plans, oldest first: made at t-2, t-1, t, each planning (1, 2, 3) from when it was made.
    assert actions == pytest.approx([1.0, (2 * w[0] + 1 * w[1]) / (w[0] + w[1]), (3 * w[0] + 2 * w[1] + 1 * w[2]) / sum(w), (3 * w[0] + 2 * w[1] + 1 * w[2]) / sum(w)])
    policy.reset()
    assert float(policy.predict(np.zeros((1, 1)))[0, 0]) == 1.0
    one = _constant(gym.spaces.Box(-5, 5, (1,), np.float32), [4.0], chunk=1, ensemble=0.5)
    assert [float(one.predict(np.zeros((1, 1)))[0, 0]) for _ in range(3)] == [4.0, 4.0, 4.0] and len(one._plans) == 1


def test_actions_are_clipped_to_the_space() -> None:
    policy = _constant(gym.spaces.Box(-2, 2, (1,), np.float32), [7.0], chunk=1)
    assert policy.predict(np.zeros((1, 1))).tolist() == [[2.0]]


def test_what_it_cannot_read_is_refused_in_one_line() -> None:
    with pytest.raises(ImitationError, match="reads Box observations or Dicts of Box and Discrete leaves"):
        build_policy("chunk", gym.spaces.Discrete(4), gym.spaces.Discrete(2), chunk=2)
    with pytest.raises(ImitationError, match="predicts Box or Discrete actions, not MultiDiscrete"):
        build_policy("chunk", BOX1, gym.spaces.MultiDiscrete([2, 2]), chunk=2)
    with pytest.raises(ImitationError, match="trains on windows"):
        _constant(gym.spaces.Discrete(2), [0.0, 0.0], chunk=1).imitation_loss(None, ImitationObjective())  # type: ignore[arg-type]
    with pytest.raises(ImitationError, match="temporal ensembling averages Box actions"):
        build_policy("chunk", BOX1, gym.spaces.Discrete(2), chunk=2, ensemble=0.1)
    with pytest.raises(ImitationError, match="reads one observation and predicts one action, not 1 and 4"):
        build_policy("actor-critic", BOX1, gym.spaces.Discrete(2), chunk=4)


def test_the_kind_trains_evaluates_records_and_runs_dagger_through_the_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "chunk"

    def main(*argv: str) -> dict[str, Any]:
        assert cli.main([*argv, "--json"]) == 0, capsys.readouterr().err
        return json.loads(capsys.readouterr().out.splitlines()[-1])

    trained = main("train", "bc", "--policy", "chunk", "--chunk", "4", "--execute", "1", "--env", "CartPole-v1", "--demos", CARTPOLE_DEMOS, "--epochs", "8", "--out", str(run))
    policy = json.loads((run / "config.json").read_text())["policy"]
    assert (policy["kind"], policy["history"], policy["chunk"], policy["execute"]) == ("chunk", 1, 4, 1)
    assert trained["validation"]["error_rate"] < 0.1 and trained["beats_baselines"] == {"constant": True}
    assert trained["eval"]["mean_return"] >= 400  # the bundled expert's 500; random play lasts ~22 steps
    assert main("eval", "policy", str(run), "--env", "CartPole-v1", "--episodes", "2")["episodes"] == 2
    demos = tmp_path / "by-chunk.mcap"
    main("record", "--env", "CartPole-v1", "--expert", str(run), "--episodes", "1", "--seed", "3", "--out", str(demos))
    (episode,) = DemoFile(demos).read_episodes()
    loaded = load_policy(run)
    assert np.array_equal(episode.actions, np.concatenate([loaded.predict(o[None]) for o in episode.observations[:-1]]))
    dagger = tmp_path / "dagger"
    main("train", "dagger", "--policy", "chunk", "--chunk", "2", "--env", "CartPole-v1", "--expert", "scripted", "--rounds", "1", "--episodes-per-round", "2", "--epochs", "3", "--out", str(dagger))
    assert json.loads((dagger / "config.json").read_text())["policy"]["chunk"] == 2


def test_a_streamed_policy_scores_the_windows_the_in_memory_loader_gathers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    dataset = DemoDataset([PENDULUM[-1]])
    episodes = list(range(3))
    torch.manual_seed(0)
    policy = build_policy("chunk", dataset.observation_space, dataset.action_space, hidden_sizes=[16], history=3, chunk=5)
    config = BCConfig(batch_size=4096)  # one batch each way: the loss is a mean over the unpadded steps of a batch
    streamed = StreamingLoader(dataset, episodes, batch_size=4096, memory=2**24, shuffle=False, window=policy.window)
    in_memory = transitions_to_torch(load_transitions(dataset, episodes=episodes, next_observations=False))
    assert _mean_loss(policy, streamed, config) == pytest.approx(_mean_loss(policy, in_memory, config), rel=1e-6)
    run = tmp_path / "streamed"
    flags = ["--policy", "chunk", "--history", "2", "--chunk", "4", "--stream-memory", "64", "--epochs", "2"]
    assert cli.main(["train", "bc", *PENDULUM, *flags, "--out", str(run), "--json", "--quiet"]) == 0, capsys.readouterr().err
    trained = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert trained["epochs"] == 2 and math.isfinite(trained["best_validation_loss"])
    assert json.loads((run / "config.json").read_text())["policy"]["chunk"] == 4


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--chunk", "4"], "--chunk is for sequence policies (chunk, diffusion); the actor-critic policy reads one observation and predicts one action"),
        (["--policy", "chunk", "--chunk", "4", "--execute", "5"], "--execute must be in [1, --chunk 4], got 5"),
        (["--observation-noise", "0.1"], "--observation-noise is for sequence policies (chunk, diffusion); the actor-critic policy reads one"),
        (["--policy", "chunk", "--observation-noise", "-1"], "--observation-noise must be in [0, 10], got -1.0"),
        (["--policy", "chunk", "--chunk", "4", "--execute", "2", "--ensemble", "0.1", *PENDULUM], "--ensemble plans every step; leave --execute unset"),
        (["--policy", "chunk", "--chunk", "4", "--ensemble", "-1", *PENDULUM], "--ensemble must be a weight in [0, 1000), got -1.0"),
        (["--policy", "chunk", "--chunk", "4", "--ensemble", "0.1"], "--env CartPole-v1: temporal ensembling averages Box actions"),
        (["--policy", "chunk", "--previous-action", "on", *PENDULUM],
         "the chunk policy is not conditioned on the previous action"),
        (["--policy", "chunk", "--env", "imitation/GridWorld8x8-v0", "--demos", str(DATASETS / "GridWorld8x8-v0.mcap")],
         "--env imitation/GridWorld8x8-v0: the chunk policy reads Box observations or Dicts of Box and Discrete leaves, not Discrete(64)"),
    ],
)
def test_sequence_flags_are_refused_where_they_do_not_apply(flags: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r"
    assert cli.main(["train", "bc", "--demos", CARTPOLE_DEMOS, "--env", "CartPole-v1", *flags, "--out", str(out)]) == 1  # later flags win
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error, error
    assert not out.exists() and not Path(f"{out}.partial").exists()

"""BC on camera frames of a real size (issue 51, items 1 and 6, the training side).

`train bc --image-size HxW --crop T,L,H,W` crops and resizes every frame once, as it is decoded (on
the loader's fast path, its general one for files with their own clock, and in the streaming
loader); the policy keeps both, and the env it acts in does the same to its frames. The
CNN's size and a training step's memory are checked before anything loads, each refusal one line
naming the flag that helps. Progress comes from the start (the loading, then every epoch's batches,
on a log as on a terminal), and Ctrl-C within a long epoch stops at the next minibatch with a
checkpoint from which --resume ends exactly where an uninterrupted run does.

The frames are real: CartPole rendered at 480×640 by `imitation record --pixels 480x640`."""

from __future__ import annotations

import dataclasses
import io
import json
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from safetensors.torch import load_file
from support import REPO, run_cli, run_cli_many
from test_crash_safety import changed
from test_cli import assert_one_line_error, last_json

from imitation.algorithms.bc import BCConfig, BehaviouralCloning, fit, policy_options
from imitation.checkpoints import snapshot
from imitation.data.columns import read_transitions
from imitation.data.dataset import DemoDataset
from imitation.data.frame_transform import FrameTransform
from imitation.data.loader import load_transitions, split_episodes, transitions_to_torch
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.writer import write_episodes
from imitation.data.stream import StreamingLoader
from imitation.errors import ImitationError
from imitation.policies import make_policy
from imitation.progress import ProgressLines, activity

GIB = 2**30


@pytest.fixture(scope="module")
def camera_demos(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Four episodes of a random CartPole player, its frames rendered at 480×640 (PNG)."""
    path = tmp_path_factory.mktemp("camera") / "cartpole-480x640.mcap"
    result = run_cli("record", "--env", "CartPole-v1", "--expert", "random", "--pixels", "480x640", "--episodes", "4",
                     "--seed", "0", "--quiet", "--out", str(path))
    assert result.returncode == 0, result.stderr
    return path


@pytest.fixture(scope="module")
def timed_demos(camera_demos: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same episodes with a clock of their own (a `/time` channel, as a converted bag has),
    which the loader reads through its general path, an episode at a time."""
    demo = DemoFile(camera_demos)
    episodes = [dataclasses.replace(episode, timestamps=np.arange(len(episode) + 1, dtype=np.int64) * 20_000_000 + 10**15)
                for episode in demo.read_episodes()]
    return write_episodes(tmp_path_factory.mktemp("timed") / "timed.mcap", episodes, env_id=demo.env_id,
                          observation_space=demo.observation_space, action_space=demo.action_space, image_codec="png")


TRANSFORM = FrameTransform((48, 64), (40, 80, 400, 480))


def test_frames_are_cropped_and_resized_as_they_load_exactly_as_the_stored_frames_would_be(camera_demos: Path, timed_demos: Path) -> None:
    whole = load_transitions(DemoDataset(camera_demos))
    assert whole.observations["pixels"].shape[1:] == (480, 640, 3)
    expected = np.stack([TRANSFORM(frame) for frame in whole.observations["pixels"]])
    expected_next = np.stack([TRANSFORM(frame) for frame in whole.next_observations["pixels"]])
    assert expected.shape[1:] == (48, 64, 3) and expected.std() > 0
    # through the fast path, and the general one (files with their own clock)
    assert read_transitions(DemoDataset(camera_demos), [0], next_observations=False, transform=TRANSFORM) is not None
    assert read_transitions(DemoDataset(timed_demos), [0], next_observations=False, transform=TRANSFORM) is None
    for path in (camera_demos, timed_demos):
        told: list[int] = []
        loaded = load_transitions(DemoDataset(path), transform=TRANSFORM, progress=told.append)
        np.testing.assert_array_equal(loaded.observations["pixels"], expected)
        np.testing.assert_array_equal(loaded.next_observations["pixels"], expected_next)
        np.testing.assert_array_equal(loaded.observations["state"], whole.observations["state"])
        np.testing.assert_array_equal(loaded.actions, whole.actions)
        assert sum(told) == len(whole) + 4  # every step and each episode's final observation
    stream = StreamingLoader(DemoDataset(camera_demos), range(4), batch_size=16, memory=64 * 2**20, shuffle=False, transform=TRANSFORM)
    streamed = torch.cat([batch.observations["pixels"] for batch in stream])
    np.testing.assert_array_equal(streamed.numpy(), expected)


def test_train_bc_learns_at_the_target_size_and_the_env_it_is_evaluated_in_resizes_its_frames_alike(camera_demos: Path, tmp_path: Path) -> None:
    run = tmp_path / "bc"
    trained, evaluated = run_cli_many([
        ["train", "bc", "--demos", camera_demos, "--env", "CartPole-v1", "--image-size", "40x64", "--crop", "100,0,300,640",
         "--epochs", "1", "--epoch-samples", "64", "--batch-size", "32", "--hidden", "16", "--quiet", "--json", "--out", run],
        ["eval", "policy", run, "--env", "CartPole-v1", "--episodes", "1", "--json"],
    ])
    assert last_json(trained)["epochs"] == 1
    config = json.loads((run / "config.json").read_text())
    assert config["bc"]["image_size"] == [40, 64] and config["bc"]["crop"] == [100, 0, 300, 640]
    assert config["policy"]["image_transform"] == {"size": [40, 64], "crop": [100, 0, 300, 640]}
    assert config["policy"]["observation_space"]["spaces"]["pixels"]["shape"] == [40, 64, 3]
    assert last_json(evaluated)["episodes"] == 1  # the env's 400×600 frames rendered at 480×640, cropped and resized


def test_frames_that_make_too_large_a_cnn_or_too_large_a_step_are_refused_before_they_load(camera_demos: Path, tmp_path: Path) -> None:
    frames = gym.spaces.Dict({"pixels": gym.spaces.Box(0, 255, (480, 640, 3), np.uint8)})
    with pytest.raises(ImitationError, match=r"^the CNN on 480×640 frames would hold 139536384 weights, more than the limit "
                                             r"policy_parameters=134217728: train on smaller frames \(train bc --image-size 96x96"):
        make_policy(frames, gym.spaces.Discrete(2))
    args = ["train", "bc", "--demos", str(camera_demos), "--env", "CartPole-v1", "--epochs", "1", "--epoch-samples", "1", "--quiet",
            "--out", str(tmp_path / "bc")]
    (cnn,) = run_cli_many([args])
    assert_one_line_error(cnn, f"error: {camera_demos}: the CNN on 480×640 frames would hold 139536384 weights", "--image-size 96x96")

    def six_gib() -> None:  # the memory this process may have, as a smaller machine's
        resource.setrlimit(resource.RLIMIT_AS, (6 * GIB, 6 * GIB))

    started = time.monotonic()
    step = run_cli("--limit", "policy_parameters=200000000", *changed(args, "--epoch-samples", "4096"), timeout=300, preexec_fn=six_gib)
    assert_one_line_error(step, f"error: {camera_demos}: a BC step on batches of ", " 480×640 frames needs about ",
                          "GiB is available; train on smaller frames (--image-size 96x96 resizes them as they load) or take "
                          "smaller batches (--batch-size)")
    assert time.monotonic() - started < 60  # refused before the demos load
    assert not (tmp_path / "bc.partial").exists()


def test_progress_lines_come_soon_after_the_start_and_while_a_step_runs() -> None:
    stream = io.StringIO()
    with ProgressLines(total=2, desc="BC", unit="epoch", every=0.2, grace=0.1, stream=stream, heartbeat=True,
                       detail=lambda: "batch 3 of 9"):
        assert stream.getvalue() == ""  # work refused at once says its one line alone
        time.sleep(0.5)
    assert stream.getvalue().startswith("[BC] epoch 0/2, batch 3 of 9 (0 s so far)")
    assert stream.getvalue().count("[BC] epoch 0/2, batch 3 of 9 (") >= 2  # no step ended, lines came anyway
    lines = io.StringIO()
    with activity("BC", "loading 10 transitions", every=0.2, grace=0.1, stream=lines) as loading:
        assert loading is not None
        loading.count(4, 11, "observations")
        time.sleep(0.35)
    assert lines.getvalue().startswith("[BC] loading 10 transitions: 4 of 11 observations (0 s so far)\n")
    assert lines.getvalue().count("[BC] loading 10 transitions: 4 of 11 observations (") >= 2


def test_train_bc_on_camera_frames_says_what_it_does_within_seconds_on_a_log(camera_demos: Path, tmp_path: Path) -> None:
    started = time.monotonic()
    process = subprocess.Popen([sys.executable, str(REPO / "cli.py"), "train", "bc", "--demos", str(camera_demos), "--image-size", "40x64",
                                "--epochs", "1", "--epoch-samples", "100000", "--batch-size", "32", "--hidden", "16", "--out",
                                str(tmp_path / "bc")],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    try:
        assert process.stderr is not None
        first = process.stderr.readline()
        seconds = time.monotonic() - started
    finally:
        process.kill()
        process.communicate()
    loading = first.startswith("[BC] loading ") and "frames resized to 40×64 as they load" in first
    assert loading or first.startswith("[BC] epoch 0/1, batch "), first  # the load, or training if the load took under 3 s
    assert seconds < 10, seconds


def _learner(demos: Path, config: BCConfig, *, streamed: bool) -> BehaviouralCloning:
    transform = config.frame_transform()
    assert transform is not None
    dataset = DemoDataset(demos)
    train_ids, validation_ids = split_episodes(len(dataset), validation_fraction=0.25, seed=0)
    if streamed:
        options = {"batch_size": config.batch_size, "memory": 16 * 2**20, "transform": transform}
        train = StreamingLoader(dataset, train_ids, seed=0, min_samples=config.epoch_samples, **options)
        validation = StreamingLoader(dataset, validation_ids, shuffle=False, **options)
    else:
        train = transitions_to_torch(load_transitions(dataset, episodes=train_ids, next_observations=False, transform=transform))
        validation = transitions_to_torch(load_transitions(dataset, episodes=validation_ids, next_observations=False, transform=transform))
    torch.manual_seed(0)
    space = transform.space(dataset.observation_space)
    policy = make_policy(space, dataset.action_space, **policy_options(config, 100), observation_keys=["pixels"])
    return BehaviouralCloning(policy, train, validation, config)


@pytest.mark.parametrize("streamed", [False, True], ids=["in memory", "streamed"])
def test_an_epoch_stopped_between_minibatches_resumes_to_the_uninterrupted_result(camera_demos: Path, streamed: bool) -> None:
    config = BCConfig(epochs=2, batch_size=16, epoch_samples=160, hidden_sizes=[16], image_size=[40, 40], threads=1, seed=3)
    uninterrupted = _learner(camera_demos, config, streamed=streamed)
    rows = fit(uninterrupted)

    stopped = _learner(camera_demos, config, streamed=streamed)
    stopped.stop_when(lambda: stopped.batch >= 4)
    assert stopped.step() is None
    assert stopped.position() == f"batch 4 of {len(stopped.loader)} in epoch 1 of 2" and stopped.epochs == 0
    saved = snapshot(*stopped.state_dict())

    resumed = _learner(camera_demos, config, streamed=streamed)
    resumed.load_state_dict(saved)
    assert resumed.batch == 4
    resumed_rows = fit(resumed)
    assert [row["train_loss"] for row in resumed_rows] == [row["train_loss"] for row in rows]
    assert [row["validation_loss"] for row in resumed_rows] == [row["validation_loss"] for row in rows]
    for name, tensor in uninterrupted.policy.state_dict().items():
        assert torch.equal(tensor, resumed.policy.state_dict()[name]), name


def test_ctrl_c_within_a_long_first_epoch_keeps_a_checkpoint_that_resume_finishes_as_if_never_stopped(camera_demos: Path, tmp_path: Path) -> None:
    def args(out: Path) -> list[str]:
        return ["train", "bc", "--demos", str(camera_demos), "--env", "CartPole-v1", "--image-size", "36x36", "--epochs", "1",
                "--epoch-samples", "40000", "--batch-size", "32", "--hidden", "16", "--threads", "1", "--out", str(out)]

    process = subprocess.Popen([sys.executable, str(REPO / "cli.py"), *args(tmp_path / "stopped")],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    try:
        assert process.stderr is not None
        for line in process.stderr:
            if line.startswith("[BC] epoch 0/1, batch "):  # within the first epoch
                break
        process.send_signal(signal.SIGINT)
        stderr = process.communicate(timeout=120)[1]
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, stderr
    last = [line for line in stderr.splitlines() if line.strip()][-1]
    partial = tmp_path / "stopped.partial"
    assert last.startswith("interrupted: BC stopped after batch ") and " in epoch 1 of 1; its checkpoint is in " in last, last
    assert (partial / "checkpoint" / "state.json").exists()

    resumed, uninterrupted = run_cli_many([[*args(tmp_path / "stopped"), "--resume", "--quiet"], [*args(tmp_path / "whole"), "--quiet"]])
    assert resumed.returncode == 0 and uninterrupted.returncode == 0, (resumed.stderr, uninterrupted.stderr)
    assert not partial.exists()
    mine, theirs = load_file(tmp_path / "stopped" / "model.safetensors"), load_file(tmp_path / "whole" / "model.safetensors")
    assert mine.keys() == theirs.keys() and all(torch.equal(mine[name], theirs[name]) for name in mine)

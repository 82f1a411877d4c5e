"""The recorder: episodes written as they end, surviving kill -9 and Ctrl-C of a real process."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.writer import DemoWriter
from imitation.data.recorder import RecordEpisodes, run_episodes
from imitation.errors import DemoFileError
from imitation.experts.scripted import cartpole
from support import REPO


def record_command(out: Path, episodes: int) -> list[str]:
    # A random CartPole policy ends episodes quickly: many episode boundaries per second.
    return [sys.executable, str(REPO / "cli.py"), "record", "--env", "CartPole-v1", "--expert", "random",
            "--episodes", str(episodes), "--seed", "3", "--out", str(out)]


def wait_for_episodes(partial: Path, count: int, process: subprocess.Popen, timeout: float = 60) -> int:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert process.poll() is None, process.stderr.read() if process.stderr else "recorder exited early"
        if partial.exists():
            try:
                found = len(DemoFile(partial, salvage=True))
            except DemoFileError:
                found = 0
            if found >= count:
                return found
        time.sleep(0.05)
    raise AssertionError(f"fewer than {count} episodes appeared in {partial} within {timeout} s")


def test_recorded_episodes_match_a_replay(tmp_path) -> None:
    env = gym.make("CartPole-v1")
    writer = DemoWriter(tmp_path / "r.mcap", env_id="CartPole-v1", observation_space=env.observation_space, action_space=env.action_space, dt=0.02)
    with writer:
        returns = run_episodes(RecordEpisodes(env, writer), cartpole, episodes=3, seed=7, progress=False)
    demo = DemoFile(tmp_path / "r.mcap")
    assert [f.episode_return for f in demo.episodes] == returns
    replay = gym.make("CartPole-v1")
    for k, episode in enumerate(demo):
        assert episode.metadata["seed"] == 7 + k
        observation, _ = replay.reset(seed=7 + k)
        np.testing.assert_array_equal(episode.observations[0], observation)
        for t, action in enumerate(episode.actions):
            assert action == cartpole(episode.observations[t])
            observation, reward, terminated, truncated, _ = replay.step(int(action))
            np.testing.assert_array_equal(episode.observations[t + 1], observation)
        assert (episode.terminated, episode.truncated) == (terminated, truncated)


def test_abandoned_episode_is_not_written(tmp_path) -> None:
    env = gym.make("CartPole-v1")
    with DemoWriter(tmp_path / "a.mcap", env_id="CartPole-v1", observation_space=env.observation_space, action_space=env.action_space) as writer:
        recorder = RecordEpisodes(env, writer)
        recorder.reset(seed=0)
        recorder.step(0)
        recorder.reset(seed=1)
        done = False
        while not done:
            _, _, terminated, truncated, _ = recorder.step(1)
            done = terminated or truncated
    demo = DemoFile(tmp_path / "a.mcap")
    assert len(demo) == 1 and demo.episodes[0].metadata["seed"] == 1


def test_kill_9_keeps_every_finished_episode(tmp_path) -> None:
    out = tmp_path / "killed.mcap"
    partial = tmp_path / "killed.mcap.partial"
    process = subprocess.Popen(record_command(out, 100_000), stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        wait_for_episodes(partial, 20, process)
    finally:
        os.kill(process.pid, signal.SIGKILL)
        process.wait()
    assert not out.exists(), "the final name appears only for a finished file"
    demo = DemoFile(partial, salvage=True, verify=True)
    assert demo.damage is not None and len(demo) >= 20
    replay = gym.make("CartPole-v1")
    for k, episode in enumerate(demo):
        assert episode.metadata["seed"] == 3 + k
        assert episode.truncated or episode.terminated
        assert len(episode) == demo.episodes[k].length and episode.episode_return == demo.episodes[k].episode_return
        observation, _ = replay.reset(seed=3 + k)
        np.testing.assert_array_equal(episode.observations[0], observation)
    with pytest.raises(DemoFileError, match="damaged or unfinished"):
        DemoFile(partial)


def test_ctrl_c_closes_the_file_with_the_finished_episodes(tmp_path) -> None:
    out = tmp_path / "interrupted.mcap"
    process = subprocess.Popen(record_command(out, 100_000), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    wait_for_episodes(tmp_path / "interrupted.mcap.partial", 10, process)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert lines[-1].startswith("interrupted: kept") and str(out) in lines[-1]
    assert "Traceback" not in stderr
    demo = DemoFile(out, verify=True)
    assert demo.damage is None and len(demo) >= 10
    assert not (tmp_path / "interrupted.mcap.partial").exists()

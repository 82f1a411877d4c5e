"""LZ4 is the default chunk compression of new demo files; files written with zstd before it
became the default (a committed fixture) load unchanged."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
from mcap.reader import make_reader
from support import run_cli

from imitation.data.loader import load_transitions
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.writer import write_episodes
from imitation.data.types import Episode

FIXTURE = Path(__file__).resolve().parent.parent / "fixtures" / "formats" / "cartpole-zstd-v1.mcap"
BOX = gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)


def fixture_episodes() -> list[Episode]:
    """What the fixture was written from (imitation-mcap 0.1.0, compression zstd)."""
    episodes = []
    for k, steps in enumerate((7, 3, 11)):
        rows = np.arange((steps + 1) * 4, dtype=np.float64).reshape(steps + 1, 4)
        episodes.append(
            Episode(observations=(rows / (k + 3)).astype(np.float32), actions=(np.arange(steps) + k) % 2,
                    rewards=np.linspace(-1.0, 1.0, steps) * (k + 1) / 3, terminated=k != 1, truncated=k == 1, metadata={"seed": 100 + k})
        )
    return episodes


def chunk_compressions(path: Path) -> set[str]:
    with open(path, "rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    return {index.compression for index in summary.chunk_indexes}


def test_a_zstd_file_written_before_lz4_became_the_default_loads_identically(tmp_path: Path) -> None:
    assert chunk_compressions(FIXTURE) == {"zstd"}
    demo = DemoFile(FIXTURE, verify=True)
    assert demo.damage is None
    for ours, expected in zip(demo.read_episodes(), fixture_episodes(), strict=True):
        for field in ("observations", "actions", "rewards"):
            got, want = getattr(ours, field), getattr(expected, field)
            assert got.dtype == want.dtype
            np.testing.assert_array_equal(got, want)
        assert (ours.terminated, ours.truncated, ours.metadata) == (expected.terminated, expected.truncated, expected.metadata)
    rewritten = write_episodes(tmp_path / "new.mcap", demo.read_episodes(), env_id="CartPole-v1", observation_space=BOX,
                               action_space=gym.spaces.Discrete(2), dt=0.02)
    assert chunk_compressions(rewritten) == {"lz4"}
    old, new = load_transitions(FIXTURE), load_transitions(rewritten)
    for field in ("observations", "actions", "rewards", "next_observations", "terminated", "truncated", "episode_index"):
        np.testing.assert_array_equal(getattr(old, field), getattr(new, field))


def test_record_writes_lz4_unless_told_zstd(tmp_path: Path) -> None:
    for compression in (None, "zstd"):
        out = tmp_path / f"{compression}.mcap"
        extra = ["--compression", compression] if compression else []
        result = run_cli("record", "--env", "CartPole-v1", "--episodes", "1", "--quiet", "--out", str(out), *extra)
        assert result.returncode == 0, result.stderr
        assert chunk_compressions(out) == {compression or "lz4"}

"""LeRobot datasets ↔ demos: v2.1 and v3.0 datasets other people recorded (../shared/testdata),
and demos → LeRobotDataset v3.0 that lerobot itself loads, and back without loss."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pyarrow.parquet as pq
import pytest

from imitation.data.convert.job import convert
from imitation.data.convert.lerobot import lerobot_to_episodes
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.writer import write_episodes
from imitation.data.types import Episode
from imitation.errors import ImitationError


def frames_by_episode(paths: list[Path]) -> dict[int, dict[str, np.ndarray]]:
    """State and action rows of each episode, read with pyarrow alone."""
    table = pq.read_table(paths, columns=["observation.state", "action", "episode_index"]).to_pydict()
    episodes: dict[int, dict[str, list]] = {}
    for state, action, index in zip(table["observation.state"], table["action"], table["episode_index"]):
        entry = episodes.setdefault(index, {"state": [], "action": []})
        entry["state"].append(state)
        entry["action"].append(action)
    return {k: {name: np.asarray(rows, dtype=np.float32) for name, rows in v.items()} for k, v in episodes.items()}


def check_against_frames(converted, frames: dict[int, dict[str, np.ndarray]]) -> None:
    assert len(converted.episodes) == len(frames)
    for episode, (index, rows) in zip(converted.episodes, sorted(frames.items())):
        assert episode.metadata["source_episode_index"] == index
        assert np.array_equal(episode.observations, rows["state"])  # every frame's observation
        assert np.array_equal(episode.actions, rows["action"][:-1])  # the last frame's action has no next observation


def test_v21_g1(testdata: Path) -> None:
    root = testdata / "lerobot" / "g1_v21"
    info = json.loads((root / "meta" / "info.json").read_text())
    converted = lerobot_to_episodes(root, progress=False)
    assert len(converted.episodes) == info["total_episodes"] == 100
    assert sum(len(e) + 1 for e in converted.episodes) == info["total_frames"] == 35965
    assert converted.observation_space.shape == converted.action_space.shape == (26,) and converted.dt == pytest.approx(1 / 30)
    assert any("observation.images.cam_high" in w and "skipped" in w for w in converted.warnings)
    check_against_frames(converted, frames_by_episode(sorted((root / "data").rglob("*.parquet"))))


def test_v30_so101(testdata: Path) -> None:
    root = testdata / "lerobot" / "so101_v30"
    info = json.loads((root / "meta" / "info.json").read_text())
    converted = lerobot_to_episodes(root, progress=False)
    assert len(converted.episodes) == info["total_episodes"] == 6
    assert sum(len(e) + 1 for e in converted.episodes) == info["total_frames"] == 1782
    assert any("observation.images.wrist" in w for w in converted.warnings)
    check_against_frames(converted, frames_by_episode(sorted((root / "data").rglob("*.parquet"))))


def test_not_a_lerobot_root(tmp_path: Path) -> None:
    (tmp_path / "data").mkdir()
    with pytest.raises(ImitationError, match="no meta/info.json"):
        lerobot_to_episodes(tmp_path)
    with pytest.raises(ImitationError, match="no meta/info.json"):
        convert(tmp_path, tmp_path / "x.mcap", source="lerobot", progress=False)
    assert not (tmp_path / "x.mcap").exists()


def test_demos_to_lerobot_and_back_is_lossless(tmp_path: Path) -> None:
    from imitation.data.export.lerobot import export_lerobot

    rng = np.random.default_rng(1)
    episodes = [
        Episode(observations=rng.normal(size=(n + 1, 3)).astype(np.float32), actions=rng.integers(0, 4, size=n),
                rewards=rng.normal(size=n), terminated=n == 4, truncated=n != 4, metadata={"seed": n})
        for n in (4, 7, 1)
    ]
    space = gym.spaces.Box(-10, 10, shape=(3,), dtype=np.float32)
    source = write_episodes(tmp_path / "demos.mcap", episodes, env_id="imitation/Test-v0", observation_space=space,
                            action_space=gym.spaces.Discrete(4), dt=0.05)
    result = export_lerobot(source, tmp_path / "dataset", progress=False)
    assert result["episodes"] == 3 and result["frames"] == 4 + 7 + 1 + 3 and result["fps"] == 20
    assert not (tmp_path / "dataset.partial").exists()

    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = LeRobotDataset("local/dataset", root=tmp_path / "dataset", video_backend="pyav")
    assert len(dataset) == 15 and dataset.num_episodes == 3 and dataset.fps == 20
    batches = list(torch.utils.data.DataLoader(dataset, batch_size=4, shuffle=False))
    states = torch.cat([b["observation.state"] for b in batches])
    assert torch.equal(states[:5], torch.from_numpy(episodes[0].observations))
    assert torch.equal(torch.cat([b["action"] for b in batches]).reshape(-1)[:4], torch.from_numpy(episodes[0].actions))
    assert torch.cat([b["next.reward"] for b in batches]).reshape(-1)[:4].tolist() == pytest.approx(episodes[0].rewards.tolist())

    back = convert(tmp_path / "dataset", tmp_path / "back.mcap", progress=False)
    demo = DemoFile(tmp_path / "back.mcap")
    assert back["from"] == "lerobot" and demo.env_id == "imitation/Test-v0" and demo.dt == pytest.approx(0.05)
    assert demo.observation_space == space and demo.action_space == gym.spaces.Discrete(4)
    for original, restored in zip(episodes, demo):
        assert np.array_equal(original.observations, restored.observations)
        assert np.array_equal(original.actions, restored.actions)
        assert np.array_equal(original.rewards, restored.rewards)  # float64 in the dataset: bit for bit
        assert (original.terminated, original.truncated, original.metadata) == (restored.terminated, restored.truncated, restored.metadata)


def test_export_refuses_a_non_empty_folder(tmp_path: Path) -> None:
    from imitation.data.export.lerobot import export_lerobot

    space = gym.spaces.Box(-1, 1, shape=(2,), dtype=np.float32)
    empty = write_episodes(tmp_path / "empty.mcap", [], env_id="", observation_space=space, action_space=space)
    with pytest.raises(ImitationError, match="holds no episode"):
        export_lerobot(empty, tmp_path / "new", progress=False)
    episode = Episode(observations=np.zeros((3, 2), np.float32), actions=np.zeros((2, 2), np.float32), rewards=np.zeros(2))
    source = write_episodes(tmp_path / "d.mcap", [episode], env_id="", observation_space=space, action_space=space)
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "notes.txt").write_text("mine")
    with pytest.raises(ImitationError, match="not an empty folder"):
        export_lerobot(source, tmp_path / "taken", progress=False)
    assert (tmp_path / "taken" / "notes.txt").read_text() == "mine" and not (tmp_path / "new").exists()


def test_one_value_features_keep_their_shape(tmp_path: Path) -> None:
    """A LeRobot feature of shape (1,) (here a float action) stays a (1,) Box, not a scalar."""
    from imitation.data.export.lerobot import export_lerobot

    episode = Episode(observations=np.arange(4, dtype=np.float32).reshape(4, 1), actions=np.full((3, 1), 0.5, np.float32), rewards=np.ones(3))
    space = gym.spaces.Box(-5, 5, shape=(1,), dtype=np.float32)
    export_lerobot(write_episodes(tmp_path / "d.mcap", [episode], env_id="", observation_space=space, action_space=space), tmp_path / "ds", progress=False)
    (tmp_path / "ds" / "meta" / "imitation.json").unlink()  # as if another tool had written it
    converted = lerobot_to_episodes(tmp_path / "ds", progress=False)
    assert converted.observation_space.shape == converted.action_space.shape == (1,)
    assert converted.episodes[0].actions.tolist() == [[0.5]] * 3 and converted.episodes[0].rewards.tolist() == [1.0] * 3

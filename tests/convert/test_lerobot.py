"""LeRobot datasets ↔ demos: v2.1 and v3.0 datasets other people recorded (../shared/testdata),
and demos → LeRobotDataset v3.0 that lerobot itself loads, and back without loss."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from types import SimpleNamespace

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
        observations = episode.observations["state"] if isinstance(episode.observations, dict) else episode.observations
        assert np.array_equal(observations, rows["state"])  # every frame's observation
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


def test_lerobot_episodes_are_truncated_and_the_file_says_why(testdata: Path, tmp_path: Path) -> None:
    """A LeRobot dataset keeps no observation after its last action (`next.done` could not tell a
    time limit from a termination anyway): every demo episode is truncated, and the file says so."""
    out = tmp_path / "g1.mcap"
    result = convert(testdata / "lerobot" / "g1_v21", out, progress=False)
    demo = DemoFile(out)
    assert not any(facts.terminated for facts in demo.episodes) and all(facts.truncated for facts in demo.episodes)
    assert demo.end_flags is not None and demo.end_flags["source_flag"] == "next.done" and demo.end_flags["truncated"] == 100
    assert demo.end_flags["final_observation"] is False and demo.end_flags["terminated"] == 0
    assert any("all are truncated" in warning for warning in result["warnings"])


def test_v30_so101(testdata: Path) -> None:
    root = testdata / "lerobot" / "so101_v30"
    info = json.loads((root / "meta" / "info.json").read_text())
    converted = lerobot_to_episodes(root, progress=False)
    assert len(converted.episodes) == info["total_episodes"] == 6
    assert sum(len(e) + 1 for e in converted.episodes) == info["total_frames"] == 1782
    assert converted.observation_space["images.wrist"].shape == (360, 640, 3)
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


@pytest.mark.parametrize(
    "tamper",
    [
        lambda sidecar: sidecar | {"env_id": 7},
        lambda sidecar: sidecar | {"source": ["x"]},
        lambda sidecar: sidecar | {"dt": "fast"},
        lambda sidecar: sidecar | {"user_metadata": []},
        lambda sidecar: sidecar | {"episodes": [e | {"terminated": True, "truncated": True} for e in sidecar["episodes"]]},
        lambda sidecar: sidecar | {"episodes": [e | {"metadata": 3} for e in sidecar["episodes"]]},
        lambda sidecar: "[" * 100_000 + "]" * 100_000,  # nested past the recursion limit
    ],
    ids=["env_id", "source", "dt", "user_metadata", "both_ends", "metadata", "deep"],
)
def test_a_hostile_sidecar_is_ignored_with_a_warning(tmp_path: Path, tamper) -> None:
    from imitation.data.export.lerobot import export_lerobot

    episode = Episode(observations=np.zeros((3, 2), np.float32), actions=np.ones((2, 2), np.float32), rewards=np.ones(2),
                      terminated=True)
    space = gym.spaces.Box(-5, 5, shape=(2,), dtype=np.float32)
    export_lerobot(write_episodes(tmp_path / "d.mcap", [episode], env_id="imitation/Test-v0", observation_space=space,
                                  action_space=space), tmp_path / "ds", progress=False)
    path = tmp_path / "ds" / "meta" / "imitation.json"
    tampered = tamper(json.loads(path.read_text()))
    path.write_text(tampered if isinstance(tampered, str) else json.dumps(tampered))
    converted = lerobot_to_episodes(tmp_path / "ds", progress=False)
    assert any(str(path) in w and "ignored" in w for w in converted.warnings)
    assert converted.env_id == "" and converted.episodes[0].truncated  # the dataset's own facts, not the sidecar's
    assert converted.episodes[0].actions.tolist() == [[1.0, 1.0]] * 2


# ------------------------------------------------------------------------------------------------
# Datasets without their video files, and info.json totals that disagree with the data (issue 17)


def files_under(root: Path) -> dict[str, int]:
    """Every file below `root` with its size: what a conversion must leave as it found it."""
    return {str(path.relative_to(root)): path.stat().st_size for path in sorted(root.rglob("*")) if path.is_file()}


def cli_warnings(stderr: str) -> list[str]:
    return [line.removeprefix("warning: ") for line in stderr.splitlines() if line.strip()]


def test_real_datasets_without_their_videos_convert_from_the_command_line(testdata: Path, tmp_path: Path) -> None:
    """G1 (v2.1: its video feature's 100 mp4 files are absent), SO-101 (v3.0, with its AV1 video)
    and a copy of SO-101 without videos/ (which lerobot 0.6.1's reader wanted to fetch from the Hub):
    all convert their numeric features through the command line, the missing files named, the
    folders left as they were, nothing asked of the Hub (HF_HUB_OFFLINE=1 here: any fetch fails)."""
    from support import run_cli_many

    g1, so101 = testdata / "lerobot" / "g1_v21", testdata / "lerobot" / "so101_v30"
    bare = tmp_path / "so101_without_videos"
    shutil.copytree(so101, bare, ignore=shutil.ignore_patterns("videos"))
    assert not (bare / "videos").exists() and (so101 / "videos/observation.images.wrist/chunk-000/file-000.mp4").is_file()
    before = {root: files_under(root) for root in (g1, so101, bare)}
    roots = {"g1": g1, "so101": so101, "bare": bare}
    results = dict(zip(roots, run_cli_many([["convert", str(root), "--out", str(tmp_path / f"{name}.mcap"), "--json", "--quiet"]
                                             for name, root in roots.items()])))
    for name, result in results.items():
        assert result.returncode == 0, (name, result.stderr)
        assert "huggingface" not in result.stderr.lower() and "HF_HUB_OFFLINE" not in result.stderr, result.stderr
    reports = {name: json.loads(result.stdout.strip().splitlines()[-1]) for name, result in results.items()}
    assert {name: (r["episodes"], r["transitions"]) for name, r in reports.items()} == {
        "g1": (100, 35965 - 100), "so101": (6, 1782 - 6), "bare": (6, 1782 - 6)}
    assert all(r["env_id"] is None for r in reports.values())  # null, as in metrics.json; the file keeps ""
    assert all(DemoFile(tmp_path / f"{name}.mcap").env_id == "" for name in roots)
    for name, result in results.items():
        assert cli_warnings(result.stderr) == reports[name]["warnings"]  # each warning once on stderr, the same in the JSON

    # G1: the 100 files its episodes.jsonl and video_path name, none present; the first three named.
    expected = [f"videos/chunk-000/observation.images.cam_high/episode_{k:06d}.mp4" for k in range(3)]
    assert not any((g1 / name).exists() for name in expected)
    missing = [w for w in reports["g1"]["warnings"] if "video files of" in w]
    assert missing == [f"{g1}: video files of 'observation.images.cam_high' missing, 100 of 100: "
                       f"{', '.join(expected)} and 97 more (the other features convert)"]
    # SO-101 with its video: no missing-file warning; without it, the one file named.
    assert not [w for w in reports["so101"]["warnings"] if "missing" in w]
    assert [w for w in reports["bare"]["warnings"] if "missing" in w] == [
        f"{bare}: video files of 'observation.images.wrist' missing, 1 of 1: "
        "videos/observation.images.wrist/chunk-000/file-000.mp4 (the other features convert)"]
    for name in ("g1", "bare"):
        assert any("video feature" in w and "skipped" in w for w in reports[name]["warnings"])

    # The demos are the datasets' frames, with or without the video beside them.
    check_against_frames(demos_of(tmp_path / "bare.mcap"), frames_by_episode(sorted((so101 / "data").rglob("*.parquet"))))
    check_against_frames(demos_of(tmp_path / "g1.mcap"), frames_by_episode(sorted((g1 / "data").rglob("*.parquet"))))
    assert {root: files_under(root) for root in (g1, so101, bare)} == before, "a conversion writes nothing into the dataset"


def demos_of(path: Path) -> SimpleNamespace:
    """A demo file's episodes, as check_against_frames reads a conversion's."""
    return SimpleNamespace(episodes=list(DemoFile(path)))


def _lerobot_written(root: Path, lengths: tuple[int, ...]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """A v3.0 dataset written by lerobot's own writer, with a video feature; the states and actions added."""
    from imitation.data.convert.lerobot import lerobot_quietly

    rng = np.random.default_rng(7)
    states = [rng.normal(size=(n, 3)).astype(np.float32) for n in lengths]
    actions = [rng.normal(size=(n, 2)).astype(np.float32) for n in lengths]
    features = {"observation.state": {"dtype": "float32", "shape": (3,), "names": None},
                "action": {"dtype": "float32", "shape": (2,), "names": None},
                "observation.images.cam": {"dtype": "video", "shape": (32, 32, 3), "names": ["height", "width", "channel"]}}
    with lerobot_quietly():
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        dataset = LeRobotDataset.create(repo_id="local/written", fps=10, features=features, root=root, use_videos=True)
        for episode_states, episode_actions in zip(states, actions):
            for state, action in zip(episode_states, episode_actions):
                dataset.add_frame({"observation.state": state, "action": action, "task": "reach",
                                   "observation.images.cam": rng.integers(0, 256, (32, 32, 3), dtype=np.uint8)})
            dataset.save_episode()
        dataset.finalize()
    return states, actions


def test_a_dataset_lerobots_writer_made_converts_after_its_videos_are_deleted(tmp_path: Path) -> None:
    from support import run_cli

    root = tmp_path / "written"
    states, actions = _lerobot_written(root, (5, 8))
    videos = sorted(str(path.relative_to(root)) for path in (root / "videos").rglob("*.mp4"))
    assert videos == ["videos/observation.images.cam/chunk-000/file-000.mp4"]
    with_video = lerobot_to_episodes(root, progress=False)
    assert not [w for w in with_video.warnings if "missing" in w]

    shutil.rmtree(root / "videos")
    result = run_cli("convert", str(root), "--out", str(tmp_path / "written.mcap"), "--json", "--quiet", timeout=300)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert (report["episodes"], report["transitions"], report["env_id"]) == (2, 4 + 7, None)
    assert f"{root}: video files of 'observation.images.cam' missing, 1 of 1: {videos[0]} (the other features convert)" in report["warnings"]
    assert cli_warnings(result.stderr) == report["warnings"]
    demos = list(DemoFile(tmp_path / "written.mcap"))
    for episode, episode_states, episode_actions, before in zip(demos, states, actions, with_video.episodes):
        assert np.array_equal(episode.observations, episode_states) and np.array_equal(episode.actions, episode_actions[:-1])
        assert np.array_equal(episode.observations, before.observations["state"]) and np.array_equal(episode.actions, before.actions)


def test_info_totals_that_disagree_with_the_data_warn_and_convert_what_is_present(testdata: Path, tmp_path: Path) -> None:
    """Trimmed copies whose info.json still counts the whole dataset: G1 (v2.1) cut to its first two
    episodes, SO-101 (v3.0) to its first four (its data file rewritten without the other rows)."""
    import pyarrow.compute as pc

    g1 = tmp_path / "g1"
    shutil.copytree(testdata / "lerobot" / "g1_v21", g1, ignore=shutil.ignore_patterns("episode_00000[2-9].parquet", "episode_0000[1-9]?.parquet"))
    listing = (g1 / "meta" / "episodes.jsonl").read_text().splitlines()[:2]
    (g1 / "meta" / "episodes.jsonl").write_text("\n".join(listing) + "\n")
    kept = [json.loads(line)["length"] for line in listing]
    assert sorted(p.name for p in (g1 / "data" / "chunk-000").iterdir()) == ["episode_000000.parquet", "episode_000001.parquet"]
    converted = lerobot_to_episodes(g1, progress=False)
    assert [len(e) + 1 for e in converted.episodes] == kept == [479, 393]
    info = g1 / "meta" / "info.json"
    assert f"{info}: total_episodes is 100, but the dataset holds 2 episodes; converting the 2 present" in converted.warnings
    assert f"{info}: total_frames is 35965, but the dataset holds 872 frames; converting the 872 present" in converted.warnings

    so101 = tmp_path / "so101"
    shutil.copytree(testdata / "lerobot" / "so101_v30", so101, ignore=shutil.ignore_patterns("videos"))
    data = so101 / "data" / "chunk-000" / "file-000.parquet"
    table = pq.read_table(data)
    pq.write_table(table.filter(pc.less(table.column("episode_index"), 4)), data)
    converted = lerobot_to_episodes(so101, progress=False)
    assert [len(e) + 1 for e in converted.episodes] == [383, 386, 379, 382]
    info = so101 / "meta" / "info.json"
    assert f"{info}: total_episodes is 6, but the dataset holds 4 episodes; converting the 4 present" in converted.warnings
    assert f"{info}: total_frames is 1782, but the dataset holds 1530 frames; converting the 1530 present" in converted.warnings
    check_against_frames(converted, frames_by_episode([data]))

    # The untouched datasets agree with their info.json: no such warning.
    for name in ("g1_v21", "so101_v30"):
        assert not [w for w in lerobot_to_episodes(testdata / "lerobot" / name, progress=False).warnings if "total_" in w]


@pytest.mark.parametrize(
    ("key", "dtype", "got"),
    [("timestamp", [-1], "a list"), ("observation.state", {"float32": 1}, "an object"),
     ("observation.images.cam_high", ["video"], "a list"), ("action", 32, "the int 32")],
)
def test_a_dtype_that_is_not_a_name_is_refused_naming_the_feature(testdata: Path, tmp_path: Path, key: str, dtype, got: str) -> None:
    """G1's info.json with one feature's dtype made a list, an object or a number (tools/fuzz.py:
    a TypeError `unhashable type`, or a damaged index feature converting as if sound)."""
    root = tmp_path / "g1"
    shutil.copytree(testdata / "lerobot" / "g1_v21", root, ignore=shutil.ignore_patterns("episode_00000[1-9].parquet", "episode_0000[1-9]?.parquet"))
    (root / "meta" / "episodes.jsonl").write_text((testdata / "lerobot" / "g1_v21" / "meta" / "episodes.jsonl").read_text().splitlines()[0] + "\n")
    info = json.loads((root / "meta" / "info.json").read_text())
    info["features"][key]["dtype"] = dtype
    (root / "meta" / "info.json").write_text(json.dumps(info))
    with pytest.raises(ImitationError) as refused:
        lerobot_to_episodes(root, progress=False)
    assert str(refused.value) == f"{root / 'meta' / 'info.json'}: feature {key!r}: 'dtype' must be a name such as 'float32' or 'video', got {got}"

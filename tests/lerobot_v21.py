"""LeRobot v2.1 datasets made by lerobot's own writer, for tests of what real v2.1 sets hold.

The installed lerobot writes v3.0 only. Asked for files of almost no megabytes, it starts a new
data file and a new video file for every episode, so each episode's parquet and mp4 are what a
v2.1 set keeps per episode (its video from time 0): they are moved to v2.1's names
(`data/chunk-000/episode_000000.parquet`, `videos/chunk-000/KEY/episode_000000.mp4`) beside a
v2.1 `meta/info.json` and `meta/episodes.jsonl`. Nothing is re-encoded.

The cameras see real footage: two 224x224 windows panning across the ALOHA top camera
(640x480) and the SO-101 wrist camera (640x360) of ../shared/testdata, encoded by lerobot's
default video encoder (SVT-AV1, GOP 2, CRF 30). A recording's wall-clock stamps are imitated by
rewriting the parquet's `timestamp` column (pyarrow) to frame_index / fps plus a few ms of jitter;
info.json may leave `timestamp` out of its features, as some recorders' sets do.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

ALOHA = "manipulation/aloha_sim_lerobot_fixtures/aloha_sim_insertion_human/videos/observation.images.top_episode_000000.mp4"
SO101 = "lerobot/so101_v30/videos/observation.images.wrist/chunk-000/file-000.mp4"
CAMERAS = {"observation.images.top": ALOHA, "observation.images.wrist": SO101}
SIDE = 224
FPS = 30
TASK = "insert the peg"


def source_frames(testdata: Path, name: str, count: int) -> np.ndarray:
    """The first `count` frames of a video of the test data (all of them, if it has fewer)."""
    import av

    frames = []
    with av.open(str(testdata / name)) as container:
        for frame in container.decode(video=0):
            frames.append(frame.to_ndarray(format="rgb24"))
            if len(frames) == count:
                break
    return np.stack(frames)


def panned(frames: np.ndarray, t: int, period: int) -> np.ndarray:
    """A SIDE x SIDE window of frame t (the footage repeats when it is shorter), moving around the
    frame once per `period` frames."""
    height, width = frames.shape[1:3]
    x = int((width - SIDE) * (0.5 + 0.5 * np.sin(2 * np.pi * t / period)))
    y = int((height - SIDE) * (0.5 + 0.5 * np.cos(np.pi * t / period)))
    return frames[t % len(frames), y : y + SIDE, x : x + SIDE]


def write_v21(
    root: Path, testdata: Path, *, lengths: tuple[int, ...], jitter_s: float, declare_timestamp: bool, seed: int = 0
) -> Path:
    """A v2.1 set at `root`: len(lengths) episodes of those frame counts, two video cameras,
    state and action float32[2], stamps jittered by up to `jitter_s`."""
    from imitation.data.convert.lerobot import lerobot_quietly

    total = sum(lengths)
    sources = {key: source_frames(testdata, name, total) for key, name in CAMERAS.items()}
    features = {
        "observation.state": {"dtype": "float32", "shape": (2,), "names": ["x", "y"]},
        "action": {"dtype": "float32", "shape": (2,), "names": ["x", "y"]},
        **{key: {"dtype": "video", "shape": (SIDE, SIDE, 3), "names": ["height", "width", "channel"]} for key in CAMERAS},
    }
    v30 = root.with_name(root.name + "-v30")
    with lerobot_quietly():
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        dataset = LeRobotDataset.create(
            repo_id="local/v21", fps=FPS, features=features, root=v30, data_files_size_in_mb=1e-9, video_files_size_in_mb=1e-9
        )
        t = 0
        for length in lengths:
            for k in range(length):
                frame = {key: panned(frames, t, length) for key, frames in sources.items()}
                dataset.add_frame(
                    {"observation.state": np.array([t, k], np.float32), "action": np.array([k, 1], np.float32), "task": TASK} | frame
                )
                t += 1
            dataset.save_episode()
        dataset.finalize()
    info = json.loads((v30 / "meta/info.json").read_text())
    rng = np.random.default_rng(seed)
    for index, length in enumerate(lengths):
        data = pq.read_table(v30 / f"data/chunk-000/file-{index:03d}.parquet")
        assert data.column("episode_index").to_pylist() == [index] * length  # one episode per file, as v2.1 keeps them
        stamps = np.arange(length) / FPS + rng.uniform(-jitter_s, jitter_s, length) * (np.arange(length) > 0)
        data = data.set_column(data.schema.get_field_index("timestamp"), "timestamp", pa.array(stamps.astype(np.float32)))
        target = root / f"data/chunk-000/episode_{index:06d}.parquet"
        target.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(data, target)
        for key in CAMERAS:
            video = root / f"videos/chunk-000/{key}/episode_{index:06d}.mp4"
            video.parent.mkdir(parents=True, exist_ok=True)
            shutil.move(v30 / f"videos/{key}/chunk-000/file-{index:03d}.mp4", video)
    features = info["features"]
    if not declare_timestamp:
        del features["timestamp"]
    (root / "meta").mkdir()
    (root / "meta/info.json").write_text(
        json.dumps(
            {
                "codebase_version": "v2.1",
                "robot_type": None,
                "total_episodes": len(lengths),
                "total_frames": total,
                "total_tasks": 1,
                "total_videos": len(lengths) * len(CAMERAS),
                "total_chunks": 1,
                "chunks_size": 1000,
                "fps": FPS,
                "splits": {"train": f"0:{len(lengths)}"},
                "data_path": "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet",
                "video_path": "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4",
                "features": features,
            },
            indent=4,
        )
    )
    (root / "meta/episodes.jsonl").write_text(
        "".join(json.dumps({"episode_index": k, "tasks": [TASK], "length": n}) + "\n" for k, n in enumerate(lengths))
    )
    (root / "meta/tasks.jsonl").write_text(json.dumps({"task_index": 0, "task": TASK}) + "\n")
    shutil.rmtree(v30)
    return root


def video_files(root: Path) -> list[Path]:
    return sorted(root.glob("videos/chunk-000/*/episode_*.mp4"))

"""LeRobot v2.1 sets as recorders write them (issue 51 item 2): made by lerobot's own writer
(tests/lerobot_v21.py), two 224x224 AV1 wrist cameras, `timestamp` in the parquet but not in
info.json's features, stamped by a wall clock with a few ms of jitter."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from lerobot_v21 import FPS, video_files, write_v21
from support import TESTDATA

from imitation.data.convert.converted import write_converted
from imitation.data.convert.endings import settle_ends
from imitation.data.convert.lerobot import lerobot_to_episodes
from imitation.data.mcap.reader import DemoFile
from imitation.errors import ImitationError

LENGTHS = (40, 30)
JITTER_S = 0.006
CAMERAS = ("images.top", "images.wrist")


@pytest.fixture(scope="module")
def wall_clock_set(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if not TESTDATA.is_dir():
        pytest.skip(f"third-party test data not found at {TESTDATA} (its camera footage feeds lerobot's writer)")
    return write_v21(tmp_path_factory.mktemp("v21") / "set", TESTDATA, lengths=LENGTHS, jitter_s=JITTER_S, declare_timestamp=False)


def copy_of(root: Path, tmp_path: Path) -> Path:
    shutil.copytree(root, tmp_path / "set")
    return tmp_path / "set"


def pyav_frames(video: Path) -> np.ndarray:
    import av

    with av.open(str(video)) as container:
        return np.stack([frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)])


def expected_frames(root: Path, camera: str, episode: int) -> np.ndarray:
    return pyav_frames(root / f"videos/chunk-000/observation.{camera}/episode_{episode:06d}.mp4")


def test_both_cameras_convert_placed_by_frame_index_to_pyavs_pixels(wall_clock_set: Path, tmp_path: Path) -> None:
    root = wall_clock_set
    assert "timestamp" not in json.loads((root / "meta/info.json").read_text())["features"]
    stamps = pq.read_table(root / "data/chunk-000/episode_000000.parquet").column("timestamp").to_numpy()
    gap = float(np.max(np.abs(stamps.astype(np.float64) - np.arange(LENGTHS[0]) / FPS)))
    assert 0.004 < gap <= JITTER_S  # more than lerobot's 1e-4 s: its own loader refuses these rows

    converted = lerobot_to_episodes(root, progress=False)
    assert sorted(converted.observation_space.spaces) == [*CAMERAS, "state"]
    assert [len(e) + 1 for e in converted.episodes] == list(LENGTHS)
    assert (
        f"{root}: the rows' timestamps stray from frame_index / fps by up to {gap * 1e3:.1f} ms, more than lerobot's 0.0001 s "
        f"(stamped by a wall clock?); video frames are placed by frame_index at the videos' {FPS} fps "
        "(--video-tolerance S places them by timestamp instead)"
    ) in converted.warnings
    placed = converted.metadata["video_frames"]
    assert placed["placed_by"] == "frame_index" and placed["tolerance_s"] == 1e-4 and placed["timestamp_gap_s"] == pytest.approx(gap)
    for index, episode in enumerate(converted.episodes):
        for camera in CAMERAS:
            assert np.array_equal(episode.observations[camera], expected_frames(root, camera, index))  # every frame, in order

    demos = tmp_path / "demos.mcap"
    write_converted(settle_ends(converted), demos, progress=False)  # PNG: the decoded frames, losslessly
    for index, episode in enumerate(DemoFile(demos)):
        for camera in CAMERAS:
            assert np.array_equal(episode.observations[camera], expected_frames(root, camera, index))
    assert DemoFile(demos).user_metadata["video_frames"]["placed_by"] == "frame_index"


def test_a_tolerance_places_frames_by_their_timestamps(wall_clock_set: Path) -> None:
    root = wall_clock_set
    wide = lerobot_to_episodes(root, progress=False, video_tolerance_s=0.01)
    assert wide.metadata["video_frames"]["placed_by"] == "timestamp" and wide.metadata["video_frames"]["tolerance_s"] == 0.01
    assert not [w for w in wide.warnings if "frame_index" in w]
    for index, episode in enumerate(wide.episodes):  # 6 ms of jitter, frames 33 ms apart: the same frames
        assert np.array_equal(episode.observations["images.wrist"], expected_frames(root, "images.wrist", index))
    with pytest.raises(ImitationError) as narrow:
        lerobot_to_episodes(root, progress=False, video_tolerance_s=0.001)
    assert str(narrow.value).startswith(
        f"{root / 'videos/chunk-000/observation.images.top/episode_000000.mp4'}: video feature 'observation.images.top', episode 0: "
        "no video frame within 0.001 s of frame "
    )


def test_frame_index_placement_is_checked_against_the_videos_clock(wall_clock_set: Path, tmp_path: Path) -> None:
    """info.json saying 25 fps of videos that run at 30: frame_index / 25 s misses the frames."""
    root = copy_of(wall_clock_set, tmp_path)
    info = json.loads((root / "meta/info.json").read_text())
    (root / "meta/info.json").write_text(json.dumps(info | {"fps": 25}))
    with pytest.raises(ImitationError) as refused:
        lerobot_to_episodes(root, progress=False)
    assert str(refused.value) == (
        f"{root / 'videos/chunk-000/observation.images.top/episode_000000.mp4'}: video feature 'observation.images.top', "
        "episode 0, placed by frame_index at 25 fps: no video frame within 0.0001 s of frame 1 (at 0.040000 s) and 32 more; "
        "the video does not run at a constant 25 fps (--video-tolerance S places frames by timestamp)"
    )


def test_without_timestamps_frames_are_placed_by_frame_index_and_without_either_the_cameras_are_skipped(
        wall_clock_set: Path, tmp_path: Path) -> None:
    root = copy_of(wall_clock_set, tmp_path)
    data = sorted(root.glob("data/chunk-000/*.parquet"))
    for path in data:
        pq.write_table(pq.read_table(path).drop_columns(["timestamp"]), path)
    placed = lerobot_to_episodes(root, progress=False)
    assert f"{root}: no timestamp column; video frames are placed by frame_index at the videos' {FPS} fps" in placed.warnings
    assert placed.metadata["video_frames"] == {"placed_by": "frame_index", "tolerance_s": 1e-4, "timestamp_gap_s": None}
    assert np.array_equal(placed.episodes[1].observations["images.top"], expected_frames(root, "images.top", 1))
    for path in data:
        pq.write_table(pq.read_table(path).drop_columns(["frame_index"]), path)
    bare = lerobot_to_episodes(root, progress=False)
    assert f"{root}: video features skipped (the data has neither a timestamp nor a frame_index column to find their frames by)" in bare.warnings
    assert bare.observation_space.shape == (2,) and "video_frames" not in bare.metadata


def test_a_v30_placeholder_in_a_v21_set_names_the_template_and_the_key(wall_clock_set: Path, tmp_path: Path) -> None:
    root = copy_of(wall_clock_set, tmp_path)
    info = json.loads((root / "meta/info.json").read_text())
    data_path, video_path = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet", "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
    (root / "meta/info.json").write_text(json.dumps(info | {"data_path": data_path}))
    with pytest.raises(ImitationError) as refused:
        lerobot_to_episodes(root, progress=False)
    assert str(refused.value) == (
        f"{root / 'meta/info.json'}: data_path {data_path!r} has the placeholder 'chunk_index', which v2.1 does not fill "
        "(it fills episode_chunk, episode_index)"
    )
    (root / "meta/info.json").write_text(json.dumps(info | {"video_path": video_path}))
    skipped = lerobot_to_episodes(root, progress=False)
    assert (
        f"{root / 'meta/info.json'}: video_path {video_path!r} has the placeholder 'chunk_index', which v2.1 does not fill "
        "(it fills episode_chunk, video_key, episode_index); video features 'observation.images.top', "
        "'observation.images.wrist' skipped"
    ) in skipped.warnings
    assert skipped.observation_space.shape == (2,)
    (root / "meta/info.json").write_text(json.dumps(info | {"data_path": "data/chunk-{episode_chunk:03d}/episode.parquet"}))
    with pytest.raises(ImitationError, match=r"data_path 'data/chunk-\{episode_chunk:03d\}/episode.parquet' has no episode_index placeholder \(v2.1 keeps one file per episode\)$"):
        lerobot_to_episodes(root, progress=False)


def test_the_set_is_lerobots_own(wall_clock_set: Path) -> None:
    """What the tests above read: lerobot's AV1 videos, one per episode and camera, from time 0."""
    import av

    assert len(video_files(wall_clock_set)) == 2 * len(LENGTHS)
    for video in video_files(wall_clock_set):
        with av.open(str(video)) as container:
            stream = container.streams.video[0]
            assert stream.codec_context.name in ("libdav1d", "libaom-av1", "av1")
            assert (stream.codec_context.width, stream.codec_context.height) == (224, 224)
            times = [float(frame.pts * stream.time_base) for frame in container.decode(stream)]
        assert times == pytest.approx(list(np.arange(len(times)) / FPS), abs=1e-9)


def test_damaged_timestamps_leave_frames_to_frame_index(wall_clock_set: Path, tmp_path: Path) -> None:
    import pyarrow as pa

    root = copy_of(wall_clock_set, tmp_path)
    path = root / "data/chunk-000/episode_000001.parquet"
    table = pq.read_table(path)
    stamps = table.column("timestamp").to_numpy().copy()
    stamps[3] = np.nan
    pq.write_table(table.set_column(table.schema.get_field_index("timestamp"), "timestamp", pa.array(stamps)), path)
    converted = lerobot_to_episodes(root, progress=False)
    assert (
        f"{root}: the rows' timestamps are not all finite numbers; video frames are placed by frame_index at the videos' "
        f"{FPS} fps (--video-tolerance S places them by timestamp instead)"
    ) in converted.warnings
    assert converted.metadata["video_frames"] == {"placed_by": "frame_index", "tolerance_s": 1e-4, "timestamp_gap_s": None}
    assert np.array_equal(converted.episodes[1].observations["images.top"], expected_frames(root, "images.top", 1))

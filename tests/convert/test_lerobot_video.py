"""LeRobot cameras ↔ demos: video (v3.0 shared files, v2.1 one file per episode) and image
features become uint8 (H, W, C) leaves of a Dict observation, decoded to the pixels lerobot's
own decoder gives; `export --to lerobot` writes them back as videos with lerobot's writer."""

from __future__ import annotations

import io
import json
import shutil
from pathlib import Path

import gymnasium as gym
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from imitation.data.convert.converted import write_converted
from imitation.data.convert.endings import settle_ends
from imitation.data.convert.lerobot import lerobot_quietly, lerobot_to_episodes
from imitation.data.convert.video import frames_at
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.writer import write_episodes
from imitation.data.types import Episode
from imitation.errors import ImitationError
from imitation.limits import LIMITS, ImageBudget

WRIST = "videos/observation.images.wrist/chunk-000/file-000.mp4"


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float("inf") if mse == 0 else float(10 * np.log10(255.0**2 / mse))


def lerobot_frames(video: Path, seconds: list[float]) -> np.ndarray:
    """The frames lerobot's own PyAV decoder gives, as uint8 (N, H, W, C)."""
    from lerobot.datasets.video_utils import decode_video_frames

    frames = decode_video_frames(video, seconds, 1e-4, backend="pyav")  # float (N, C, H, W) in [0, 1]
    return (frames * 255).round().clamp(0, 255).byte().permute(0, 2, 3, 1).numpy()


def test_so101_wrist_video_decodes_to_lerobots_pixels(testdata: Path) -> None:
    """Episodes 4 and 5 of SO-101 (90 and 162 frames, located in the one shared AV1 file by
    from_timestamp 51.0 and 54.0): every frame an image leaf, a sample of them identical to
    lerobot's decoder's at from_timestamp + the row's timestamp."""
    root = testdata / "lerobot" / "so101_v30"
    converted = lerobot_to_episodes(root, episodes=[4, 5], progress=False)
    assert converted.observation_space == gym.spaces.Dict(
        {"images.wrist": gym.spaces.Box(0, 255, (360, 640, 3), np.uint8), "state": gym.spaces.Box(-np.inf, np.inf, (6,), np.float32)}
    )
    assert [len(e) + 1 for e in converted.episodes] == [90, 162] and converted.metadata["episodes"] == [4, 5]
    assert not [w for w in converted.warnings if "wrist" in w]
    listing = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pydict()
    rows = pq.read_table(root / "data/chunk-000/file-000.parquet", columns=["timestamp", "episode_index", "observation.state"]).to_pydict()
    for episode in converted.episodes:
        index = episode.metadata["source_episode_index"]
        mine = [k for k, e in enumerate(rows["episode_index"]) if e == index]
        assert np.array_equal(episode.observations["state"], np.asarray([rows["observation.state"][k] for k in mine], np.float32))
        picks = [*range(0, len(mine), 23), len(mine) - 1]
        start = listing["videos/observation.images.wrist/from_timestamp"][index]
        expected = lerobot_frames(root / WRIST, [start + rows["timestamp"][mine[k]] for k in picks])
        frames = episode.observations["images.wrist"][picks]
        assert frames.dtype == np.uint8 and frames.shape == (len(picks), 360, 640, 3)
        assert psnr(frames, expected) == float("inf")  # identical: same seek, same frames, same rgb24 conversion


def test_a_missing_frame_or_a_broken_video_is_one_line_naming_file_feature_and_frame(
        testdata: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    video = testdata / "lerobot" / "so101_v30" / WRIST
    with pytest.raises(ImitationError) as missing:
        frames_at(video, np.array([0.0, 1 / 30, 100.0]), tolerance_s=1e-4, shape=(360, 640, 3), what="video feature 'w', episode 0",
                  budget=ImageBudget(str(video), video.stat().st_size))
    assert str(missing.value) == (
        f"{video}: video feature 'w', episode 0: no video frame within 0.0001 s of frame 2 (at 100.000000 s)"
    )
    with pytest.raises(ImitationError, match="cannot decode the video \\(ValueError: frames are 640x360, the dataset declares 64x36\\)"):
        frames_at(video, np.array([0.0]), tolerance_s=1e-4, shape=(36, 64, 3), what="w", budget=ImageBudget(str(video), video.stat().st_size))

    root = tmp_path / "so101"
    shutil.copytree(testdata / "lerobot" / "so101_v30", root)
    (root / WRIST).write_bytes(b"\x00\x00\x00\x20ftypisom" + bytes(range(256)) * 8)
    # Without the 3.5 MB video the folder is too small for its frames (image_expansion_ratio):
    # the bound raised, the broken video itself is what is refused.
    monkeypatch.setattr(LIMITS, "image_expansion_ratio", 10**6)
    with pytest.raises(ImitationError) as broken:
        lerobot_to_episodes(root, episodes=[0], progress=False)
    message = str(broken.value)
    assert "\n" not in message and message.startswith(f"{root / WRIST}: video feature 'observation.images.wrist', episode 0: cannot decode")

    # Frames asked for half a frame after the file's: none lies within the tolerance.
    shutil.copy(video, root / WRIST)
    listing = root / "meta/episodes/chunk-000/file-000.parquet"
    table = pq.read_table(listing)
    column = "videos/observation.images.wrist/from_timestamp"
    shifted = pa.array([t + 0.5 / 30 for t in table.column(column).to_pylist()], pa.float64())
    pq.write_table(table.set_column(table.schema.get_field_index(column), column, shifted), listing)
    with pytest.raises(ImitationError, match=r"file-000.mp4: video feature 'observation.images.wrist', episode 4: no video frame within 0.0001 s of frame 0 \(at 51.016667 s\) and 89 more"):
        lerobot_to_episodes(root, episodes=[4], progress=False)


def test_a_video_stream_of_a_codec_ffmpeg_does_not_know_is_one_line(testdata: Path, tmp_path: Path) -> None:
    """SO-101's wrist video with its sample entry's codec (stsd `av01`) renamed: PyAV opens the
    stream but gives it no codec context (tools/fuzz.py: an AttributeError on its `height`)."""
    root = tmp_path / "so101"
    shutil.copytree(testdata / "lerobot" / "so101_v30", root)
    data = (root / WRIST).read_bytes()
    entry = data.index(b"av01", data.index(b"stsd"))
    (root / WRIST).write_bytes(data[:entry] + b"zzzz" + data[entry + 4 :])
    with pytest.raises(ImitationError) as refused:
        lerobot_to_episodes(root, episodes=[4], progress=False)
    assert str(refused.value) == (
        f"{root / WRIST}: video feature 'observation.images.wrist', episode 4: cannot decode the video "
        "(ValueError: the video stream names no codec PyAV can decode)"
    )


def test_a_frame_larger_than_the_limits_is_refused_before_decoding(testdata: Path, tmp_path: Path) -> None:
    root = tmp_path / "so101"
    shutil.copytree(testdata / "lerobot" / "so101_v30", root, ignore=shutil.ignore_patterns("videos"))
    info = json.loads((root / "meta/info.json").read_text())
    info["features"]["observation.images.wrist"]["shape"] = [4320, 7680, 3]
    (root / "meta/info.json").write_text(json.dumps(info))
    with pytest.raises(ImitationError, match=r"'observation.images.wrist': numbers per frame: 99532800 is more than the limit sample_elements"):
        lerobot_to_episodes(root, progress=False)


def test_frames_that_decode_to_far_more_than_the_dataset_are_refused_before_decoding(
        testdata: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """SO-101's episodes decode to 337 times the folder's bytes (AV1, 2 KB a 640x360 frame): under
    a bound of 300 they are refused by their count, before a frame is decoded."""
    root = testdata / "lerobot" / "so101_v30"
    monkeypatch.setattr(LIMITS, "image_expansion_ratio", 300)
    size = sum(f.stat().st_size for f in root.rglob("*") if f.is_file())
    with pytest.raises(ImitationError) as caught:
        lerobot_to_episodes(root, progress=False)
    assert str(caught.value).startswith(
        f"{root}: decoded bytes of its camera frames (from {size} bytes): {1782 * 360 * 640 * 3} is more than the limit "
        "image_expansion_ratio=300"
    )


def test_video_frames_passed_over_on_the_way_count_too(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A timestamp 10 s in a video of one keyframe: the 300 frames before it are decoded to reach
    it, and each is counted, so a small video of thousands of frames stops at the bound."""
    import av

    import imitation.limits

    video = tmp_path / "still.mp4"
    with av.open(str(video), "w") as container:
        stream = container.add_stream("h264", rate=30, options={"g": "1000"})
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv420p"
        for _ in range(301):
            container.mux(stream.encode(av.VideoFrame.from_ndarray(np.zeros((48, 64, 3), np.uint8), format="rgb24")))
        container.mux(stream.encode())
    monkeypatch.setattr(imitation.limits, "FREE_EXPANSION_BYTES", 0)
    monkeypatch.setattr(LIMITS, "image_expansion_ratio", 100)  # the video's frames decode to 290 times its bytes
    size, frame = video.stat().st_size, 48 * 64 * 3
    budget = ImageBudget(str(video), size)
    assert budget.allowed < 301 * frame
    with pytest.raises(ImitationError, match=r"decoded bytes of its camera frames .* is more than the limit image_expansion_ratio=100"):
        frames_at(video, np.array([10.0]), tolerance_s=1e-4, shape=(48, 64, 3), what="w", budget=budget)
    assert budget.decoded == (budget.allowed // frame + 1) * frame  # stopped at the first frame past the bound
    monkeypatch.setattr(LIMITS, "image_expansion_ratio", 10**6)
    admitted = ImageBudget(str(video), size)
    assert frames_at(video, np.array([10.0]), tolerance_s=1e-4, shape=(48, 64, 3), what="w", budget=admitted).shape == (1, 48, 64, 3)
    assert admitted.decoded == 301 * frame


def test_an_unknown_episode_is_refused(testdata: Path) -> None:
    with pytest.raises(ImitationError, match=r"no episode 9 in the dataset \(it holds 6, episode_index 0 to 5\)"):
        lerobot_to_episodes(testdata / "lerobot" / "so101_v30", episodes=[1, 9], progress=False)


def camera_demos(path: Path, lengths: tuple[int, ...] = (6, 3)) -> tuple[Path, list[Episode]]:
    """Demos with a smooth 24x32 RGB camera (video codecs keep such frames well) and a state."""
    rng = np.random.default_rng(3)
    y, x = np.mgrid[0:24, 0:32]
    episodes = []
    for n in lengths:
        frames = np.stack([np.stack([x * 4 + 3 * t, y * 5 + 2 * t, 100 + x + y], -1) for t in range(n + 1)])
        episodes.append(Episode(observations={"cam": frames.astype(np.uint8), "state": rng.normal(size=(n + 1, 3)).astype(np.float32)},
                                actions=rng.normal(size=(n, 2)).astype(np.float32), rewards=rng.normal(size=n),
                                terminated=n == 6, truncated=n != 6, metadata={"n": n}))
    space = gym.spaces.Dict({"cam": gym.spaces.Box(0, 255, (24, 32, 3), np.uint8), "state": gym.spaces.Box(-9, 9, (3,), np.float32)})
    written = write_episodes(path, episodes, env_id="", observation_space=space,
                             action_space=gym.spaces.Box(-9, 9, (2,), np.float32), dt=0.1)
    return written, episodes


def test_cameras_export_as_lerobot_videos_and_convert_back(tmp_path: Path) -> None:
    from imitation.data.export.lerobot import export_lerobot

    source, episodes = camera_demos(tmp_path / "demos.mcap")
    result = export_lerobot(source, tmp_path / "ds", progress=False)
    assert result["frames"] == 7 + 4 and "observation.cam" in result["features"]
    feature = json.loads((tmp_path / "ds/meta/info.json").read_text())["features"]["observation.cam"]
    assert feature["dtype"] == "video" and feature["shape"] == [24, 32, 3] and feature["info"]["video.codec"] == "av1"
    assert sorted(p.relative_to(tmp_path / "ds").as_posix() for p in (tmp_path / "ds/videos").rglob("*.mp4")) == [
        "videos/observation.cam/chunk-000/file-000.mp4"]

    back = lerobot_to_episodes(tmp_path / "ds", progress=False)  # with the sidecar: the demos' own spaces
    assert back.observation_space == DemoFile(source).observation_space and back.warnings == []
    for original, restored in zip(episodes, back.episodes):
        assert restored.observations["cam"].shape == original.observations["cam"].shape and restored.observations["cam"].dtype == np.uint8
        assert psnr(restored.observations["cam"], original.observations["cam"]) >= 35  # AV1 at lerobot's crf 30: lossy
        assert np.array_equal(restored.observations["state"], original.observations["state"])
        assert (restored.terminated, restored.truncated, restored.metadata) == (original.terminated, original.truncated, original.metadata)

    # The sidecar's space, less the camera whose video is gone.
    shutil.copytree(tmp_path / "ds", tmp_path / "no_video", ignore=shutil.ignore_patterns("videos"))
    without = lerobot_to_episodes(tmp_path / "no_video", progress=False)
    assert without.observation_space == gym.spaces.Dict({"state": DemoFile(source).observation_space["state"]})
    assert f"{tmp_path / 'no_video'}: video feature 'observation.cam' skipped (the folder lacks its video files)" in without.warnings
    assert np.array_equal(without.episodes[0].observations["state"], episodes[0].observations["state"])

    # Without the sidecar, as another tool's dataset: the camera is found by the feature alone.
    (tmp_path / "ds/meta/imitation.json").unlink()
    plain = lerobot_to_episodes(tmp_path / "ds", progress=False)
    assert plain.observation_space["cam"] == gym.spaces.Box(0, 255, (24, 32, 3), np.uint8)
    assert [len(e) for e in plain.episodes] == [6, 3]

    # Without its videos: the camera is skipped, the state converts.
    shutil.rmtree(tmp_path / "ds/videos")
    bare = lerobot_to_episodes(tmp_path / "ds", progress=False)
    assert bare.observation_space == gym.spaces.Box(-np.inf, np.inf, (3,), np.float32)
    assert f"{tmp_path / 'ds'}: video feature 'observation.cam' skipped (the folder lacks its video files)" in bare.warnings


def test_lerobot_image_features_convert_losslessly(tmp_path: Path) -> None:
    """dtype "image": one PNG per frame inside the parquet, decoded to the very pixels added."""
    rng = np.random.default_rng(5)
    features = {"observation.state": {"dtype": "float32", "shape": (2,), "names": None},
                "action": {"dtype": "float32", "shape": (2,), "names": None},
                "observation.images.top": {"dtype": "image", "shape": (12, 16, 3), "names": ["height", "width", "channel"]}}
    images = [rng.integers(0, 256, (n, 12, 16, 3), dtype=np.uint8) for n in (4, 3)]
    with lerobot_quietly():
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        dataset = LeRobotDataset.create(repo_id="local/img", fps=10, features=features, root=tmp_path / "img", use_videos=False)
        for frames in images:
            for frame in frames:
                dataset.add_frame({"observation.state": np.zeros(2, np.float32), "action": np.ones(2, np.float32),
                                   "observation.images.top": frame, "task": "look"})
            dataset.save_episode()
        dataset.finalize()
    converted = lerobot_to_episodes(tmp_path / "img", progress=False)
    assert converted.observation_space["images.top"] == gym.spaces.Box(0, 255, (12, 16, 3), np.uint8)
    for episode, frames in zip(converted.episodes, images):
        assert np.array_equal(episode.observations["images.top"], frames)

    # A frame whose bytes are no image: one line naming the episode, the feature and the frame.
    data = tmp_path / "img/data/chunk-000/file-000.parquet"
    table = pq.read_table(data)
    column = table.column("observation.images.top").combine_chunks()
    blobs = column.field("bytes").to_pylist()
    blobs[5] = b"not a png"
    broken = pa.StructArray.from_arrays([pa.array(blobs, pa.binary()), column.field("path")], names=["bytes", "path"])
    pq.write_table(table.set_column(table.schema.get_field_index("observation.images.top"), "observation.images.top", broken), data)
    with pytest.raises(ImitationError, match=r"img: episode 1: image feature 'observation.images.top', frame 1: cannot decode it as a 16x12 image with 3 channels \(UnidentifiedImageError"):
        lerobot_to_episodes(tmp_path / "img", progress=False)

    # A JPEG of more scans than the limit jpeg_scans: refused before it is decoded.
    from PIL import Image

    from imitation.data.jpeg_scans import scan_count

    out = io.BytesIO()
    Image.fromarray(images[1][1]).save(out, format="JPEG", progressive=True)
    jpeg = out.getvalue()
    last, end = jpeg.rindex(b"\xff\xda"), jpeg.rindex(b"\xff\xd9")
    blobs[5] = jpeg[:end] + jpeg[last:end] * (500 - scan_count(jpeg)) + jpeg[end:]
    many = pa.StructArray.from_arrays([pa.array(blobs, pa.binary()), column.field("path")], names=["bytes", "path"])
    pq.write_table(table.set_column(table.schema.get_field_index("observation.images.top"), "observation.images.top", many), data)
    with pytest.raises(ImitationError, match=r"img: episode 1: image feature 'observation.images.top', frame 1: scans of one JPEG frame: 500 is more than the limit jpeg_scans=100"):
        lerobot_to_episodes(tmp_path / "img", progress=False)


def test_a_bare_camera_observation_exports_as_observation_image(tmp_path: Path) -> None:
    from imitation.data.export.lerobot import export_lerobot

    y, x = np.mgrid[0:16, 0:24]
    episode = Episode(observations=np.stack([np.stack([x * 6 + t, y * 8, 90 + x], -1) for t in range(5)]).astype(np.uint8),
                      actions=np.array([0, 1, 2, 1]), rewards=np.ones(4), truncated=True)
    space = gym.spaces.Box(0, 255, (16, 24, 3), np.uint8)
    source = write_episodes(tmp_path / "d.mcap", [episode], env_id="", observation_space=space, action_space=gym.spaces.Discrete(3))
    assert "observation.image" in export_lerobot(source, tmp_path / "ds", progress=False)["features"]
    # No dt (1 ms, 1000 fps) and 24 pixels wide: more than SVT-AV1 takes, so H.264 it is.
    assert json.loads((tmp_path / "ds/meta/info.json").read_text())["features"]["observation.image"]["info"]["video.codec"] == "h264"
    back = lerobot_to_episodes(tmp_path / "ds", progress=False)
    assert back.observation_space == space and back.episodes[0].observations.shape == (5, 16, 24, 3)
    assert psnr(back.episodes[0].observations, episode.observations) >= 30  # measured 34.6 on these 16x24 frames
    assert np.array_equal(back.episodes[0].actions, episode.actions)

    # A sidecar edited to give the camera another space is refused, naming the feature.
    sidecar = json.loads((tmp_path / "ds/meta/imitation.json").read_text())
    sidecar["observation_space"]["shape"] = [16, 24, 1]
    (tmp_path / "ds/meta/imitation.json").write_text(json.dumps(sidecar))
    with pytest.raises(ImitationError, match=r"gives camera 'observation.image' a space other than its uint8 \[16, 24, 3\] frames"):
        lerobot_to_episodes(tmp_path / "ds", progress=False)


def test_v21_one_h264_file_per_episode(tmp_path: Path) -> None:
    """A v2.1 layout (jsonl listing, a parquet and an mp4 per episode), its videos H.264 written
    with PyAV: each episode's frames start at 0 in its own file."""
    import av

    root = tmp_path / "v21"
    lengths = (5, 4)
    y, x = np.mgrid[0:16, 0:32]
    sources = []
    for index, n in enumerate(lengths):
        frames = np.stack([np.stack([(x * 8 + 30 * t + 90 * index) % 256, y * 16, np.full_like(x, 128)], -1) for t in range(n)]).astype(np.uint8)
        sources.append(frames)
        video = root / f"videos/chunk-000/observation.images.front/episode_{index:06d}.mp4"
        video.parent.mkdir(parents=True, exist_ok=True)
        with av.open(str(video), "w") as container:
            stream = container.add_stream("libx264", rate=10, options={"qp": "0"})
            stream.width, stream.height, stream.pix_fmt = 32, 16, "yuv444p"
            for frame in frames:
                container.mux(stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")))
            container.mux(stream.encode())
        data = root / f"data/chunk-000/episode_{index:06d}.parquet"
        data.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.table({"observation.state": [[float(t), 1.0] for t in range(n)], "action": [[0.5] for _ in range(n)],
                                 "timestamp": pa.array([t / 10 for t in range(n)], pa.float32()),
                                 "episode_index": [index] * n, "frame_index": list(range(n))}), data)
    (root / "meta").mkdir()
    (root / "meta/episodes.jsonl").write_text("".join(json.dumps({"episode_index": k, "length": n}) + "\n" for k, n in enumerate(lengths)))
    (root / "meta/info.json").write_text(json.dumps({
        "codebase_version": "v2.1", "fps": 10, "total_episodes": 2, "total_frames": 9, "chunks_size": 1000,
        "data_path": "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet",
        "video_path": "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4",
        "features": {"observation.state": {"dtype": "float32", "shape": [2]}, "action": {"dtype": "float32", "shape": [1]},
                     "observation.images.front": {"dtype": "video", "shape": [3, 16, 32], "names": ["channels", "height", "width"]},
                     "timestamp": {"dtype": "float32", "shape": [1]}, "episode_index": {"dtype": "int64", "shape": [1]},
                     "frame_index": {"dtype": "int64", "shape": [1]}}}))
    converted = lerobot_to_episodes(root, progress=False)
    assert converted.observation_space["images.front"] == gym.spaces.Box(0, 255, (16, 32, 3), np.uint8)
    for episode, frames in zip(converted.episodes, sources):
        assert episode.observations["images.front"].shape == frames.shape
        assert psnr(episode.observations["images.front"], frames) >= 40  # lossless H.264, then yuv444p → rgb24 rounding


def test_so101_round_trips_through_export_as_video(testdata: Path, tmp_path: Path) -> None:
    """SO-101 episodes 4 and 5 → demo file → `export --to lerobot` (AV1 by lerobot's writer) →
    convert: the same frame counts and shapes, the pixels close to the source's."""
    from imitation.data.export.lerobot import export_lerobot

    demos = tmp_path / "so101.mcap"
    write_converted(settle_ends(lerobot_to_episodes(testdata / "lerobot" / "so101_v30", episodes=[4, 5], progress=False)), demos, progress=False)
    result = export_lerobot(demos, tmp_path / "ds", progress=False)
    assert result["frames"] == 90 + 162
    back = lerobot_to_episodes(tmp_path / "ds", progress=False)
    assert back.observation_space == DemoFile(demos).observation_space
    for original, restored in zip(DemoFile(demos), back.episodes):
        assert restored.observations["images.wrist"].shape == original.observations["images.wrist"].shape
        assert psnr(restored.observations["images.wrist"], original.observations["images.wrist"]) >= 40  # measured 48.3
        assert np.array_equal(restored.observations["state"], original.observations["state"])

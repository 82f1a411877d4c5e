"""LeRobot datasets → episodes.

Both codebase versions are read directly from the folder, with pyarrow: v3.0's `meta/info.json`,
`meta/episodes/*/*.parquet` and the frames in `data/*/*.parquet` (the files lerobot's loader
reads); v2.1's `meta/info.json`, `meta/episodes.jsonl` and one parquet file per episode (lerobot
0.6 refuses v2.1). lerobot's own `LeRobotDataset` is not used for reading: it fetches whatever
the folder lacks (an episode's video file, a missing episode) from the Hugging Face Hub, and a
converter reads the local folder only.

`meta/info.json`'s totals (`total_episodes`, `total_frames`) are compared with what the data
holds; a difference is a warning, and what is present is converted.

A LeRobot frame t holds the observation at t and the action taken at t. An episode of L frames
becomes T = L - 1 steps: all L observations, the first L - 1 actions and `next.reward` values
(the last frame's action led to an observation the dataset does not hold). `observation.*`
features form the observation (a Dict space keyed by the name after `observation.` when there
are several), `action` the action. `next.done` cannot tell a time limit from a termination, and
the kept last frame is the state the last action was taken in, so every episode is truncated;
with `--env`, each episode's `source_end` says whether it ended at the env's time limit
(`imitation.data.convert.endings`). Features the demos have no place for are skipped with a
warning.

Cameras (`observation.images.*`, dtype "video" or "image") become uint8 (H, W, C) leaves
(`imitation.data.convert.cameras`), decoded one episode at a time, each frame resized once to
`image_size` when one is given (the frames' own size is in the metadata, `cameras`); the frames
the episodes hold (at that size),
and every video frame decoded on the way to them, may come to at most `image_expansion_ratio`
times the dataset folder's bytes (counted before the first frame is decoded, and as the videos
are). A row's video frame is the one at the episode's `videos/<key>/from_timestamp` (v3.0; 0 in
v2.1's one file per episode) plus an offset, within lerobot's default tolerance of 1e-4 s
(`video_tolerance_s` to widen it). The offset is the row's `timestamp`, as lerobot finds it,
when every row's timestamp lies within the tolerance of `frame_index / fps` (a LeRobot writer's
stamps do), or when a tolerance is given; otherwise, for stamps a wall clock wrote (jittered by a
few ms while the video runs at a constant fps), it is `frame_index / fps`, and a frame must lie
within 1e-4 s of it: the video's own clock confirms it runs at the constant fps. Which one was
used is in the demo file's metadata (`video_frames`), with a warning when it is frame_index. The
`timestamp` and `frame_index` columns are read whether or not info.json declares them. A video
feature some of whose files the folder lacks, or whose `video_path` has placeholders the
version does not fill, is skipped with a warning naming them, and the other features convert.

Datasets written by `imitation export --to lerobot` carry `meta/imitation.json`, which restores
the env id, the exact spaces and each episode's flags and metadata.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import re
import string
from collections.abc import Collection, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.data.convert.cameras import Camera, camera_for, decoded_images
from imitation.data.convert.converted import REWARDS_RECORDED, Converted, box_for, cast_rows, infer_action_space
from imitation.data.convert.endings import SourceEnds
from imitation.data.convert.video import frames_at
from imitation.data.image_resize import RESIZE_FILTER
from imitation.data.spaces import space_from_json, space_leaves
from imitation.data.types import Episode, Tree
from imitation.errors import ImitationError
from imitation.limits import LIMITS, ImageBudget, input_bytes, over_limit

SIDECAR = "meta/imitation.json"
_INDEX_FEATURES = {"timestamp", "frame_index", "episode_index", "index", "task_index"}
_VISUAL = {"image", "video"}
# lerobot's default `tolerance_s`: how far a video frame may lie from the timestamp asked for.
TOLERANCE_S = 1e-4
# The columns a row's video frame is found by, read whether or not info.json declares them.
_PLACING = ("timestamp", "frame_index")
# The placeholders each version fills in data_path and video_path.
_TEMPLATE_FIELDS = {
    ("v2.1", "data_path"): ("episode_chunk", "episode_index"),
    ("v2.1", "video_path"): ("episode_chunk", "video_key", "episode_index"),
    ("v3.0", "video_path"): ("video_key", "chunk_index", "file_index"),
}


@dataclass
class _Read:
    """What the dataset's files hold: numeric columns (one row per frame), each image feature's
    encoded frames, and where each video feature keeps each episode's frames."""

    columns: dict[str, np.ndarray]
    blobs: dict[str, Any]  # a pyarrow binary array per image feature, one entry per frame
    # video key → episode index → (file name, or None where the dataset does not say; from_timestamp)
    videos: dict[str, dict[int, tuple[str | None, float | None]]]


@dataclass(frozen=True)
class _Placement:
    """How rows find their video frames: by `timestamp` within `tolerance_s`, or by
    `frame_index` / fps; `gap_s` is how far the timestamps stray from frame_index / fps (None
    without both columns)."""

    by: str
    tolerance_s: float
    gap_s: float | None

    def to_json(self) -> dict[str, Any]:
        return {"placed_by": self.by, "tolerance_s": self.tolerance_s, "timestamp_gap_s": self.gap_s}


def lerobot_to_episodes(
    root: str | Path,
    *,
    episodes: Collection[int] | None = None,
    progress: bool = True,
    video_tolerance_s: float | None = None,
    image_size: tuple[int, int] | None = None,
) -> Converted:
    """Read the LeRobot dataset at `root` (v3.0 or v2.1); `episodes` keeps only the episodes of
    those `episode_index` values; `video_tolerance_s` places video frames by the rows'
    timestamps within that many seconds (default: see the module's docstring); `image_size`
    (height, width) resizes every camera's frames."""
    root = Path(root)
    info_path = root / "meta" / "info.json"
    if not info_path.is_file():
        raise ImitationError(f"{root}: not a LeRobot dataset root (no meta/info.json)")
    try:
        info = json.loads(info_path.read_bytes())
        version, features, fps = info["codebase_version"], info["features"], info["fps"]
    except (OSError, ValueError, KeyError, TypeError, RecursionError) as error:  # ValueError: not JSON, or not UTF-8
        raise ImitationError(f"{info_path}: not a LeRobot info.json ({type(error).__name__}: {str(error)[:200]})") from None
    if not isinstance(features, dict) or not all(isinstance(key, str) and isinstance(f, dict) for key, f in features.items()):
        raise ImitationError(f"{info_path}: 'features' must map each feature name to its description")
    for key, feature in features.items():  # lerobot writes every dtype as a name: anything else is damage
        dtype = feature.get("dtype")
        if not isinstance(dtype, str):
            if dtype is None:
                got = "none"
            elif isinstance(dtype, (list, dict)):
                got = "a list" if isinstance(dtype, list) else "an object"
            else:
                got = f"the {type(dtype).__name__} {dtype}"
            raise ImitationError(
                f"{info_path}: feature {key[:100]!r}: 'dtype' must be a name such as 'float32' or 'video', got {got[:60]}"
            )
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not 0 < fps < 1e6:
        raise ImitationError(f"{info_path}: 'fps' must be a positive number of frames per second, got {str(fps)[:40]}")
    observation_keys, cameras, action_key, warnings = _choose_features(root, info_path, features)
    if image_size is not None:
        cameras = [dataclasses.replace(camera, size=image_size) for camera in cameras]
    if version not in ("v3.0", "v2.1"):
        raise ImitationError(f"{root}: LeRobot codebase version {version!r} is not supported (v3.0 or v2.1)")
    if video_tolerance_s is not None and not 0 < video_tolerance_s < 1e6:
        raise ImitationError(f"video_tolerance_s must be a positive number of seconds below 1e6, got {video_tolerance_s}")
    videos = [camera.key for camera in cameras if camera.dtype == "video"]
    if videos and (problem := _template_problem(info.get("video_path"), version, "video_path")) is not None:
        shown = str(info["video_path"])[:120]
        warnings.append(f"{info_path}: video_path {shown!r} {problem}; video features {', '.join(map(repr, videos))} skipped")
        cameras = [camera for camera in cameras if camera.dtype != "video"]
    wanted = [*observation_keys, action_key, *(k for k in ("next.reward", "next.done") if k in features), "episode_index"]
    # Read where the data has them, declared in info.json or not: video frames are found by them.
    optional = list(_PLACING) if any(camera.dtype == "video" for camera in cameras) else []
    image_keys = [camera.key for camera in cameras if camera.dtype == "image"]
    video_keys = [key for key, feature in features.items() if feature.get("dtype") == "video"]
    if version == "v3.0":
        read = _read_v30(root, info, wanted, optional, image_keys, video_keys, progress)
    else:
        read = _read_v21(root, info, wanted, optional, image_keys, video_keys, progress)
    columns = {key: _shaped(root, key, values, features.get(key, {})) for key, values in read.columns.items()}
    # One number per row, declared or not.
    columns |= {key: _shaped(root, key, read.columns[key], {"shape": [1]}).reshape(-1) for key in _PLACING if key in columns}
    if len(columns["episode_index"]) == 0:
        raise ImitationError(f"{root}: the dataset holds no frames")
    placement = None
    if any(camera.dtype == "video" for camera in cameras):
        placement = _placement(root, fps, columns, video_tolerance_s, warnings)
        if placement is None:
            cameras = [camera for camera in cameras if camera.dtype != "video"]
    files = {
        key: list(dict.fromkeys(name for name, _ in where.values() if name is not None)) for key, where in read.videos.items()
    }
    warnings += _missing_videos(root, files)
    cameras = [camera for camera in cameras if camera.dtype == "image" or _video_usable(root, camera.key, read, warnings)]
    warnings += _totals_differ(info_path, info, columns["episode_index"])
    if not observation_keys and not cameras:
        raise ImitationError(f"{root}: no observation.* feature that converts (numeric, video or image)")
    return _build(
        root,
        version,
        fps,
        features,
        observation_keys,
        cameras,
        action_key,
        _Read(columns, read.blobs, read.videos),
        placement,
        episodes,
        warnings,
        progress,
    )


def _choose_features(root: Path, info_path: Path, features: dict[str, Any]) -> tuple[list[str], list[Camera], str, list[str]]:
    warnings = []
    observation_keys = []
    cameras = []
    for key, feature in features.items():
        dtype = feature.get("dtype")
        if key in _INDEX_FEATURES or key in ("action", "next.reward", "next.done"):
            continue
        if isinstance(dtype, str) and dtype in _VISUAL and key.startswith("observation."):
            camera = camera_for(info_path, key, feature)
            if isinstance(camera, Camera):
                cameras.append(camera)
            else:
                warnings.append(camera)
        elif key.startswith("observation.") and _numeric(dtype):
            observation_keys.append(key)
        else:
            warnings.append(f"{root}: feature {key!r} ({dtype}) has no place in the demos; skipped")
    if not observation_keys and not cameras:
        raise ImitationError(f"{root}: no observation.* feature that converts (numeric, video or image)")
    if "action" not in features or not _numeric(features["action"].get("dtype")):
        raise ImitationError(f"{root}: no numeric 'action' feature")
    return observation_keys, cameras, "action", warnings


def _video_usable(root: Path, key: str, read: _Read, warnings: list[str]) -> bool:
    """Whether every episode's frames of video feature `key` can be found: its files present (a
    missing one was warned about already) and each episode's file and start time known."""
    where = read.videos.get(key, {})
    episodes = set(np.unique(read.columns["episode_index"].astype(np.int64)).tolist())  # as _build reads them
    unknown = sorted(index for index in episodes if where.get(index, (None, None))[0] is None or where[index][1] is None)
    if unknown:
        warnings.append(
            f"{root}: video feature {key!r} skipped (the dataset does not say which file holds episode {unknown[0]}'s frames)"
        )
        return False
    if not all(_is_file(root / name) for name, _ in where.values() if name is not None):
        warnings.append(f"{root}: video feature {key!r} skipped (the folder lacks its video files)")
        return False
    return True


def _placement(
    root: Path, fps: float, columns: dict[str, np.ndarray], tolerance_s: float | None, warnings: list[str]
) -> _Placement | None:
    """How the rows find their video frames (module docstring); None, with a warning, when the
    data has neither a timestamp nor a frame_index column."""
    stamps, indices = columns.get("timestamp"), columns.get("frame_index")
    if indices is not None and (indices.dtype.kind not in "iu" or (len(indices) and indices.min() < 0)):
        warnings.append(f"{root}: the frame_index column does not hold whole numbers from 0; it places no video frame")
        indices = None
    if stamps is not None and stamps.dtype.kind != "f":
        stamps = stamps.astype(np.float64)
    if stamps is None and indices is None:
        warnings.append(
            f"{root}: video features skipped (the data has neither a timestamp nor a frame_index column to find their "
            "frames by)"
        )
        return None
    tolerance = TOLERANCE_S if tolerance_s is None else tolerance_s
    gap = None
    if stamps is not None and indices is not None:
        gap = float(np.max(np.abs(stamps.astype(np.float64) - indices / float(fps)), initial=0.0))
        gap = gap if math.isfinite(gap) else None  # NaN or inf stamps: damage, and no distance to report
    if stamps is not None and (indices is None or tolerance_s is not None or (gap is not None and gap <= tolerance)):
        return _Placement("timestamp", tolerance, gap)
    if stamps is None:
        warnings.append(f"{root}: no timestamp column; video frames are placed by frame_index at the videos' {fps:g} fps")
    else:
        strayed = (
            f"stray from frame_index / fps by up to {gap * 1e3:.1f} ms, more than lerobot's {TOLERANCE_S} s (stamped by a "
            "wall clock?)"
            if gap is not None
            else "are not all finite numbers"
        )
        warnings.append(
            f"{root}: the rows' timestamps {strayed}; video frames are placed by frame_index at the videos' {fps:g} fps "
            "(--video-tolerance S places them by timestamp instead)"
        )
    return _Placement("frame_index", TOLERANCE_S, gap)


def _template_problem(template: Any, version: str, name: str) -> str | None:
    """What is wrong with info.json's data_path or video_path (`name`) for `version`, said after
    the template: a placeholder the version does not fill (v3.0's chunk_index in a v2.1 set), or
    no episode_index in a v2.1 one; None when it fits (or is absent, no text, or no pattern:
    reading it says so)."""
    if not isinstance(template, str):
        return None
    fills = _TEMPLATE_FIELDS[(version, name)]
    try:
        fields = [field for _, field, _, _ in string.Formatter().parse(template) if field is not None]
    except ValueError:  # an unmatched brace: filling it in fails, and says so
        return None
    for field in fields:
        if field not in fills:
            return f"has the placeholder {field[:40]!r}, which {version} does not fill (it fills {', '.join(fills)})"
    if version == "v2.1" and "episode_index" not in fields:
        return "has no episode_index placeholder (v2.1 keeps one file per episode)"
    return None


def _numeric(dtype: Any) -> bool:
    try:
        return np.dtype(dtype).kind in "biuf"
    except (TypeError, ValueError, SyntaxError):  # numpy parses some dtype strings as Python
        return False


@contextmanager
def lerobot_quietly() -> Iterator[None]:
    """lerobot is imported here only, for its writer (`imitation export --to lerobot`; the import
    costs seconds). Its loaders look at the Hub unless told not to, it logs warnings about fields
    it ignores, and its writer runs a `datasets` map per episode, each with a progress bar; its
    video encoder (SVT-AV1) and muxer (FFmpeg) print to stderr for every episode. We write local
    folders and keep our own bar."""
    # Before the import: huggingface_hub reads HF_HUB_OFFLINE once, when it is first imported.
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1's errors only; it reads this when an encoder starts
    import av

    import datasets

    logger = logging.getLogger("lerobot")
    level = logger.level
    logger.setLevel(logging.ERROR)
    bars = datasets.is_progress_bar_enabled()
    datasets.disable_progress_bars()
    # lerobot hands FFmpeg's log back to FFmpeg's own printer after each encode: quiet it there.
    av.logging.set_libav_level(av.logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)
        av.logging.set_libav_level(av.logging.INFO)  # FFmpeg's default (it has no getter to save the old one)
        if bars:
            datasets.enable_progress_bars()


def _read_v30(
    root: Path,
    info: dict[str, Any],
    wanted: list[str],
    optional: list[str],
    image_keys: list[str],
    video_keys: list[str],
    progress: bool,
) -> _Read:
    """The `wanted` columns (and the `optional` ones every file has) and the image features'
    frames of every frame in data/*/*.parquet (in the order lerobot's loader reads them), and
    where each video feature keeps each episode's frames (from meta/episodes)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from imitation.progress import progress_over

    videos = _v30_video_files(root, info, video_keys)
    files = sorted((root / "data").glob("*/*.parquet"))
    if not files:
        raise ImitationError(f"{root / 'data'}: no frames (a v3.0 dataset keeps them in data/chunk-*/file-*.parquet)")
    parts: dict[str, list[np.ndarray]] = {key: [] for key in [*wanted, *optional]}
    blobs: dict[str, list[Any]] = {key: [] for key in image_keys}
    for path in progress_over(files, total=len(files), desc="read", unit="file", enabled=progress):
        try:
            present = _present(path, optional)
            table = pq.read_table(path, columns=[*wanted, *present, *image_keys])
            columns = {key: _column(table.column(key)) for key in [*wanted, *present]} if table.num_rows else {}
            images = {key: _image_bytes(table.column(key)) for key in image_keys} if table.num_rows else {}
        except (OSError, ValueError, KeyError, TypeError, pa.ArrowException) as error:
            raise ImitationError(f"{path}: cannot read its frames ({type(error).__name__}: {str(error)[:200]})") from None
        for key, values in columns.items():
            parts[key].append(values)
        for key, array in images.items():
            blobs[key].append(array)
    return _Read(_concatenated(root, _complete(parts, optional)), _joined(blobs), videos)


def _v30_video_files(
    root: Path, info: dict[str, Any], video_keys: list[str]
) -> dict[str, dict[int, tuple[str | None, float | None]]]:
    """Each video feature's file and from_timestamp for each episode, as meta/episodes/*/*.parquet
    and info.json's video_path name them."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    listing = root / "meta" / "episodes"
    parts = ("chunk_index", "file_index", "from_timestamp")
    wanted = [f"videos/{key}/{part}" for key in video_keys for part in parts]
    rows: dict[str, list[Any]] = {name: [] for name in ["episode_index", *wanted]}
    try:
        files = sorted(listing.glob("*/*.parquet"))
        if not files:
            raise FileNotFoundError("no chunk-*/file-*.parquet in it")
        for path in files:
            present = [name for name in wanted if name in pq.read_schema(path).names]
            table = pq.read_table(path, columns=["episode_index", *present])
            rows["episode_index"] += table.column("episode_index").to_pylist()
            for name in wanted:
                rows[name] += table.column(name).to_pylist() if name in present else [None] * table.num_rows
    except (OSError, ValueError, KeyError, TypeError, pa.ArrowException) as error:
        raise _unreadable_listing(listing, "v3.0", error) from None
    template = info.get("video_path")
    videos: dict[str, dict[int, tuple[str | None, float | None]]] = {}
    for key in video_keys:
        chunks, numbers, starts = (rows[f"videos/{key}/{part}"] for part in parts)
        videos[key] = {
            int(index): (_video_file(template, video_key=key, chunk_index=c, file_index=f), _seconds(start))
            for index, c, f, start in zip(rows["episode_index"], chunks, numbers, starts)
            if isinstance(index, int)
        }
    return videos


def _seconds(value: Any) -> float | None:
    """A from_timestamp as read from meta/episodes: a finite number of seconds, else None."""
    if isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value):
        return float(value)
    return None


def _unreadable_listing(path: Path, version: str, error: BaseException) -> ImitationError:
    return ImitationError(f"{path}: cannot read the {version} episode list ({type(error).__name__}: {str(error)[:200]})")


def _video_file(template: Any, **fields: Any) -> str | None:
    """info.json's video_path filled in; None where the dataset does not say (no path, no index)
    or says it in a way that is not a file name pattern (format specs other than widths such as
    `03d`: a hostile `{chunk_index:999999999}` would build a gigabyte name per episode)."""
    if not isinstance(template, str) or any(value is None for value in fields.values()):
        return None
    try:
        if not all(re.fullmatch(r"0?\d{0,2}d?", spec or "") for _, _, spec, _ in string.Formatter().parse(template)):
            return None
        return template.format(**fields)
    except (KeyError, IndexError, ValueError, TypeError, AttributeError):
        return None


def _missing_videos(root: Path, videos: dict[str, list[str]]) -> list[str]:
    """One warning per video feature some of whose files the folder lacks, naming them (the
    first three, and how many more)."""
    warnings = []
    for key, names in videos.items():
        missing = [name for name in names if not _is_file(root / name)]
        if missing:
            shown = ", ".join(missing[:3]) + (f" and {len(missing) - 3} more" if len(missing) > 3 else "")
            warnings.append(
                f"{root}: video files of {key!r} missing, {len(missing)} of {len(names)}: {shown} (the other features convert)"
            )
    return warnings


def _is_file(path: Path) -> bool:
    try:
        return path.is_file()
    except (OSError, ValueError):  # a name the OS refuses (too long, a NUL byte) is no file
        return False


def _totals_differ(info_path: Path, info: dict[str, Any], episode_index: np.ndarray) -> list[str]:
    """Warnings where info.json's total_episodes or total_frames differ from the frames present."""
    indices = episode_index.reshape(-1)
    # Episodes as they are converted: runs of frames with one episode_index.
    present = {"total_episodes": int(np.count_nonzero(np.diff(indices))) + 1, "total_frames": len(indices)}
    warnings = []
    for key, count in present.items():
        claimed = info.get(key)
        if isinstance(claimed, int) and not isinstance(claimed, bool) and claimed != count:
            what = key.removeprefix("total_")
            warnings.append(
                f"{info_path}: {key} is {claimed}, but the dataset holds {count} {what}; converting the {count} present"
            )
    return warnings


def _read_v21(
    root: Path,
    info: dict[str, Any],
    wanted: list[str],
    optional: list[str],
    image_keys: list[str],
    video_keys: list[str],
    progress: bool,
) -> _Read:
    """As `_read_v30`, from v2.1's one parquet (and one video file per video feature) per episode."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from imitation.progress import progress_over

    episodes_path = root / "meta" / "episodes.jsonl"
    try:
        listed = [json.loads(line) for line in episodes_path.read_bytes().splitlines() if line.strip()]
        template, chunk_size = str(info["data_path"]), int(info.get("chunks_size", 1000))
        if chunk_size < 1:
            raise ValueError(f"chunks_size {chunk_size} is not positive")
    except (
        OSError,
        ValueError,
        KeyError,
        TypeError,
        OverflowError,
        RecursionError,
    ) as error:  # ValueError: JSON, UTF-8 or a number
        raise _unreadable_listing(episodes_path, "v2.1", error) from None
    if (problem := _template_problem(template, "v2.1", "data_path")) is not None:
        raise ImitationError(f"{root / 'meta' / 'info.json'}: data_path {template[:120]!r} {problem}")
    parts: dict[str, list[np.ndarray]] = {key: [] for key in [*wanted, *optional]}
    blobs: dict[str, list[Any]] = {key: [] for key in image_keys}
    videos: dict[str, dict[int, tuple[str | None, float | None]]] = {key: {} for key in video_keys}
    for line, entry in enumerate(progress_over(listed, total=len(listed), desc="read", unit="episode", enabled=progress), 1):
        try:
            index = int(entry["episode_index"])
            length = int(entry.get("length", -1))
            path = root / template.format(episode_chunk=index // chunk_size, episode_index=index)
            for key in video_keys:
                name = _video_file(
                    info.get("video_path"), episode_chunk=index // chunk_size, video_key=key, episode_index=index
                )
                videos[key][index] = (name, 0.0)  # one file per episode: its frames start at 0
        except (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError) as error:
            raise ImitationError(
                f"{episodes_path}: line {line} is not an episode entry, or data_path does not fit it "
                f"({type(error).__name__}: {str(error)[:100]})"
            ) from None
        try:
            present = _present(path, optional)
            table = pq.read_table(path, columns=[*wanted, *present, *image_keys])
            columns = {key: _column(table.column(key)) for key in [*wanted, *present]}
            images = {key: _image_bytes(table.column(key)) for key in image_keys}
        except (OSError, ValueError, KeyError, TypeError, pa.ArrowException) as error:
            raise ImitationError(f"{path}: cannot read episode {index} ({type(error).__name__}: {str(error)[:200]})") from None
        if length >= 0 and table.num_rows != length:
            raise ImitationError(f"{path}: episode {index} has {table.num_rows} frames, meta/episodes.jsonl says {length}")
        for key, values in columns.items():
            parts[key].append(values)
        for key in image_keys:
            blobs[key].append(images[key])
    if not listed:
        raise ImitationError(f"{episodes_path}: lists no episode")
    return _Read(_concatenated(root, _complete(parts, optional)), _joined(blobs), videos)


def _present(path: Path, optional: list[str]) -> list[str]:
    """The `optional` columns the parquet file at `path` holds (its footer alone is read)."""
    import pyarrow.parquet as pq

    if not optional:
        return []
    names = set(pq.read_schema(path).names)
    return [key for key in optional if key in names]


def _complete(parts: dict[str, list[np.ndarray]], optional: list[str]) -> dict[str, list[np.ndarray]]:
    """`parts` less the optional columns some file lacks (a row without one cannot be placed by it)."""
    files = max(len(values) for key, values in parts.items() if key not in optional)
    return {key: values for key, values in parts.items() if key not in optional or len(values) == files}


def _concatenated(root: Path, parts: dict[str, list[np.ndarray]]) -> dict[str, np.ndarray]:
    try:
        return {key: np.concatenate(values) if values else np.empty(0) for key, values in parts.items()}
    except ValueError as error:  # rows of one feature differ in width between episodes (or files)
        raise ImitationError(f"{root}: episodes disagree on a feature's shape ({str(error)[:200]})") from None


def _joined(blobs: dict[str, list[Any]]) -> dict[str, Any]:
    import pyarrow as pa

    return {key: pa.concat_arrays(arrays) if arrays else pa.array([], pa.large_binary()) for key, arrays in blobs.items()}


def _image_bytes(column: Any) -> Any:
    """An image feature's column as one binary array: `datasets` stores each image as a struct of
    its encoded `bytes` and a `path` (kept for files beside the parquet, which lerobot never
    writes: such a row has no bytes, and is refused when its episode is decoded)."""
    import pyarrow as pa

    array = column.combine_chunks()
    if pa.types.is_struct(array.type):
        array = array.field("bytes")
    if not (pa.types.is_binary(array.type) or pa.types.is_large_binary(array.type)):
        raise TypeError(f"an image column of type {array.type}")
    return array.cast(pa.large_binary())


def _column(column: Any) -> np.ndarray:
    """A parquet column of scalars or (nested) fixed-length lists as one numpy array, rows first."""
    import pyarrow as pa

    array = column.combine_chunks()
    rows = len(array)
    while pa.types.is_list(array.type) or pa.types.is_fixed_size_list(array.type) or pa.types.is_large_list(array.type):
        array = array.flatten()
    return array.to_numpy(zero_copy_only=False).reshape(rows, -1)


def _shaped(root: Path, key: str, values: np.ndarray, feature: dict[str, Any]) -> np.ndarray:
    """Rows of the feature's declared shape (lerobot hands (1,)-shaped features over as scalars)."""
    shape = feature.get("shape") or [1]
    try:
        if values.dtype.kind not in "biuf":
            raise ValueError(f"values of type {values.dtype}")
        return values.reshape((len(values), *shape))
    except (ValueError, TypeError) as error:
        raise ImitationError(
            f"{root}: feature {key!r} does not hold rows of its declared shape {str(shape)[:40]} ({str(error)[:100]})"
        ) from None


def _build(
    root: Path,
    version: str,
    fps: float,
    features: dict[str, Any],
    observation_keys: list[str],
    cameras: list[Camera],
    action_key: str,
    read: _Read,
    placement: _Placement | None,
    selected: Collection[int] | None,
    warnings: list[str],
    progress: bool,
) -> Converted:
    from imitation.progress import progress_over

    columns = read.columns
    episode_index = columns["episode_index"].reshape(-1).astype(np.int64)
    starts = np.flatnonzero(np.diff(episode_index, prepend=episode_index[0] - 1) != 0)
    bounds = np.append(starts, len(episode_index))
    kept = _kept(root, episode_index[starts], selected)
    sidecar = _sidecar(root, [int(b - a) for a, b in zip(bounds[:-1], bounds[1:])], warnings)
    leaves = _Leaves(root, fps, features, observation_keys, cameras, read, placement)
    if sidecar is not None:
        observation_space = leaves.fitted(space_from_json(sidecar["observation_space"]), warnings)
        action_space = space_from_json(sidecar["action_space"])
    else:
        observation_space = leaves.inferred()
        action_space = infer_action_space(columns[action_key])
    elements = sum(math.prod(shape) for _, _, shape in space_leaves(observation_space))
    if elements > LIMITS.sample_elements:
        raise over_limit(f"{root}: numbers per observation (all features together)", elements, "sample_elements")
    actions = (
        cast_rows(columns[action_key], action_space, f"{root}: action")
        if not isinstance(action_space, gym.spaces.Dict)
        else None
    )
    if actions is None:
        raise ImitationError(f"{root}: Dict action spaces are not supported")
    rewards = columns["next.reward"].reshape(-1) if "next.reward" in columns else None
    done = columns["next.done"].reshape(-1) if "next.done" in columns else None
    if cameras:
        # The frames the episodes hold, counted before the first is decoded; `leaves.budget`
        # counts each video frame decoded on the way to them too.
        frame_bytes = sum(math.prod(leaves.cameras[key].frame_shape) for key in leaves.used.values() if key in leaves.cameras)
        rows = sum(int(bounds[k + 1] - bounds[k]) for k in kept)
        ImageBudget(str(root), leaves.budget.source_bytes).take(rows * frame_bytes)
    episodes = []
    for k in progress_over(kept, total=len(kept), desc="decode", unit="episode", enabled=progress and bool(cameras)):
        start, end = int(bounds[k]), int(bounds[k + 1])
        steps = end - start - 1
        # Without the sidecar the demo stops one step before the episode ended: truncated (see `ends` below).
        facts: dict[str, Any] = sidecar["episodes"][k] if sidecar else {"terminated": False, "truncated": True}
        episodes.append(
            Episode(
                observations=leaves.observations(observation_space, int(episode_index[start]), start, end),
                actions=actions[start : start + steps],
                rewards=rewards[start : start + steps].astype(np.float64) if rewards is not None else np.zeros(steps),
                terminated=bool(facts.get("terminated", False)),
                truncated=bool(facts.get("truncated", False)),
                metadata=facts.get("metadata", {"source_episode_index": int(episode_index[start])}),
            )
        )
    if rewards is None:
        warnings.append(f"{root}: no next.reward feature; rewards are zero")
    # Without our sidecar, `next.done` is gymnasium's old `done` (a time limit counts as one), and
    # each episode's last frame is the state its last action was taken in, not the state after:
    # the episodes' ends are decided by `settle_ends`.
    ends = None
    if sidecar is None:
        ends = SourceEnds(
            flag="next.done",
            steps=[int(bounds[k + 1] - bounds[k]) for k in kept],
            done=[bool(done[bounds[k + 1] - 1]) for k in kept] if done is not None else None,
            final_observation=False,
        )
    observed = list(leaves.used.values())
    metadata: dict[str, Any] = {
        "converter": "lerobot",
        "root": str(root),
        "codebase_version": version,
        "observation_features": observed,
        "action_feature": action_key,
        "names": {key: features[key].get("names") for key in [*observed, action_key]},
    }
    if rewards is None:
        metadata[REWARDS_RECORDED] = False
    if selected is not None:
        metadata["episodes"] = sorted(int(episode_index[bounds[k]]) for k in kept)
    if placement is not None and any(leaves.cameras[key].dtype == "video" for key in observed if key in leaves.cameras):
        metadata["video_frames"] = placement.to_json()
    resized = {key: leaves.cameras[key] for key in observed if key in leaves.cameras and leaves.cameras[key].size is not None}
    if resized:
        metadata["cameras"] = {
            key: {"resized_from": list(camera.shape[:2]), "filter": RESIZE_FILTER} for key, camera in resized.items()
        }
    return Converted(
        episodes=episodes,
        observation_space=observation_space,
        action_space=action_space,
        source=sidecar["source"] if sidecar else f"LeRobot {version} {root}",
        env_id=sidecar["env_id"] if sidecar else "",
        dt=sidecar["dt"] if sidecar else 1.0 / float(fps),
        metadata={**sidecar["user_metadata"], **_said(metadata)} if sidecar else metadata,
        warnings=warnings,
        ends=ends,
    )


def _said(metadata: dict[str, Any]) -> dict[str, Any]:
    """What the conversion itself decided (frames placed, cameras resized): kept beside a
    sidecar's metadata, which otherwise replaces ours."""
    return {key: metadata[key] for key in ("video_frames", "cameras") if key in metadata}


def _kept(root: Path, indices: np.ndarray, selected: Collection[int] | None) -> list[int]:
    """Positions of the episodes (runs of one episode_index, whose values are `indices`) to convert."""
    if selected is None:
        return list(range(len(indices)))
    absent = sorted(set(selected) - set(indices.tolist()))
    if absent:
        raise ImitationError(
            f"{root}: no episode {absent[0]} in the dataset "
            f"(it holds {len(indices)}, episode_index {indices.min()} to {indices.max()})"
        )
    return [k for k, index in enumerate(indices.tolist()) if index in selected]


class _Leaves:
    """The observation's leaves: each named after its feature, less `observation.`, in
    info.json's order; numeric features come from the columns, cameras are decoded per episode."""

    def __init__(
        self,
        root: Path,
        fps: float,
        features: dict[str, Any],
        numeric: list[str],
        cameras: list[Camera],
        read: _Read,
        placement: _Placement | None,
    ) -> None:
        self.root, self.fps, self.read, self.placement = root, fps, read, placement
        self.cameras = {camera.key: camera for camera in cameras}
        chosen = set(numeric) | set(self.cameras)
        self.features = {key.removeprefix("observation."): key for key in features if key in chosen}
        # A dataset without a camera that converts: its cameras' names, for a sidecar that names one.
        self.skipped = {
            key.removeprefix("observation."): key
            for key, feature in features.items()
            if isinstance(feature.get("dtype"), str) and feature["dtype"] in _VISUAL and key not in self.cameras
        }
        self.used: dict[str, str] = {}  # leaf name ("" for a bare space) → feature, once the space is known
        self.budget = ImageBudget(str(root), input_bytes(root) if cameras else 0)

    def inferred(self) -> gym.Space:
        """The space the features give: one leaf's own, or a Dict of them all."""
        spaces: dict[str, gym.Space] = {
            name: self.cameras[key].space if key in self.cameras else box_for(self.read.columns[key])
            for name, key in self.features.items()
        }
        if len(spaces) == 1:
            self.used = {"": next(iter(self.features.values()))}
            return next(iter(spaces.values()))
        self.used = dict(self.features)
        return gym.spaces.Dict(spaces)

    def fitted(self, space: gym.Space, warnings: list[str]) -> gym.Space:
        """The sidecar's space, less the cameras whose videos the folder lacks (warned about
        already); the cameras it does not name are skipped with a warning."""
        if isinstance(space, gym.spaces.Dict):
            names = [name for name in space.spaces if name not in self.skipped]
            missing = [name for name in names if name not in self.features]
            if missing:
                raise ImitationError(f"{self.root}: {SIDECAR} names observation key {missing[0]!r}, which has no feature")
            self.used = {name: self.features[name] for name in names}
            space = gym.spaces.Dict({name: self._resized(space.spaces[name], self.used[name]) for name in names})
        else:
            # A bare space: the camera whose frames it holds, else the first numeric feature.
            fits = [key for key, camera in self.cameras.items() if (space.dtype, space.shape) == (np.uint8, camera.shape)]
            numeric = [key for key in self.features.values() if key not in self.cameras]
            self.used = {"": (fits or numeric or list(self.cameras))[0]}
            space = self._resized(space, self.used[""])
        for key in sorted(set(self.cameras) - set(self.used.values())):
            warnings.append(f"{self.root}: camera feature {key!r} skipped (not in {SIDECAR}'s observation space)")
        return space

    def _resized(self, space: gym.Space, key: str) -> gym.Space:
        """The sidecar's space of feature `key`; a camera's, at its stored size when it is resized
        (the sidecar says the frames' own)."""
        camera = self.cameras.get(key)
        if camera is None or camera.size is None or not isinstance(space, gym.spaces.Box) or space.shape != camera.shape:
            return space
        return camera.space

    def observations(self, space: gym.Space, episode: int, start: int, end: int) -> Tree:
        """Rows start..end (one episode) of every leaf, as `space` holds them."""
        if isinstance(space, gym.spaces.Dict):
            return {name: self._rows(self.used[name], sub, episode, start, end) for name, sub in space.spaces.items()}
        return self._rows(self.used[""], space, episode, start, end)

    def _rows(self, key: str, space: gym.Space, episode: int, start: int, end: int) -> np.ndarray:
        camera = self.cameras.get(key)
        if camera is None:
            return cast_rows(self.read.columns[key][start:end], space, f"{self.root}: {key}")
        if not (isinstance(space, gym.spaces.Box) and space.dtype == np.uint8 and space.shape == camera.frame_shape):
            raise ImitationError(
                f"{self.root}: {SIDECAR} gives camera {key!r} a space other than its uint8 {list(camera.frame_shape)} frames"
            )
        if camera.dtype == "image":
            blobs = self.read.blobs[key].slice(start, end - start).to_pylist()
            return decoded_images(blobs, camera, f"{self.root}: episode {episode}")
        name, offset = self.read.videos[key][episode]
        placement = self.placement
        # Episodes whose frames cannot be found, and data with neither column, skip the camera.
        assert name is not None and offset is not None and placement is not None
        what = f"video feature {key!r}, episode {episode}"
        if placement.by == "timestamp":
            # lerobot's query: from_timestamp plus the row's timestamp (a float32, widened exactly).
            seconds = offset + self.read.columns["timestamp"][start:end].astype(np.float64)
            hint = ""
        else:
            seconds = offset + self.read.columns["frame_index"][start:end] / float(self.fps)
            what += f", placed by frame_index at {self.fps:g} fps"
            hint = f"; the video does not run at a constant {self.fps:g} fps (--video-tolerance S places frames by timestamp)"
        return frames_at(
            self.root / name,
            seconds,
            tolerance_s=placement.tolerance_s,
            shape=camera.shape,
            what=what,
            budget=self.budget,
            hint=hint,
            size=camera.size,
        )


def _check_sidecar(sidecar: dict[str, Any]) -> None:
    """TypeError or ValueError for a sidecar whose fields are not what `export --to lerobot` writes."""
    if not isinstance(sidecar["env_id"], str) or not isinstance(sidecar["source"], str):
        raise TypeError("env_id and source must be strings")
    dt = sidecar["dt"]
    if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not 0 < dt < 1e6:
        raise ValueError(f"dt must be a positive number of seconds, got {str(dt)[:40]}")
    if not isinstance(sidecar["user_metadata"], dict):
        raise TypeError("user_metadata must be an object")
    for episode in sidecar["episodes"]:
        terminated, truncated = episode.get("terminated", False), episode.get("truncated", False)
        if not isinstance(terminated, bool) or not isinstance(truncated, bool) or (terminated and truncated):
            raise ValueError("an episode's terminated and truncated must be true or false, not both true")
        if not isinstance(episode.get("metadata", {}), dict):
            raise TypeError("an episode's metadata must be an object")


def _sidecar(root: Path, frames: list[int], warnings: list[str]) -> dict[str, Any] | None:
    """meta/imitation.json if present and consistent with the frames found (else a warning)."""
    path = root / SIDECAR
    if not path.is_file():
        return None
    try:
        sidecar = json.loads(path.read_text())
        lengths = [int(e["length"]) + 1 for e in sidecar["episodes"]]
        for key in ("observation_space", "action_space", "env_id", "dt", "source", "user_metadata"):
            sidecar[key]
        _check_sidecar(sidecar)
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, RecursionError) as error:
        warnings.append(f"{path}: unreadable ({type(error).__name__}: {str(error)[:200]}); ignored")
        return None
    if lengths != frames:
        warnings.append(f"{path}: describes other episodes than the dataset holds (edited since export?); ignored")
        return None
    return sidecar

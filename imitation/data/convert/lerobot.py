"""LeRobot datasets → episodes.

Both codebase versions are read directly from the folder, with pyarrow: v3.0's `meta/info.json`,
`meta/episodes/*/*.parquet` and the frames in `data/*/*.parquet` (the files lerobot's loader
reads); v2.1's `meta/info.json`, `meta/episodes.jsonl` and one parquet file per episode (lerobot
0.6 refuses v2.1). lerobot's own `LeRobotDataset` is not used for reading: it fetches whatever
the folder lacks (an episode's video file, a missing episode) from the Hugging Face Hub, and a
converter reads the local folder only. Videos are neither decoded nor required: the files the
dataset's video features name and the folder lacks are listed in a warning.

`meta/info.json`'s totals (`total_episodes`, `total_frames`) are compared with what the data
holds; a difference is a warning, and what is present is converted.

A LeRobot frame t holds the observation at t and the action taken at t. An episode of L frames
becomes T = L - 1 steps: all L observations, the first L - 1 actions and `next.reward` values
(the last frame's action led to an observation the dataset does not hold). `observation.*`
features form the observation (a Dict space when there are several), `action` the action.
`next.done` cannot tell a time limit from a termination, and the kept last frame is the state
the last action was taken in, so every episode is truncated; with `--env`, each episode's
`source_end` says whether it ended at the env's time limit (`imitation.data.convert.endings`).
Image and video features are skipped with a warning, as are other features the demos have no
place for.

Datasets written by `imitation export --to lerobot` carry `meta/imitation.json`, which restores
the env id, the exact spaces and each episode's flags and metadata.
"""

from __future__ import annotations

import json
import logging
import os
import re
import string
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.data.convert.converted import Converted, box_for, cast_rows, infer_action_space
from imitation.data.convert.endings import SourceEnds
from imitation.data.spaces import space_from_json
from imitation.data.types import Episode
from imitation.errors import ImitationError

SIDECAR = "meta/imitation.json"
_INDEX_FEATURES = {"timestamp", "frame_index", "episode_index", "index", "task_index"}
_VISUAL = {"image", "video"}


def lerobot_to_episodes(root: str | Path, *, progress: bool = True) -> Converted:
    """Read the LeRobot dataset at `root` (v3.0 or v2.1)."""
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
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not 0 < fps < 1e6:
        raise ImitationError(f"{info_path}: 'fps' must be a positive number of frames per second, got {str(fps)[:40]}")
    observation_keys, action_key, warnings = _choose_features(root, features)
    wanted = [*observation_keys, action_key, *(k for k in ("next.reward", "next.done") if k in features), "episode_index"]
    video_keys = [key for key, feature in features.items() if feature.get("dtype") == "video"]
    if version == "v3.0":
        columns, videos = _read_v30(root, info, wanted, video_keys, progress)
    elif version == "v2.1":
        columns, videos = _read_v21(root, info, wanted, video_keys, progress)
    else:
        raise ImitationError(f"{root}: LeRobot codebase version {version!r} is not supported (v3.0 or v2.1)")
    columns = {key: _shaped(root, key, values, features.get(key, {})) for key, values in columns.items()}
    if len(columns["episode_index"]) == 0:
        raise ImitationError(f"{root}: the dataset holds no frames")
    warnings += _missing_videos(root, videos)
    warnings += _totals_differ(info_path, info, columns["episode_index"])
    return _build(root, version, fps, features, observation_keys, action_key, columns, warnings)


def _choose_features(root: Path, features: dict[str, Any]) -> tuple[list[str], str, list[str]]:
    warnings = []
    observation_keys = []
    for key, feature in features.items():
        dtype = feature.get("dtype")
        if key in _INDEX_FEATURES or key in ("action", "next.reward", "next.done"):
            continue
        if isinstance(dtype, str) and dtype in _VISUAL:
            warnings.append(f"{root}: {dtype} feature {key!r} skipped (image demos are not supported yet)")
        elif key.startswith("observation.") and _numeric(dtype):
            observation_keys.append(key)
        else:
            warnings.append(f"{root}: feature {key!r} ({dtype}) has no place in the demos; skipped")
    if not observation_keys:
        raise ImitationError(f"{root}: no numeric observation.* feature (images and videos are skipped)")
    if "action" not in features or not _numeric(features["action"].get("dtype")):
        raise ImitationError(f"{root}: no numeric 'action' feature")
    return observation_keys, "action", warnings


def _numeric(dtype: Any) -> bool:
    try:
        return np.dtype(dtype).kind in "biuf"
    except (TypeError, ValueError, SyntaxError):  # numpy parses some dtype strings as Python
        return False


@contextmanager
def lerobot_quietly() -> Iterator[None]:
    """lerobot is imported here only, for its writer (`imitation export --to lerobot`; the import
    costs seconds). Its loaders look at the Hub unless told not to, it logs warnings about fields
    it ignores, and its writer runs a `datasets` map per episode, each with a progress bar. We
    write local folders and keep our own bar."""
    # Before the import: huggingface_hub reads HF_HUB_OFFLINE once, when it is first imported.
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    import datasets

    logger = logging.getLogger("lerobot")
    level = logger.level
    logger.setLevel(logging.ERROR)
    bars = datasets.is_progress_bar_enabled()
    datasets.disable_progress_bars()
    try:
        yield
    finally:
        logger.setLevel(level)
        if bars:
            datasets.enable_progress_bars()


def _read_v30(
    root: Path, info: dict[str, Any], wanted: list[str], video_keys: list[str], progress: bool
) -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:
    """The `wanted` columns of every frame in data/*/*.parquet (in the order lerobot's loader
    reads them), and the video files each video feature's episodes name (from meta/episodes)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from tqdm import tqdm

    videos = _v30_video_files(root, info, video_keys)
    files = sorted((root / "data").glob("*/*.parquet"))
    if not files:
        raise ImitationError(f"{root / 'data'}: no frames (a v3.0 dataset keeps them in data/chunk-*/file-*.parquet)")
    parts: dict[str, list[np.ndarray]] = {key: [] for key in wanted}
    for path in tqdm(files, desc="read", unit="file", disable=None if progress else True, dynamic_ncols=True):
        try:
            table = pq.read_table(path, columns=wanted)
            columns = {key: _column(table.column(key)) for key in wanted} if table.num_rows else {}
        except (OSError, ValueError, KeyError, TypeError, pa.ArrowException) as error:
            raise ImitationError(f"{path}: cannot read its frames ({type(error).__name__}: {str(error)[:200]})") from None
        for key, values in columns.items():
            parts[key].append(values)
    return _concatenated(root, parts), videos


def _v30_video_files(root: Path, info: dict[str, Any], video_keys: list[str]) -> dict[str, list[str]]:
    """Each video feature's files, as meta/episodes/*/*.parquet and info.json's video_path name them."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    listing = root / "meta" / "episodes"
    wanted = [f"videos/{key}/{part}" for key in video_keys for part in ("chunk_index", "file_index")]
    rows: dict[str, list[Any]] = {name: [] for name in wanted}
    try:
        files = sorted(listing.glob("*/*.parquet"))
        if not files:
            raise FileNotFoundError("no chunk-*/file-*.parquet in it")
        for path in files:
            present = [name for name in wanted if name in pq.read_schema(path).names]
            table = pq.read_table(path, columns=["episode_index", *present])
            for name in wanted:
                rows[name] += table.column(name).to_pylist() if name in present else [None] * table.num_rows
    except (OSError, ValueError, KeyError, TypeError, pa.ArrowException) as error:
        raise _unreadable_listing(listing, "v3.0", error) from None
    template = info.get("video_path")
    videos: dict[str, list[str]] = {}
    for key in video_keys:
        chunks, numbers = rows[f"videos/{key}/chunk_index"], rows[f"videos/{key}/file_index"]
        names = [_video_file(template, video_key=key, chunk_index=c, file_index=f) for c, f in zip(chunks, numbers)]
        videos[key] = list(dict.fromkeys(name for name in names if name is not None))
    return videos


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
    root: Path, info: dict[str, Any], wanted: list[str], video_keys: list[str], progress: bool
) -> tuple[dict[str, np.ndarray], dict[str, list[str]]]:
    import pyarrow as pa
    import pyarrow.parquet as pq
    from tqdm import tqdm

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
    parts: dict[str, list[np.ndarray]] = {key: [] for key in wanted}
    videos: dict[str, list[str]] = {key: [] for key in video_keys}
    for line, entry in enumerate(
        tqdm(listed, desc="read", unit="episode", disable=None if progress else True, dynamic_ncols=True), 1
    ):
        try:
            index = int(entry["episode_index"])
            length = int(entry.get("length", -1))
            path = root / template.format(episode_chunk=index // chunk_size, episode_index=index)
            for key in video_keys:
                name = _video_file(
                    info.get("video_path"), episode_chunk=index // chunk_size, video_key=key, episode_index=index
                )
                videos[key] += [name] if name is not None else []
        except (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError) as error:
            raise ImitationError(
                f"{episodes_path}: line {line} is not an episode entry, or data_path does not fit it "
                f"({type(error).__name__}: {str(error)[:100]})"
            ) from None
        try:
            table = pq.read_table(path, columns=wanted)
            columns = {key: _column(table.column(key)) for key in wanted}
        except (OSError, ValueError, KeyError, TypeError, pa.ArrowException) as error:
            raise ImitationError(f"{path}: cannot read episode {index} ({type(error).__name__}: {str(error)[:200]})") from None
        if length >= 0 and table.num_rows != length:
            raise ImitationError(f"{path}: episode {index} has {table.num_rows} frames, meta/episodes.jsonl says {length}")
        for key in wanted:
            parts[key].append(columns[key])
    if not listed:
        raise ImitationError(f"{episodes_path}: lists no episode")
    return _concatenated(root, parts), videos


def _concatenated(root: Path, parts: dict[str, list[np.ndarray]]) -> dict[str, np.ndarray]:
    try:
        return {key: np.concatenate(values) if values else np.empty(0) for key, values in parts.items()}
    except ValueError as error:  # rows of one feature differ in width between episodes (or files)
        raise ImitationError(f"{root}: episodes disagree on a feature's shape ({str(error)[:200]})") from None


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
    action_key: str,
    columns: dict[str, np.ndarray],
    warnings: list[str],
) -> Converted:
    episode_index = columns["episode_index"].reshape(-1).astype(np.int64)
    starts = np.flatnonzero(np.diff(episode_index, prepend=episode_index[0] - 1) != 0)
    bounds = np.append(starts, len(episode_index))
    sidecar = _sidecar(root, [int(b - a) for a, b in zip(bounds[:-1], bounds[1:])], warnings)
    names = {key: key.removeprefix("observation.") for key in observation_keys}
    if sidecar is not None:
        observation_space = space_from_json(sidecar["observation_space"])
        action_space = space_from_json(sidecar["action_space"])
    else:
        leaves: dict[str, gym.Space] = {names[key]: box_for(columns[key]) for key in observation_keys}
        observation_space = next(iter(leaves.values())) if len(leaves) == 1 else gym.spaces.Dict(leaves)
        action_space = infer_action_space(columns[action_key])
    observations = _observation_tree(columns, observation_keys, names, observation_space, root)
    actions = (
        cast_rows(columns[action_key], action_space, f"{root}: action")
        if not isinstance(action_space, gym.spaces.Dict)
        else None
    )
    if actions is None:
        raise ImitationError(f"{root}: Dict action spaces are not supported")
    rewards = columns["next.reward"].reshape(-1) if "next.reward" in columns else None
    done = columns["next.done"].reshape(-1) if "next.done" in columns else None
    episodes = []
    for k, (start, end) in enumerate(zip(bounds[:-1], bounds[1:])):
        steps = int(end - start) - 1
        # Without the sidecar the demo stops one step before the episode ended: truncated (see `ends` below).
        facts: dict[str, Any] = sidecar["episodes"][k] if sidecar else {"terminated": False, "truncated": True}
        episodes.append(
            Episode(
                observations=_slice(observations, start, end),
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
            steps=[int(end - start) for start, end in zip(bounds[:-1], bounds[1:])],
            done=[bool(done[end - 1]) for end in bounds[1:]] if done is not None else None,
            final_observation=False,
        )
    return Converted(
        episodes=episodes,
        observation_space=observation_space,
        action_space=action_space,
        source=sidecar["source"] if sidecar else f"LeRobot {version} {root}",
        env_id=sidecar["env_id"] if sidecar else "",
        dt=sidecar["dt"] if sidecar else 1.0 / float(fps),
        metadata=sidecar["user_metadata"]
        if sidecar
        else {
            "converter": "lerobot",
            "root": str(root),
            "codebase_version": version,
            "observation_features": observation_keys,
            "action_feature": action_key,
            "names": {key: features[key].get("names") for key in [*observation_keys, action_key]},
        },
        warnings=warnings,
        ends=ends,
    )


def _observation_tree(
    columns: dict[str, np.ndarray], keys: list[str], names: dict[str, str], space: gym.Space, root: Path
) -> Any:
    if isinstance(space, gym.spaces.Dict):
        by_name = {names[key]: key for key in keys}
        missing = [name for name in space.spaces if name not in by_name]
        if missing:
            raise ImitationError(f"{root}: {SIDECAR} names observation key {missing[0]!r}, which has no feature")
        return {name: cast_rows(columns[by_name[name]], sub, f"{root}: {by_name[name]}") for name, sub in space.spaces.items()}
    return cast_rows(columns[keys[0]], space, f"{root}: {keys[0]}")


def _slice(tree: Any, start: int, end: int) -> Any:
    if isinstance(tree, dict):
        return {key: _slice(sub, start, end) for key, sub in tree.items()}
    return tree[start:end]


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
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as error:
        warnings.append(f"{path}: unreadable ({error}); ignored")
        return None
    if lengths != frames:
        warnings.append(f"{path}: describes other episodes than the dataset holds (edited since export?); ignored")
        return None
    return sidecar

"""LeRobot datasets → episodes.

Codebase v3.0 is read through lerobot's own `LeRobotDataset` (tabular columns only: videos are
neither downloaded nor decoded). lerobot 0.6 refuses v2.1 datasets (it asks for a conversion
to v3.0 first), so v2.1 is read directly: `meta/info.json`, `meta/episodes.jsonl` and one
parquet file per episode, with pyarrow.

A LeRobot frame t holds the observation at t and the action taken at t. An episode of L frames
becomes T = L - 1 steps: all L observations, the first L - 1 actions and `next.reward` values
(the last frame's action led to an observation the dataset does not hold). `observation.*`
features form the observation (a Dict space when there are several), `action` the action;
`next.done` on the last frame marks a terminated episode. Image and video features are skipped
with a warning, as are other features the demos have no place for.

Datasets written by `imitation export --to lerobot` carry `meta/imitation.json`, which restores
the env id, the exact spaces and each episode's flags and metadata.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.data.convert.converted import Converted, box_for, cast_rows, infer_action_space
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
    if version == "v3.0":
        columns = _read_v30(root, wanted)
    elif version == "v2.1":
        columns = _read_v21(root, info, wanted, progress)
    else:
        raise ImitationError(f"{root}: LeRobot codebase version {version!r} is not supported (v3.0 or v2.1)")
    columns = {key: _shaped(root, key, values, features.get(key, {})) for key, values in columns.items()}
    if len(columns["episode_index"]) == 0:
        raise ImitationError(f"{root}: the dataset holds no frames")
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
    """lerobot is imported here only (it costs seconds). Its loaders look at the Hub unless told
    not to, it logs warnings about fields it ignores, and its writer runs a `datasets` map per
    episode, each with a progress bar. We read and write local folders and keep our own bar."""
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


def _read_v30(root: Path, wanted: list[str]) -> dict[str, np.ndarray]:
    with lerobot_quietly():
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        try:
            dataset = LeRobotDataset(repo_id=f"local/{root.name}", root=root, download_videos=False, video_backend="pyav")
        except Exception as error:
            raise ImitationError(
                f"{root}: lerobot cannot load it ({type(error).__name__}: "
                f"{str(error).strip().splitlines()[0] if str(error).strip() else ''})"
            ) from None
        try:
            table = dataset.hf_dataset.select_columns(wanted).with_format("numpy")
            return {key: np.asarray(table[key]) for key in wanted}
        except (ValueError, KeyError, TypeError) as error:  # a column missing, or rows of different lengths
            raise ImitationError(
                f"{root}: its data does not match meta/info.json's features ({type(error).__name__}: {str(error)[:200]})"
            ) from None


def _read_v21(root: Path, info: dict[str, Any], wanted: list[str], progress: bool) -> dict[str, np.ndarray]:
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
        raise ImitationError(
            f"{episodes_path}: cannot read the v2.1 episode list ({type(error).__name__}: {str(error)[:200]})"
        ) from None
    parts: dict[str, list[np.ndarray]] = {key: [] for key in wanted}
    for line, entry in enumerate(
        tqdm(listed, desc="read", unit="episode", disable=None if progress else True, dynamic_ncols=True), 1
    ):
        try:
            index = int(entry["episode_index"])
            length = int(entry.get("length", -1))
            path = root / template.format(episode_chunk=index // chunk_size, episode_index=index)
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
    try:
        return {key: np.concatenate(values) for key, values in parts.items()}
    except ValueError as error:  # rows of one feature differ in width between episodes
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
        facts = sidecar["episodes"][k] if sidecar else {}
        terminated = bool(facts.get("terminated", bool(done[end - 1]) if done is not None else False))
        episodes.append(
            Episode(
                observations=_slice(observations, start, end),
                actions=actions[start : start + steps],
                rewards=rewards[start : start + steps].astype(np.float64) if rewards is not None else np.zeros(steps),
                terminated=terminated,
                truncated=bool(facts.get("truncated", False)),
                metadata=facts.get("metadata", {"source_episode_index": int(episode_index[start])}),
            )
        )
    if rewards is None:
        warnings.append(f"{root}: no next.reward feature; rewards are zero")
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

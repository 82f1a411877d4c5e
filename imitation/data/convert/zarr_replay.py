"""Zarr replay buffers, the layout of the Diffusion Policy code (Chi et al. 2023) and of the datasets
published with it (PushT's human demonstrations among them): a group `data` of arrays with one row
per step (`action` and the observations: `state`, `keypoint`, `img`, ...) and `meta/episode_ends`,
the row after each episode's last.

Rows hold the state s_t and the action a_t taken in it, so an episode of L rows becomes T = L − 1
steps: all L observations and the first L − 1 actions (the state after the last action is not
recorded; `SourceEnds` says so and the episodes are truncated). Without `--env` the observation is
a Dict of every array but `action`; an array of whole numbers in [0, 255] with rows of (H, W, 3) or
(H, W, 1) is a camera (uint8 image leaf, stored as `--image-codec` says, resized by
`--image-size`). With `--env` the observation is the one array whose rows fit the env's Box
observation, and the arrays left out are named in a warning. The buffer has no rewards: they are
zero, with a warning. Read through the `zarr` package (stores of zarr format 2 and 3).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, cast

import gymnasium as gym
import numpy as np

from imitation.data.convert.converted import REWARDS_RECORDED, Converted, box_for, cast_rows, infer_action_space
from imitation.data.convert.endings import SourceEnds
from imitation.data.image_resize import resized
from imitation.data.types import Episode, Tree
from imitation.errors import ImitationError
from imitation.limits import LIMITS, over_limit
from imitation.progress import progress_over

ACTION = "action"


def is_replay_buffer(path: Path) -> bool:
    """A zarr group holding `data/` and `meta/episode_ends` (format 2's .zgroup or format 3's zarr.json)."""
    return (
        path.is_dir()
        and ((path / ".zgroup").is_file() or (path / "zarr.json").is_file())
        and (path / "data").is_dir()
        and (path / "meta" / "episode_ends").is_dir()
    )


def _open(path: Path) -> tuple[dict[str, Any], np.ndarray]:
    """The `data` arrays by name and the episode ends, checked."""
    import zarr

    try:
        group = zarr.open_group(str(path), mode="r")
        data: dict[str, Any] = dict(cast(Any, group["data"]).arrays())
        ends = np.asarray(cast(Any, group["meta"])["episode_ends"][:])
    except (KeyError, ValueError, TypeError, OSError) as error:
        raise ImitationError(
            f"{path}: not a readable zarr replay buffer ({type(error).__name__}: {str(error)[:120]})"
        ) from None
    if ACTION not in data:
        raise ImitationError(f"{path}: data/ holds no action array (it holds {', '.join(sorted(data))[:200]})")
    rows = data[ACTION].shape[0]
    for name, array in data.items():
        if array.shape[0] != rows:
            raise ImitationError(f"{path}: data/{name} has {array.shape[0]} rows where data/action has {rows}")
    if ends.ndim != 1 or ends.dtype.kind not in "iu" or len(ends) == 0:
        raise ImitationError(f"{path}: meta/episode_ends must be a non-empty 1-D integer array, got {ends.dtype} {ends.shape}")
    lengths = np.diff(ends, prepend=0)
    if np.any(lengths < 2) or ends[-1] != rows:
        raise ImitationError(
            f"{path}: meta/episode_ends must rise by at least 2 rows per episode and end at data/action's {rows} rows "
            f"(ends {ends[:3].tolist()}…{int(ends[-1])})"
        )
    return data, ends


def _is_camera(array: Any) -> bool:
    return len(array.shape) == 4 and array.shape[-1] in (1, 3)


def _camera_rows(name: str, rows: np.ndarray, size: tuple[int, int] | None, path: Path) -> np.ndarray:
    """A camera's frames as uint8 (whole numbers in [0, 255] only: anything else is refused, not rounded)."""
    if rows.size and (rows.min() < 0 or rows.max() > 255 or not np.array_equal(rows, np.round(rows))):
        raise ImitationError(f"{path}: data/{name} has frame values that are not whole numbers in [0, 255]")
    frames = rows.astype(np.uint8)
    return np.stack([resized(frames[row], size) for row in range(len(frames))]) if size is not None else frames


def _observation_leaves(path: Path, data: dict[str, Any], env_id: str | None) -> tuple[list[str], list[str]]:
    """The arrays the observation is made of, and a warning for each left out."""
    names = [name for name in data if name != ACTION]
    if not env_id:
        return names, []
    from imitation.envs.make import make_env

    with make_env(env_id) as env:
        space = env.observation_space
    if not isinstance(space, gym.spaces.Box):
        raise ImitationError(f"--env {env_id}: its observations are a {type(space).__name__}; a replay buffer fits Box ones")
    fitting = [name for name in names if math.prod(data[name].shape[1:]) == math.prod(space.shape)]
    if len(fitting) != 1:
        raise ImitationError(
            f"{path}: {len(fitting)} of the arrays ({', '.join(names)[:200]}) have rows of {math.prod(space.shape)} "
            f"numbers like {env_id}'s observations; one must"
        )
    left_out = [name for name in names if name not in fitting]
    warnings = (
        [f"{path}: the observation is data/{fitting[0]}, which fits {env_id}; left out: {', '.join(left_out)}"]
        if left_out
        else []
    )
    return fitting, warnings


def replay_to_episodes(
    path: str | Path, *, env_id: str | None = None, progress: bool = True, image_size: tuple[int, int] | None = None
) -> Converted:
    """The buffer's episodes (the module docstring); `env_id` chooses the observation array."""
    path = Path(path)
    data, ends = _open(path)
    names, warnings = _observation_leaves(path, data, env_id)
    cameras = {name for name in names if _is_camera(data[name])}
    sizes = {name: (*(image_size or data[name].shape[1:3]), data[name].shape[3]) for name in cameras}
    elements = sum(math.prod(sizes[name]) if name in cameras else math.prod(data[name].shape[1:]) for name in names)
    if elements > LIMITS.sample_elements:
        raise over_limit(f"{path}: numbers per observation (all arrays together)", elements, "sample_elements")
    actions = np.asarray(data[ACTION][:])
    action_space = infer_action_space(actions)
    actions = cast_rows(actions, action_space, f"{path}: data/action")
    spaces: dict[str, gym.Space] = {
        name: gym.spaces.Box(0, 255, shape=sizes[name], dtype=np.uint8) if name in cameras else box_for(data[name][:1])
        for name in names
    }
    starts = np.concatenate([[0], ends[:-1]])
    episodes = []
    for k in progress_over(range(len(ends)), total=len(ends), desc="read", unit="episode", enabled=progress):
        start, end = int(starts[k]), int(ends[k])
        leaves: dict[str, np.ndarray] = {
            name: _camera_rows(name, np.asarray(data[name][start:end]), image_size, path)
            if name in cameras
            else np.asarray(data[name][start:end], dtype=spaces[name].dtype)
            for name in names
        }
        steps = end - start - 1
        episodes.append(
            Episode(
                observations=cast(Tree, leaves) if len(names) > 1 else leaves[names[0]],
                actions=actions[start : start + steps],
                rewards=np.zeros(steps),
                metadata={"source_episode_index": k},
            )
        )
    observation_space = gym.spaces.Dict(spaces) if len(names) > 1 else spaces[names[0]]
    warnings.append(f"{path}: a replay buffer holds no rewards; rewards are zero")
    metadata: dict[str, Any] = {
        "converter": "zarr",
        "root": str(path),
        "observation_arrays": names,
        "action_array": ACTION,
        REWARDS_RECORDED: False,
    }
    if image_size is not None and cameras:
        metadata["cameras"] = {name: {"resized_from": list(data[name].shape[1:3]), "filter": "area"} for name in cameras}
    return Converted(
        episodes=episodes,
        observation_space=observation_space,
        action_space=action_space,
        source=f"zarr replay buffer {path}",
        metadata=metadata,
        warnings=warnings,
        ends=SourceEnds(flag="meta/episode_ends", steps=np.diff(ends, prepend=0).tolist(), done=None, final_observation=False),
    )

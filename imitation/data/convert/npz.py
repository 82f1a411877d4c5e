"""npz rollouts → episodes, without unpickling anything.

Two layouts are recognised by their keys:

- stable-baselines' GAIL expert format: `obs`, `actions`, `rewards`, `episode_starts`,
  `episode_returns`, one row per step. It stores no final observation, so an episode of L rows
  becomes T = L - 1 steps: all L observations, the first L - 1 actions and rewards (the last
  action led to an observation nobody recorded). The file's own return is kept in the episode's
  metadata as `source_return`. The demo stops one step before its episode ended, so every episode
  is truncated; the file does not say why its episodes ended, which `endings.settle_ends` decides
  from the env's time limit when there is one (episode metadata `source_end`).
- HumanCompatibleAI/imitation's flat trajectory format: `obs` (each trajectory's T+1 rows, one
  after the other), `acts`, `indices` (where each trajectory after the first starts in `acts`),
  `terminal` (one flag per trajectory), optional `rews`. Its `infos` is a pickled object array
  and is never read: the arrays are loaded with `allow_pickle=False`, which refuses object arrays.
  imitation sets `terminal` at every trajectory end its rollouts saw `done`, time limits included,
  so `endings.settle_ends` decides terminated or truncated from the env's time limit.
"""

from __future__ import annotations

import math
import zipfile
import zlib
from pathlib import Path
from tokenize import TokenError  # numpy parses old .npy headers with tokenize
from typing import Any

import numpy as np

from imitation.data.convert.converted import Converted, box_for, cast_rows, infer_action_space
from imitation.data.convert.endings import SourceEnds
from imitation.data.types import Episode
from imitation.errors import ImitationError
from imitation.inputs import open_input
from imitation.limits import check_zip_member

SB_KEYS = {"obs", "actions", "rewards", "episode_starts"}
IMITATION_KEYS = {"obs", "acts", "indices", "terminal"}


def npz_to_episodes(path: str | Path) -> Converted:
    """Read an SB GAIL or imitation npz file; ImitationError names the file and what is wrong."""
    path = Path(path)
    arrays, object_keys = _read_npz(path)
    keys = set(arrays) | object_keys
    if keys >= SB_KEYS:
        return _stable_baselines(path, _used(path, arrays, object_keys, SB_KEYS | ({"episode_returns"} & keys)))
    if keys >= IMITATION_KEYS:
        return _imitation(path, _used(path, arrays, object_keys, IMITATION_KEYS | ({"rews"} & keys)))
    raise ImitationError(
        f"{path}: unknown npz layout (keys {', '.join(sorted(keys))[:200]}); expected stable-baselines' "
        f"({', '.join(sorted(SB_KEYS))}) or imitation's ({', '.join(sorted(IMITATION_KEYS))})"
    )


def _used(path: Path, arrays: dict[str, np.ndarray], object_keys: set[str], keys: set[str]) -> dict[str, np.ndarray]:
    """The arrays a layout reads; one it needs that holds Python objects is refused."""
    if unreadable := sorted(keys & object_keys):
        raise ImitationError(
            f"{path}: array {unreadable[0]!r} holds Python objects; it is not read (that would unpickle them)"
        )
    return {key: arrays[key] for key in keys}


def _read_npz(path: Path) -> tuple[dict[str, np.ndarray], set[str]]:
    """Every numeric array of the archive, and the names of its object arrays, which are left
    unread (reading them would unpickle; imitation's `infos` is one, and is not needed). Each
    member's .npy header is checked before its data is read: a header promising more bytes than
    the member holds is refused (a damaged file must not make us allocate what it claims)."""
    try:
        with open_input(path) as stream:
            if stream.read(6) == b"\x93NUMPY":
                raise ImitationError(f"{path}: a single .npy array, not an npz archive of named arrays")
        arrays: dict[str, np.ndarray] = {}
        object_keys: set[str] = set()
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                key = info.filename.removesuffix(".npy")
                check_zip_member(path, info)
                with archive.open(info) as member:
                    version = np.lib.format.read_magic(member)
                    read_header = (
                        np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                    )
                    shape, _, dtype = read_header(member)
                    if dtype.hasobject:
                        object_keys.add(key)
                        continue
                    if math.prod(shape) * dtype.itemsize > info.file_size:
                        raise ImitationError(
                            f"{path}: array {key!r} is damaged (its header promises more data than the archive holds)"
                        )
                with archive.open(info) as member:
                    arrays[key] = np.lib.format.read_array(member, allow_pickle=False)
        return arrays, object_keys
    except ImitationError:
        raise
    except (
        OSError,
        EOFError,
        ValueError,
        KeyError,
        SyntaxError,
        TokenError,
        zipfile.BadZipFile,
        zlib.error,
        NotImplementedError,
        RuntimeError,
    ) as error:
        # zipfile's and numpy's ways of saying the bytes are not an npz archive (or a damaged one).
        raise ImitationError(f"{path}: not a readable npz file ({type(error).__name__}: {str(error)[:200]})") from None


def _numeric(path: Path, key: str, array: np.ndarray, *, flat: bool = False) -> np.ndarray:
    """A numeric array with one row per step (1-D when `flat`); ImitationError otherwise."""
    if array.dtype.kind not in "biuf" or array.ndim == 0 or (flat and array.ndim != 1):
        shape = "one value per row" if flat else "one row per step"
        raise ImitationError(
            f"{path}: array {key!r} must be numbers with {shape}, got {array.dtype} of shape {list(array.shape)}"
        )
    return array


def _stable_baselines(path: Path, data: dict[str, np.ndarray]) -> Converted:
    obs, actions = _numeric(path, "obs", data["obs"]), _numeric(path, "actions", data["actions"])
    rewards = _numeric(path, "rewards", data["rewards"], flat=True).astype(np.float64)
    starts = _numeric(path, "episode_starts", data["episode_starts"], flat=True).astype(bool)
    steps = len(obs)
    if not (len(actions) == len(rewards) == len(starts) == steps) or steps == 0 or not starts[0]:
        raise ImitationError(
            f"{path}: obs, actions, rewards and episode_starts must have one row per step and start with an episode start"
        )
    returns = data.get("episode_returns")
    if returns is not None:
        returns = _numeric(path, "episode_returns", returns.reshape(-1) if returns.ndim == 0 else returns, flat=True)
    bounds = np.append(np.flatnonzero(starts), steps)
    observation_space, action_space = box_for(obs), infer_action_space(actions)
    obs, actions = cast_rows(obs, observation_space, f"{path}: obs"), cast_rows(actions, action_space, f"{path}: actions")
    episodes = []
    for index, (start, end) in enumerate(zip(bounds[:-1], bounds[1:])):
        metadata: dict[str, Any] = {"source_index": index, "source_length": int(end - start)}
        if returns is not None and index < len(returns):
            metadata["source_return"] = float(returns[index])
        episodes.append(
            Episode(
                observations=obs[start:end],
                actions=actions[start : end - 1],
                rewards=rewards[start : end - 1],
                truncated=True,  # its final observation is the one its last kept action led to, not where it ended
                metadata=metadata,
            )
        )
    return Converted(
        episodes=episodes,
        observation_space=observation_space,
        action_space=action_space,
        source=f"stable-baselines npz {path}",
        metadata={"converter": "npz", "layout": "stable-baselines", "file": str(path)},
        warnings=[f"{path}: the format stores no final observations; each episode's last action and reward were dropped"],
        ends=SourceEnds(flag="episode_starts", steps=np.diff(bounds).tolist(), done=None, final_observation=False),
    )


def _imitation(path: Path, data: dict[str, np.ndarray]) -> Converted:
    obs, acts = _numeric(path, "obs", data["obs"]), _numeric(path, "acts", data["acts"])
    terminal = _numeric(path, "terminal", data["terminal"], flat=True).astype(bool)
    indices = _numeric(path, "indices", data["indices"], flat=True)
    if indices.dtype.kind not in "iu":
        raise ImitationError(f"{path}: array 'indices' must hold integers, got {indices.dtype}")
    indices = indices.astype(np.int64)
    count = len(terminal)
    if len(indices) != count - 1 or len(obs) != len(acts) + count:
        raise ImitationError(
            f"{path}: inconsistent trajectories: {count} terminal flags need {count - 1} indices and "
            f"len(obs) = len(acts) + {count}; got {len(indices)} indices, {len(obs)} obs, {len(acts)} acts"
        )
    if np.any(np.diff(np.concatenate([[0], indices, [len(acts)]])) < 0):
        raise ImitationError(f"{path}: indices must be increasing split points within acts (0..{len(acts)})")
    rewards = data.get("rews")
    if rewards is not None:
        rewards = _numeric(path, "rews", rewards, flat=True)
    if rewards is not None and len(rewards) != len(acts):
        raise ImitationError(f"{path}: rews has {len(rewards)} rows, acts {len(acts)}")
    observation_space, action_space = box_for(obs), infer_action_space(acts)
    obs, acts = cast_rows(obs, observation_space, f"{path}: obs"), cast_rows(acts, action_space, f"{path}: acts")
    act_bounds = np.concatenate([[0], indices, [len(acts)]])
    episodes = []
    for index in range(count):
        start, end = int(act_bounds[index]), int(act_bounds[index + 1])
        episodes.append(
            Episode(
                observations=obs[start + index : end + index + 1],  # each earlier trajectory has one extra observation
                actions=acts[start:end],
                rewards=rewards[start:end].astype(np.float64) if rewards is not None else np.zeros(end - start),
                terminated=bool(terminal[index]),
                truncated=not terminal[index],
                metadata={"source_index": index},
            )
        )
    return Converted(
        episodes=episodes,
        observation_space=observation_space,
        action_space=action_space,
        source=f"imitation npz {path}",
        metadata={"converter": "npz", "layout": "imitation", "file": str(path)},
        warnings=[] if rewards is not None else [f"{path}: no rews array; rewards are zero"],
        ends=SourceEnds(flag="terminal", steps=np.diff(act_bounds).tolist(), done=terminal.tolist(), final_observation=True),
    )

"""Bare arrays → episodes: one (episodes, steps, columns) array, in a `.npy` file or an `.npz`
member, whose meaning a small YAML layout states (docs/CONVERT.md, "Bare arrays"):

    columns: [position, velocity, action]   # optional names, one per column
    observation: [position, velocity]       # the columns forming the observation, in order
    action: [action]                        # the columns forming the action
    discrete_action: true                   # whole numbers ≥ 0 in one column: a Discrete action
    rows: state             # state: row t holds s_t and a_t | next_state: row t holds a_t and s_{t+1}
    final_state: row        # rows: state only. row: the row after the last action holds the final
                            # state (its action columns are ignored) | none: the final state is not stored
    padding: nan            # after an episode's end: nan | a number | repeat (its last row again) | none
    reward: -1              # a number paid every step | {column: NAME} | none (zeros)
    ends: time_limit        # time_limit (from --env's time limit) | terminated | truncated
                            # | terminal_state (cut where --env's termination rule first holds)
    array: demos            # .npz only: the member holding the array

Nothing is guessed: an episode's end is where its padding starts (rows of padding must run to the
end of the episode's slot), and what is dropped (the final state's missing action, the first
step of `next_state` rows, whose starting state is not stored) is said in a warning and kept in
each episode's metadata as `source_return` / `source_steps`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from tokenize import TokenError
from typing import Any

import numpy as np

from imitation.data.convert.converted import Converted, box_for, cast_rows, infer_action_space
from imitation.data.convert.endings import SourceEnds
from imitation.data.convert.yaml_bounded import read_yaml_file
from imitation.data.types import Episode
from imitation.errors import ImitationError
from imitation.inputs import open_input

ROWS = ("state", "next_state")
FINAL_STATES = ("row", "none")
ENDS = ("time_limit", "terminated", "truncated", "terminal_state")
_KEYS = {"columns", "observation", "action", "discrete_action", "rows", "final_state", "padding", "reward", "ends", "array"}


@dataclass(frozen=True)
class Layout:
    path: Path
    columns: tuple[str, ...] | None
    observation: tuple[str | int, ...]
    action: tuple[str | int, ...]
    discrete_action: bool
    rows: str
    final_state: str | None  # for rows: state
    padding: float | str | None  # a number (NaN included), "repeat", or None (no padding)
    reward: float | str | None  # a number, a column (str or int), or None (zeros)
    reward_is_column: bool
    ends: str
    array: str | None
    raw: dict[str, Any]


def load_layout(path: str | Path) -> Layout:
    """Read and check a layout file; ImitationError names the file and what is wrong."""
    path = Path(path)
    return parse_layout(read_yaml_file(path, "layout"), path)


def parse_layout(raw: Any, path: Path) -> Layout:
    def fail(message: str) -> ImitationError:
        return ImitationError(f"{path}: {message}")

    def bad(key: str, what: str, value: Any) -> ImitationError:
        return fail(f"{key} must be {what}, got {str(value)[:80]}")

    if not isinstance(raw, dict) or not all(isinstance(key, str) for key in raw):
        raise fail("a layout is a YAML mapping with observation, action and rows (see docs/CONVERT.md)")
    unknown = sorted(set(raw) - _KEYS)
    if unknown:
        raise fail(f"unknown key {unknown[0]!r} (a layout has {', '.join(sorted(_KEYS))})")

    def columns_of(key: str) -> tuple[str | int, ...]:
        value = raw.get(key)
        value = [value] if isinstance(value, (str, int)) and not isinstance(value, bool) else value
        if (
            not isinstance(value, list)
            or not value
            or not all(isinstance(c, (str, int)) and not isinstance(c, bool) for c in value)
            or len(set(value)) != len(value)
        ):
            raise bad(key, "a list of distinct columns (names or 0-based indices)", value)
        return tuple(value)

    def choice(key: str, options: tuple[str, ...], default: str | None) -> str:
        value = raw.get(key, default)
        if value not in options:
            raise bad(key, " or ".join(options), value)
        return value

    names = raw.get("columns")
    if names is not None and (
        not isinstance(names, list) or not all(isinstance(n, str) and n for n in names) or len(set(names)) != len(names)
    ):
        raise bad("columns", "a list of distinct names, one per column", names)
    observation, action = columns_of("observation"), columns_of("action")
    if set(observation) & set(action):
        raise fail(f"column {sorted(set(observation) & set(action), key=str)[0]!r} is both observation and action")
    rows = choice("rows", ROWS, None)
    if rows == "next_state" and "final_state" in raw:
        raise fail("final_state is for rows: state (with rows: next_state, each row's state is the one its action led to)")
    final_state = choice("final_state", FINAL_STATES, "row") if rows == "state" else None
    padding = raw.get("padding", "nan")
    if padding == "nan":
        padding = math.nan
    elif padding == "none":
        padding = None
    elif padding != "repeat" and (isinstance(padding, bool) or not isinstance(padding, (int, float))):
        raise bad("padding", "nan, a number, repeat or none", padding)
    reward, reward_is_column = raw.get("reward"), False
    if reward == "none":
        reward = None
    elif isinstance(reward, dict) and set(reward) == {"column"} and isinstance(reward["column"], (str, int)):
        reward, reward_is_column = reward["column"], True
    elif reward is not None and (
        isinstance(reward, bool) or not isinstance(reward, (int, float)) or not math.isfinite(reward)
    ):
        raise bad("reward", "a number paid every step, {column: NAME} or none", reward)
    discrete = raw.get("discrete_action", False)
    if not isinstance(discrete, bool):
        raise bad("discrete_action", "true or false", discrete)
    array = raw.get("array")
    if array is not None and not isinstance(array, str):
        raise bad("array", "the name of an npz member", array)
    ends = choice("ends", ENDS, "time_limit")
    return Layout(
        path=path,
        columns=tuple(names) if names is not None else None,
        observation=observation,
        action=action,
        discrete_action=discrete,
        rows=rows,
        final_state=final_state,
        padding=float(padding) if isinstance(padding, (int, float)) else padding,
        reward=reward,
        reward_is_column=reward_is_column,
        ends=ends,
        array=array,
        raw=raw,
    )


def read_array(path: str | Path, member: str | None) -> tuple[np.ndarray, str]:
    """The array of a `.npy` file or an `.npz` member (the only numeric one, or `member`), read
    without unpickling; and its name for messages."""
    path = Path(path)
    try:
        with open_input(path) as stream:
            is_npy = stream.read(6) == b"\x93NUMPY"
    except OSError as error:
        raise ImitationError(f"{path}: cannot read: {error.strerror or error}") from None
    if not is_npy:
        from imitation.data.convert.npz import _read_npz

        arrays, object_keys = _read_npz(path)
        numeric = sorted(arrays)
        held = ", ".join(sorted(numeric + sorted(object_keys)))[:200]
        if member is None and len(numeric) != 1:
            problem = f"holds {len(numeric)} numeric arrays ({held})"
        elif member is not None and member not in arrays:
            problem = f"has no numeric array {member!r} (it holds {held})"
        else:
            problem = ""
        if problem:
            raise ImitationError(f"{path}: {problem}; name one with array: in the layout")
        name = member if member is not None else numeric[0]
        return arrays[name], f"{path}[{name}]"
    try:
        with open(path, "rb") as stream:
            version = np.lib.format.read_magic(stream)
            read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, fortran, dtype = read_header(stream)
            if dtype.hasobject or dtype.kind not in "biuf":  # refused before reading: object arrays are pickles
                raise ImitationError(
                    f"{path}: expected numbers of shape (episodes, steps, columns), got {dtype} of shape {list(shape)}"
                )
            if math.prod(shape) * dtype.itemsize > os.path.getsize(path) - stream.tell():
                raise ValueError(f"its header promises {math.prod(shape) * dtype.itemsize} bytes, the file holds fewer")
            stream.seek(0)
            return np.lib.format.read_array(stream, allow_pickle=False), str(path)
    except ImitationError:
        raise
    except (OSError, EOFError, ValueError, SyntaxError, TokenError) as error:
        raise ImitationError(f"{path}: not a readable .npy array ({type(error).__name__}: {str(error)[:200]})") from None


def array_to_episodes(path: str | Path, layout: Layout) -> Converted:
    """Cut `path`'s (episodes, steps, columns) array into episodes as `layout` says."""
    data, name = read_array(path, layout.array)
    if data.dtype.kind not in "biuf" or data.ndim != 3 or 0 in data.shape:
        raise ImitationError(
            f"{name}: expected numbers of shape (episodes, steps, columns), got {data.dtype} of shape {list(data.shape)}"
        )
    episodes_count, slots, width = data.shape

    def column(key: str, c: str | int) -> int:
        if isinstance(c, int) and 0 <= c < width:
            return c
        if isinstance(c, str) and layout.columns is not None and c in layout.columns:
            return layout.columns.index(c)
        named = f", named {', '.join(layout.columns)}" if layout.columns else ""
        raise ImitationError(f"{layout.path}: {key}: no column {c!r} in {name} (it has {width} columns{named})")

    if layout.columns is not None and len(layout.columns) != width:
        raise ImitationError(f"{layout.path}: columns names {len(layout.columns)} columns; {name} has {width}")
    obs_cols = [column("observation", c) for c in layout.observation]
    act_cols = [column("action", c) for c in layout.action]
    reward_col = column("reward", layout.reward) if layout.reward_is_column and isinstance(layout.reward, (str, int)) else None
    used = _used_rows(data, obs_cols, layout, name)
    state_rows = layout.rows == "state"
    # The demos keep the observation each episode ended in, unless rows hold s_t and a_t with no final-state row.
    final_observation = not state_rows or layout.final_state == "row"
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]] = []
    source_steps: list[int] = []
    skipped: list[int] = []
    for k in range(episodes_count):
        n = int(used[k])
        rows = data[k, :n]
        if n < 2:  # no step survives: no row, or one state without an action after it
            skipped.append(k)
            continue
        # Env steps the source's episode took (its actions): with a final-state row, one fewer than its rows.
        steps = n - 1 if state_rows and final_observation else n
        # Row t holds s_t and a_t; or a_t and s_{t+1}, where s_0 is missing and the first action has no state to start from.
        kept = slice(0, n - 1) if state_rows else slice(1, n)
        metadata: dict[str, Any] = {"source_index": k, "source_steps": steps}
        if not (state_rows and final_observation):  # a step was dropped: the source's own return, where known
            source = _source_return(rows, steps, layout, reward_col)
            if source is not None:
                metadata["source_return"] = source
        parts.append((rows[:, obs_cols], rows[kept][:, act_cols], _rewards(rows, kept, layout, reward_col), metadata))
        source_steps.append(steps)
    if not parts:
        raise ImitationError(f"{name}: no episode holds a step (every slot is padding, or one row)")
    warnings: list[str] = []
    if skipped:
        warnings.append(f"{name}: episode slot(s) {', '.join(map(str, skipped[:20]))} hold no step; skipped")
    if not final_observation:
        warnings.append(f"{name}: final_state: none, so each episode's last action and reward were dropped")
    if not state_rows:
        warnings.append(
            f"{name}: rows: next_state stores no starting state, so each episode's first action and reward were dropped"
        )
    if layout.reward is None:
        warnings.append(f"{name}: the layout gives no reward; rewards are zero")
    all_actions = np.concatenate([actions for _, actions, _, _ in parts])
    if layout.discrete_action:
        if len(act_cols) != 1 or not np.all(np.equal(np.mod(all_actions, 1), 0)) or all_actions.min() < 0:
            raise ImitationError(
                f"{layout.path}: discrete_action: true needs one action column of whole numbers ≥ 0 in {name}"
            )
        all_actions = all_actions.astype(np.int64)
    observation_space = box_for(np.concatenate([observations for observations, _, _, _ in parts]))
    action_space = infer_action_space(all_actions[:, 0] if layout.discrete_action else all_actions)
    ends: SourceEnds | None = None
    end_flags: dict[str, Any] | None = None
    terminated = False  # ends: terminal_state: decided once the env is known (terminal_states.py)
    if layout.ends == "time_limit":  # decided once the env is known (endings.settle_ends)
        terminated = final_observation
        ends = SourceEnds(
            flag="padding",
            steps=source_steps,
            done=[True] * len(parts),
            final_observation=final_observation,
            needs_limit="the layout's ends: time_limit",
        )
    elif layout.ends != "terminal_state":
        terminated = layout.ends == "terminated" and final_observation
        end_flags = {"decided": "layout", "layout_ends": layout.ends}
        if not final_observation:
            end_flags["final_observation"] = False
            for _, _, _, metadata in parts:
                metadata["source_end"] = layout.ends
        end_flags.update(terminated=len(parts) * terminated, truncated=len(parts) * (not terminated))
    episodes = [
        Episode(
            observations=cast_rows(observations, observation_space, f"{name}: observation"),
            actions=cast_rows(actions, action_space, f"{name}: action"),
            rewards=rewards,
            terminated=terminated,
            truncated=not terminated,
            metadata=metadata,
        )
        for observations, actions, rewards, metadata in parts
    ]
    return Converted(
        episodes=episodes,
        observation_space=observation_space,
        action_space=action_space,
        source=f"array {name}",
        metadata={"converter": "array", "file": str(path), "layout": layout.raw},
        warnings=warnings,
        ends=ends,
        end_flags=end_flags,
        end_at_terminal_state="the layout's ends: terminal_state" if layout.ends == "terminal_state" else None,
    )


def _used_rows(data: np.ndarray, obs_cols: list[int], layout: Layout, name: str) -> np.ndarray:
    """How many rows of each episode's slot hold data: padding must fill the rest of the slot."""
    episodes_count, slots, _ = data.shape
    if layout.padding is None:
        return np.full(episodes_count, slots)
    if layout.padding == "repeat":
        # A padding row repeats the row before it in every column; the end is after the last change.
        same = data[:, 1:] == data[:, :-1]
        if data.dtype.kind == "f":
            same |= np.isnan(data[:, 1:]) & np.isnan(data[:, :-1])  # a repeated NaN (a final state's missing action)
        changed = ~same.all(axis=2)
        last = np.where(changed.any(axis=1), slots - 1 - np.argmax(changed[:, ::-1], axis=1), 0)
        return last + 1
    assert isinstance(layout.padding, float)
    observations = data[:, :, obs_cols]
    padded = np.isnan(observations) if math.isnan(layout.padding) else observations == layout.padding
    padded = padded.all(axis=2)
    used = np.where(padded.any(axis=1), np.argmax(padded, axis=1), slots)
    for k in range(episodes_count):
        if not padded[k, used[k] :].all():
            row = used[k] + int(np.argmin(padded[k, used[k] :]))
            value = layout.raw.get("padding", "nan")
            raise ImitationError(
                f"{name}: episode {k}: row {row} holds data after padding starts at row {used[k]} (padding {value} must "
                "fill every row after an episode's end)"
            )
    return used


def _rewards(rows: np.ndarray, kept: slice, layout: Layout, reward_col: int | None) -> np.ndarray:
    count = len(range(*kept.indices(len(rows))))
    if reward_col is not None:
        return rows[kept, reward_col].astype(np.float64)
    if layout.reward is None:
        return np.zeros(count)
    assert isinstance(layout.reward, (int, float))
    return np.full(count, float(layout.reward))


def _source_return(rows: np.ndarray, steps: int, layout: Layout, reward_col: int | None) -> float | None:
    """The return of all the source's steps, the dropped one included, when the layout knows it."""
    if reward_col is not None:
        return float(np.sum(rows[:steps, reward_col], dtype=np.float64))
    if isinstance(layout.reward, (int, float)):
        return float(layout.reward) * steps
    return None

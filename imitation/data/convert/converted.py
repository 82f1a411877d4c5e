"""What every converter returns, how its spaces are chosen, and how it is written.

Without an env id the spaces are inferred from the data: floats → Box(-inf, inf) of that dtype
and row shape; integer actions of one column (≥ 0) → Discrete(max + 1), of several →
MultiDiscrete. With an env id the env's own spaces are used (so `train bc --env` and `eval
policy` accept the demos) and the data is checked and cast to them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from imitation.data.convert.endings import SourceEnds
from imitation.data.mcap.images import DEFAULT_JPEG_QUALITY, DEFAULT_WEBP_QUALITY
from imitation.data.mcap.writer import DemoWriter
from imitation.data.spaces import describe_space
from imitation.data.types import Episode, first_nonfinite
from imitation.errors import ImitationError
from imitation.progress import progress_over

# In a demo file's metadata: false where the source held no rewards (they are zero), so that
# nothing scores a policy against the demos' return.
REWARDS_RECORDED = "rewards_recorded"


@dataclass
class Converted:
    """Episodes from a foreign source, with their spaces and where they came from."""

    episodes: list[Episode]
    observation_space: gym.Space
    action_space: gym.Space
    source: str  # one line: the format and the file
    env_id: str = ""  # "" when no simulator is behind the data
    dt: float | None = None
    metadata: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    # What the source says about its episodes' ends when it cannot tell time limits from
    # terminations (endings.py settles the flags); None for sources that can.
    ends: SourceEnds | None = None
    max_episode_steps: int | None = None  # the env's time limit, once fitted to an env
    end_flags: dict[str, Any] | None = None  # how the flags were decided: the demo file's `end_flags`
    # What asks for each episode to end at its first terminal state by the env's rule
    # (terminal_states.py), for messages; None when nothing does.
    end_at_terminal_state: str | None = None


def box_for(rows: np.ndarray) -> gym.spaces.Box:
    """An unbounded Box with the dtype (floats) and row shape of `rows` (integers become float32)."""
    dtype = rows.dtype if rows.dtype.kind == "f" else np.dtype(np.float32)
    return gym.spaces.Box(low=-np.inf, high=np.inf, shape=rows.shape[1:], dtype=dtype)


def infer_action_space(actions: np.ndarray) -> gym.Space:
    """Discrete for one column of non-negative integers, MultiDiscrete for several, else a Box."""
    # Below 2^31 choices: larger integers are measurements, not choices (and would overflow int64 spaces).
    if actions.dtype.kind in "iub" and actions.size and actions.min() >= 0 and actions.max() < 2**31:
        if actions.ndim == 1 or actions.shape[1:] == (1,):
            return gym.spaces.Discrete(int(actions.max()) + 1)
        if actions.ndim == 2:
            return gym.spaces.MultiDiscrete(actions.max(axis=0).astype(np.int64) + 1)
    return box_for(actions)


def cast_rows(rows: np.ndarray, space: gym.Space, what: str) -> np.ndarray:
    """`rows` (one row per step) as `space` holds them: dtype and row shape, values checked for
    discrete spaces; ImitationError names `what` otherwise."""
    if isinstance(space, gym.spaces.Discrete):
        flat = rows.reshape(len(rows), -1)
        if flat.shape[1] != 1:
            raise ImitationError(
                f"{what}: rows of {flat.shape[1]} values do not fit {describe_space(space)} (one integer per step)"
            )
        values = flat[:, 0]
        if not np.all(np.equal(np.mod(values, 1), 0)):
            raise ImitationError(f"{what}: non-integer values do not fit {describe_space(space)}")
        values = values.astype(np.int64)
        if values.size and (values.min() < space.start or values.max() >= space.start + space.n):
            raise ImitationError(f"{what}: values {values.min()}..{values.max()} lie outside {describe_space(space)}")
        return values
    if isinstance(space, (gym.spaces.Box, gym.spaces.MultiDiscrete, gym.spaces.MultiBinary)):
        shape = tuple(space.shape)
        if int(np.prod(rows.shape[1:])) != int(np.prod(shape)):
            raise ImitationError(f"{what}: rows of shape {list(rows.shape[1:])} do not fit {describe_space(space)}")
        return rows.reshape((len(rows), *shape)).astype(space.dtype)
    raise ImitationError(f"{what}: converting into a {type(space).__name__} space is not supported")


def fit_to_env(converted: Converted, env_id: str) -> Converted:
    """Use `env_id`'s spaces (checked against the data), its id, and its step time when the source had none."""
    from imitation.envs.make import control_period, make_env

    with make_env(env_id) as env:
        observation_space, action_space, dt = env.observation_space, env.action_space, control_period(env)
        max_episode_steps = env.spec.max_episode_steps if env.spec is not None else None
    if isinstance(converted.observation_space, gym.spaces.Dict) or isinstance(converted.action_space, gym.spaces.Dict):
        raise ImitationError(f"--env {env_id}: demos with Dict spaces cannot be fitted to an env's spaces")
    episodes = []
    for episode in converted.episodes:
        # Arrays, not dicts: Dict spaces were refused above.
        assert isinstance(episode.observations, np.ndarray) and isinstance(episode.actions, np.ndarray)
        episodes.append(
            dataclasses.replace(
                episode,
                observations=cast_rows(episode.observations, observation_space, f"observations (for {env_id})"),
                actions=cast_rows(episode.actions, action_space, f"actions (for {env_id})"),
            )
        )
    return dataclasses.replace(
        converted,
        episodes=episodes,
        observation_space=observation_space,
        action_space=action_space,
        env_id=env_id,
        dt=converted.dt or dt,  # a recording's own rate wins over the simulator's step
        max_episode_steps=max_episode_steps,
    )


def write_converted(
    converted: Converted,
    out: str | Path,
    *,
    progress: bool = True,
    image_codec: str = "png",
    image_quality: int | None = None,
) -> dict[str, Any]:
    """Write the episodes to demo file `out` (atomically) and describe what was written. Each
    episode is flushed as it is written, so a killed conversion leaves every finished one in
    `out`.partial, readable with `DemoFile(..., salvage=True)`. Camera frames are stored with
    `image_codec` (png, jpeg, webp or raw; DemoWriter), lossy ones at `image_quality` (default:
    each codec's); frames the source kept as pictures of that codec are stored as they are."""
    out = Path(out)
    if out.is_dir():
        raise ImitationError(f"--out {out}: is a directory; give a file name such as {out / 'demos.mcap'}")
    if not converted.episodes:
        raise ImitationError(f"{converted.source}: no episode to write")
    for index, episode in enumerate(converted.episodes):
        for what, tree in (
            ("observation", episode.observations),
            ("action", episode.actions),
            ("reward", np.asarray(episode.rewards, dtype=np.float64)),
        ):
            if found := first_nonfinite(tree, what):
                step, name, value = found
                raise ImitationError(
                    f"{converted.source}: episode {index}, step {step}: the {name} is {value}; "
                    "demo files hold finite observations, actions and rewards only (nothing was written)"
                )
    writer = DemoWriter(
        out,
        env_id=converted.env_id,
        observation_space=converted.observation_space,
        action_space=converted.action_space,
        dt=converted.dt,
        source=converted.source,
        metadata=converted.metadata,
        end_flags=converted.end_flags,
        flush_episodes=True,
        image_codec=image_codec,
        jpeg_quality=DEFAULT_JPEG_QUALITY if image_quality is None else image_quality,
        webp_quality=DEFAULT_WEBP_QUALITY if image_quality is None else image_quality,
    )
    with writer:
        for episode in _bar(converted.episodes, progress):
            writer.write(episode)
    lengths = [len(episode) for episode in converted.episodes]
    return {
        "out": str(out),
        "source": converted.source,
        "env_id": converted.env_id or None,  # null for "no env", as in run directories' metrics.json
        "episodes": len(lengths),
        "transitions": int(sum(lengths)),
        "observation_space": describe_space(converted.observation_space),
        "action_space": describe_space(converted.action_space),
        "dt": converted.dt,
        "terminated": sum(episode.terminated for episode in converted.episodes),
        "truncated": sum(episode.truncated for episode in converted.episodes),
        "end_flags": converted.end_flags,
        "warnings": converted.warnings,
    }


def _bar(episodes: list[Episode], progress: bool) -> Iterator[Episode]:
    yield from progress_over(episodes, total=len(episodes), desc="write", unit="episode", enabled=progress)

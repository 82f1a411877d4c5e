"""Demo file → an MCAP file Foxglove can plot: one JSON message per step.

The demo format packs hundreds of steps into each binary block message, which keeps loading fast
but means generic viewers cannot decode it. This export writes, per episode of T steps, T + 1
messages on `/step` (JSON, with a `jsonschema` schema Foxglove reads): the episode and step
index, the observation, and — for steps 0…T-1 — the action and reward; the last message holds
the final observation with `final: true` and the episode's terminated/truncated flags. Log times
are the steps' times in the demo file (real times for recordings). `/episode` repeats each
episode's marker. Plot e.g. `/step.observation[0]` or `/step.reward`.

Camera leaves of the observation are not numbers to plot: they stay out of `/step` (an
observation that is a camera alone leaves no `observation` there) and are copied, message for
message, from the demo file's own image channels (`foxglove.CompressedImage` or `RawImage`, the
same topic, bytes and log times), which Foxglove shows as video.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, BinaryIO

import gymnasium as gym
import numpy as np
from mcap.writer import CompressionType, Writer

from imitation import __version__
from imitation.data.mcap.format import EpisodeFacts, Field, to_json_text
from imitation.data.mcap.images import IMAGE_ENCODING, schema_data, schema_name
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.records import Damage, chunk_records, decode_chunks
from imitation.data.mcap.source import ByteSource, refuse_url
from imitation.data.spaces import LeafPath, space_to_json
from imitation.data.types import Episode, Tree
from imitation.errors import DemoFileError, ImitationError
from imitation.output import OutputLock, check_target, create_exclusive, lstat_kind, writing
from imitation.progress import progress_over

STEP_TOPIC = "/step"
EPISODE_TOPIC = "/episode"


def space_schema(space: gym.Space) -> dict[str, Any]:
    """The JSON schema of one sample of `space` as `_value` writes it."""
    if isinstance(space, gym.spaces.Dict):
        return {"type": "object", "properties": {key: space_schema(sub) for key, sub in space.spaces.items()}}
    if isinstance(space, gym.spaces.Discrete):
        return {"type": "integer"}
    item = (
        {"type": "number"} if isinstance(space, gym.spaces.Box) and np.dtype(space.dtype).kind == "f" else {"type": "integer"}
    )
    schema: dict[str, Any] = item
    assert space.shape is not None  # Box, MultiDiscrete or MultiBinary: the spaces a demo file holds besides the above
    for size in reversed(space.shape):
        schema = {"type": "array", "items": schema, "minItems": size, "maxItems": size}
    return schema


def step_schema(observation_space: gym.Space | None, action_space: gym.Space) -> dict[str, Any]:
    """The schema of `/step`; `observation_space` None: the observation is cameras alone."""
    observation = {"observation": space_schema(observation_space)} if observation_space is not None else {}
    return {
        "type": "object",
        "title": "imitation step",
        "properties": {
            "episode": {"type": "integer"},
            "step": {"type": "integer"},
            **observation,
            "action": space_schema(action_space),
            "reward": {"type": "number"},
            "final": {"type": "boolean"},
            "terminated": {"type": "boolean"},
            "truncated": {"type": "boolean"},
        },
        "required": ["episode", "step", *observation, "final"],
    }


def _without_cameras(space: gym.Space, cameras: set[LeafPath], path: LeafPath = ()) -> gym.Space | None:
    """`space` less the leaves at `cameras`; None when nothing is left."""
    if path in cameras:
        return None
    if isinstance(space, gym.spaces.Dict):
        kept = {key: _without_cameras(sub, cameras, (*path, key)) for key, sub in space.spaces.items()}
        left = {key: sub for key, sub in kept.items() if sub is not None}
        return gym.spaces.Dict(left) if left else None
    return space


def _tree_without_cameras(tree: Tree, cameras: set[LeafPath], path: LeafPath = ()) -> Tree | None:
    """`tree` less the leaves at `cameras`; None when nothing is left."""
    if path in cameras:
        return None
    if isinstance(tree, dict):
        kept = {key: _tree_without_cameras(sub, cameras, (*path, key)) for key, sub in tree.items()}
        left = {key: sub for key, sub in kept.items() if sub is not None}
        return left or None
    return tree


def _value(tree: Tree, row: int) -> Any:
    if isinstance(tree, dict):
        return {key: _value(sub, row) for key, sub in tree.items()}
    return tree[row].tolist()


def export_foxglove(demo_path: str | os.PathLike, out: str | os.PathLike, *, progress: bool = True) -> dict[str, Any]:
    """Write `out` (atomically: `<out>.partial` renamed when complete); returns counts."""
    refuse_url(out)
    demo = DemoFile(demo_path)
    out = Path(out)
    if out.is_dir():
        raise ImitationError(f"{out}: is a directory; give a file name such as {out / 'steps.mcap'}")
    if isinstance(demo.path, Path) and out.resolve() == demo.path.resolve():
        raise ImitationError(f"{out}: is the demo file itself; choose another name")
    check_target(out)
    partial = out.with_name(out.name + ".partial")
    with OutputLock(out), writing(out):
        if lstat_kind(partial) == "a regular file":
            partial.unlink()  # an earlier export's leftover: derived data, made again below
        messages = _write(demo, create_exclusive(partial), partial, out, progress=progress)
    return {
        "out": str(out),
        "to": "foxglove",
        "episodes": len(demo),
        "messages": messages,
        "topics": [STEP_TOPIC, EPISODE_TOPIC, *(f.topic for f in _cameras(demo).values())],
    }


def _cameras(demo: DemoFile) -> dict[int, Field]:
    """The demo file's image channels (the observation's camera leaves), by channel id."""
    return {channel_id: f for channel_id, f in demo.channel_fields.items() if f is not None and f.codec is not None}


def _frames(
    demo: DemoFile, source: ByteSource, facts: EpisodeFacts, cameras: dict[int, Field]
) -> list[tuple[int, int, bytes]]:
    """(log time, channel id, message) of the episode's camera frames, as the demo file holds
    them, in log-time order."""
    frames = []
    try:
        for _, decoded in decode_chunks(source, demo.chunks_of(facts), None):
            for channel_id, log_time, data in chunk_records(decoded.result(), lambda channel: None):
                if channel_id in cameras and facts.t_start_ns <= log_time <= facts.t_end_ns:
                    frames.append((log_time, channel_id, bytes(data)))
    except Damage as error:  # the episode read whole a moment ago: the file changed since
        raise DemoFileError(f"{demo.path}: {error}") from None
    frames.sort(key=lambda frame: frame[0])
    return frames


def _write(demo: DemoFile, stream: BinaryIO, partial: Path, out: Path, *, progress: bool) -> int:
    """Write the steps to `stream` (the file `partial`), then move it to `out`; the number of messages."""
    dt_ns = max(1, round(demo.dt * 1e9))
    messages = 0
    try:
        with stream:
            writer = Writer(stream, compression=CompressionType.ZSTD)
            writer.start(profile="", library=f"imitation-mcap {__version__}")
            writer.add_metadata(
                "imitation.export",
                {
                    "source_file": str(demo.path),
                    "env_id": demo.env_id,
                    "observation_space": json.dumps(space_to_json(demo.observation_space)),
                    "action_space": json.dumps(space_to_json(demo.action_space)),
                    "source": demo.source,
                },
            )
            cameras = _cameras(demo)
            paths = {f.path for f in cameras.values()}
            step_channel = writer.register_channel(
                STEP_TOPIC,
                "json",
                writer.register_schema(
                    "imitation.Step",
                    "jsonschema",
                    json.dumps(step_schema(_without_cameras(demo.observation_space, paths), demo.action_space)).encode(),
                ),
            )
            image_schemas = {
                codec: writer.register_schema(schema_name(codec), IMAGE_ENCODING, schema_data(codec))
                for codec in sorted({f.codec for f in cameras.values() if f.codec is not None})
            }
            image_channels = {
                channel_id: writer.register_channel(f.topic, IMAGE_ENCODING, image_schemas[f.codec])
                for channel_id, f in cameras.items()
                if f.codec is not None
            }
            episode_channel = writer.register_channel(
                EPISODE_TOPIC,
                "json",
                writer.register_schema(
                    "imitation.Episode",
                    "jsonschema",
                    json.dumps({"type": "object", "title": "imitation episode marker"}).encode(),
                ),
            )
            bar = progress_over(zip(demo.episodes, demo), total=len(demo), desc="export", unit="episode", enabled=progress)
            with demo.byte_source() as source:
                for facts, episode in bar:
                    frames = _frames(demo, source, facts, cameras) if cameras else []
                    messages += _write_episode(
                        writer, step_channel, episode_channel, image_channels, facts, episode, frames, paths, dt_ns
                    )
            writer.finish()
        os.replace(partial, out)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    return messages


def _write_episode(
    writer: Writer,
    step_channel: int,
    episode_channel: int,
    image_channels: dict[int, int],
    facts: EpisodeFacts,
    episode: Episode,
    frames: list[tuple[int, int, bytes]],
    cameras: set[LeafPath],
    dt_ns: int,
) -> int:
    """An episode's step messages, each followed by the camera frames logged at or before it,
    and its marker; the number of messages written."""
    steps = len(episode)
    observations = _tree_without_cameras(episode.observations, cameras)
    if episode.timestamps is not None:
        times = episode.timestamps.astype(np.int64) + facts.time_shift_ns
    else:
        times = facts.t_start_ns + np.arange(steps + 1, dtype=np.int64) * dt_ns
    next_frame = 0
    for i in range(steps + 1):
        message: dict[str, Any] = {"episode": facts.index, "step": i}
        if observations is not None:
            message["observation"] = _value(observations, i)
        message["final"] = i == steps
        if i < steps:
            message["action"] = _value(episode.actions, i)
            message["reward"] = float(episode.rewards[i])
        else:
            message["terminated"], message["truncated"] = facts.terminated, facts.truncated
        time_ns = int(times[i])
        writer.add_message(step_channel, log_time=time_ns, publish_time=time_ns, data=to_json_text(message).encode())
        while next_frame < len(frames) and (frames[next_frame][0] <= time_ns or i == steps):
            log_time, channel_id, data = frames[next_frame]
            writer.add_message(image_channels[channel_id], log_time=log_time, publish_time=log_time, data=data)
            next_frame += 1
    writer.add_message(
        episode_channel, log_time=facts.t_end_ns, publish_time=facts.t_end_ns, data=to_json_text(facts.to_json()).encode()
    )
    return steps + 2 + len(frames)

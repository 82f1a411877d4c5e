"""Demo file → an MCAP file Foxglove can plot: one JSON message per step.

The demo format packs hundreds of steps into each binary block message, which keeps loading fast
but means generic viewers cannot decode it. This export writes, per episode of T steps, T + 1
messages on `/step` (JSON, with a `jsonschema` schema Foxglove reads): the episode and step
index, the observation, and — for steps 0…T-1 — the action and reward; the last message holds
the final observation with `final: true` and the episode's terminated/truncated flags. Log times
are the steps' times in the demo file (real times for recordings). `/episode` repeats each
episode's marker. Plot e.g. `/step.observation[0]` or `/step.reward`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, BinaryIO

import gymnasium as gym
import numpy as np
from mcap.writer import CompressionType, Writer
from tqdm import tqdm

from imitation import __version__
from imitation.data.mcap.format import to_json_text
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.source import refuse_url
from imitation.data.spaces import space_to_json
from imitation.data.types import Tree
from imitation.errors import ImitationError
from imitation.output import OutputLock, check_target, create_exclusive, lstat_kind, writing

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


def step_schema(observation_space: gym.Space, action_space: gym.Space) -> dict[str, Any]:
    return {
        "type": "object",
        "title": "imitation step",
        "properties": {
            "episode": {"type": "integer"},
            "step": {"type": "integer"},
            "observation": space_schema(observation_space),
            "action": space_schema(action_space),
            "reward": {"type": "number"},
            "final": {"type": "boolean"},
            "terminated": {"type": "boolean"},
            "truncated": {"type": "boolean"},
        },
        "required": ["episode", "step", "observation", "final"],
    }


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
        "topics": [STEP_TOPIC, EPISODE_TOPIC],
    }


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
            step_channel = writer.register_channel(
                STEP_TOPIC,
                "json",
                writer.register_schema(
                    "imitation.Step", "jsonschema", json.dumps(step_schema(demo.observation_space, demo.action_space)).encode()
                ),
            )
            episode_channel = writer.register_channel(
                EPISODE_TOPIC,
                "json",
                writer.register_schema(
                    "imitation.Episode",
                    "jsonschema",
                    json.dumps({"type": "object", "title": "imitation episode marker"}).encode(),
                ),
            )
            bar = tqdm(
                zip(demo.episodes, demo),
                total=len(demo),
                desc="export",
                unit="episode",
                disable=None if progress else True,
                dynamic_ncols=True,
            )
            for facts, episode in bar:
                steps = len(episode)
                if episode.timestamps is not None:
                    times = episode.timestamps.astype(np.int64) + facts.time_shift_ns
                else:
                    times = facts.t_start_ns + np.arange(steps + 1, dtype=np.int64) * dt_ns
                for i in range(steps + 1):
                    message: dict[str, Any] = {
                        "episode": facts.index,
                        "step": i,
                        "observation": _value(episode.observations, i),
                        "final": i == steps,
                    }
                    if i < steps:
                        message["action"] = _value(episode.actions, i)
                        message["reward"] = float(episode.rewards[i])
                    else:
                        message["terminated"], message["truncated"] = facts.terminated, facts.truncated
                    time_ns = int(times[i])
                    writer.add_message(
                        step_channel, log_time=time_ns, publish_time=time_ns, data=to_json_text(message).encode()
                    )
                writer.add_message(
                    episode_channel,
                    log_time=facts.t_end_ns,
                    publish_time=facts.t_end_ns,
                    data=to_json_text(facts.to_json()).encode(),
                )
                messages += steps + 2
            writer.finish()
        os.replace(partial, out)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    return messages

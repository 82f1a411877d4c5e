"""The demo format: its constants, the channels an episode's fields are written to, the facts
of an episode, and the JSON and checksums of its metadata. docs/FORMAT.md specifies it; in short:

- Dataset facts (format version, env id, spaces as JSON, source, creator) are an MCAP Metadata
  record `imitation.dataset` written right after the header.
- Every per-step field is a channel (`/observation`, `/observation/<key>` for Dict spaces,
  `/action`, `/reward`, optional `/time` and `/info`); its messages are *blocks* of up to
  `block_steps` consecutive rows as raw little-endian bytes, dtype and row shape in the channel
  metadata. Blocks keep the per-message cost of the reader (~5 µs) off the per-step path.
- Each episode ends with a JSON message on `/episode` (index, length, return, terminated,
  truncated, time range, metadata). All of an episode's messages have log times in
  [t_start_ns, t_end_ns] and episodes' time ranges are disjoint and increasing, so the chunk
  index finds episode k by time without reading the others.
- On close, an `imitation.episodes` Metadata record repeats every episode's facts, so `info` and
  random access need only the summary and two small records.
- Episodes a person could take over from a learner carry `/intervention/…` JSON channels, one
  message per step (who drove, the learner's proposed and the executed action) and one per
  hand-over; readers that do not know them skip them.
- Image observations (uint8 (H, W[, C]) leaves) are the exception to blocks: one Foxglove image
  message per frame, codec in the channel metadata (`images`). Files with such channels are
  format version 2; all others stay version 1, byte for byte.
"""

from __future__ import annotations

import functools
import json
import math
import zlib
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from mcap.records import Channel
from mcap.writer import CompressionType

from imitation.data.mcap.images import is_image_leaf
from imitation.data.spaces import LeafPath, space_leaves
from imitation.errors import ImitationError

# Version 2 adds image channels (one Foxglove image message per frame). The writer writes 1 for
# files without them, so that readers of version 1 still read those; this reader reads both.
PLAIN_FORMAT_VERSION = 1
IMAGE_FORMAT_VERSION = 2
FORMAT_VERSION = IMAGE_FORMAT_VERSION
PROFILE = "imitation"
DATASET_METADATA = "imitation.dataset"
EPISODES_METADATA = "imitation.episodes"
BLOCK_ENCODING = "imitation.ndarray"
EPISODE_TOPIC = "/episode"
# LZ4 is the default: the fastest-decoding codec that MCAP tools and Foxglove read natively; zstd
# is ~10 % smaller, for archives; "none" is read in place. Measured: bench/RESULTS.md.
COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
DEFAULT_COMPRESSION = "lz4"
MAGIC = b"\x89MCAP0\r\n"

EPISODE_SCHEMA = {
    "type": "object",
    "title": "imitation episode marker",
    "properties": {
        "index": {"type": "integer"},
        "length": {"type": "integer"},
        "return": {"type": "number"},
        "terminated": {"type": "boolean"},
        "truncated": {"type": "boolean"},
        "t_start_ns": {"type": "integer"},
        "t_end_ns": {"type": "integer"},
        "metadata": {"type": "object"},
    },
    "required": ["index", "length", "return", "terminated", "truncated", "t_start_ns", "t_end_ns"],
}


@dataclass(frozen=True, kw_only=True)
class EpisodeFacts:
    """What is known of an episode without reading its steps."""

    index: int
    length: int
    episode_return: float
    terminated: bool
    truncated: bool
    t_start_ns: int
    t_end_ns: int
    metadata: dict[str, Any] = field(default_factory=dict)
    time_shift_ns: int = 0  # added to a recording's own timestamps to keep episodes disjoint

    def to_json(self) -> dict[str, Any]:
        shift = {"time_shift_ns": self.time_shift_ns} if self.time_shift_ns else {}
        return {
            "index": self.index,
            "length": self.length,
            "return": self.episode_return,
            "terminated": self.terminated,
            "truncated": self.truncated,
            "t_start_ns": self.t_start_ns,
            "t_end_ns": self.t_end_ns,
            "metadata": self.metadata,
            **shift,
        }

    @staticmethod
    def from_json(data: dict[str, Any]) -> EpisodeFacts:
        return EpisodeFacts(
            index=int(data["index"]),
            length=int(data["length"]),
            episode_return=float(data["return"]),
            terminated=bool(data["terminated"]),
            truncated=bool(data["truncated"]),
            t_start_ns=int(data["t_start_ns"]),
            t_end_ns=int(data["t_end_ns"]),
            metadata=dict(data.get("metadata") or {}),
            time_shift_ns=int(data.get("time_shift_ns", 0)),
        )


@dataclass(frozen=True, eq=False)
class Field:
    """One channel: which part of an episode it carries and how its rows are laid out."""

    kind: str  # "observation" | "action" | "reward" | "time" | "info" | "intervention"
    path: LeafPath
    dtype: np.dtype | None  # None for JSON channels
    shape: tuple[int, ...]
    codec: str | None = None  # image channels: "png" | "jpeg" | "raw", one message per frame; None: blocks

    # Cached: the reader asks for these once per block.
    @functools.cached_property
    def topic(self) -> str:
        return "/" + "/".join((self.kind, *self.path))

    @functools.cached_property
    def row_nbytes(self) -> int:
        assert self.dtype is not None
        return self.dtype.itemsize * math.prod(self.shape)

    @functools.cached_property
    def native_dtype(self) -> np.dtype:
        assert self.dtype is not None
        return self.dtype.newbyteorder("=")

    def channel_metadata(self) -> dict[str, str]:
        if self.dtype is None:
            return {"field": self.kind}
        layout = {"field": self.kind, "dtype": self.dtype.newbyteorder("<").str, "shape": json.dumps(list(self.shape))}
        return layout if self.codec is None else {**layout, "codec": self.codec}

    @staticmethod
    def from_channel(topic: str, metadata: dict[str, str]) -> Field:
        parts = topic.strip("/").split("/")
        kind, path = parts[0], tuple(parts[1:])
        if "dtype" not in metadata:
            return Field(kind, path, None, ())
        return Field(kind, path, np.dtype(metadata["dtype"]), tuple(json.loads(metadata["shape"])), metadata.get("codec"))


REWARD_FIELD = Field("reward", (), np.dtype("<f8"), ())
TIME_FIELD = Field("time", (), np.dtype("<i8"), ())
# Episodes a person could take over (docs/FORMAT.md §6.7): one JSON message per step on each
# per-step channel, so that Foxglove plots them on the recording's timeline, and one per hand-over.
HUMAN_FIELD = Field("intervention", ("human",), None, ())
PROPOSED_FIELD = Field("intervention", ("proposed_action",), None, ())
EXECUTED_FIELD = Field("intervention", ("executed_action",), None, ())
HANDOVER_FIELD = Field("intervention", ("handover",), None, ())
INTERVENTION_FIELDS = (HUMAN_FIELD, PROPOSED_FIELD, EXECUTED_FIELD, HANDOVER_FIELD)


def fields_for(observation_space: gym.Space, action_space: gym.Space, image_codec: str | None = None) -> list[Field]:
    """The channels a file of these spaces uses; dtypes are little-endian, as stored. With an
    `image_codec`, the image leaves of the observation space are image channels of that codec."""
    fields = [
        Field("observation", path, dtype.newbyteorder("<"), shape, image_codec if is_image_leaf(dtype, shape) else None)
        for path, dtype, shape in space_leaves(observation_space)
    ]
    fields += [Field("action", path, dtype.newbyteorder("<"), shape) for path, dtype, shape in space_leaves(action_space)]
    fields += [REWARD_FIELD, TIME_FIELD, Field("info", (), None, ()), *INTERVENTION_FIELDS]
    for f in fields:
        if f.dtype is not None and f.dtype.kind not in "biuf":
            raise ImitationError(f"space field {f.topic}: dtype {f.dtype} is not a number or bool")
    return fields


def metadata_crc(data: dict[str, str]) -> str:
    """CRC-32 over every key except `crc32`, sorted: key, NUL, value, NUL (see docs/FORMAT.md)."""
    crc = 0
    for key in sorted(k for k in data if k != "crc32"):
        crc = zlib.crc32(key.encode() + b"\0" + data[key].encode() + b"\0", crc)
    return str(crc)


def channel_field(channel: Channel) -> Field | None:
    """The field a channel carries; None for the `/episode` channel."""
    if channel.topic == EPISODE_TOPIC:
        return None
    return Field.from_channel(channel.topic, dict(channel.metadata))


def to_json_text(value: Any) -> str:
    """Strict JSON (no NaN/Infinity literals) of infos and metadata: numpy values become plain
    numbers and lists, non-finite floats the strings "nan", "inf", "-inf", anything else that
    JSON cannot hold its repr()."""
    return json.dumps(_plain(value), allow_nan=False)


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(key): _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return _plain(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return repr(value)

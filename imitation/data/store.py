"""The MCAP demo store: write episodes to an MCAP file, read them back lazily or by index.

The format is specified in docs/FORMAT.md. In short:

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

Crash safety: with `flush_episodes=True` the writer closes the MCAP chunk after each episode and
hands it to the operating system, so a killed process leaves a file whose complete chunks hold
every finished episode; `durable=True` also fsyncs it, so that a power cut does too.
`DemoFile(..., salvage=True)` scans such a file record by record and recovers them.
"""

from __future__ import annotations

import bisect
import functools
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
import json
import math
import mmap
import os
import signal
import struct
import threading
import zlib
from contextlib import contextmanager
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

import gymnasium as gym
import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, ChunkIndex, Footer, Metadata, MetadataIndex, Schema
from mcap.writer import CompressionType, IndexType, Writer

from imitation import __version__
from imitation.data.spaces import LeafPath, space_from_json, space_leaves, space_to_json, spaces_equal
from imitation.data.types import Episode, Tree, check_fits_space, first_nonfinite, tree_from_leaves, tree_leaves
from imitation.errors import DemoFileError, ImitationError
from imitation.limits import FREE_EXPANSION_BYTES, LIMITS, over_limit
from imitation.output import OutputLock, check_target, create_exclusive, lstat_kind, os_error

FORMAT_VERSION = 1
PROFILE = "imitation"
DATASET_METADATA = "imitation.dataset"
EPISODES_METADATA = "imitation.episodes"
BLOCK_ENCODING = "imitation.ndarray"
EPISODE_TOPIC = "/episode"
DEFAULT_BLOCK_STEPS = 4096
# zstd is the default; "none" trades size for the fastest loads (chunks are read in place).
COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
MAGIC = b"\x89MCAP0\r\n"
# No writer makes chunks this large (ours: 1 MiB); a header claiming more is damaged, and is
# refused before a buffer of that size is asked for.

_OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 0x02, 0x03, 0x04, 0x05, 0x06
_OP_CHUNK_INDEX, _OP_METADATA, _OP_METADATA_INDEX, _OP_DATA_END = 0x08, 0x0C, 0x0D, 0x0F
_RECORD_HEADER = struct.Struct("<BQ")
_MESSAGE_HEADER = struct.Struct("<HIQQ")
_FOOTER_LENGTH = 1 + 8 + 20

_EPISODE_SCHEMA = {
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
class _Field:
    """One channel: which part of an episode it carries and how its rows are laid out."""

    kind: str  # "observation" | "action" | "reward" | "time" | "info"
    path: LeafPath
    dtype: np.dtype | None  # None for JSON channels
    shape: tuple[int, ...]

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
        return {"field": self.kind, "dtype": self.dtype.newbyteorder("<").str, "shape": json.dumps(list(self.shape))}

    @staticmethod
    def from_channel(topic: str, metadata: dict[str, str]) -> _Field:
        parts = topic.strip("/").split("/")
        kind, path = parts[0], tuple(parts[1:])
        if "dtype" not in metadata:
            return _Field(kind, path, None, ())
        return _Field(kind, path, np.dtype(metadata["dtype"]), tuple(json.loads(metadata["shape"])))


_REWARD_FIELD = _Field("reward", (), np.dtype("<f8"), ())
_TIME_FIELD = _Field("time", (), np.dtype("<i8"), ())


def _fields_for(observation_space: gym.Space, action_space: gym.Space) -> list[_Field]:
    """The channels a file of these spaces uses; dtypes are little-endian, as stored."""
    fields = [_Field("observation", path, dtype.newbyteorder("<"), shape) for path, dtype, shape in space_leaves(observation_space)]
    fields += [_Field("action", path, dtype.newbyteorder("<"), shape) for path, dtype, shape in space_leaves(action_space)]
    fields += [_REWARD_FIELD, _TIME_FIELD, _Field("info", (), None, ())]
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


def _with_crc(data: dict[str, str]) -> dict[str, str]:
    return {**data, "crc32": metadata_crc(data)}


@contextmanager
def _interrupts_deferred() -> Iterator[None]:
    """Hold SIGINT until the block ends, so Ctrl-C never leaves half an episode in the file.

    Signal handlers can only be set from the main thread; elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if received and callable(previous):
            previous(signal.SIGINT, None)
        elif received and (previous == signal.SIG_DFL or signal.SIGTERM in received):  # SIGTERM stops even where SIGINT is ignored
            raise KeyboardInterrupt


class DemoWriter:
    """Write episodes of one environment to an MCAP demo file.

    The file is written under `<path>.partial` (created exclusively, under a lock on `path`: a
    second writer fails at once) and renamed to `path` by `close()`, so `path` never holds a
    half-written file. Used as a context manager, a KeyboardInterrupt still closes the file
    properly. Any other failure (a full disk included) keeps `<path>.partial` when it holds a
    finished episode, for `recover_partial`; and a new writer refuses to start over a partial
    file that holds finished episodes, rather than truncating it.

    With `flush_episodes=True` every episode is flushed as its own chunk as soon as it is written,
    so if the process is killed, `<path>.partial` holds every finished episode; `durable=True`
    also fsyncs it (power cuts too). bench/flush.py: on 10-step episodes a chunk per episode
    costs 1.7× the time and 1.7× the size, the fsync 3× the time again; on 500-step ones, 3 %.

    NaN and ±inf in float observations, actions or rewards are refused where they enter, with the
    episode and step named; `finite_only=False` stores them as they are (bit-exact round trips of
    any data), and learners then refuse the file when they load it.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        env_id: str,
        observation_space: gym.Space,
        action_space: gym.Space,
        dt: float | None = None,
        source: str = "",
        metadata: dict[str, Any] | None = None,
        block_steps: int = DEFAULT_BLOCK_STEPS,
        flush_episodes: bool = False,
        durable: bool = False,
        chunk_size: int = 1024 * 1024,
        compression: str = "zstd",
        finite_only: bool = True,
        temporary: str | os.PathLike | None = None,
        lock: bool = True,
    ) -> None:
        self.path = Path(path)
        self._finite_only = finite_only
        self.partial_path = Path(temporary) if temporary is not None else self.path.with_name(self.path.name + ".partial")
        self.observation_space = observation_space
        self.action_space = action_space
        self._fields = _fields_for(observation_space, action_space)
        self._block_steps = block_steps
        self._durable = durable
        self._flush_episodes = flush_episodes or durable
        if compression not in COMPRESSIONS:
            raise ImitationError(f"compression must be one of {', '.join(COMPRESSIONS)}, got {compression!r}")
        if dt is not None and not dt > 0:
            raise ImitationError(f"dt must be a positive number of seconds, got {dt}")
        self._dt_ns = max(1, round((dt or 0.001) * 1e9))
        self._next_time_ns = 0
        self._facts: list[EpisodeFacts] = []
        # Everything that can fail on bad arguments happens before the file exists.
        dataset = {
            "format_version": str(FORMAT_VERSION),
            "env_id": env_id,
            "observation_space": json.dumps(space_to_json(observation_space)),
            "action_space": json.dumps(space_to_json(action_space)),
            "dt_ns": str(self._dt_ns),
            "source": source,
            "creator": f"imitation-mcap {__version__}",
            "user_metadata": to_json_text(metadata or {}),
        }
        check_target(self.path)
        self._lock = OutputLock(self.path).acquire() if lock else None
        try:
            _clear_partial(self.partial_path)
            self._file = create_exclusive(self.partial_path, target=self.path)
        except BaseException:
            self._release()
            raise
        self._closed = False
        try:
            self._start(dataset, chunk_size, compression)
        except OSError as error:
            raise self._failed(error) from None

    def _start(self, dataset: dict[str, str], chunk_size: int, compression: str) -> None:
        # No attachment index: python-mcap would point a summary offset at the empty group,
        # which `mcap doctor` reports as an error.
        self._writer = Writer(
            self._file,
            chunk_size=chunk_size,
            compression=COMPRESSIONS[compression],
            index_types=IndexType.CHUNK | IndexType.MESSAGE | IndexType.METADATA,
        )
        self._writer.start(profile=PROFILE, library=f"imitation-mcap {__version__}")
        self._writer.add_metadata(DATASET_METADATA, _with_crc(dataset))
        self._channels: dict[str, int] = {}
        for f in self._fields:
            if f.kind in ("observation", "action", "reward"):
                self._register(f)
        episode_schema = self._writer.register_schema("imitation.Episode", "jsonschema", json.dumps(_EPISODE_SCHEMA).encode())
        self._channels[EPISODE_TOPIC] = self._writer.register_channel(EPISODE_TOPIC, "json", episode_schema, {"field": "episode"})

    @property
    def episodes_written(self) -> int:
        return len(self._facts)

    def write(self, episode: Episode) -> EpisodeFacts:
        """Append one episode; returns its facts (its index in this file, return, time range)."""
        check_fits_space(episode.observations, self.observation_space, "observations")
        check_fits_space(episode.actions, self.action_space, "actions")
        rewards = np.asarray(episode.rewards, dtype=np.float64)
        if self._finite_only:
            for what, tree in (("observation", episode.observations), ("action", episode.actions), ("reward", rewards)):
                if found := first_nonfinite(tree, what):
                    step, name, value = found
                    raise ImitationError(
                        f"{self.path}: episode {len(self._facts)}, step {step}: the {name} is {value}; "
                        "demo files hold finite observations, actions and rewards only"
                    )
        times, time_shift_ns = self._episode_times(episode)
        columns: list[tuple[_Field, np.ndarray]] = []
        for f in self._fields:
            if f.kind in ("observation", "action"):
                tree = episode.observations if f.kind == "observation" else episode.actions
                columns.append((f, dict(tree_leaves(tree))[f.path]))
            elif f.kind == "reward":
                columns.append((f, rewards))
            elif f.kind == "time" and episode.timestamps is not None:
                columns.append((f, times))

        try:
            with _interrupts_deferred():
                return self._append(episode, columns, times, time_shift_ns, rewards)
        except OSError as error:
            raise self._failed(error) from None

    def _append(
        self, episode: Episode, columns: list[tuple[_Field, np.ndarray]], times: np.ndarray, time_shift_ns: int, rewards: np.ndarray
    ) -> EpisodeFacts:
        steps = len(episode)
        facts = EpisodeFacts(
            index=len(self._facts),
            length=steps,
            episode_return=float(rewards.sum()),
            terminated=bool(episode.terminated),
            truncated=bool(episode.truncated),
            t_start_ns=int(times[0]),
            t_end_ns=int(times[-1]),
            metadata=json.loads(to_json_text(episode.metadata)),
            time_shift_ns=time_shift_ns,
        )
        # Interleave by block so that log times never go backwards within the file.
        for start in range(0, steps + 1, self._block_steps):
            for f, rows in columns:
                block = rows[start : start + self._block_steps]
                if len(block) == 0 or f.row_nbytes == 0:
                    continue
                data = np.ascontiguousarray(block, dtype=f.dtype).tobytes()
                self._add(f.topic, int(times[start]), data)
            if episode.infos is not None and start < steps:
                infos = episode.infos[start : start + self._block_steps]
                self._add("/info", int(times[start]), to_json_text(infos).encode())
        self._add(EPISODE_TOPIC, facts.t_end_ns, to_json_text(facts.to_json()).encode())
        self._facts.append(facts)
        self._next_time_ns = facts.t_end_ns + self._dt_ns
        if self._flush_episodes:
            self._writer.flush()
        if self._durable:
            os.fsync(self._file.fileno())
        return facts

    def close(self) -> Path:
        """Write the episode index and summary, then rename `<path>.partial` to `path`."""
        if self._closed:
            return self.path
        try:
            self._writer.flush()
            episodes = to_json_text([facts.to_json() for facts in self._facts])
            self._writer.add_metadata(EPISODES_METADATA, _with_crc({"episodes": episodes}))
            self._writer.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
            self._closed = True
            os.replace(self.partial_path, self.path)
        except OSError as error:
            raise self._failed(error) from None
        self._release()
        return self.path

    def abort(self) -> int:
        """Stop writing after a failure. The partial file stays when it holds finished episodes
        (how many is returned), so that nothing recorded is lost; otherwise it is removed."""
        if self._closed:
            return 0
        self._closed = True
        try:
            self._file.close()
        except OSError:
            pass  # the buffered tail cannot be written (a full disk); the flushed episodes are on disk
        kept = salvageable_episodes(self.partial_path)
        if not kept:
            self.partial_path.unlink(missing_ok=True)
        self._release()
        return kept

    def _failed(self, error: OSError) -> ImitationError:
        """Abort, and the one-line error saying what was kept."""
        error = os_error(self.path, error)
        self.__exit__(type(error), error, None)
        return error

    def _release(self) -> None:
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def __enter__(self) -> DemoWriter:
        return self

    def __exit__(self, exc_type: type | None, exc: BaseException | None, tb: Any) -> None:
        if exc_type is None or (issubclass(exc_type, KeyboardInterrupt) and self._facts):
            self.close()
            return
        kept = self.abort()
        if kept and isinstance(exc, ImitationError):
            exc.args = (f"{exc}; {self.partial_path} keeps {kept} finished episode(s): `imitation recover {self.partial_path}` makes it a demo file",)

    def _register(self, f: _Field) -> None:
        encoding = "json" if f.dtype is None else BLOCK_ENCODING
        self._channels[f.topic] = self._writer.register_channel(f.topic, encoding, 0, f.channel_metadata())

    def _add(self, topic: str, log_time: int, data: bytes) -> None:
        if topic not in self._channels:  # /time and /info exist only in files that use them
            self._register(next(f for f in self._fields if f.topic == topic))
        self._writer.add_message(self._channels[topic], log_time=log_time, data=data, publish_time=log_time)

    def _episode_times(self, episode: Episode) -> tuple[np.ndarray, int]:
        """Log times of the episode's observations, and the shift applied to its own timestamps."""
        steps = len(episode)
        if episode.timestamps is None:
            return self._next_time_ns + np.arange(steps + 1, dtype=np.int64) * self._dt_ns, 0
        times = np.asarray(episode.timestamps, dtype=np.int64)
        if np.any(np.diff(times) < 0):
            raise ImitationError(f"episode {len(self._facts)}: timestamps go backwards")
        # Episodes must occupy disjoint, increasing time ranges (and MCAP log times are unsigned):
        # shift one that starts too early, and record the shift so readers can undo it.
        shift = max(0, self._next_time_ns - int(times[0]))
        return times + shift, shift


def salvageable_episodes(path: str | os.PathLike) -> int:
    """How many complete episodes a (partial) demo file holds; 0 when it is not readable as one."""
    try:
        return len(DemoFile(path, salvage=True))
    except ImitationError:
        return 0


def _clear_partial(partial: Path) -> None:
    """Make way for a new partial file: remove one that holds no finished episode, refuse to
    touch one that does (an interrupted write's episodes) or that is not a regular file."""
    kind = lstat_kind(partial)
    if kind is None:
        return
    if kind != "a regular file":
        raise ImitationError(f"{partial}: is {kind}; not writing through it (remove it)")
    kept = salvageable_episodes(partial)
    if kept:
        raise ImitationError(
            f"{partial}: holds {kept} finished episode(s) of an interrupted write; keep them with "
            f"`imitation recover {partial}`, or delete it to start over"
        )
    partial.unlink()


def write_episodes(
    path: str | os.PathLike,
    episodes: Iterable[Episode],
    *,
    env_id: str,
    observation_space: gym.Space,
    action_space: gym.Space,
    **writer_options: Any,
) -> Path:
    """Write all `episodes` to `path` in one go (atomically: all or nothing)."""
    with DemoWriter(path, env_id=env_id, observation_space=observation_space, action_space=action_space, **writer_options) as writer:
        for episode in episodes:
            writer.write(episode)
    return writer.path


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


# ------------------------------------------------------------------------------------------------
# Reading


@dataclass(frozen=True)
class _ChunkRef:
    offset: int
    length: int
    start_time: int
    end_time: int
    uncompressed_size: int


@dataclass
class _Index:
    """Everything needed to read episodes: from the summary, or rebuilt by a salvage scan."""

    dataset: dict[str, str]
    channels: dict[int, _Field | None]  # None: the /episode channel
    chunks: list[_ChunkRef]
    episodes: list[EpisodeFacts]
    damage: str | None = None


class _EpisodeAssembler:
    """Collects block messages in file order and emits an Episode when its marker arrives."""

    def __init__(
        self,
        observation_space: gym.Space,
        action_space: gym.Space,
        channels: dict[int, _Field | None],
        facts_by_end_time: dict[int, EpisodeFacts] | None = None,
    ):
        self._channels = channels
        # Known facts (from a checked index) by t_end_ns, the marker's log time, which is unique
        # per episode: looking them up is cheaper than parsing each marker's JSON again.
        self._facts_by_end_time = facts_by_end_time or {}
        fields = _fields_for(observation_space, action_space)
        self._observation_fields = [f for f in fields if f.kind == "observation"]
        self._action_fields = [f for f in fields if f.kind == "action"]
        self._blocks: dict[str, list[bytes | memoryview]] = {}

    def add(
        self, channel_id: int, log_time: int, data: memoryview, keep: Callable[[EpisodeFacts], bool] | None = None
    ) -> tuple[EpisodeFacts, Episode | None] | None:
        """Route one message; at an episode marker return its facts and, if `keep(facts)`
        (default: always), the assembled episode. Blocks of a dropped episode are discarded
        unread, so they may be incomplete (the tail of an episode begun in an unread chunk)."""
        if channel_id not in self._channels:
            raise ValueError(f"message on unknown channel id {channel_id}")
        f = self._channels[channel_id]
        if f is not None:
            self._blocks.setdefault(f.topic, []).append(data)
            return None
        facts = self._facts_by_end_time.get(log_time) or EpisodeFacts.from_json(json.loads(bytes(data)))
        blocks, self._blocks = self._blocks, {}
        if keep is not None and not keep(facts):
            return facts, None
        return facts, self._build(facts, blocks)

    def _build(self, facts: EpisodeFacts, blocks: dict[str, list[bytes | memoryview]]) -> Episode:
        steps = facts.length

        def rows(f: _Field, count: int) -> np.ndarray:
            parts = blocks.get(f.topic, [])
            if f.row_nbytes == 0:
                return np.zeros((count, *f.shape), dtype=f.native_dtype)
            data = parts[0] if len(parts) == 1 else b"".join(parts)
            if len(data) != count * f.row_nbytes:
                raise ValueError(f"episode {facts.index}: {f.topic} holds {len(data) // f.row_nbytes} rows, expected {count}")
            array = np.frombuffer(data, dtype=f.dtype).reshape((count, *f.shape))
            return array if f.dtype == f.native_dtype else array.astype(f.native_dtype)

        def tree(fields: list[_Field], count: int) -> Tree:
            return tree_from_leaves({f.path: rows(f, count) for f in fields})

        infos = None
        if "/info" in blocks:
            infos = [info for part in blocks["/info"] for info in json.loads(bytes(part))]
        timestamps = None
        if "/time" in blocks:
            timestamps = rows(_TIME_FIELD, steps + 1) - facts.time_shift_ns
        return Episode(
            observations=tree(self._observation_fields, steps + 1),
            actions=tree(self._action_fields, steps),
            rewards=rows(_REWARD_FIELD, steps),
            terminated=facts.terminated,
            truncated=facts.truncated,
            infos=infos,
            timestamps=timestamps,
            metadata=facts.metadata,
        )


def _check_episode_index(episodes: list[EpisodeFacts], content_bytes: int) -> None:
    """The episode index must be what a writer could have written: episodes numbered in order,
    in disjoint increasing time ranges, and no more steps than the chunks hold 8-byte rewards
    for. A forged index (duplicated episodes, 10^15 steps) is damage, which the scan rebuilds."""
    previous_end = -1
    for position, facts in enumerate(episodes):
        if facts.index != position:
            raise _Damage(f"the episode index is inconsistent (entry {position} is numbered {facts.index})")
        if facts.length < 0 or facts.t_start_ns > facts.t_end_ns or facts.t_start_ns <= previous_end:
            raise _Damage(f"the episode index is inconsistent (episode {position}: length {facts.length}, time range overlapping or reversed)")
        previous_end = facts.t_end_ns
    steps = sum(facts.length for facts in episodes)
    if 8 * steps > content_bytes:
        raise _Damage(f"the episode index claims {steps} steps, more than the file's chunks hold")


class DemoFile:
    """One MCAP demo file, opened for reading.

    `len(f)` episodes; `f[k]` reads episode k alone (only the chunks in its time range);
    iterating reads the file once, front to back, yielding episodes lazily. `f.episodes` lists
    every episode's facts without reading any step.

    A damaged or unfinished file (truncated, killed writer, flipped bits) raises DemoFileError
    naming the file and the damage, unless `salvage=True`: then every complete episode before
    the damage is readable and `f.damage` describes what was lost.
    """

    def __init__(self, path: str | os.PathLike, *, salvage: bool = False, verify: bool = False) -> None:
        self.path = Path(path)
        try:
            self._size = self.path.stat().st_size
            stream = open(self.path, "rb")
        except OSError as error:
            raise DemoFileError(f"{self.path}: cannot open: {error.strerror or error}") from error
        with stream:
            if self._size < len(MAGIC) or stream.read(len(MAGIC)) != MAGIC:
                raise DemoFileError(f"{self.path}: not an MCAP file (it does not start with the MCAP magic bytes)")
            index: _Index | None = None
            summary_damage: str | None = None
            try:
                index = self._read_summary(stream)
            except DemoFileError:
                raise
            except Exception as error:  # any malformed byte in the summary means: rebuild it by scanning
                summary_damage = str(error) if isinstance(error, _Damage) else f"unreadable summary ({type(error).__name__}: {error})"
            if index is not None and not index.dataset:
                self._check_dataset(index.dataset)  # a sound MCAP file from another tool (a ROS 2 bag): say so, not "damaged"
            if index is None and not salvage:
                raise DemoFileError(
                    f"{self.path}: damaged or unfinished ({summary_damage}); "
                    "`imitation info` shows how many episodes can be salvaged"
                )
            if index is None or verify:
                # A full scan checks every chunk's checksum, so it also finds damage the
                # summary cannot show (flipped bits inside the data).
                scanned = self._scan(stream)
                scanned.damage = scanned.damage or summary_damage
                # The scan reads the file in order, training through the summary's index: the
                # verdict must hold for both.
                unread = self._index_unreadable(index) if index is not None else None
                if scanned.damage is None and unread is not None:
                    scanned.damage = f"the summary's episode index does not fit the data ({unread})"
                if scanned.damage and not salvage:
                    raise DemoFileError(f"{self.path}: damaged ({scanned.damage})")
                if index is not None and scanned.damage and unread is None:
                    # The damage lies where the episode index never reads (an /episode marker, a
                    # message index): every episode is readable, as training will read it.
                    index.damage = f"{scanned.damage}; outside the data the episode index reads, so every episode is whole"
                elif index is None or scanned.damage:
                    index = scanned
        self._use(index)

    def _index_unreadable(self, index: _Index) -> str | None:
        """Why some episode `index` lists does not read (each chunk's checksum checked), or None."""
        self._use(index)
        try:
            self.read_episodes(range(len(index.episodes)))
        except (ImitationError, _Damage) as error:
            return str(error).replace(f"{self.path}: ", "")[:200]
        return None

    def _use(self, index: _Index) -> None:
        self._index = index
        self._check_dataset(index.dataset)
        self.env_id: str = index.dataset["env_id"]
        self.observation_space: gym.Space = space_from_json(index.dataset["observation_space"])
        self.action_space: gym.Space = space_from_json(index.dataset["action_space"])
        self.format_version = int(index.dataset["format_version"])
        self.dt = int(index.dataset.get("dt_ns", "1000000")) / 1e9
        self.source: str = index.dataset.get("source", "")
        self.creator: str = index.dataset.get("creator", "")
        self.user_metadata: dict[str, Any] = json.loads(index.dataset.get("user_metadata", "{}"))
        self.episodes: list[EpisodeFacts] = index.episodes
        self.damage: str | None = index.damage
        self._chunk_starts = [chunk.start_time for chunk in index.chunks]
        self._chunk_ends = [chunk.end_time for chunk in index.chunks]
        self._facts_by_end_time = {facts.t_end_ns: facts for facts in self.episodes}

    def _count_chunk(self, uncompressed_size: int) -> None:
        """Count a chunk's declared size before it is decompressed, and refuse a file whose
        chunks would expand beyond the limits (a small file of compressed zeros)."""
        if uncompressed_size > LIMITS.chunk_bytes:
            raise DemoFileError(f"{self.path}: {over_limit('uncompressed bytes of one chunk', uncompressed_size, 'chunk_bytes')}")
        self._expanded += uncompressed_size
        if self._expanded > max(FREE_EXPANSION_BYTES, LIMITS.expansion_ratio * self._size):
            raise DemoFileError(f"{self.path}: {over_limit(f'uncompressed bytes of its chunks (the file has {self._size})', self._expanded, 'expansion_ratio')}")

    # -- public API ---------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self.episodes)

    @property
    def num_transitions(self) -> int:
        return sum(facts.length for facts in self.episodes)

    @property
    def fingerprint(self) -> str:
        """The file's size and checksums of its dataset metadata, episode index and summary
        section: a run records it, and `--resume` refuses demos whose content changed since."""
        described = json.dumps(self._index.dataset, sort_keys=True) + to_json_text([facts.to_json() for facts in self.episodes])
        return f"{self._size}-{zlib.crc32(described.encode()):08x}-{self._summary_crc:08x}"

    @property
    def channels(self) -> list[str]:
        topics = [EPISODE_TOPIC if f is None else f.topic for f in self._index.channels.values()]
        return sorted(set(topics))

    def __getitem__(self, k: int) -> Episode:
        if not -len(self) <= k < len(self):
            raise IndexError(f"{self.path}: episode {k} out of range (the file holds {len(self)})")
        return self.read_episodes([k % len(self)])[0]

    def __iter__(self) -> Iterator[Episode]:
        for _, episode in self._read(self._index.chunks, keep=None, bulk=False):
            yield episode

    def read_episodes(self, indices: Sequence[int] | None = None) -> list[Episode]:
        """Episodes `indices` (all by default), in file order, reading each needed chunk once.

        Arrays are read-only views of the chunk buffers read for them (no copy beyond the read)."""
        if indices is None:
            return [episode for _, episode in self._read(self._index.chunks, keep=None, bulk=True)]
        wanted = set(indices)
        for k in wanted:
            if not 0 <= k < len(self):
                raise IndexError(f"{self.path}: episode {k} out of range (the file holds {len(self)})")
        needed: dict[int, _ChunkRef] = {}
        for k in wanted:
            for chunk in self._chunks_of(self.episodes[k]):
                needed[chunk.offset] = chunk
        chunks = sorted(needed.values(), key=lambda c: (c.start_time, c.offset))
        found = {facts.index: episode for facts, episode in self._read(chunks, keep=lambda f: f.index in wanted, bulk=True)}
        missing = wanted - set(found)
        if missing:
            raise DemoFileError(f"{self.path}: episode {min(missing)} is listed in the index but its data is missing")
        return [found[k] for k in sorted(wanted)]

    # -- internals ----------------------------------------------------------------------------

    def _chunks_of(self, facts: EpisodeFacts) -> list[_ChunkRef]:
        # Log times never decrease through the file, so chunk start and end times are both
        # sorted: the chunks overlapping [t_start, t_end] form one contiguous run.
        first = bisect.bisect_left(self._chunk_ends, facts.t_start_ns)
        last = bisect.bisect_right(self._chunk_starts, facts.t_end_ns)
        return self._index.chunks[first:last]

    def _read(
        self, chunks: Sequence[_ChunkRef], *, keep: Callable[[EpisodeFacts], bool] | None, bulk: bool
    ) -> Iterator[tuple[EpisodeFacts, Episode]]:
        """Assemble episodes from `chunks` (in file order); yield those `keep` accepts.

        `bulk`: the caller keeps everything, so read into two large buffers (raw records and
        decompressed content) instead of one buffer per chunk. Measured here, large numpy
        allocations (huge pages) fault in 2-3x faster than many 1 MiB ones; lazy iteration keeps
        memory bounded with per-chunk buffers instead."""
        if not chunks:
            return
        assembler = _EpisodeAssembler(self.observation_space, self.action_space, self._index.channels, self._facts_by_end_time)
        try:
            buffers = _ChunkBuffers(chunks) if bulk else None
        except _Damage as error:
            raise DemoFileError(f"{self.path}: {error}") from None
        with open(self.path, "rb") as stream:
            for chunk, decoded in _decode_chunks(stream.fileno(), chunks, buffers):
                yield from self._assemble(chunk, decoded, assembler, keep)

    def _assemble(
        self, chunk: _ChunkRef, decoded: Future, assembler: _EpisodeAssembler, keep: Callable[[EpisodeFacts], bool] | None
    ) -> Iterator[tuple[EpisodeFacts, Episode]]:
        """The episodes a decoded chunk completes, errors named by the chunk's offset."""
        try:
            content = decoded.result()
            for channel_id, log_time, data in _chunk_records(content, self._register_channel):
                result = assembler.add(channel_id, log_time, data, keep)
                if result is not None and result[1] is not None:
                    yield result[0], result[1]
        except _Damage as error:
            raise DemoFileError(f"{self.path}: damaged chunk at byte {chunk.offset}: {error}") from None
        except (ValueError, KeyError, TypeError, OverflowError, RecursionError) as error:  # RecursionError: JSON nested too deep
            raise DemoFileError(f"{self.path}: bad data in chunk at byte {chunk.offset}: {type(error).__name__}: {str(error)[:200]}") from None

    def _register_channel(self, channel: Channel) -> None:
        self._index.channels.setdefault(channel.id, _channel_field(channel))

    def _check_dataset(self, dataset: dict[str, str]) -> None:
        if not dataset:
            raise DemoFileError(
                f"{self.path}: an MCAP file but not an imitation demo file (no '{DATASET_METADATA}' metadata); "
                "convert it with `imitation convert`"
            )
        # The version comes first: a newer format may checksum differently.
        version_text = dataset.get("format_version", "")
        if not (version_text.isascii() and version_text.isdigit() and int(version_text) >= 1):
            raise DemoFileError(f"{self.path}: dataset metadata has no valid format_version ({version_text!r})")
        version = int(version_text)
        if version > FORMAT_VERSION:
            raise DemoFileError(
                f"{self.path}: format version {version} is newer than this reader supports ({FORMAT_VERSION}); upgrade imitation-mcap"
            )
        if dataset.get("crc32") != metadata_crc(dataset):
            raise DemoFileError(f"{self.path}: dataset metadata is corrupt (checksum mismatch)")
        for key in ("env_id", "observation_space", "action_space"):
            if key not in dataset:
                raise DemoFileError(f"{self.path}: dataset metadata lacks '{key}'")
        try:
            space_from_json(dataset["observation_space"])
            space_from_json(dataset["action_space"])
        except Exception as error:
            raise DemoFileError(f"{self.path}: bad space in dataset metadata: {error}") from None
        if not dataset.get("dt_ns", "1").isdigit():
            raise DemoFileError(f"{self.path}: dataset metadata has a bad dt_ns ({dataset['dt_ns']!r})")
        try:
            json.loads(dataset.get("user_metadata", "{}"))
        except (ValueError, RecursionError) as error:
            raise DemoFileError(f"{self.path}: dataset metadata has bad user_metadata JSON ({error})") from None

    def _read_summary(self, stream: Any) -> _Index:
        """The fast path: footer → summary (channels, chunk index, metadata index) → 2 records."""
        self._summary_crc = 0
        self._expanded = 0
        if self._size < len(MAGIC) * 2 + _FOOTER_LENGTH:
            raise _Damage("file too short to hold an MCAP footer")
        stream.seek(self._size - len(MAGIC) - _FOOTER_LENGTH)
        tail = stream.read(_FOOTER_LENGTH + len(MAGIC))
        if tail[-len(MAGIC) :] != MAGIC or tail[0] != _OP_FOOTER:
            raise _Damage("no MCAP footer: the file was truncated or its writer did not finish")
        footer = Footer.read(ReadDataStream(BytesIO(tail[9:-len(MAGIC)])))
        if footer.summary_start == 0:
            raise _Damage("the file has no summary section")
        footer_start = self._size - len(MAGIC) - _FOOTER_LENGTH
        if not len(MAGIC) <= footer.summary_start <= footer_start:
            raise _Damage("footer points outside the file")
        stream.seek(footer.summary_start)
        summary = stream.read(footer_start - footer.summary_start)
        self._summary_crc = footer.summary_crc
        if footer.summary_crc != 0:
            expected = zlib.crc32(tail[:9 + 16], zlib.crc32(summary))
            if expected != footer.summary_crc:
                raise _Damage("summary section checksum mismatch")
        channels: dict[int, _Field | None] = {}
        chunks: list[_ChunkRef] = []
        metadata_offsets: dict[str, tuple[int, int]] = {}
        for opcode, body in _records(summary, 0, len(summary)):
            if opcode == _OP_CHANNEL:
                channel = Channel.read(ReadDataStream(BytesIO(body)))
                channels[channel.id] = _channel_field(channel)
            elif opcode == _OP_CHUNK_INDEX:
                entry = ChunkIndex.read(ReadDataStream(BytesIO(body)))
                self._count_chunk(entry.uncompressed_size)
                chunks.append(
                    _ChunkRef(entry.chunk_start_offset, entry.chunk_length, entry.message_start_time, entry.message_end_time, entry.uncompressed_size)
                )
            elif opcode == _OP_METADATA_INDEX:
                entry = MetadataIndex.read(ReadDataStream(BytesIO(body)))
                metadata_offsets[entry.name] = (entry.offset, entry.length)
        if DATASET_METADATA not in metadata_offsets:
            return _Index({}, channels, chunks, [])
        dataset = self._read_metadata(stream, *metadata_offsets[DATASET_METADATA])
        self._check_dataset(dataset)
        if EPISODES_METADATA not in metadata_offsets:
            raise _Damage("the episode index is missing")
        listing = self._read_metadata(stream, *metadata_offsets[EPISODES_METADATA])
        if listing.get("crc32") != metadata_crc(listing):
            raise _Damage("the episode index is corrupt (checksum mismatch)")
        episodes = [EpisodeFacts.from_json(item) for item in json.loads(listing["episodes"])]
        for chunk in chunks:
            if chunk.offset + chunk.length > footer.summary_start:
                raise _Damage("chunk index points past the data section")
        _check_episode_index(episodes, sum(chunk.uncompressed_size for chunk in chunks))
        chunks.sort(key=lambda c: (c.start_time, c.offset))
        return _Index(dataset, channels, chunks, episodes)

    def _read_metadata(self, stream: Any, offset: int, length: int) -> dict[str, str]:
        stream.seek(offset)
        record = stream.read(length)
        if len(record) != length or length < 9 or record[0] != _OP_METADATA:
            raise _Damage(f"metadata index points at a non-metadata record (byte {offset})")
        try:
            return dict(Metadata.read(ReadDataStream(BytesIO(record[9:]))).metadata)
        except Exception as error:
            raise _Damage(f"unreadable metadata record at byte {offset}: {error}") from None

    def _scan(self, stream: Any) -> _Index:
        """Salvage: read the data section record by record, keeping every complete episode."""
        self._expanded = 0
        data = mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ)
        dataset: dict[str, str] = {}
        channels: dict[int, _Field | None] = {}
        chunks: list[_ChunkRef] = []
        episodes: list[EpisodeFacts] = []
        damage: str | None = None
        assembler: _EpisodeAssembler | None = None
        pending_chunks: list[_ChunkRef] = []
        messages_after_last_episode = 0
        offset = len(MAGIC)
        try:
            for opcode, body, record_offset in _records_with_offsets(data, offset, len(data)):
                if opcode == _OP_METADATA:
                    metadata = Metadata.read(ReadDataStream(BytesIO(body)))
                    if metadata.name == DATASET_METADATA and not dataset:
                        dataset = dict(metadata.metadata)
                        self._check_dataset(dataset)
                        assembler = _EpisodeAssembler(
                            space_from_json(dataset["observation_space"]), space_from_json(dataset["action_space"]), channels
                        )
                elif opcode == _OP_CHANNEL:
                    channel = Channel.read(ReadDataStream(BytesIO(body)))
                    channels.setdefault(channel.id, _channel_field(channel))
                elif opcode == _OP_CHUNK:
                    if assembler is None:
                        raise _Damage("data before the dataset metadata")
                    start_time, end_time, uncompressed_size = struct.unpack_from("<QQQ", body)
                    self._count_chunk(uncompressed_size)
                    ref = _ChunkRef(record_offset, 9 + len(body), start_time, end_time, uncompressed_size)
                    pending_chunks.append(ref)
                    record = data[record_offset : record_offset + ref.length]
                    content = _decode_chunk(memoryview(record))
                    for channel_id, log_time, message in _chunk_records(content, lambda c: channels.setdefault(c.id, _channel_field(c))):
                        result = assembler.add(channel_id, log_time, message)
                        messages_after_last_episode += 1
                        if result is not None:
                            episodes.append(result[0])
                            chunks.extend(pending_chunks)
                            pending_chunks = [ref]
                            messages_after_last_episode = 0
                elif opcode in (_OP_DATA_END, _OP_FOOTER):
                    break
            else:
                damage = "truncated: the file ends before its data section does"
        except DemoFileError:
            raise
        except _Damage as error:
            damage = str(error)
        except Exception as error:
            damage = f"unreadable record ({type(error).__name__}: {error})"
        if not dataset:
            raise DemoFileError(f"{self.path}: damaged before any dataset metadata ({damage or 'none found'})")
        if damage is None and messages_after_last_episode:
            damage = "an incomplete episode after the last complete one"
        unique = sorted({(c.start_time, c.offset): c for c in chunks}.values(), key=lambda c: (c.start_time, c.offset))
        return _Index(dataset, channels, unique, episodes, damage)


class _Damage(Exception):
    """Internal: a structural problem found while reading; becomes a DemoFileError or salvage."""


def _channel_field(channel: Channel) -> _Field | None:
    if channel.topic == EPISODE_TOPIC:
        return None
    return _Field.from_channel(channel.topic, dict(channel.metadata))


def _records(buffer: bytes | memoryview, start: int, end: int) -> Iterator[tuple[int, memoryview]]:
    for opcode, body, _ in _records_with_offsets(buffer, start, end):
        yield opcode, body


def _records_with_offsets(buffer: bytes | memoryview, start: int, end: int) -> Iterator[tuple[int, memoryview, int]]:
    """(opcode, record body, record offset) for each record in buffer[start:end], bounds-checked."""
    view = memoryview(buffer)
    offset = start
    while offset < end:
        if end - offset < 9:
            raise _Damage(f"truncated record header at byte {offset}")
        opcode, length = _RECORD_HEADER.unpack_from(view, offset)
        body_start = offset + 9
        if length > end - body_start:
            raise _Damage(f"truncated: record at byte {offset} needs {length} bytes, {end - body_start} remain")
        yield opcode, view[body_start : body_start + length], offset
        offset = body_start + length


@dataclass(frozen=True)
class _ChunkHeader:
    compression: str
    uncompressed_size: int
    uncompressed_crc: int
    payload: memoryview  # the compressed records


def _chunk_header(record: memoryview) -> _ChunkHeader:
    """Parse one Chunk record (opcode and length included) down to its compressed payload."""
    if len(record) < 9 or record[0] != _OP_CHUNK:
        raise _Damage("chunk index points at a non-chunk record")
    body = record[9:]
    try:
        _, _, uncompressed_size, uncompressed_crc, compression_length = struct.unpack_from("<QQQII", body)
        position = 32
        compression = bytes(body[position : position + compression_length]).decode()
        position += compression_length
        (data_length,) = struct.unpack_from("<Q", body, position)
        position += 8
    except (struct.error, UnicodeDecodeError) as error:
        raise _Damage(f"bad chunk header ({error})") from None
    payload = body[position : position + data_length]
    if len(payload) != data_length:
        raise _Damage("chunk data is truncated")
    if compression not in ("zstd", "lz4", ""):
        raise _Damage(f"unsupported chunk compression {compression!r}")
    if uncompressed_size > LIMITS.chunk_bytes:
        raise _Damage(f"the chunk claims {uncompressed_size} bytes uncompressed, more than the limit chunk_bytes={LIMITS.chunk_bytes}")
    return _ChunkHeader(compression, uncompressed_size, uncompressed_crc, payload)


def _decode_chunk(record: memoryview, out: memoryview | None = None) -> memoryview | bytes:
    """The checked, decompressed content of one Chunk record (zstd, lz4 or none), decompressed
    into `out` when given (it must hold exactly the uncompressed size).

    Decompression and CRC-32 release the GIL, so chunks decode in parallel threads."""
    header = _chunk_header(record)
    compressed, uncompressed_size = header.payload, header.uncompressed_size
    content: memoryview | bytes
    if header.compression == "zstd":
        try:
            if out is not None and len(out) == uncompressed_size:
                content = _zstd_decompress_into(compressed, out)
            else:
                content = zstandard.ZstdDecompressor().decompress(compressed, max_output_size=uncompressed_size)
        except zstandard.ZstdError as error:
            raise _Damage(f"zstd cannot decompress it ({error})") from None
    elif header.compression == "lz4":
        import lz4.frame  # only files from other writers use lz4

        try:
            content = lz4.frame.decompress(bytes(compressed))
        except RuntimeError as error:
            raise _Damage(f"lz4 cannot decompress it ({error})") from None
    else:
        content = compressed  # a view of the record's own buffer: no copy
    if len(content) != uncompressed_size:
        raise _Damage("decompressed size differs from the chunk header")
    if header.uncompressed_crc != 0 and zlib.crc32(content) != header.uncompressed_crc:
        raise _Damage("checksum mismatch: the chunk's bytes were altered")
    return content


def _zstd_decompress_into(compressed: memoryview, out: memoryview) -> memoryview:
    reader = zstandard.ZstdDecompressor().stream_reader(compressed)
    filled = 0
    while filled < len(out):
        count = reader.readinto(out[filled:])
        if count == 0:
            raise _Damage("zstd data ends before the chunk's uncompressed size")
        filled += count
    return out


class _ChunkBuffers:
    """One large buffer for the raw records of many chunks and one for their decompressed
    content; each chunk gets its slices."""

    def __init__(self, chunks: Sequence[_ChunkRef]) -> None:
        raw, content = sum(c.length for c in chunks), sum(c.uncompressed_size for c in chunks)
        try:
            self.raw = memoryview(np.empty(raw, dtype=np.uint8))
            self.content = memoryview(np.empty(content, dtype=np.uint8))
        except MemoryError:
            raise _Damage(f"its chunks add up to {(raw + content) / 2**30:.1f} GiB, more than this machine can hold") from None
        self._slices: dict[int, tuple[memoryview, memoryview]] = {}
        raw_at = content_at = 0
        for c in chunks:
            self._slices[c.offset] = (self.raw[raw_at : raw_at + c.length], self.content[content_at : content_at + c.uncompressed_size])
            raw_at += c.length
            content_at += c.uncompressed_size

    def __getitem__(self, chunk: _ChunkRef) -> tuple[memoryview, memoryview]:
        return self._slices[chunk.offset]


def _read_chunk(fd: int, chunk: _ChunkRef, buffers: _ChunkBuffers | None) -> memoryview | bytes:
    # pread into our own buffer, not mmap: measured here, faulting in a mapped file's pages
    # varied 4x between runs.
    if buffers is None:
        record: memoryview | bytes = os.pread(fd, chunk.length, chunk.offset)
        out = None
    else:
        record, out = buffers[chunk]
        if os.preadv(fd, [record], chunk.offset) != chunk.length:
            raise _Damage("chunk is truncated")
    if len(record) != chunk.length:
        raise _Damage("chunk is truncated")
    return _decode_chunk(memoryview(record), out)


def _decode_chunks(fd: int, chunks: Sequence[_ChunkRef], buffers: _ChunkBuffers | None) -> Iterator[tuple[_ChunkRef, Future]]:
    """Read and decode chunks on a small thread pool (reading, decompression and CRC-32 release
    the GIL), a bounded window ahead of the consumer, in order.

    A chunk that cannot be decoded raises _Damage from its future's result()."""
    threads = min(len(chunks), os.cpu_count() or 1, 8)
    window: deque[tuple[_ChunkRef, Future]] = deque()
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for chunk in chunks:
            window.append((chunk, pool.submit(_read_chunk, fd, chunk, buffers)))
            if len(window) > 2 * threads:
                yield window.popleft()
        while window:
            yield window.popleft()


def _chunk_records(content: memoryview | bytes, on_channel: Callable[[Channel], Any]) -> Iterator[tuple[int, int, memoryview]]:
    """(channel id, log time, data) of each message in a decoded chunk; channels are registered."""
    view = memoryview(content)
    for opcode, inner in _records(view, 0, len(view)):
        if opcode == _OP_MESSAGE:
            channel_id, _, log_time, _ = _MESSAGE_HEADER.unpack_from(inner)
            yield channel_id, log_time, inner[_MESSAGE_HEADER.size :]
        elif opcode == _OP_CHANNEL:
            on_channel(Channel.read(ReadDataStream(BytesIO(inner))))
        elif opcode == _OP_SCHEMA:
            Schema.read(ReadDataStream(BytesIO(inner)))


class DemoDataset:
    """Several demo files of one environment as one dataset of episodes (shards, DAgger rounds).

    Indexing is global: episodes of the first file come first. Every file must share the env id
    and the observation and action spaces; a mismatch names the file.
    """

    def __init__(self, paths: Sequence[str | os.PathLike] | str | os.PathLike, *, salvage: bool = False) -> None:
        if isinstance(paths, (str, os.PathLike)):
            paths = [paths]
        if not paths:
            raise ImitationError("no demo files given")
        self.files = [DemoFile(path, salvage=salvage) for path in paths]
        first = self.files[0]
        for other in self.files[1:]:
            if other.env_id != first.env_id:
                raise DemoFileError(f"{other.path}: env id {other.env_id!r} differs from {first.path}'s {first.env_id!r}")
            for name in ("observation_space", "action_space"):
                if not spaces_equal(getattr(other, name), getattr(first, name)):
                    raise DemoFileError(f"{other.path}: {name.replace('_', ' ')} differs from {first.path}'s")
        self.env_id = first.env_id
        self.observation_space = first.observation_space
        self.action_space = first.action_space
        self._offsets = np.cumsum([0] + [len(f) for f in self.files])

    def __len__(self) -> int:
        return int(self._offsets[-1])

    @property
    def episodes(self) -> list[EpisodeFacts]:
        return [facts for f in self.files for facts in f.episodes]

    @property
    def num_transitions(self) -> int:
        return sum(f.num_transitions for f in self.files)

    def locate(self, k: int) -> tuple[DemoFile, int]:
        """The file that holds dataset-wide episode k, and k's index within that file."""
        file_index = int(np.searchsorted(self._offsets, k, side="right")) - 1
        return self.files[file_index], k - int(self._offsets[file_index])

    def __getitem__(self, k: int) -> Episode:
        if not -len(self) <= k < len(self):
            raise IndexError(f"episode {k} out of range (the dataset holds {len(self)})")
        k %= len(self)
        file_index = int(np.searchsorted(self._offsets, k, side="right")) - 1
        return self.files[file_index][k - int(self._offsets[file_index])]

    def __iter__(self) -> Iterator[Episode]:
        for f in self.files:
            yield from f

    def read_episodes(self, indices: Sequence[int] | None = None) -> list[Episode]:
        """Episodes `indices` (dataset-wide; all by default) in ascending order, each chunk read once."""
        if indices is None:
            return [episode for f in self.files for episode in f.read_episodes()]
        chosen = sorted(set(int(k) for k in indices))
        if chosen and not 0 <= chosen[0] <= chosen[-1] < len(self):
            raise IndexError(f"episode indices must lie in [0, {len(self)}), got {chosen[0]}..{chosen[-1]}")
        episodes: list[Episode] = []
        for file_index, f in enumerate(self.files):
            start, end = int(self._offsets[file_index]), int(self._offsets[file_index + 1])
            local = [k - start for k in chosen if start <= k < end]
            if local:
                episodes += f.read_episodes(local)
        return episodes

"""Reading demo files: `DemoFile` finds episodes through the file's summary (footer, chunk
index, episode index) and assembles them from their chunks' blocks; a damaged or unfinished
file is refused with the damage named or, with `salvage=True`, scanned record by record for
every complete episode.

The salvage scan stays here rather than in a module of its own: it builds the same `_Index`
with the same `_EpisodeAssembler`, and shares DemoFile's dataset checks and expansion limits."""

from __future__ import annotations

import bisect
import json
import os
import struct
import zlib
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, ChunkIndex, Footer, Metadata, MetadataIndex

from imitation.data.mcap.format import (
    DATASET_METADATA,
    EPISODE_TOPIC,
    EPISODES_METADATA,
    EXECUTED_FIELD,
    FORMAT_VERSION,
    HUMAN_FIELD,
    INTERVENTION_FIELDS,
    MAGIC,
    PROPOSED_FIELD,
    REWARD_FIELD,
    TIME_FIELD,
    EpisodeFacts,
    Field,
    channel_field,
    fields_for,
    metadata_crc,
    to_json_text,
)
from imitation.data.mcap.images import FrameError, FrameLimitError, FrameMap, decode_frames, is_image_leaf
from imitation.data.mcap.records import (
    OP_CHANNEL,
    OP_CHUNK,
    OP_CHUNK_INDEX,
    OP_DATA_END,
    OP_FOOTER,
    OP_METADATA,
    OP_METADATA_INDEX,
    ChunkBuffers,
    ChunkRef,
    Damage,
    chunk_records,
    decode_chunk,
    decode_chunks,
    iter_records,
    iter_records_with_offsets,
)
from imitation.data.mcap.source import ByteSource, ReadCounter, is_url, open_source
from imitation.data.spaces import space_from_json
from imitation.data.types import Episode, Interventions, Tree, stack_samples, tree_from_leaves
from imitation.errors import DemoFileError, ImitationError
from imitation.limits import FREE_EXPANSION_BYTES, LIMITS, ImageBudget, over_limit

_FOOTER_LENGTH = 1 + 8 + 20


@dataclass
class _Index:
    """Everything needed to read episodes: from the summary, or rebuilt by a salvage scan."""

    dataset: dict[str, str]
    channels: dict[int, Field | None]  # None: the /episode channel
    chunks: list[ChunkRef]
    episodes: list[EpisodeFacts]
    damage: str | None = None


class _EpisodeAssembler:
    """Collects block messages in file order and emits an Episode when its marker arrives."""

    def __init__(
        self,
        observation_space: gym.Space,
        action_space: gym.Space,
        channels: dict[int, Field | None],
        facts_by_end_time: dict[int, EpisodeFacts] | None = None,
        transform: FrameMap | None = None,
    ):
        self._channels = channels
        self._transform = transform  # done to every frame of the observations as it is decoded
        # Known facts (from a checked index) by t_end_ns, the marker's log time, which is unique
        # per episode: looking them up is cheaper than parsing each marker's JSON again.
        self._facts_by_end_time = facts_by_end_time or {}
        self._action_space = action_space
        fields = fields_for(observation_space, action_space)
        self._observation_fields = [f for f in fields if f.kind == "observation"]
        self._action_fields = [f for f in fields if f.kind == "action"]
        self._blocks: dict[str, list[bytes | memoryview]] = {}
        # Set by the salvage scan, which decodes episodes as it finds them (a file read through
        # its summary is checked whole when it is opened).
        self.budget: ImageBudget | None = None

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
        if self.budget is not None:
            _take(self.budget, (facts.length + 1) * image_row_bytes(self._channels))
        return facts, self._build(facts, blocks)

    def _build(self, facts: EpisodeFacts, blocks: dict[str, list[bytes | memoryview]]) -> Episode:
        steps = facts.length

        images = {c.topic: c for c in self._channels.values() if c is not None and c.codec is not None}

        def rows(f: Field, count: int) -> np.ndarray:
            parts = blocks.get(f.topic, [])
            if f.topic in images:
                return _frames(f, images[f.topic], parts, count, facts.index, self._transform)
            if f.row_nbytes == 0:
                return np.zeros((count, *f.shape), dtype=f.native_dtype)
            data = parts[0] if len(parts) == 1 else b"".join(parts)
            if len(data) != count * f.row_nbytes:
                raise ValueError(f"episode {facts.index}: {f.topic} holds {len(data) // f.row_nbytes} rows, expected {count}")
            array = np.frombuffer(data, dtype=f.dtype).reshape((count, *f.shape))
            return array if f.dtype == f.native_dtype else array.astype(f.native_dtype)

        def tree(fields: list[Field], count: int) -> Tree:
            return tree_from_leaves({f.path: rows(f, count) for f in fields})

        infos = None
        if "/info" in blocks:
            infos = [info for part in blocks["/info"] for info in json.loads(bytes(part))]
        timestamps = None
        if "/time" in blocks:
            timestamps = rows(TIME_FIELD, steps + 1) - facts.time_shift_ns
        interventions = None
        if any(f.topic in blocks for f in INTERVENTION_FIELDS):
            interventions = _interventions(blocks, steps, self._action_space, facts.index)
        return Episode(
            observations=tree(self._observation_fields, steps + 1),
            actions=tree(self._action_fields, steps),
            rewards=rows(REWARD_FIELD, steps),
            terminated=facts.terminated,
            truncated=facts.truncated,
            infos=infos,
            timestamps=timestamps,
            interventions=interventions,
            metadata=facts.metadata,
        )


def _take(budget: ImageBudget, amount: int) -> None:
    """`budget.take`, refusing as the reader does: a DemoFileError, which neither the summary's
    nor the salvage scan's handling of damage takes for damage."""
    try:
        budget.take(amount)
    except ImitationError as error:
        raise DemoFileError(str(error)) from None


def image_row_bytes(channels: dict[int, Field | None]) -> int:
    """Bytes one step's frames decode to, as the image channels declare them (0 without any). A
    channel that declares other than its space's leaf is refused before a frame is decoded."""
    return sum(f.row_nbytes for f in channels.values() if f is not None and f.codec is not None)


def _interventions(
    blocks: dict[str, list[bytes | memoryview]], steps: int, action_space: gym.Space, episode: int
) -> Interventions:
    """An episode's intervention channels: T messages on each per-step channel (§6.7)."""

    def values(f: Field, key: str) -> list[Any]:
        messages = blocks.get(f.topic, [])
        if len(messages) != steps:
            raise ValueError(f"episode {episode}: {f.topic} holds {len(messages)} messages, expected {steps}")
        return [json.loads(bytes(message))[key] for message in messages]

    human = values(HUMAN_FIELD, "human")
    if not all(isinstance(value, bool) for value in human):
        raise ValueError(f"episode {episode}: {HUMAN_FIELD.topic} holds a value that is not true or false")
    return Interventions(
        human=np.array(human, dtype=bool).reshape(steps),
        proposed_actions=stack_samples(values(PROPOSED_FIELD, "action"), action_space),
        executed_actions=stack_samples(values(EXECUTED_FIELD, "action"), action_space),
    )


def _frames(
    f: Field, channel: Field, frames: list[bytes | memoryview], count: int, episode: int, transform: FrameMap | None = None
) -> np.ndarray:
    """The rows of an image channel: one message per frame, decoded to the space's leaf (and
    `transform`ed, frame by frame)."""
    assert channel.codec is not None
    if channel.dtype != f.dtype or channel.shape != f.shape or not is_image_leaf(f.dtype, f.shape):
        raise ValueError(
            f"{f.topic}: an image channel declaring {channel.dtype} {list(channel.shape)}, but the space's leaf is {f.dtype} "
            f"{list(f.shape)}, not an image"
        )
    # Counted before anything is allocated: the frames are messages the file really holds.
    if len(frames) != count:
        raise ValueError(f"episode {episode}: {f.topic} holds {len(frames)} frames, expected {count}")
    return decode_frames(channel.codec, f.shape, frames, topic=f.topic, episode=episode, transform=transform)


def _check_episode_index(episodes: list[EpisodeFacts], content_bytes: int) -> None:
    """The episode index must be what a writer could have written: episodes numbered in order,
    in disjoint increasing time ranges, and no more steps than the chunks hold 8-byte rewards
    for. A forged index (duplicated episodes, 10^15 steps) is damage, which the scan rebuilds."""
    previous_end = -1
    for position, facts in enumerate(episodes):
        if facts.index != position:
            raise Damage(f"the episode index is inconsistent (entry {position} is numbered {facts.index})")
        if facts.length < 0 or facts.t_start_ns > facts.t_end_ns or facts.t_start_ns <= previous_end:
            raise Damage(
                f"the episode index is inconsistent (episode {position}: length {facts.length}, time range overlapping or "
                "reversed)"
            )
        previous_end = facts.t_end_ns
    steps = sum(facts.length for facts in episodes)
    if 8 * steps > content_bytes:
        raise Damage(f"the episode index claims {steps} steps, more than the file's chunks hold")


class DemoFile:
    """One MCAP demo file, opened for reading.

    `len(f)` episodes; `f[k]` reads episode k alone (only the chunks in its time range);
    iterating reads the file once, front to back, yielding episodes lazily. `f.episodes` lists
    every episode's facts without reading any step.

    A damaged or unfinished file (truncated, killed writer, flipped bits) raises DemoFileError
    naming the file and the damage, unless `salvage=True`: then every complete episode before
    the damage is readable and `f.damage` describes what was lost.

    `path` may be a URL that fsspec reads (http(s)://, s3://, gs://, memory://, ...): opening
    reads only the footer, the summary and the two metadata records it points at, and each
    episode read fetches only its chunks, by range requests (`bytes_read`, `requests` count them).
    """

    def __init__(self, path: str | os.PathLike, *, salvage: bool = False, verify: bool = False) -> None:
        # A URL stays as given: Path() would turn "http://host" into "http:/host".
        self.path: Path | str = os.fspath(path) if is_url(path) else Path(path)
        self._counter = ReadCounter()
        with open_source(self.path, self._counter) as stream:
            self.size = stream.size
            if self.size < len(MAGIC) or stream.read(0, len(MAGIC)) != MAGIC:
                raise DemoFileError(f"{self.path}: not an MCAP file (it does not start with the MCAP magic bytes)")
            index: _Index | None = None
            summary_damage: str | None = None
            try:
                index = self._read_summary(stream)
            except DemoFileError:
                raise
            except Exception as error:  # any malformed byte in the summary means: rebuild it by scanning
                summary_damage = (
                    str(error) if isinstance(error, Damage) else f"unreadable summary ({type(error).__name__}: {error})"
                )
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
        except (ImitationError, Damage) as error:
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
        # How the terminated/truncated flags were decided; None in files that do not say (older ones).
        self.end_flags: dict[str, Any] | None = json.loads(index.dataset.get("end_flags", "null"))
        self.episodes: list[EpisodeFacts] = index.episodes
        self.damage: str | None = index.damage
        self._chunk_starts = [chunk.start_time for chunk in index.chunks]
        self._chunk_ends = [chunk.end_time for chunk in index.chunks]
        self._facts_by_end_time = {facts.t_end_ns: facts for facts in self.episodes}

    def _count_chunk(self, uncompressed_size: int) -> None:
        """Count a chunk's declared size before it is decompressed, and refuse a file whose
        chunks would expand beyond the limits (a small file of compressed zeros)."""
        if uncompressed_size > LIMITS.chunk_bytes:
            raise DemoFileError(
                f"{self.path}: {over_limit('uncompressed bytes of one chunk', uncompressed_size, 'chunk_bytes')}"
            )
        self._expanded += uncompressed_size
        if self._expanded > max(FREE_EXPANSION_BYTES, LIMITS.expansion_ratio * self.size):
            what = f"uncompressed bytes of its chunks (the file has {self.size})"
            raise DemoFileError(f"{self.path}: {over_limit(what, self._expanded, 'expansion_ratio')}")

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
        described = json.dumps(self._index.dataset, sort_keys=True) + to_json_text(
            [facts.to_json() for facts in self.episodes]
        )
        return f"{self.size}-{zlib.crc32(described.encode()):08x}-{self._summary_crc:08x}"

    @property
    def bytes_read(self) -> int:
        """Bytes read from the file or fetched from its URL since it was opened, opening included."""
        return self._counter.bytes

    @property
    def requests(self) -> int:
        """Reads made (range requests, for a URL) since the file was opened, opening included."""
        return self._counter.requests

    def byte_source(self) -> ByteSource:
        """A reading session of the file's bytes by offset (close it, or use it in `with`); its
        reads count toward `bytes_read` and `requests`."""
        return open_source(self.path, self._counter, self.size)

    @property
    def channels(self) -> list[str]:
        topics = [EPISODE_TOPIC if f is None else f.topic for f in self._index.channels.values()]
        return sorted(set(topics))

    @property
    def channel_fields(self) -> dict[int, Field | None]:
        """What each channel id carries (None: the episode markers), for readers of raw chunks."""
        return self._index.channels

    def chunks_of(self, facts: EpisodeFacts) -> list[ChunkRef]:
        """The chunks that hold an episode's messages, in file order."""
        # Log times never decrease through the file, so chunk start and end times are both
        # sorted: the chunks overlapping [t_start, t_end] form one contiguous run.
        first = bisect.bisect_left(self._chunk_ends, facts.t_start_ns)
        last = bisect.bisect_right(self._chunk_starts, facts.t_end_ns)
        return self._index.chunks[first:last]

    def __getitem__(self, k: int) -> Episode:
        if not -len(self) <= k < len(self):
            raise IndexError(f"{self.path}: episode {k} out of range (the file holds {len(self)})")
        return self.read_episodes([k % len(self)])[0]

    def __iter__(self) -> Iterator[Episode]:
        for _, episode in self._read(self._index.chunks, keep=None, bulk=False):
            yield episode

    def read_episodes(self, indices: Sequence[int] | None = None, *, transform: FrameMap | None = None) -> list[Episode]:
        """Episodes `indices` (all by default), in file order, reading each needed chunk once;
        with `transform`, the observations' frames as it makes them, each as it is decoded.

        Arrays are read-only views of the chunk buffers read for them (no copy beyond the read)."""
        if indices is None:
            return [episode for _, episode in self._read(self._index.chunks, keep=None, bulk=True, transform=transform)]
        wanted = set(indices)
        for k in wanted:
            if not 0 <= k < len(self):
                raise IndexError(f"{self.path}: episode {k} out of range (the file holds {len(self)})")
        needed: dict[int, ChunkRef] = {}
        for k in wanted:
            for chunk in self.chunks_of(self.episodes[k]):
                needed[chunk.offset] = chunk
        chunks = sorted(needed.values(), key=lambda c: (c.start_time, c.offset))
        read = self._read(chunks, keep=lambda f: f.index in wanted, bulk=True, transform=transform)
        found = {facts.index: episode for facts, episode in read}
        missing = wanted - set(found)
        if missing:
            raise DemoFileError(f"{self.path}: episode {min(missing)} is listed in the index but its data is missing")
        return [found[k] for k in sorted(wanted)]

    # -- internals ----------------------------------------------------------------------------

    def _read(
        self,
        chunks: Sequence[ChunkRef],
        *,
        keep: Callable[[EpisodeFacts], bool] | None,
        bulk: bool,
        transform: FrameMap | None = None,
    ) -> Iterator[tuple[EpisodeFacts, Episode]]:
        """Assemble episodes from `chunks` (in file order); yield those `keep` accepts.

        `bulk`: the caller keeps everything, so read into two large buffers (raw records and
        decompressed content) instead of one buffer per chunk: large allocations (huge pages) fault
        in faster than many 1 MiB ones (bench/RESULTS.md). Lazy iteration keeps memory bounded with
        per-chunk buffers instead."""
        if not chunks:
            return
        assembler = _EpisodeAssembler(
            self.observation_space, self.action_space, self._index.channels, self._facts_by_end_time, transform
        )
        try:
            buffers = ChunkBuffers(chunks) if bulk else None
        except Damage as error:
            raise DemoFileError(f"{self.path}: {error}") from None
        with self.byte_source() as stream:
            for chunk, decoded in decode_chunks(stream, chunks, buffers):
                yield from self._assemble(chunk, decoded, assembler, keep)

    def _assemble(
        self, chunk: ChunkRef, decoded: Future, assembler: _EpisodeAssembler, keep: Callable[[EpisodeFacts], bool] | None
    ) -> Iterator[tuple[EpisodeFacts, Episode]]:
        """The episodes a decoded chunk completes, errors named by the chunk's offset."""
        try:
            content = decoded.result()
            for channel_id, log_time, data in chunk_records(content, self._register_channel):
                result = assembler.add(channel_id, log_time, data, keep)
                if result is not None and result[1] is not None:
                    yield result[0], result[1]
        except Damage as error:
            raise DemoFileError(f"{self.path}: damaged chunk at byte {chunk.offset}: {error}") from None
        except FrameError as error:
            raise DemoFileError(f"{self.path}: {error}") from None
        except (
            ValueError,
            KeyError,
            TypeError,
            OverflowError,
            RecursionError,
        ) as error:  # RecursionError: JSON nested too deep
            raise DemoFileError(
                f"{self.path}: bad data in chunk at byte {chunk.offset}: {type(error).__name__}: {str(error)[:200]}"
            ) from None

    def _register_channel(self, channel: Channel) -> None:
        self._index.channels.setdefault(channel.id, channel_field(channel))

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
                f"{self.path}: format version {version} is newer than this reader supports ({FORMAT_VERSION}); upgrade "
                "imitation-mcap"
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
        try:
            end_flags = json.loads(dataset.get("end_flags", "null"))
        except (ValueError, RecursionError) as error:
            end_flags = error
        if not (end_flags is None or isinstance(end_flags, dict)):
            raise DemoFileError(f"{self.path}: dataset metadata has bad end_flags (not a JSON object: {str(end_flags)[:100]})")

    def _read_summary(self, stream: ByteSource) -> _Index:
        """The fast path: footer → summary (channels, chunk index, metadata index) → 2 records."""
        self._summary_crc = 0
        self._expanded = 0
        if self.size < len(MAGIC) * 2 + _FOOTER_LENGTH:
            raise Damage("file too short to hold an MCAP footer")
        tail = stream.read(self.size - len(MAGIC) - _FOOTER_LENGTH, _FOOTER_LENGTH + len(MAGIC))
        if tail[-len(MAGIC) :] != MAGIC or tail[0] != OP_FOOTER:
            raise Damage("no MCAP footer: the file was truncated or its writer did not finish")
        footer = Footer.read(ReadDataStream(BytesIO(tail[9 : -len(MAGIC)])))
        if footer.summary_start == 0:
            raise Damage("the file has no summary section")
        footer_start = self.size - len(MAGIC) - _FOOTER_LENGTH
        if not len(MAGIC) <= footer.summary_start <= footer_start:
            raise Damage("footer points outside the file")
        summary = stream.read(footer.summary_start, footer_start - footer.summary_start)
        self._summary_crc = footer.summary_crc
        if footer.summary_crc != 0:
            expected = zlib.crc32(tail[: 9 + 16], zlib.crc32(summary))
            if expected != footer.summary_crc:
                raise Damage("summary section checksum mismatch")
        channels: dict[int, Field | None] = {}
        chunks: list[ChunkRef] = []
        metadata_offsets: dict[str, tuple[int, int]] = {}
        for opcode, body in iter_records(summary, 0, len(summary)):
            if opcode == OP_CHANNEL:
                channel = Channel.read(ReadDataStream(BytesIO(body)))
                channels[channel.id] = channel_field(channel)
            elif opcode == OP_CHUNK_INDEX:
                entry = ChunkIndex.read(ReadDataStream(BytesIO(body)))
                self._count_chunk(entry.uncompressed_size)
                chunks.append(
                    ChunkRef(
                        entry.chunk_start_offset,
                        entry.chunk_length,
                        entry.message_start_time,
                        entry.message_end_time,
                        entry.uncompressed_size,
                    )
                )
            elif opcode == OP_METADATA_INDEX:
                entry = MetadataIndex.read(ReadDataStream(BytesIO(body)))
                metadata_offsets[entry.name] = (entry.offset, entry.length)
        if DATASET_METADATA not in metadata_offsets:
            return _Index({}, channels, chunks, [])
        dataset = self._read_metadata(stream, *metadata_offsets[DATASET_METADATA])
        self._check_dataset(dataset)
        if EPISODES_METADATA not in metadata_offsets:
            raise Damage("the episode index is missing")
        listing = self._read_metadata(stream, *metadata_offsets[EPISODES_METADATA])
        if listing.get("crc32") != metadata_crc(listing):
            raise Damage("the episode index is corrupt (checksum mismatch)")
        episodes = [EpisodeFacts.from_json(item) for item in json.loads(listing["episodes"])]
        for chunk in chunks:
            if chunk.offset + chunk.length > footer.summary_start:
                raise Damage("chunk index points past the data section")
        _check_episode_index(episodes, sum(chunk.uncompressed_size for chunk in chunks))
        _take(ImageBudget(str(self.path), self.size), sum(facts.length + 1 for facts in episodes) * image_row_bytes(channels))
        chunks.sort(key=lambda c: (c.start_time, c.offset))
        return _Index(dataset, channels, chunks, episodes)

    def _read_metadata(self, stream: ByteSource, offset: int, length: int) -> dict[str, str]:
        record = stream.read(offset, length)
        if len(record) != length or length < 9 or record[0] != OP_METADATA:
            raise Damage(f"metadata index points at a non-metadata record (byte {offset})")
        try:
            return dict(Metadata.read(ReadDataStream(BytesIO(record[9:]))).metadata)
        except Exception as error:
            raise Damage(f"unreadable metadata record at byte {offset}: {error}") from None

    def _scan(self, stream: ByteSource) -> _Index:
        """Salvage: read the data section record by record, keeping every complete episode."""
        self._expanded = 0
        data = memoryview(stream.whole())
        dataset: dict[str, str] = {}
        channels: dict[int, Field | None] = {}
        chunks: list[ChunkRef] = []
        episodes: list[EpisodeFacts] = []
        damage: str | None = None
        assembler: _EpisodeAssembler | None = None
        pending_chunks: list[ChunkRef] = []
        messages_after_last_episode = 0
        offset = len(MAGIC)
        try:
            for opcode, body, record_offset in iter_records_with_offsets(data, offset, len(data)):
                if opcode == OP_METADATA:
                    metadata = Metadata.read(ReadDataStream(BytesIO(body)))
                    if metadata.name == DATASET_METADATA and not dataset:
                        dataset = dict(metadata.metadata)
                        self._check_dataset(dataset)
                        assembler = _EpisodeAssembler(
                            space_from_json(dataset["observation_space"]), space_from_json(dataset["action_space"]), channels
                        )
                        assembler.budget = ImageBudget(str(self.path), self.size)
                elif opcode == OP_CHANNEL:
                    channel = Channel.read(ReadDataStream(BytesIO(body)))
                    channels.setdefault(channel.id, channel_field(channel))
                elif opcode == OP_CHUNK:
                    if assembler is None:
                        raise Damage("data before the dataset metadata")
                    start_time, end_time, uncompressed_size = struct.unpack_from("<QQQ", body)
                    self._count_chunk(uncompressed_size)
                    ref = ChunkRef(record_offset, 9 + len(body), start_time, end_time, uncompressed_size)
                    pending_chunks.append(ref)
                    record = data[record_offset : record_offset + ref.length]
                    content = decode_chunk(memoryview(record))
                    for channel_id, log_time, message in chunk_records(
                        content, lambda c: channels.setdefault(c.id, channel_field(c))
                    ):
                        result = assembler.add(channel_id, log_time, message)
                        messages_after_last_episode += 1
                        if result is not None:
                            episodes.append(result[0])
                            chunks.extend(pending_chunks)
                            pending_chunks = [ref]
                            messages_after_last_episode = 0
                elif opcode in (OP_DATA_END, OP_FOOTER):
                    break
            else:
                damage = "truncated: the file ends before its data section does"
        except DemoFileError:
            raise
        except FrameLimitError as error:
            raise DemoFileError(f"{self.path}: {error}") from None
        except Damage as error:
            damage = str(error)
        except Exception as error:
            damage = f"unreadable record ({type(error).__name__}: {error})"
        if not dataset:
            raise DemoFileError(f"{self.path}: damaged before any dataset metadata ({damage or 'none found'})")
        if damage is None and messages_after_last_episode:
            damage = "an incomplete episode after the last complete one"
        unique = sorted({(c.start_time, c.offset): c for c in chunks}.values(), key=lambda c: (c.start_time, c.offset))
        return _Index(dataset, channels, unique, episodes, damage)


def salvageable_episodes(path: str | os.PathLike) -> int:
    """How many complete episodes a (partial) demo file holds; 0 when it is not readable as one."""
    try:
        return len(DemoFile(path, salvage=True))
    except ImitationError:
        return 0

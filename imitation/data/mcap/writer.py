"""Writing demo files: `DemoWriter` appends episodes to `<path>.partial` and renames it to
`path` when closed; `write_episodes` writes a whole file in one go.

Crash safety: with `flush_episodes=True` the writer closes the MCAP chunk after each episode and
hands it to the operating system, so a killed process leaves a file whose complete chunks hold
every finished episode; `durable=True` also fsyncs it, so that a power cut does too.
`DemoFile(..., salvage=True)` scans such a file record by record and recovers them.
"""

from __future__ import annotations

import json
import os
import signal
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from mcap.writer import IndexType, Writer

from imitation import __version__
from imitation.data.mcap.format import (
    BLOCK_ENCODING,
    COMPRESSIONS,
    DATASET_METADATA,
    DEFAULT_COMPRESSION,
    EPISODE_SCHEMA,
    EPISODE_TOPIC,
    EPISODES_METADATA,
    EXECUTED_FIELD,
    HANDOVER_FIELD,
    HUMAN_FIELD,
    IMAGE_FORMAT_VERSION,
    PLAIN_FORMAT_VERSION,
    PROFILE,
    PROPOSED_FIELD,
    EpisodeFacts,
    Field,
    fields_for,
    metadata_crc,
    to_json_text,
)
from imitation.data.mcap.images import (
    CODECS,
    DEFAULT_JPEG_QUALITY,
    DEFAULT_WEBP_QUALITY,
    IMAGE_ENCODING,
    channels_of,
    encode_frames,
    schema_data,
    schema_name,
)
from imitation.data.mcap.reader import salvageable_episodes
from imitation.data.mcap.source import refuse_url
from imitation.data.spaces import space_to_json
from imitation.data.types import Episode, Interventions, Tree, check_fits_space, first_nonfinite, tree_leaves
from imitation.errors import ImitationError
from imitation.output import OutputLock, check_target, create_exclusive, lstat_kind, os_error

DEFAULT_BLOCK_STEPS = 4096


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
        elif received and (
            previous == signal.SIG_DFL or signal.SIGTERM in received
        ):  # SIGTERM stops even where SIGINT is ignored
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

    `end_flags` says how the episodes' terminated/truncated flags were decided (`{"decided": "env"}`
    for the env's own signals; converters say more, see imitation/data/convert/endings.py); files
    written without it do not say.

    NaN and ±inf in float observations, actions or rewards are refused where they enter, with the
    episode and step named; `finite_only=False` stores them as they are (bit-exact round trips of
    any data), and learners then refuse the file when they load it.

    Image observations (uint8 leaves of shape (H, W) or (H, W, C), C in {1, 3, 4}) are written one
    Foxglove image message per frame, which MCAP viewers show as video: `image_codec` "png"
    (lossless, the default), "jpeg" (lossy and compact, at `jpeg_quality`; not for 4 channels),
    "webp" (lossy and about a third of JPEG's bytes at the same PSNR, at `webp_quality`; not for
    1 channel) or "raw" (lossless, left to the chunk compression); frames that come as
    `KeptFrames` with pictures of that codec are stored as those pictures. Such files are format
    version 2. With
    `image_codec=None` they are blocks of rows like any other leaf, and the file version 1.
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
        end_flags: dict[str, Any] | None = None,
        block_steps: int = DEFAULT_BLOCK_STEPS,
        flush_episodes: bool = False,
        durable: bool = False,
        chunk_size: int = 1024 * 1024,
        compression: str = DEFAULT_COMPRESSION,
        finite_only: bool = True,
        temporary: str | os.PathLike | None = None,
        lock: bool = True,
        image_codec: str | None = "png",
        jpeg_quality: int = DEFAULT_JPEG_QUALITY,
        webp_quality: int = DEFAULT_WEBP_QUALITY,
    ) -> None:
        refuse_url(path)
        self.path = Path(path)
        self._finite_only = finite_only
        self.partial_path = Path(temporary) if temporary is not None else self.path.with_name(self.path.name + ".partial")
        self.observation_space = observation_space
        self.action_space = action_space
        if image_codec is not None and image_codec not in CODECS:
            raise ImitationError(f"image_codec must be one of {', '.join(CODECS)} or None, got {image_codec!r}")
        for name, quality in (("jpeg_quality", jpeg_quality), ("webp_quality", webp_quality)):
            if not (isinstance(quality, int) and 1 <= quality <= 100):
                raise ImitationError(f"{name} must be an integer from 1 to 100, got {quality!r}")
        self._jpeg_quality, self._webp_quality = jpeg_quality, webp_quality
        self._fields = fields_for(observation_space, action_space, image_codec)
        self._image_fields = [f for f in self._fields if f.codec is not None]
        for f in self._image_fields:
            if f.codec == "jpeg" and f.shape[2:] == (4,):
                raise ImitationError(
                    f"{f.topic}: JPEG has no alpha channel for its shape {list(f.shape)}; use image_codec png or raw"
                )
            if f.codec == "webp" and channels_of(f.shape) == 1:
                raise ImitationError(
                    f"{f.topic}: WebP has no grey pictures for its shape {list(f.shape)}; use image_codec png, jpeg or raw"
                )
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
            "format_version": str(IMAGE_FORMAT_VERSION if self._image_fields else PLAIN_FORMAT_VERSION),
            "env_id": env_id,
            "observation_space": json.dumps(space_to_json(observation_space)),
            "action_space": json.dumps(space_to_json(action_space)),
            "dt_ns": str(self._dt_ns),
            "source": source,
            "creator": f"imitation-mcap {__version__}",
            "user_metadata": to_json_text(metadata or {}),
        }
        if end_flags is not None:  # how the episodes' terminated/truncated flags were decided (FORMAT.md §3.1)
            dataset["end_flags"] = to_json_text(end_flags)
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
        self._schemas: dict[str, int] = {}
        for f in self._fields:
            if f.kind in ("observation", "action", "reward"):
                self._register(f)
        episode_schema = self._writer.register_schema("imitation.Episode", "jsonschema", json.dumps(EPISODE_SCHEMA).encode())
        self._channels[EPISODE_TOPIC] = self._writer.register_channel(
            EPISODE_TOPIC, "json", episode_schema, {"field": "episode"}
        )

    @property
    def episodes_written(self) -> int:
        return len(self._facts)

    def write(self, episode: Episode) -> EpisodeFacts:
        """Append one episode; returns its facts (its index in this file, return, time range)."""
        check_fits_space(episode.observations, self.observation_space, "observations")
        check_fits_space(episode.actions, self.action_space, "actions")
        rewards = np.asarray(episode.rewards, dtype=np.float64)
        checked = [("observation", episode.observations), ("action", episode.actions), ("reward", rewards)]
        if episode.interventions is not None:
            for what in ("proposed_actions", "executed_actions"):
                check_fits_space(getattr(episode.interventions, what), self.action_space, f"interventions.{what}")
                checked.append((what.removesuffix("s").replace("_", " "), getattr(episode.interventions, what)))
        if self._finite_only:
            for what, tree in checked:
                if found := first_nonfinite(tree, what):
                    step, name, value = found
                    raise ImitationError(
                        f"{self.path}: episode {len(self._facts)}, step {step}: the {name} is {value}; "
                        "demo files hold finite observations, actions and rewards only"
                    )
        times, time_shift_ns = self._episode_times(episode)
        columns: list[tuple[Field, np.ndarray]] = []
        frames: list[tuple[Field, list[bytes]]] = []
        for f in self._fields:
            if f.codec is not None:
                pixels = dict(tree_leaves(episode.observations))[f.path]
                frames.append(
                    (
                        f,
                        encode_frames(
                            f.codec, pixels, times, jpeg_quality=self._jpeg_quality, webp_quality=self._webp_quality
                        ),
                    )
                )
            elif f.kind in ("observation", "action"):
                tree = episode.observations if f.kind == "observation" else episode.actions
                columns.append((f, dict(tree_leaves(tree))[f.path]))
            elif f.kind == "reward":
                columns.append((f, rewards))
            elif f.kind == "time" and episode.timestamps is not None:
                columns.append((f, times))

        try:
            with _interrupts_deferred():
                return self._append(episode, columns, frames, times, time_shift_ns, rewards)
        except OSError as error:
            raise self._failed(error) from None

    def _append(
        self,
        episode: Episode,
        columns: list[tuple[Field, np.ndarray]],
        frames: list[tuple[Field, list[bytes]]],
        times: np.ndarray,
        time_shift_ns: int,
        rewards: np.ndarray,
    ) -> EpisodeFacts:
        steps = len(episode)
        per_step = _intervention_messages(episode.interventions) if episode.interventions is not None else {}
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
            # Each frame and intervention message at its own row's time: after its block group
            # (stamped with the group's first row), before the next group, row by row.
            for row in range(start, min(start + self._block_steps, steps + 1)):
                for f, messages in frames:
                    self._add(f.topic, int(times[row]), messages[row])
                for topic, message in per_step.get(row, []):
                    self._add(topic, int(times[row]), message)
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
        with suppress(OSError):  # the buffered tail cannot be written (a full disk); the flushed episodes are on disk
            self._file.close()
        kept = salvageable_episodes(self.partial_path)
        if not kept:
            self.partial_path.unlink(missing_ok=True)
        self._release()
        return kept

    def _failed(self, error: OSError) -> ImitationError:
        """Abort, and the one-line error saying what was kept."""
        failure = os_error(self.path, error)
        self.__exit__(type(failure), failure, None)
        return failure

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
            exc.args = (
                f"{exc}; {self.partial_path} keeps {kept} finished episode(s): `imitation recover {self.partial_path}` makes "
                "it a demo file",
            )

    def _register(self, f: Field) -> None:
        if f.codec is not None:
            name = schema_name(f.codec)
            if name not in self._schemas:
                self._schemas[name] = self._writer.register_schema(name, IMAGE_ENCODING, schema_data(f.codec))
            channel = self._writer.register_channel(f.topic, IMAGE_ENCODING, self._schemas[name], f.channel_metadata())
        else:
            encoding = "json" if f.dtype is None else BLOCK_ENCODING
            channel = self._writer.register_channel(f.topic, encoding, 0, f.channel_metadata())
        self._channels[f.topic] = channel

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


def _intervention_messages(interventions: Interventions) -> dict[int, list[tuple[str, bytes]]]:
    """Row → its intervention messages (topic, JSON): who drove, both actions, and a hand-over."""

    def row_of(tree: Tree, row: int) -> object:
        return {key: row_of(sub, row) for key, sub in tree.items()} if isinstance(tree, dict) else tree[row]

    messages = {
        row: [
            (HUMAN_FIELD.topic, to_json_text({"human": bool(human)}).encode()),
            (PROPOSED_FIELD.topic, to_json_text({"action": row_of(interventions.proposed_actions, row)}).encode()),
            (EXECUTED_FIELD.topic, to_json_text({"action": row_of(interventions.executed_actions, row)}).encode()),
        ]
        for row, human in enumerate(interventions.human)
    }
    for row, to_human in interventions.handovers():
        handover = {"step": row, "to": "human" if to_human else "learner"}
        messages[row].append((HANDOVER_FIELD.topic, to_json_text(handover).encode()))
    return messages


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
    with DemoWriter(
        path, env_id=env_id, observation_space=observation_space, action_space=action_space, **writer_options
    ) as writer:
        for episode in episodes:
            writer.write(episode)
    return writer.path

"""ROS bags as one interface: topics with types, counts and times, and decoded messages in time order.

- ROS 2 MCAP (a `.mcap` file, or a rosbag2 directory whose storage is MCAP): decoded with
  mcap-ros2-support from the `ros2msg` schemas the file carries.
- ROS 1 `.bag` and rosbag2 sqlite (a directory with `metadata.yaml` and `.db3` files): read
  with the `rosbags` package, types from the definitions in the bag; a sqlite bag that carries
  none (rosbag2 before Iron) is decoded with the message definitions of `ros_distro` (checked
  before any bag is opened, whatever the bag).

A topic whose schema cannot be parsed (rosbag2's `*/_service_event` topics carry raw `.srv`
text) or whose messages do not decode is kept in the listing with a `problem` and skipped by
`messages()`, so the rest of the bag still converts.

ROS 1's own tools read a message's fields and ignore bytes after them; rosbags refuses a record
longer than its message. librealsense writes 4 bytes after a sensor_msgs/Image's `data`, so a
ROS 1 message whose type ends with a `uint8[]` field (Image, CompressedImage) is read as ROS 1
reads it: decoded with rosbags' own deserialiser for its type (the public `get_msgdef` of its
type store, which gives the length it consumed), the bytes after a complete message left out
and reported (`extra_bytes`, `extra_bytes_warnings`). Every other type must fill its record.

`field_type` reads a field's declared primitive type (`float64`, `int32`, ...) from the bag's
own definitions, parsed by rosbags for every format, so that conversion keeps float64 fields
float64 (decoded messages hold plain Python floats whatever the field's width).
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Callable, Generator, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import yaml

from imitation.data.convert.fields import declared_type
from imitation.data.convert.sources import MCAP_MAGIC, ROS1_MAGIC
from imitation.data.convert.yaml_bounded import load_yaml
from imitation.errors import ImitationError


def _damage_errors() -> tuple[type[BaseException], ...]:
    """What the third-party readers raise on damaged bytes: their own errors, and the struct,
    decompression, decoding and lookup errors their parsers let through (rosbags asserts on
    malformed records). Caught only around calls into those readers, never around our own code."""
    import sqlite3
    import struct

    import zstandard
    from mcap.exceptions import McapError
    from rosbags.rosbag1 import ReaderError as Ros1Error
    from rosbags.rosbag2 import ReaderError as Ros2Error

    try:
        import apsw  # rosbags reads sqlite bags through apsw

        sqlite_errors: tuple[type[BaseException], ...] = (sqlite3.Error, apsw.Error)
    except ImportError:
        sqlite_errors = (sqlite3.Error,)
    return (
        McapError,
        Ros1Error,
        Ros2Error,
        *sqlite_errors,
        zstandard.ZstdError,
        struct.error,
        EOFError,
        AssertionError,
        KeyError,
        IndexError,
        ValueError,
        TypeError,
        RuntimeError,
        OverflowError,
        MemoryError,
    )


@contextlib.contextmanager
def _reading(path: Path, what: str) -> Iterator[None]:
    """One line for a bag whose bytes the reader chokes on."""
    try:
        yield
    except ImitationError:
        raise
    except _damage_errors() as error:
        raise ImitationError(
            f"{path}: cannot read {what}: the file is damaged or not what it claims ({type(error).__name__}: "
            f"{str(error)[:200]})"
        ) from None


@dataclass
class TopicInfo:
    """What a bag holds on one topic; times are log times in ns (None without messages)."""

    topic: str
    type: str
    count: int = 0
    first_ns: int | None = None
    last_ns: int | None = None
    problem: str | None = None  # why its messages cannot be decoded; None if they can
    latched: bool = False  # ROS 1 `latching=1`, or ROS 2 durability transient_local

    @property
    def rate_hz(self) -> float | None:
        if self.count < 2 or self.first_ns is None or self.last_ns is None or self.last_ns == self.first_ns:
            return None
        return (self.count - 1) / ((self.last_ns - self.first_ns) / 1e9)


class Bag(Protocol):
    path: Path
    format: str  # "ros2 mcap", "ros1 bag", "rosbag2 sqlite"

    def topics(self) -> dict[str, TopicInfo]:
        """Every topic, with counts and time range (read from the index or one pass over the bag)."""

    def messages(self, topics: Iterable[str]) -> Generator[tuple[str, int, Any], None, None]:
        """(topic, log time ns, decoded message) of these topics, in log-time order."""

    def field_type(self, topic: str, field: str) -> str | None:
        """The primitive type the topic's definition declares for `field` (an array's element
        type), e.g. `float64`; None where the definitions do not say."""

    @property
    def extra_bytes(self) -> dict[str, set[int]]:
        """Topic: the numbers of bytes found after a complete message on it and left out (ROS 1)."""

    def close(self) -> None: ...


def extra_bytes_warnings(bag: Bag, topics: Iterable[str]) -> list[str]:
    """A line for each of `topics` whose messages carried bytes after their end."""
    lines = []
    for topic in topics:
        sizes = sorted(bag.extra_bytes.get(topic, ()))
        if sizes:
            amount = f"{sizes[0]}" if len(sizes) == 1 else f"{sizes[0]} to {sizes[-1]}"
            lines.append(
                f"{bag.path}: {topic}: messages carry {amount} bytes after a complete {bag.topics()[topic].type} "
                "(librealsense writes 4 after an Image's data); read without them, as ROS 1's tools do"
            )
    return lines


def open_bag(path: str | Path, kind: str, *, ros_distro: str = "latest") -> Bag:
    """Open a ROS 2 (`kind="ros2"`) or ROS 1 (`kind="ros1"`) bag; one-line errors otherwise."""
    store = ros_distro_store(ros_distro)  # first, whatever the bag: only some bags use it
    path = Path(path)
    if not path.exists():
        raise ImitationError(f"{path}: no such file or directory")
    if kind == "ros1":
        if path.is_dir() or _starts_with(path, ROS1_MAGIC) is False:
            hint = "; a rosbag2 directory is a ROS 2 bag (--from ros2)" if path.is_dir() else ""
            raise ImitationError(f"{path}: not a ROS 1 bag (it does not start with '#ROSBAG V2.0'){hint}")
        return RosbagsBag(path, "ros1 bag", store)
    if kind != "ros2":
        raise ImitationError(f"unknown bag kind {kind!r}")
    if path.is_file() and path.suffix == ".db3":
        path = path.parent
    if path.is_file():
        if not _starts_with(path, MCAP_MAGIC):
            raise ImitationError(f"{path}: not an MCAP file (a ROS 2 bag is a .mcap file or a rosbag2 directory)")
        return McapBag(path, [path])
    storage, files = _rosbag2_directory(path)
    if storage == "sqlite3":
        return RosbagsBag(path, "rosbag2 sqlite", store)
    return McapBag(path, files)


def ros_distro_store(ros_distro: str) -> Any:
    """rosbags' type store for `--ros-distro` (`latest`, or a ROS 2 distro: `humble`, ...).

    Only rosbag2 sqlite bags recorded before Iron, which carry no message definitions, use it;
    the name is checked before any bag is opened all the same, so that a misspelt one is refused
    whatever the bag rather than ignored until a bag needs it."""
    from rosbags.typesys import Stores

    try:
        return Stores(ros_distro if ros_distro == "latest" else f"ros2_{ros_distro}")
    except ValueError:
        names = ", ".join(s.value.removeprefix("ros2_") for s in Stores if s.value.startswith("ros2_"))
        raise ImitationError(f"--ros-distro {ros_distro!r}: unknown (one of latest, {names})") from None


def _is_file(path: Path) -> bool:
    """Path.is_file, false for names the OS refuses (too long, a NUL byte) instead of raising."""
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def _starts_with(path: Path, magic: bytes) -> bool:
    try:
        with open(path, "rb") as stream:
            return stream.read(len(magic)) == magic
    except OSError as error:
        raise ImitationError(f"{path}: cannot read: {error.strerror or error}") from None


def _rosbag2_directory(path: Path) -> tuple[str, list[Path]]:
    """(storage, files) of a rosbag2 directory, from metadata.yaml or, without one, its files."""
    metadata = path / "metadata.yaml"
    if metadata.is_file():
        try:
            info = load_yaml(metadata.read_bytes())["rosbag2_bagfile_information"]
            storage = str(info.get("storage_identifier", ""))
            # Recorders write paths relative to a folder that is often renamed: keep the names.
            names = info.get("relative_file_paths", [])
            if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
                raise TypeError("relative_file_paths is not a list of file names")
            files = [path / Path(name).name for name in names]
        except ImitationError as error:
            raise ImitationError(f"{metadata}: {error}") from None
        except (OSError, yaml.YAMLError, KeyError, TypeError, AttributeError, ValueError, RecursionError) as error:
            raise ImitationError(
                f"{metadata}: not a rosbag2 metadata file ({type(error).__name__}: {' '.join(str(error).split())[:200]})"
            ) from None
        if storage not in ("sqlite3", "mcap"):
            raise ImitationError(f"{metadata}: storage {storage!r} is not supported (sqlite3 or mcap)")
        missing = [f.name[:80] for f in files if not _is_file(f)]
        if missing:
            raise ImitationError(f"{path}: metadata.yaml lists {', '.join(missing)}, which is missing")
        return storage, files
    if sorted(path.glob("*.db3")):
        raise ImitationError(f"{path}: a sqlite rosbag2 directory needs its metadata.yaml")
    files = sorted(path.glob("*.mcap"))
    if not files:
        raise ImitationError(f"{path}: not a rosbag2 directory (no metadata.yaml, .mcap or .db3 files)")
    return "mcap", files


@contextlib.contextmanager
def _quiet_stderr() -> Iterator[None]:
    """mcap-ros2-support's vendored message parser prints to stderr before it raises; the
    error it raises says the same, and our one-line error contract needs the silence."""
    with contextlib.redirect_stderr(io.StringIO()):
        yield


class McapBag:
    """A ROS 2 bag in MCAP files (split bags are read one file after the other)."""

    format = "ros2 mcap"

    def __init__(self, path: Path, files: list[Path]) -> None:
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        self.path = path
        self._files = files
        self._make_reader = make_reader
        self._factory_type = DecoderFactory
        self._decoders: dict[str, Callable[[bytes], Any]] = {}
        self._topics: dict[str, TopicInfo] | None = None
        self._schemas: dict[str, tuple[str, bytes]] = {}  # topic: (type name, ros2msg text)
        self._fielddefs: dict[str, dict[str, Any] | None] = {}  # topic: rosbags' parse of its schema

    @property
    def extra_bytes(self) -> dict[str, set[int]]:
        return {}  # CDR messages are read by mcap-ros2-support, which accepts CDR's padding only

    def topics(self) -> dict[str, TopicInfo]:
        if self._topics is not None:
            return self._topics
        topics: dict[str, TopicInfo] = {}
        for file in self._files:
            with self._open(file) as reader:
                summary = reader.get_summary()
                for channel in summary.channels.values() if summary else []:
                    schema = summary.schemas.get(channel.schema_id)
                    info = topics.setdefault(channel.topic, TopicInfo(channel.topic, schema.name if schema else "?"))
                    info.latched = info.latched or _transient_local(channel.metadata.get("offered_qos_profiles"))
                    if info.problem is None and channel.topic not in self._decoders:
                        info.problem = self._prepare_decoder(channel, schema)
                for schema, channel, message in reader.iter_messages(log_time_order=False):
                    info = topics.setdefault(channel.topic, TopicInfo(channel.topic, schema.name if schema else "?"))
                    if info.count == 0 and info.problem is None and channel.topic not in self._decoders:
                        info.problem = self._prepare_decoder(channel, schema)
                    if info.count == 0 and info.problem is None:
                        info.problem = self._try_decode(channel.topic, message.data)
                    info.count += 1
                    info.first_ns = message.log_time if info.first_ns is None else min(info.first_ns, message.log_time)
                    info.last_ns = message.log_time if info.last_ns is None else max(info.last_ns, message.log_time)
        self._topics = topics
        return topics

    def messages(self, topics: Iterable[str]) -> Generator[tuple[str, int, Any], None, None]:
        wanted = [t for t in topics if self.topics()[t].problem is None]
        for file in self._files:
            with self._open(file) as reader:
                for _, channel, message in reader.iter_messages(topics=wanted, log_time_order=True):
                    try:
                        decoded = self._decoders[channel.topic](message.data)
                    except Exception as error:
                        raise ImitationError(
                            f"{file}: a message on {channel.topic} at {message.log_time} ns does not decode ({error})"
                        ) from None
                    yield channel.topic, message.log_time, decoded

    def field_type(self, topic: str, field: str) -> str | None:
        self.topics()  # the schemas are read with the listing
        if topic not in self._fielddefs:
            self._fielddefs[topic] = None
            if topic in self._schemas:
                from rosbags.typesys import get_types_from_msg

                name, text = self._schemas[topic]
                # A schema rosbags cannot parse leaves the types unknown (kept as float64).
                with contextlib.suppress(Exception):
                    self._fielddefs[topic] = dict(get_types_from_msg(text.decode(), name))
        fielddefs = self._fielddefs[topic]
        if fielddefs is None:
            return None
        name = self._schemas[topic][0]
        # rosbags names types pkg/msg/Type; a schema may say pkg/Type
        msgtype = name if name in fielddefs else next((t for t in fielddefs if t.split("/")[-1] == name.split("/")[-1]), name)
        return declared_type(fielddefs, msgtype, field)

    def close(self) -> None:
        pass

    @contextlib.contextmanager
    def _open(self, file: Path) -> Iterator[Any]:
        try:
            with open(file, "rb") as stream, _reading(file, "this MCAP file"):
                yield self._make_reader(stream)
        except OSError as error:
            raise ImitationError(f"{file}: cannot read: {error.strerror or error}") from None

    def _prepare_decoder(self, channel: Any, schema: Any) -> str | None:
        if schema is None or channel.message_encoding != "cdr" or schema.encoding != "ros2msg":
            return f"not a CDR message with a ros2msg schema (encoding {channel.message_encoding!r})"
        try:
            with _quiet_stderr():
                # A fresh factory: its cache is keyed by schema id, which split files may reuse.
                decoder = self._factory_type().decoder_for(channel.message_encoding, schema)
        except Exception as error:
            return f"its schema {schema.name} cannot be parsed ({type(error).__name__}: {str(error).strip() or 'no detail'})"
        assert decoder is not None  # decoder_for returns None only for the encodings refused above
        self._decoders[channel.topic] = decoder
        self._schemas[channel.topic] = (schema.name, schema.data)
        return None

    def _try_decode(self, topic: str, data: bytes) -> str | None:
        try:
            self._decoders[topic](data)
        except Exception as error:
            return f"its messages do not decode ({type(error).__name__}: {error})"
        return None


class RosbagsBag:
    """A ROS 1 `.bag` or a rosbag2 sqlite directory, through the `rosbags` readers.

    Types are registered connection by connection, so one unparsable definition costs its own
    topic only (rosbags' AnyReader would refuse the whole bag)."""

    def __init__(self, path: Path, format: str, store: Any) -> None:
        """`store`: the rosbags type store (`ros_distro_store`) for connections without definitions."""
        from rosbags.interfaces import MessageDefinitionFormat
        from rosbags.rosbag1 import Reader as Reader1
        from rosbags.rosbag2 import Reader as Reader2
        from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

        self.path = path
        self.format = format
        self._ros1 = format == "ros1 bag"
        try:
            self._reader = Reader1(path) if self._ros1 else Reader2(path)
            self._reader.open()
        except Exception as error:
            raise ImitationError(f"{path}: cannot open as a {format}: {error}") from None
        self._typestore = get_typestore(Stores.EMPTY)
        self._problems: dict[str, str] = {}
        connections = list(self._reader.connections)
        if any(c.msgdef.format == MessageDefinitionFormat.NONE for c in connections):
            self._typestore.register(get_typestore(store).fielddefs)
        for connection in connections:
            if connection.msgdef.format == MessageDefinitionFormat.NONE:
                continue
            try:
                if connection.msgdef.format == MessageDefinitionFormat.MSG:
                    types = get_types_from_msg(connection.msgdef.data, connection.msgtype)
                else:
                    types = {}
                    for part in connection.msgdef.data.split("=" * 80 + "\n"):
                        idl = part.split("\n", 1)[1] if part.startswith("IDL: ") else part
                        if idl.strip():
                            types.update(get_types_from_idl(idl))
                self._typestore.register(types)
            except Exception as error:
                self._problems[str(connection.topic)] = f"its definition of {connection.msgtype} cannot be parsed ({error})"
        self._connections = connections
        self._topics: dict[str, TopicInfo] | None = None
        self._extra_bytes: dict[str, set[int]] = {}

    @property
    def extra_bytes(self) -> dict[str, set[int]]:
        return self._extra_bytes

    def _deserialize(self, raw: bytes, msgtype: str, topic: str) -> Any:
        if not self._ros1:
            return self._typestore.deserialize_cdr(raw, msgtype)
        from rosbags.serde import SerdeError

        try:
            return self._typestore.deserialize_ros1(raw, msgtype)
        except SerdeError as error:
            if not self._ends_with_bytes(msgtype):
                raise
            refusal = error
        # Decoded again by the same generated function, which says how many bytes the message took.
        msgdef = self._typestore.get_msgdef(msgtype)
        try:
            message, end = msgdef.deserialize_ros1(raw, 0, msgdef.cls, self._typestore)
        except Exception:
            raise refusal from None
        if not 0 < end < len(raw):
            raise refusal
        self._extra_bytes.setdefault(topic, set()).add(len(raw) - end)
        return message

    def _ends_with_bytes(self, msgtype: str) -> bool:
        """Whether the type's last field is a uint8[] (an Image's or CompressedImage's data)."""
        from rosbags.interfaces import Nodetype

        fields = self._typestore.fielddefs.get(msgtype, ((), ()))[1]
        if not fields:
            return False
        kind, detail = fields[-1][1]
        return kind == Nodetype.SEQUENCE and detail[0] == (Nodetype.BASE, ("uint8", 0))

    def topics(self) -> dict[str, TopicInfo]:
        if self._topics is not None:
            return self._topics
        topics: dict[str, TopicInfo] = {}
        for connection in self._connections:
            topic = str(connection.topic)  # a damaged metadata.yaml may name a topic with a number or a list
            info = topics.setdefault(topic, TopicInfo(topic, str(connection.msgtype)))
            info.problem = info.problem or self._problems.get(topic)
            info.latched = info.latched or _latched(connection)
        with _reading(self.path, f"this {self.format}"):
            for connection, time_ns, raw in self._reader.messages():
                info = topics[str(connection.topic)]
                if info.count == 0 and info.problem is None:
                    try:
                        self._deserialize(raw, connection.msgtype, str(connection.topic))
                    except Exception as error:
                        info.problem = f"its messages do not decode as {connection.msgtype} ({type(error).__name__}: {error})"
                info.count += 1
                info.first_ns = time_ns if info.first_ns is None else min(info.first_ns, time_ns)
                info.last_ns = time_ns if info.last_ns is None else max(info.last_ns, time_ns)
        self._topics = topics
        return topics

    def messages(self, topics: Iterable[str]) -> Generator[tuple[str, int, Any], None, None]:
        wanted = {t for t in topics if self.topics()[t].problem is None}
        connections = [c for c in self._connections if str(c.topic) in wanted]
        if not connections:
            return
        with _reading(self.path, f"this {self.format}"):
            listing = self._reader.messages(connections=connections)
            for connection, time_ns, raw in listing:
                try:
                    decoded = self._deserialize(raw, connection.msgtype, str(connection.topic))
                except Exception as error:
                    raise ImitationError(
                        f"{self.path}: a message on {connection.topic} at {time_ns} ns does not decode ({error})"
                    ) from None
                yield str(connection.topic), time_ns, decoded

    def field_type(self, topic: str, field: str) -> str | None:
        if topic in self._problems:
            return None
        msgtype = next((str(c.msgtype) for c in self._connections if str(c.topic) == topic), None)
        return None if msgtype is None else declared_type(self._typestore.fielddefs, msgtype, field)

    def close(self) -> None:
        self._reader.close()


def _latched(connection: Any) -> bool:
    """A ROS 1 connection with `latching=1`, or a rosbag2 one offered as transient_local."""
    ext = getattr(connection, "ext", None)
    if getattr(ext, "latching", None) == 1:
        return True
    profiles = getattr(ext, "offered_qos_profiles", None)
    if isinstance(profiles, str):
        return _transient_local(profiles)
    return any(getattr(getattr(qos, "durability", None), "name", None) == "TRANSIENT_LOCAL" for qos in profiles or [])


def _transient_local(profiles: str | None) -> bool:
    """Whether a rosbag2 `offered_qos_profiles` YAML text offers durability transient_local (1)."""
    if not profiles:
        return False
    try:
        parsed = load_yaml(profiles.encode())
    except (yaml.YAMLError, ImitationError, RecursionError, ValueError, UnicodeError):
        return False
    return isinstance(parsed, list) and any(
        isinstance(qos, dict) and qos.get("durability") in (1, "transient_local") for qos in parsed
    )

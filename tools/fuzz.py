"""Mutation fuzzing of every reader of files that come from strangers.

Each target takes seed inputs (real files: the bundled demo files, a small run directory, the
third-party recordings in ../shared/testdata) and feeds mutated copies to the code that reads
them. Every input must load, load a salvaged prefix, or be refused with the project's own error
(an ImitationError subclass); any other exception, or an input that runs longer than the time
limit, is a failure: its input is saved with the traceback for reproduction.

Mutations: bit flips, interesting bytes and integers at record boundaries, byte insertion and
deletion, truncation, splicing two seeds; and, aware of the formats, JSON and YAML documents
mutated node by node (types swapped, numbers pushed to extremes, keys dropped, deep nesting),
MCAP files re-written record by record with mutated metadata, channels, schemas and messages
(with valid checksums, so the semantic checks behind them are reached; image frames edited
inside their Foxglove protobuf message: the PNG or JPEG bytes, PNG chunk CRCs made valid again, the
format, size, step and encoding), npz archives and parquet tables re-written with arrays and
columns dropped, retyped, reshaped or truncated.

Input k of a target is mutated with random.Random(f"{target}:{seed}:{k}"), so a run is
deterministic and any input can be regenerated from (target, seed, k).

    python tools/fuzz.py                          # every target, 10,000 inputs each
    python tools/fuzz.py --targets demo,npz --count 500 --seed 1
    python tools/fuzz.py --json                   # one JSON object with the figures

The short run inside `make test` is tests/test_fuzz.py (seeded, a few hundred inputs per target).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import random
import resource
import shutil
import signal
import sqlite3
import struct
import sys
import tempfile
import time
import traceback
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

REPO = Path(__file__).resolve().parent.parent
TESTDATA = REPO.parent / "shared" / "testdata"
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from imitation.errors import ImitationError  # noqa: E402

Files = dict[str, bytes]  # one input: relative path -> content (a file, or a folder's files)
NOTES: list[str] = []  # one-line errors a target met and handled itself (recorded with the refusals)

# ------------------------------------------------------------------------------------------------
# Byte-level mutations

INTERESTING = [0, 1, 2, 7, 8, 9, 0x7F, 0x80, 0xFF, 0x100, 0x7FFF, 0x8000, 0xFFFF, 0x10000, 0x7FFFFFFF, 0x80000000,
               0xFFFFFFFF, 0x100000000, 2**53, 2**63 - 1, 2**63, 2**64 - 1]


def _position(rng: random.Random, size: int, hot: Sequence[int]) -> int:
    """Uniform, or (half the time) just at or after a record boundary, where lengths and opcodes sit."""
    if size == 0:
        return 0
    if hot and rng.random() < 0.5:
        return min(size - 1, max(0, rng.choice(hot) + rng.randrange(-2, 24)))
    return rng.randrange(size)


def mutate_bytes(data: bytes, rng: random.Random, *, hot: Sequence[int] = (), donors: Sequence[bytes] = ()) -> bytes:
    buffer = bytearray(data)
    for _ in range(rng.choice((1, 1, 1, 2, 2, 3, 4, 8))):
        size = len(buffer)
        at = _position(rng, size, hot)
        op = rng.randrange(11)
        if op == 0 and size:  # flip a bit
            buffer[at] ^= 1 << rng.randrange(8)
        elif op == 1 and size:  # an interesting byte
            buffer[at] = rng.choice((0, 0xFF, 0x7F, 0x80, 0x01, rng.randrange(256)))
        elif op == 2 and size:  # an interesting integer, 1-8 bytes little-endian
            width = rng.choice((1, 2, 4, 8))
            value = rng.choice(INTERESTING) % (1 << (8 * width))
            buffer[at : at + width] = value.to_bytes(width, "little")
        elif op == 3:  # insert random bytes
            buffer[at:at] = rng.randbytes(rng.choice((1, 2, 4, 8, 64, 512)))
        elif op == 4 and size:  # delete a range
            del buffer[at : at + rng.choice((1, 2, 4, 8, 64, 512, max(1, size // 4)))]
        elif op == 5 and size:  # duplicate a range
            length = rng.choice((1, 8, 64, 1024))
            buffer[at:at] = buffer[at : at + length]
        elif op == 6:  # truncate
            del buffer[at:]
        elif op == 7 and donors:  # splice: our head, another seed's tail
            donor = rng.choice(donors)
            buffer[at:] = donor[rng.randrange(len(donor) + 1) :]
        elif op == 8 and size > 16:  # swap two ranges
            length = rng.randrange(1, 64)
            other = rng.randrange(size)
            a, b = bytes(buffer[at : at + length]), bytes(buffer[other : other + length])
            if len(a) == len(b):
                buffer[at : at + length], buffer[other : other + length] = b, a
        elif op == 9 and size:  # overwrite a run with one byte
            buffer[at : at + rng.choice((4, 16, 256))] = bytes([rng.choice((0, 0xFF))]) * rng.choice((4, 16, 256))
        elif op == 10:  # ASCII digits or brackets: what text formats trip on
            buffer[at:at] = rng.choice((b"9" * 30, b"-1", b"[" * 2000, b"{", b"\x00", b"nan", b"'", b'"', b"\n", b": "))
    return bytes(buffer)


# ------------------------------------------------------------------------------------------------
# Document-level mutations (JSON and YAML values)


def _deep(depth: int) -> Any:
    value: Any = 0
    for _ in range(depth):
        value = [value]
    return value


WEIRD = [None, True, False, 0, -1, 1, 3, 2**31, 2**53 + 1, 2**63, -(2**63), 10**30, 1e308, -1e308, 1e-320, 0.5, -0.0,
         float("nan"), float("inf"), float("-inf"), "", "a", "nan", "inf", "-1", "1e999", "x" * 5000, "/", "\u2603", "<f4", "O",
         [], {}, [0], [-1], [2**31, 2**31], [1e308], [None], {"type": "Box"}, {"": None}, "[" * 50]


def _nodes(value: Any) -> list[tuple]:
    """Paths to the nodes of a document (breadth first, at most 2,000, at most 40 deep)."""
    found, queue = [], [((), value)]
    while queue and len(found) < 2000:
        path, node = queue.pop(0)
        found.append(path)
        if len(path) < 40:
            items = node.items() if isinstance(node, dict) else enumerate(node[:200]) if isinstance(node, list) else ()
            queue += [(path + (key,), item) for key, item in items]
    return found


def _get(value: Any, path: tuple) -> Any:
    for key in path:
        value = value[key]
    return value


def _set(root: Any, path: tuple, new: Any) -> Any:
    if not path:
        return new
    _get(root, path[:-1])[path[-1]] = new
    return root


def _variant(old: Any, rng: random.Random) -> Any:
    """A value near `old` (a number pushed to an extreme, a string edited) or a weird one."""
    if isinstance(old, bool) or rng.random() < 0.45:
        return rng.choice(WEIRD) if rng.random() > 0.05 else _deep(rng.choice((100, 2000, 100_000)))
    if isinstance(old, int):
        return rng.choice((old + 1, old - 1, -old, old * 2**20, old * 2**40, 0, float(old), str(old), old + 0.5))
    if isinstance(old, float):
        return rng.choice((old * 1e300, -old, 0.0, int(old) if math.isfinite(old) else 0, str(old), float("nan")))
    if isinstance(old, str):
        return rng.choice((old + "x", old[: len(old) // 2], old * 50, old.upper(), "", old.replace("/", "//"), old + "\x00", [old]))
    if isinstance(old, list):
        return rng.choice((old[:-1], old + old[-1:] if old else [0], list(reversed(old)), [old], old * 1000 if len(old) < 20 else old))
    if isinstance(old, dict):
        return rng.choice(({}, {**old, "unexpected": 1}, [old], dict(list(old.items())[: len(old) // 2])))
    return rng.choice(WEIRD)


def mutate_document(value: Any, rng: random.Random) -> Any:
    """1-3 node-level edits of a JSON-like value: replace, drop, duplicate, rename keys."""
    try:
        return _mutate_document(value, rng)
    except RecursionError:  # a document nested too deep to copy: give it deeper still
        return _deep(100_000)


def _mutate_document(value: Any, rng: random.Random) -> Any:
    value = json.loads(json.dumps(value))  # a private copy
    for _ in range(rng.choice((1, 1, 2, 3))):
        nodes = _nodes(value)
        path = rng.choice(nodes)
        node = _get(value, path)
        action = rng.random()
        if action < 0.6:
            value = _set(value, path, _variant(node, rng))
        elif action < 0.75 and path:  # drop this key or item
            parent = _get(value, path[:-1])
            del parent[path[-1]]
        elif action < 0.85 and isinstance(node, dict) and node:  # rename a key
            key = rng.choice(list(node))
            node[key + rng.choice(("_", "x", "", "/x")) if isinstance(key, str) else key] = node.pop(key)
        elif isinstance(node, list) and node:  # duplicate an item
            node.insert(rng.randrange(len(node) + 1), json.loads(json.dumps(rng.choice(node))))
        else:
            value = _set(value, path, _variant(node, rng))
    return value


def dumps(value: Any) -> str:
    try:
        return json.dumps(value)
    except RecursionError:
        return "[" * 100_000 + "]" * 100_000


def mutate_json_text(text: bytes, rng: random.Random) -> bytes:
    """Node-level mutation of a JSON document (most often), or byte-level."""
    if rng.random() < 0.75:
        try:
            return dumps(mutate_document(json.loads(text), rng)).encode()
        except (ValueError, RecursionError):
            pass
    return mutate_bytes(text, rng)


def alias_bomb(levels: int) -> bytes:
    """A YAML mapping whose last alias expands to 9^levels nodes."""
    lines = ["bomb0: &bomb0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"bomb{i}: &bomb{i} [" + ", ".join([f"*bomb{i - 1}"] * 9) + "]" for i in range(1, levels + 1)]
    return ("\n".join(lines) + "\n").encode()


def mutate_yaml_text(text: bytes, rng: random.Random) -> bytes:
    import yaml

    if rng.random() < 0.75:
        try:
            document = mutate_document(yaml.safe_load(text), rng)
            if rng.random() < 0.3:
                return dumps(document).encode()  # JSON is YAML too
            return yaml.safe_dump(document).encode()
        except (yaml.YAMLError, ValueError, TypeError, RecursionError):
            pass
    edits = (b"&a [*a, *a]", b"!!python/object/apply:os.system ['true']", b": : :", b"\t", b"- - -", b"{{{{", b"'", b"%YAML 9.9\n---\n")
    if rng.random() < 0.15:
        return alias_bomb(rng.randrange(2, 10)) + text  # ×9 per level once expanded
    if rng.random() < 0.15:
        return b"3: x\n" + text if rng.random() < 0.5 else text + b"\n7: [1, 2]\n"  # int keys beside str ones
    if rng.random() < 0.3:
        at = rng.randrange(len(text) + 1)
        return text[:at] + rng.choice(edits) + text[at:]
    return mutate_bytes(text, rng)


# ------------------------------------------------------------------------------------------------
# Format-aware rewriting: MCAP, safetensors, npz, parquet


def mcap_record_offsets(data: bytes) -> list[int]:
    """Top-level record starts (where opcodes and lengths sit), for biased byte mutations."""
    offsets, at = [], 8
    while at + 9 <= len(data):
        offsets.append(at)
        (length,) = struct.unpack_from("<Q", data, at + 1)
        at += 9 + length
    return offsets


def rewrite_mcap(data: bytes, rng: random.Random) -> bytes:
    """Read every record and write the file again through python-mcap's Writer with 1-3 semantic
    edits: the result has valid structure, chunk CRCs and summary, so it reaches the checks on
    what the records say (spaces, dtypes, shapes, episode facts, log times, schemas)."""
    from mcap.records import Channel, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import CompressionType, Writer

    from imitation.data.mcap.format import DATASET_METADATA, EPISODES_METADATA, metadata_crc

    records = [r for r in StreamReader(io.BytesIO(data), emit_chunks=False).records if isinstance(r, (Header, Metadata, Schema, Channel, Message))]
    header = next((r for r in records if isinstance(r, Header)), Header(profile="", library=""))
    body = [r for r in records if not isinstance(r, Header)]
    # Summary-section copies of schemas, channels and metadata come after the data: keep the first of each.
    seen: set = set()
    unique = []
    for record in body:
        key = (type(record).__name__, getattr(record, "id", None), getattr(record, "name", None)) if not isinstance(record, Message) else None
        if key is None or key not in seen:
            unique.append(record)
            if key is not None:
                seen.add(key)
    body = unique
    # Channels carrying Foxglove image messages (demo files' image leaves): their frames are edited
    # inside the protobuf message, so that the PNG and JPEG payloads themselves are reached.
    schemas = {r.id: r.name for r in body if isinstance(r, Schema)}
    images = {r.id: schemas[r.schema_id] for r in body if isinstance(r, Channel) and schemas.get(r.schema_id, "").startswith("foxglove.")}
    framed = [i for i, r in enumerate(body) if isinstance(r, Message) and r.channel_id in images]
    for _ in range(rng.choice((1, 1, 2, 3))):
        if not body:
            break
        index = rng.choice(framed) if framed and rng.random() < 0.5 else rng.randrange(len(body))
        record = body[index]
        roll = rng.random()
        if roll < 0.08:
            del body[index]
        elif roll < 0.14:
            body.insert(rng.randrange(len(body) + 1), record)
        elif roll < 0.18 and len(body) > 1:
            other = rng.randrange(len(body))
            body[index], body[other] = body[other], body[index]
        elif isinstance(record, Metadata):
            values = dict(record.metadata)
            key = rng.choice(sorted(values) or ["x"])
            old = values.get(key, "")
            try:
                values[key] = dumps(mutate_document(json.loads(old), rng)) if old[:1] in "[{" else _string_variant(old, rng)
            except (ValueError, RecursionError):
                values[key] = _string_variant(old, rng)
            if rng.random() < 0.3:
                values[rng.choice(("format_version", "env_id", "extra", "crc32"))] = _string_variant("1", rng)
            if record.name in (DATASET_METADATA, EPISODES_METADATA) and rng.random() < 0.9:
                values = {**{k: v for k, v in values.items() if k != "crc32"}, "crc32": metadata_crc(values)}
            body[index] = Metadata(name=record.name if rng.random() < 0.95 else _string_variant(record.name, rng), metadata=values)
        elif isinstance(record, Channel):
            metadata = dict(record.metadata)
            choice = rng.random()
            if choice < 0.4 and metadata:
                key = rng.choice(sorted(metadata))
                metadata[key] = rng.choice(("<f4", ">f8", "|b1", "<i8", "O", "<U4", "V8", "<c16", "|S3", "<M8[s]", "f16", "bogus", "[]",
                                            "[4]", "[-1]", "[0]", "[2147483648, 2147483648]", "[4, 4, 4, 4]", _string_variant(metadata[key], rng)))
            elif choice < 0.6:
                metadata = {}
            topic = record.topic if rng.random() < 0.8 else rng.choice(("/observation", "/action", "/reward", "/episode", "/time", "/info", "/observation/x", "/x", ""))
            encoding = record.message_encoding if rng.random() < 0.85 else rng.choice(("json", "cdr", "imitation.ndarray", "ros1", ""))
            body[index] = Channel(id=record.id if rng.random() < 0.9 else rng.choice((0, 1, 7, 65535)), schema_id=record.schema_id,
                                  topic=topic, message_encoding=encoding, metadata=metadata)
        elif isinstance(record, Schema):
            text = record.data
            new = mutate_bytes(text, rng) if rng.random() < 0.7 else text.replace(b"float64", rng.choice((b"float32", b"int8", b"string", b"float64[]", b"bogus")))
            body[index] = Schema(id=record.id, name=record.name if rng.random() < 0.9 else _string_variant(record.name, rng),
                                 encoding=record.encoding if rng.random() < 0.9 else rng.choice(("ros2msg", "ros2idl", "jsonschema", "")), data=new)
        elif isinstance(record, Message):
            payload = record.data
            if record.channel_id in images and rng.random() < 0.8:
                payload = mutate_image_message(payload, images[record.channel_id], rng)
            elif payload[:1] == b"{" and rng.random() < 0.7:
                payload = mutate_json_text(payload, rng)
            elif rng.random() < 0.7:
                payload = mutate_bytes(payload, rng)
            log_time = record.log_time if rng.random() < 0.7 else rng.choice((0, 1, record.log_time + 1, max(0, record.log_time - 10**9), 2**63, 2**64 - 1))
            channel_id = record.channel_id if rng.random() < 0.9 else rng.choice((0, 1, 2, 99))
            body[index] = Message(channel_id=channel_id, sequence=record.sequence, log_time=log_time, publish_time=record.publish_time, data=payload)
    out = io.BytesIO()
    writer = Writer(out, chunk_size=rng.choice((512, 64 * 1024, 1024 * 1024)), compression=rng.choice((CompressionType.ZSTD, CompressionType.NONE, CompressionType.LZ4)))
    writer.start(profile=header.profile, library=header.library)
    for record in body:
        if isinstance(record, Metadata):
            writer.add_metadata(record.name, record.metadata)
        elif isinstance(record, (Schema, Channel)):
            _register(writer, record)
        else:
            writer.add_message(record.channel_id, log_time=record.log_time, data=record.data, publish_time=record.publish_time, sequence=record.sequence)
    writer.finish()
    return out.getvalue()


def png_chunk_offsets(data: bytes) -> list[int]:
    """Where a PNG's chunks start (length, type), for biased byte mutations; [] if it is no PNG."""
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        return []
    offsets, at = [], 8
    while at + 12 <= len(data):
        offsets.append(at)
        (length,) = struct.unpack_from(">I", data, at)
        at += 12 + length
    return offsets


def fix_png_crcs(data: bytes) -> bytes:
    """Recompute every chunk's CRC, so a mutated PNG gets past the checksums to its header fields
    and zlib stream."""
    import zlib

    out, at = bytearray(data), 8
    while at + 12 <= len(out):
        (length,) = struct.unpack_from(">I", out, at)
        end = at + 8 + length
        if end + 4 > len(out):
            break
        struct.pack_into(">I", out, end, zlib.crc32(bytes(out[at + 4:end])))
        at = end + 4
    return bytes(out)


def mutate_image_message(payload: bytes, schema: str, rng: random.Random) -> bytes:
    """A foxglove.CompressedImage or RawImage message with its fields edited: most often the
    picture's bytes (PNG chunks with their CRCs made valid again, JPEG markers, raw rows), else its
    format, size, encoding or step."""
    if schema == "foxglove.RawImage":
        from foxglove_schemas_protobuf.RawImage_pb2 import RawImage as Class
    elif schema == "foxglove.CompressedImage":
        from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage as Class
    else:
        return mutate_bytes(payload, rng)
    message = Class()
    try:
        message.ParseFromString(payload)
    except Exception:  # noqa: BLE001 - an earlier edit broke it: damage the bytes instead
        return mutate_bytes(payload, rng)
    roll = rng.random()
    if roll < 0.7 or not message.data:
        data = bytes(message.data)
        hot = png_chunk_offsets(data) or [i for i in range(len(data) - 1) if data[i] == 0xFF and data[i + 1] not in (0, 0xFF)][:64]
        data = mutate_bytes(data, rng, hot=hot) if data else bytes(rng.randrange(256) for _ in range(rng.randrange(64)))
        if png_chunk_offsets(data) and rng.random() < 0.6:
            data = fix_png_crcs(data)
        message.data = data
    elif schema == "foxglove.CompressedImage":
        message.format = rng.choice(("png", "jpeg", "PNG", "jpg", "raw", "", "webp", _string_variant(message.format, rng)))
    else:
        edit = rng.choice(("width", "height", "step", "encoding"))
        if edit == "encoding":
            message.encoding = rng.choice(("mono8", "rgb8", "rgba8", "bgr8", "mono16", "16UC1", "", _string_variant(message.encoding, rng)))
        else:
            setattr(message, edit, rng.choice((0, 1, getattr(message, edit) + 1, max(0, getattr(message, edit) - 1), 2**31 - 1, 2**32 - 1)))
    return message.SerializeToString()


def _register(writer: Any, record: Any) -> None:
    """Write a schema or channel keeping its original id (the public register_* methods number
    them afresh, and ROS bags' ids need not start at 1). Uses python-mcap 1.x's private tables."""
    from mcap.records import Schema

    is_schema = isinstance(record, Schema)
    (writer._Writer__schemas if is_schema else writer._Writer__channels)[record.id] = record
    builder = writer._Writer__chunk_builder
    if builder is not None:
        (builder.add_schema if is_schema else builder.add_channel)(record)
    else:
        record.write(writer._Writer__record_builder)


def _string_variant(text: str, rng: random.Random) -> str:
    return rng.choice(("", "0", "-1", "01", "1.0", "9" * 40, "2", text + "x", text[:-1], text * 3, "\x00", "nan", str(rng.choice(INTERESTING))))


def mutate_safetensors(data: bytes, rng: random.Random) -> bytes:
    """Edit the JSON header (dtypes, shapes, offsets) and re-emit it with a consistent length."""
    try:
        (length,) = struct.unpack_from("<Q", data)
        header = json.loads(data[8 : 8 + length])
        rest = data[8 + length :]
    except (struct.error, ValueError):
        return mutate_bytes(data, rng)
    if isinstance(header, dict) and header and rng.random() < 0.5:
        name = rng.choice([k for k in header if k != "__metadata__"] or list(header))
        entry = header[name]
        if isinstance(entry, dict):
            key = rng.choice(("dtype", "shape", "data_offsets"))
            entry[key] = rng.choice(("F64", "I8", "BOOL", "F8_E4M3", "U64", "X", [], [0], [1, 2**40], [2**63, 2**63], [-1], [0, len(rest) + 8], "F16"))
            header = json.loads(json.dumps(header))
    else:
        header = mutate_document(header, rng)
    text = dumps(header).encode()
    return struct.pack("<Q", len(text)) + text + rest


def npz_bytes(arrays: dict[str, Any]) -> bytes:
    import numpy as np

    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def mutate_npz(data: bytes, rng: random.Random) -> bytes:
    """Load the arrays (never unpickling) and save them again with 1-3 edits."""
    import numpy as np

    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as archive:
            arrays = {key: archive[key] for key in archive.files}
    except Exception:  # noqa: BLE001 - a mutated seed that no longer loads: mutate its bytes
        return mutate_bytes(data, rng)
    for _ in range(rng.choice((1, 1, 2, 3))):
        if not arrays:
            break
        key = rng.choice(sorted(arrays))
        array = arrays[key]
        roll = rng.random()
        try:
            if roll < 0.12:
                del arrays[key]
            elif roll < 0.2:
                arrays[key + rng.choice(("_", "s", ""))] = arrays.pop(key)
            elif roll < 0.4:
                arrays[key] = array.astype(rng.choice(("int8", "uint64", "float16", "float64", "bool", "complex64", "<U3", "V4", "int64", "float32")))
            elif roll < 0.55:
                arrays[key] = rng.choice((array.reshape(-1), array[None], array.T, array.reshape(len(array), -1)[:, :1] if array.ndim else array))
            elif roll < 0.7:
                cut = rng.randrange(len(array) + 1) if array.ndim else 0
                arrays[key] = rng.choice((array[:cut], array[cut:], array[:0], np.concatenate([array, array[:cut]]) if array.ndim else array))
            elif roll < 0.8 and array.dtype.kind == "f":
                changed = array.copy()
                changed.reshape(-1)[rng.randrange(max(1, changed.size))] = rng.choice((np.nan, np.inf, -np.inf, 1e38, -0.0))
                arrays[key] = changed
            elif roll < 0.86:
                arrays[key] = np.asarray(rng.choice((0, 1.5, True, "text", -1)))
            elif roll < 0.9:
                arrays[key] = np.array([1, "two", None], dtype=object)  # pickled by np.savez: must be refused, never unpickled
            elif roll < 0.95:
                arrays[key] = rng.choice((np.full(array.shape, rng.choice((-1, 2**31, 0))).astype(array.dtype), np.arange(array.size).reshape(array.shape)))
            else:
                arrays[rng.choice(("obs", "acts", "actions", "rews", "rewards", "indices", "terminal", "episode_starts", "extra"))] = np.zeros(rng.choice((0, 1, 5)))
        except (ValueError, TypeError, OverflowError, IndexError):
            continue
    return npz_bytes(arrays)


def mutate_parquet(data: bytes, rng: random.Random) -> bytes:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(io.BytesIO(data))
    except Exception:  # noqa: BLE001
        return mutate_bytes(data, rng)
    roll = rng.random()
    try:
        if roll < 0.2 and table.num_columns:
            table = table.remove_column(rng.randrange(table.num_columns))
        elif roll < 0.35 and table.num_columns:
            names = list(table.column_names)
            names[rng.randrange(len(names))] += rng.choice(("_", "x"))
            table = table.rename_columns(names)
        elif roll < 0.55:
            cut = rng.randrange(table.num_rows + 1)
            table = rng.choice((table.slice(0, cut), table.slice(cut), table.slice(0, 0)))
        elif roll < 0.75 and table.num_columns:
            index = rng.randrange(table.num_columns)
            column = table.column(index)
            target = rng.choice((pa.string(), pa.float64(), pa.int8(), pa.bool_(), pa.list_(pa.float32()), pa.float16()))
            try:
                column = column.cast(target, safe=False)
            except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
                column = pa.nulls(table.num_rows, target)
            table = table.set_column(index, table.column_names[index], column)
        elif table.num_columns:
            index = rng.randrange(table.num_columns)
            table = table.set_column(index, table.column_names[index], pa.nulls(table.num_rows, table.column(index).type))
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, pa.ArrowTypeError, ValueError, IndexError):
        return mutate_bytes(data, rng)
    out = io.BytesIO()
    pq.write_table(table, out)
    return out.getvalue()


# ------------------------------------------------------------------------------------------------
# Targets: seeds, how to mutate an input, and what reading it means


@dataclass
class Target:
    name: str
    what: str
    seeds: Callable[[Path], list[Files]]  # built once, in a work folder
    mutate: Callable[[Files, random.Random, list[Files]], Files]
    run: Callable[[Path, Path], str]  # (input folder, scratch folder) -> outcome
    needs_testdata: bool = False


def _read_folder(folder: Path, prefix: str = "", skip: tuple[str, ...] = ()) -> Files:
    return {prefix + str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file() and not any(s in p.parts for s in skip)}


def _pick(files: Files, rng: random.Random, weights: Callable[[str], float]) -> str:
    names = sorted(files)
    return rng.choices(names, weights=[weights(name) for name in names])[0]


def _donors(seeds: list[Files], name: str) -> list[bytes]:
    return [files[name] for files in seeds if name in files]


# -- demo files: the MCAP reader, `info`, the bulk loader ------------------------------------------


def demo_seeds(work: Path) -> list[Files]:
    import gymnasium as gym
    import numpy as np

    from imitation.data.mcap.writer import write_episodes
    from imitation.data.types import Episode

    seeds = [{"demo.mcap": path.read_bytes()} for path in sorted((REPO / "datasets").glob("*.mcap"))]
    # A file using what the bundled ones do not: Dict observations, MultiDiscrete/MultiBinary
    # actions, own timestamps (/time), infos (/info), several blocks per episode, no compression.
    observation_space = gym.spaces.Dict({"pos": gym.spaces.Box(-1, 1, (2,), np.float32), "mode": gym.spaces.Discrete(3)})
    action_space = gym.spaces.Dict({"keys": gym.spaces.MultiBinary(3), "gear": gym.spaces.MultiDiscrete([2, 4])})
    rng = np.random.default_rng(0)
    episodes = []
    for i, steps in enumerate((5, 9, 0, 7)):
        episodes.append(Episode(
            observations={"pos": rng.uniform(-1, 1, (steps + 1, 2)).astype(np.float32), "mode": rng.integers(0, 3, steps + 1)},
            actions={"keys": rng.integers(0, 2, (steps, 3)).astype(np.int8), "gear": rng.integers(0, 2, (steps, 2))},
            rewards=rng.normal(size=steps), terminated=i % 2 == 0, truncated=i % 2 == 1,
            infos=[{"t": t} for t in range(steps)], timestamps=10**9 * i + np.arange(steps + 1) * 10**7, metadata={"i": i},
        ))
    path = work / "dict.mcap"
    write_episodes(path, episodes, env_id="Fuzz-v0", observation_space=observation_space, action_space=action_space, block_steps=3, compression="none")
    seeds.append({"demo.mcap": path.read_bytes()})
    seeds.extend({"demo.mcap": image_demo(work / f"images-{codec}.mcap", codec).read_bytes()} for codec in ("png", "jpeg", "raw"))
    seeds.append({"demo.mcap": image_demo(work / "images-webp.mcap", "webp", grey=False).read_bytes()})
    seeds.append({"demo.mcap": progressive(image_demo(work / "images-jpeg.mcap", "jpeg"), work / "images-progressive.mcap").read_bytes()})
    return seeds


def progressive(path: Path, out: Path) -> Path:
    """The JPEG image demo `path` with every frame encoded again by Pillow as a progressive JPEG
    (10 scans for colour, 6 for grey, which the reader counts from the markers before decoding)."""
    import numpy as np
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from mcap.reader import make_reader
    from mcap.writer import Writer
    from PIL import Image

    with open(path, "rb") as stream, open(out, "wb") as target:
        reader = make_reader(stream)
        writer = Writer(target)
        writer.start(profile="", library="fuzz")
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, record.metadata)
        summary = reader.get_summary()
        schemas = {s.id: writer.register_schema(s.name, s.encoding, s.data) for s in summary.schemas.values()}
        channels = {c.id: writer.register_channel(c.topic, c.message_encoding, schemas.get(c.schema_id, 0), c.metadata) for c in summary.channels.values()}
        names = {s.id: s.name for s in summary.schemas.values()}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            data = message.data
            if schema is not None and names.get(schema.id) == "foxglove.CompressedImage":
                frame = CompressedImage.FromString(data)
                picture = io.BytesIO()
                Image.fromarray(np.asarray(Image.open(io.BytesIO(frame.data)))).save(picture, format="JPEG", progressive=True, quality=95)
                data = CompressedImage(timestamp=frame.timestamp, format="jpeg", data=picture.getvalue()).SerializeToString()
            writer.add_message(channels[channel.id], log_time=message.log_time, data=data, publish_time=message.publish_time)
        writer.finish()
    return out


def image_demo(path: Path, codec: str, *, grey: bool = True) -> Path:
    """Image observations, one Foxglove image message per frame (format version 2): an RGB
    (16, 16, 3) and (if `grey`; WebP has none) a mono (8, 8) leaf beside a float vector, frames
    written with `codec`, uncompressed so that the mutations reach the frames' bytes."""
    import gymnasium as gym
    import numpy as np

    from imitation.data.mcap.writer import write_episodes
    from imitation.data.types import Episode

    leaves = {"rgb": gym.spaces.Box(0, 255, (16, 16, 3), np.uint8), "mono": gym.spaces.Box(0, 255, (8, 8), np.uint8),
              "vec": gym.spaces.Box(-1, 1, (3,), np.float32)}
    observation_space = gym.spaces.Dict({key: space for key, space in leaves.items() if grey or key != "mono"})
    rng = np.random.default_rng(1)
    episodes = []
    for i, steps in enumerate((4, 6)):
        ramp = np.linspace(0, 255, 16 * 16 * 3).reshape(16, 16, 3)  # smooth pictures, as cameras see them
        episodes.append(Episode(
            observations={key: value for key, value in {
                "rgb": np.stack([np.roll(ramp, t, axis=1) for t in range(steps + 1)]).astype(np.uint8),
                "mono": rng.integers(0, 256, (steps + 1, 8, 8), dtype=np.uint8), "vec": rng.uniform(-1, 1, (steps + 1, 3)).astype(np.float32),
            }.items() if key in observation_space.spaces},
            actions=rng.integers(0, 2, steps), rewards=np.ones(steps), terminated=i == 0, truncated=i == 1,
        ))
    return write_episodes(path, episodes, env_id="FuzzPixels-v0", observation_space=observation_space, action_space=gym.spaces.Discrete(2),
                          compression="none", image_codec=codec)


def demo_mutate(files: Files, rng: random.Random, seeds: list[Files]) -> Files:
    data = files["demo.mcap"]
    if rng.random() < 0.5:
        try:
            rewritten = rewrite_mcap(data, rng)
            # Sometimes damage the bytes as well: reaches lz4 and uncompressed chunks too.
            return {"demo.mcap": mutate_bytes(rewritten, rng) if rng.random() < 0.3 else rewritten}
        except Exception:  # noqa: BLE001 - python-mcap refused the edit: fall back to bytes
            pass
    return {"demo.mcap": mutate_bytes(data, rng, hot=mcap_record_offsets(data), donors=_donors(seeds, "demo.mcap"))}


def demo_run(folder: Path, scratch: Path) -> str:
    from imitation.data.loader import load_transitions
    from imitation.data.dataset import DemoDataset
    from imitation.data.mcap.reader import DemoFile
    from imitation.data.summary import format_summary, summarize
    from imitation.errors import DemoFileError

    path = folder / "demo.mcap"
    summary = summarize(path)  # what `imitation info` does: salvage and verify every chunk
    format_summary(summary)
    if summary["damage"]:
        episodes = DemoFile(path, salvage=True).read_episodes()
        if summary["episodes"]:
            load_transitions(DemoDataset([path], salvage=True), finite=False)
        try:
            DemoFile(path).read_episodes()  # what a learner sees: most often refused, the damage named
        except DemoFileError as error:
            NOTES.append(str(error))
        return "salvaged" if episodes else "salvaged-empty"
    demo = DemoFile(path)
    demo.read_episodes()
    list(demo)
    if demo.num_transitions:
        load_transitions(path, finite=False)
        load_transitions(path, next_observations=False)  # the finite check refuses NaN with one line
    return "loaded"


# -- run directories: config.json and model.safetensors ----------------------------------------------


def run_seeds(work: Path) -> list[Files]:
    import gymnasium as gym
    import numpy as np

    from imitation.policies import make_policy, policy_tensors
    from imitation.rewards import make_reward_model, reward_tensors
    from imitation.runs import RunWriter

    import torch

    torch.manual_seed(0)  # the same weights every run: inputs are reproducible from (target, seed, k)
    seeds = []
    cartpole = (gym.spaces.Box(-np.inf, np.inf, (4,), np.float32), gym.spaces.Discrete(2))
    pendulum = (gym.spaces.Box(np.array([-1, -1, -8], np.float32), np.array([1, 1, 8], np.float32)), gym.spaces.Box(-2, 2, (1,), np.float32))
    for name, (observations, actions), options in (("ppo", cartpole, {"hidden_sizes": [16, 16]}),
                                                   ("bc", pendulum, {"hidden_sizes": [8], "normalize_observations": True, "activation": "relu"})):
        policy = make_policy(observations, actions, **options)
        with RunWriter(work / name, config={"kind": name, "env_id": "X", "policy": policy.config.to_json()}, tensorboard=False) as run:
            run.save_weights(policy_tensors(policy))
            run.finish({})
        seeds.append(_read_folder(work / name, skip=("progress.csv", "metrics.json")))
    reward = make_reward_model(*pendulum, hidden_sizes=[8], inputs="sas", normalize_observations=True)
    policy = make_policy(*pendulum, hidden_sizes=[8])
    with RunWriter(work / "reward", config={"kind": "reward", "env_id": "X", "reward": reward.config.to_json(), "policy": policy.config.to_json()}, tensorboard=False) as run:
        run.save_weights(reward_tensors(reward) | policy_tensors(policy))
        run.finish({})
    seeds.append(_read_folder(work / "reward", skip=("progress.csv", "metrics.json")))
    return seeds


def run_mutate(files: Files, rng: random.Random, seeds: list[Files]) -> Files:
    files = dict(files)
    name = rng.choice(("config.json", "config.json", "model.safetensors"))
    if name == "config.json":
        files[name] = mutate_json_text(files[name], rng)
    elif rng.random() < 0.6:
        files[name] = mutate_safetensors(files[name], rng)
    else:
        files[name] = mutate_bytes(files[name], rng, hot=(0, 8), donors=_donors(seeds, name))
    return files


def run_run(folder: Path, scratch: Path) -> str:
    from imitation.policy_kinds import load_policy
    from imitation.rewards import load_reward

    loaded, refusal = [], None
    for kind, load in (("policy", load_policy), ("reward", load_reward)):
        try:
            load(folder)
            loaded.append(kind)
        except ImitationError as error:
            refusal = error
    if not loaded:
        raise refusal  # both readers refused it
    return "+".join(loaded)


# -- converters -------------------------------------------------------------------------------------


def _convert(path: Path, scratch: Path, **options: Any) -> str:
    from imitation.data.convert.job import convert

    out = scratch / "out.mcap"
    result = convert(path, out, progress=False, **options)
    out.unlink(missing_ok=True)
    return f"converted:{result['from']}"


def npz_seeds(work: Path) -> list[Files]:
    import numpy as np

    from imitation.data.mcap.reader import DemoFile

    seeds = []
    for name in ("expert_cartpole.npz", "expert_pendulum.npz"):
        with np.load(TESTDATA / "experts" / name, allow_pickle=False) as archive:
            arrays = {key: archive[key] for key in archive.files}
        end = int(np.flatnonzero(arrays["episode_starts"])[3])  # three episodes: the same layout, smaller
        trimmed = {key: (value[:end] if key != "episode_returns" else value[:3]) for key, value in arrays.items()}
        seeds.append({"x.npz": npz_bytes(trimmed)})
    # imitation's flat trajectory layout, from three bundled CartPole episodes.
    episodes = DemoFile(REPO / "datasets" / "CartPole-v1.mcap").read_episodes([0, 1, 2])
    lengths = np.cumsum([len(e) for e in episodes])[:-1]
    seeds.append({"x.npz": npz_bytes({
        "obs": np.concatenate([e.observations for e in episodes]), "acts": np.concatenate([e.actions for e in episodes]),
        "indices": lengths, "terminal": np.array([e.terminated for e in episodes]), "rews": np.concatenate([e.rewards for e in episodes]),
    })})
    return seeds


def npz_mutate(files: Files, rng: random.Random, seeds: list[Files]) -> Files:
    data = files["x.npz"]
    return {"x.npz": mutate_npz(data, rng) if rng.random() < 0.6 else mutate_bytes(data, rng, donors=_donors(seeds, "x.npz"))}


def npz_run(folder: Path, scratch: Path) -> str:
    return _convert(folder / "x.npz", scratch)


def lerobot_seeds(work: Path) -> list[Files]:
    g1 = TESTDATA / "lerobot" / "g1_v21"
    keep = 2
    info = json.loads((g1 / "meta" / "info.json").read_text())
    lines = (g1 / "meta" / "episodes.jsonl").read_text().splitlines()[:keep]
    info.update(total_episodes=keep, total_frames=sum(json.loads(line)["length"] for line in lines), splits={"train": f"0:{keep}"})
    v21 = {
        "ds/meta/info.json": json.dumps(info, indent=2).encode(),
        "ds/meta/episodes.jsonl": ("\n".join(lines) + "\n").encode(),
        "ds/meta/tasks.jsonl": (g1 / "meta" / "tasks.jsonl").read_bytes(),
        "ds/meta/episodes_stats.jsonl": ("\n".join((g1 / "meta" / "episodes_stats.jsonl").read_text().splitlines()[:keep]) + "\n").encode(),
    }
    for index in range(keep):
        name = f"data/chunk-000/episode_{index:06d}.parquet"
        v21["ds/" + name] = (g1 / name).read_bytes()
    # so101's 1,782-frame AV1 camera takes seconds to decode: without its videos/ folder the
    # converter skips the camera (with a warning) and converts the state; the cameras are fuzzed
    # on a small dataset of our own export instead.
    v30 = _read_folder(TESTDATA / "lerobot" / "so101_v30", prefix="ds/", skip=("videos",))
    return [v21, v30, _read_folder(small_lerobot_video(work), prefix="ds/")]


def small_lerobot_video(work: Path) -> Path:
    """A LeRobot v3.0 dataset with a camera: 2 episodes × 10 steps of a (32, 48, 3) image leaf
    beside a float vector, exported as `cli.py export --to lerobot` does (H.264 for frames this
    small), built once per work folder."""
    import gymnasium as gym
    import numpy as np

    from imitation.data.export.lerobot import export_lerobot
    from imitation.data.mcap.writer import write_episodes
    from imitation.data.types import Episode

    out = work / "lerobot-video"
    if (out / "meta" / "info.json").exists():
        return out
    observation_space = gym.spaces.Dict({"front": gym.spaces.Box(0, 255, (32, 48, 3), np.uint8), "state": gym.spaces.Box(-1, 1, (2,), np.float32)})
    rng = np.random.default_rng(2)
    ramp = np.linspace(0, 255, 32 * 48 * 3).reshape(32, 48, 3)
    episodes = [Episode(observations={"front": np.stack([np.roll(ramp, 2 * t, axis=1) for t in range(11)]).astype(np.uint8),
                                      "state": rng.uniform(-1, 1, (11, 2)).astype(np.float32)},
                        actions=rng.uniform(-1, 1, (10, 2)).astype(np.float32), rewards=np.zeros(10), terminated=True, truncated=False)
                for _ in range(2)]
    demo = write_episodes(work / "lerobot-video.mcap", episodes, env_id="FuzzCamera-v0", observation_space=observation_space,
                          action_space=gym.spaces.Box(-1, 1, (2,), np.float32))
    export_lerobot(demo, out, progress=False)
    return out


def lerobot_mutate(files: Files, rng: random.Random, seeds: list[Files]) -> Files:
    files = dict(files)

    def weight(name: str) -> float:
        return 3.0 if name.endswith(".mp4") else 6.0 if name.endswith("info.json") else 3.0 if name.endswith(".parquet") else 1.0

    name = _pick(files, rng, weight)
    data = files[name]
    if name.endswith(".json"):
        files[name] = mutate_json_text(data, rng)
    elif name.endswith(".jsonl") and rng.random() < 0.7:
        lines = data.splitlines() or [b"{}"]
        at = rng.randrange(len(lines))
        lines[at] = mutate_json_text(lines[at], rng)
        files[name] = b"\n".join(lines) + b"\n"
    elif name.endswith(".parquet") and rng.random() < 0.7:
        files[name] = mutate_parquet(data, rng)
    elif rng.random() < 0.1:
        del files[name]
    else:
        files[name] = mutate_bytes(data, rng)
    return files


def lerobot_run(folder: Path, scratch: Path) -> str:
    return _convert(folder / "ds", scratch)


TURTLE_MAP = {
    "rate_hz": 10, "time": "log",
    "observation": [{"topic": "/turtle1/pose", "fields": ["x", "y", "theta", "linear_velocity", "angular_velocity"]}],
    "action": [{"topic": "/turtle1/cmd_vel", "fields": ["linear.x", "angular.z"]}],
    "episodes": {"split": "file"},
}


def _yaml(data: Any) -> bytes:
    import yaml

    return yaml.safe_dump(data).encode()


def small_turtle_bag(path: Path, seconds: float = 3.0) -> Path:
    """The first seconds of PlotJuggler's turtlesim bag, written again with rosbags (a real ROS 1
    bag, ten times smaller, so each fuzzed input reads in milliseconds)."""
    from rosbags.rosbag1 import Reader, Writer

    with Reader(TESTDATA / "ros1" / "plotjuggler_example.bag") as reader:
        start = reader.start_time
        wanted = [c for c in reader.connections if c.topic in ("/turtle1/pose", "/turtle1/cmd_vel", "/rosout")]
        path.unlink(missing_ok=True)
        with Writer(path) as writer:
            added: dict[tuple, Any] = {}
            mapping = {}
            for c in wanted:  # one connection per topic and type, however many publishers it had
                key = (c.topic, c.msgtype, c.digest)
                if key not in added:
                    added[key] = writer.add_connection(c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest)
                mapping[c.id] = added[key]
            for connection, timestamp, raw in reader.messages(connections=wanted):
                if timestamp - start > seconds * 1e9:
                    break
                writer.write(mapping[connection.id], timestamp, raw)
    return path


def ros1_seeds(work: Path) -> list[Files]:
    bag = small_turtle_bag(work / "turtle.bag")
    interpolate = {**TURTLE_MAP, "align": "interpolate", "episodes": {"split": "gap", "seconds": 0.5}}
    return [{"bag.bag": bag.read_bytes(), "map.yaml": _yaml(TURTLE_MAP)}, {"bag.bag": bag.read_bytes(), "map.yaml": _yaml(interpolate)}]


def ros1_mutate(files: Files, rng: random.Random, seeds: list[Files]) -> Files:
    files = dict(files)
    if rng.random() < 0.1:
        files["map.yaml"] = mutate_yaml_text(files["map.yaml"], rng)
    else:
        files["bag.bag"] = mutate_bytes(files["bag.bag"], rng, donors=_donors(seeds, "bag.bag"))
    return files


def _inspect_and_convert(bag: Path, map_path: Path | None, scratch: Path, source: str) -> str:
    from imitation.data.convert.job import inspect
    from imitation.data.convert.inspect import format_report, starter_map

    report = inspect(bag, source=source)
    format_report(report)
    starter_map(report)
    if map_path is None or not map_path.exists():
        return "inspected"
    return _convert(bag, scratch, source=source, map_path=map_path)


def ros1_run(folder: Path, scratch: Path) -> str:
    return _inspect_and_convert(folder / "bag.bag", folder / "map.yaml", scratch, "ros1")


def ros2_seeds(work: Path) -> list[Files]:
    root = TESTDATA / "ros2"
    twist_map = {"rate_hz": 25, "observation": [{"topic": "/vehicle/cmd_vel", "fields": ["twist.linear.x", "twist.angular.z"]}],
                 "action": [{"topic": "/scaled/cmd_vel", "fields": ["twist.linear.x", "twist.angular.z"]}], "time": "header"}
    seeds = [{"bag/bag.mcap": (root / "replay_testing" / "cmd_vel_only_2.mcap").read_bytes(), "map.yaml": _yaml(twist_map)}]
    # The rosbag2 folders whose messages are numbers convert with a map (tests/convert/test_ros.py);
    # the others, text and service events, are inspected only.
    arrays_map = {"rate_hz": 10, "observation": [{"topic": "/one_shot/joint_state", "fields": ["position", "velocity", "effort"]}],
                  "action": [{"topic": "/one_shot/imu", "fields": ["linear_acceleration.z"]}]}
    base_map = {"rate_hz": 10, "observation": [{"topic": "/one_shot/vector3", "fields": ["x", "y", "z"]}],
                "action": [{"topic": "/one_shot/twist", "fields": ["linear.x", "angular.z"]}]}
    for folder, bag_map in (("rosbag2parquet/array_msgs", arrays_map), ("rosbag2_tests/cdr_test", None), ("rosbag2_tests/talker", None),
                            ("rosbag2_tests/bag_with_topics_and_service_events", None), ("rosbag2parquet/base_msgs", base_map)):
        files = _read_folder(root / folder, prefix="bag/")
        if bag_map is not None:
            files["map.yaml"] = _yaml(bag_map)
        seeds.append(files)
    # Cameras: a sensor_msgs/Image and two CompressedImage topics (PNG, progressive JPEG), mapped with image entries.
    camera_map = {"rate_hz": 10, "observation": [{"topic": "/joint", "fields": ["position"]}, {"topic": "/camera/raw", "image": "front", "size": [8, 12]},
                                                 {"topic": "/camera/compressed", "image": "wrist"}, {"topic": "/camera/jpeg", "image": "side"}],
                  "action": [{"topic": "/cmd", "fields": ["data"]}]}
    seeds.append({**_read_folder(camera_bag(work / "camera"), prefix="bag/"), "map.yaml": _yaml(camera_map)})
    return seeds


def camera_bag(folder: Path) -> Path:
    """A ROS 2 MCAP bag (rosbag2 folder) of 6 steps at 10 Hz: 8x12 frames on a raw rgb8 topic with
    padded rows, a PNG and a progressive JPEG CompressedImage topic (whose scans the converter
    counts from the markers), a joint state and a command."""
    import numpy as np
    from PIL import Image
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    start = 1_700_000_000 * 10**9
    shutil.rmtree(folder, ignore_errors=True)
    with Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        topics = {topic: writer.add_connection(topic, msgtype, typestore=store) for topic, msgtype in (
            ("/camera/raw", "sensor_msgs/msg/Image"), ("/camera/compressed", "sensor_msgs/msg/CompressedImage"),
            ("/camera/jpeg", "sensor_msgs/msg/CompressedImage"),
            ("/joint", "sensor_msgs/msg/JointState"), ("/cmd", "std_msgs/msg/Float64"))}

        def write(topic: str, time_ns: int, message: Any) -> None:
            writer.write(topics[topic], time_ns, store.serialize_cdr(message, message.__msgtype__))

        for i in range(6):
            t = start + i * 10**8
            header = types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9), frame_id="camera")
            pixels = ((np.arange(8 * 12 * 3).reshape(8, 12, 3) * 3 + 20 * i) % 256).astype(np.uint8)
            rows = np.concatenate([pixels.reshape(8, -1), np.full((8, 4), 0xAB, np.uint8)], axis=1)
            write("/camera/raw", t, types["sensor_msgs/msg/Image"](header=header, height=8, width=12, encoding="rgb8", is_bigendian=0, step=rows.shape[1], data=rows.reshape(-1)))
            png = io.BytesIO()
            Image.fromarray(pixels).save(png, format="PNG")
            write("/camera/compressed", t, types["sensor_msgs/msg/CompressedImage"](header=header, format="png", data=np.frombuffer(png.getvalue(), np.uint8)))
            jpeg = io.BytesIO()
            Image.fromarray(pixels).save(jpeg, format="JPEG", progressive=True)
            write("/camera/jpeg", t, types["sensor_msgs/msg/CompressedImage"](header=header, format="jpeg", data=np.frombuffer(jpeg.getvalue(), np.uint8)))
            write("/joint", t + 10**6, types["sensor_msgs/msg/JointState"](header=header, name=["a"], position=np.array([0.1 * i]), velocity=np.zeros(1), effort=np.zeros(0)))
            write("/cmd", t + 2 * 10**6, types["std_msgs/msg/Float64"](data=float(i % 3)))
    return folder


def ros2_mutate(files: Files, rng: random.Random, seeds: list[Files]) -> Files:
    files = dict(files)
    name = _pick(files, rng, lambda n: 8.0 if n.endswith(".mcap") else 1.0)
    data = files[name]
    if name.endswith(".mcap"):
        if rng.random() < 0.5:
            try:
                files[name] = rewrite_mcap(data, rng)
                return files
            except Exception:  # noqa: BLE001
                pass
        files[name] = mutate_bytes(data, rng, hot=mcap_record_offsets(data))
    else:
        files[name] = mutate_yaml_text(data, rng)
    return files


def ros2_run(folder: Path, scratch: Path) -> str:
    bag = folder / "bag"
    target = bag / "bag.mcap" if (bag / "bag.mcap").exists() and not (bag / "metadata.yaml").exists() else bag
    return _inspect_and_convert(target, folder / "map.yaml", scratch, "ros2")


def small_sqlite_bag(folder: Path, per_topic: int = 40) -> Path:
    """PlotJuggler's rosbag2 sqlite bag cut to its first messages of each topic."""
    source = TESTDATA / "ros1" / "plotjuggler_rosbag2_sqlite"
    folder.mkdir(parents=True, exist_ok=True)
    db = folder / "rosbag2_test_0.db3"
    shutil.copy(source / "rosbag2_test_0.db3", db)
    with contextlib.closing(sqlite3.connect(db)) as connection:
        connection.execute("DELETE FROM messages WHERE id NOT IN (SELECT id FROM (SELECT id, ROW_NUMBER() OVER (PARTITION BY topic_id ORDER BY timestamp) AS n FROM messages) WHERE n <= ?)", (per_topic,))
        connection.commit()
        connection.execute("VACUUM")
    shutil.copy(source / "metadata.yaml", folder / "metadata.yaml")
    return folder


def sqlite_seeds(work: Path) -> list[Files]:
    bag = small_sqlite_bag(work / "sqlite")
    imu_map = {"rate_hz": 20, "observation": [{"topic": "/imu", "fields": ["angular_velocity.x", "angular_velocity.y", "linear_acceleration.z"]}],
               "action": [{"topic": "/pose", "fields": ["pose.position.x", "pose.orientation.w"]}], "time": "header",
               "episodes": {"split": "gap", "seconds": 1.0}}
    return [{**_read_folder(bag, prefix="bag/"), "map.yaml": _yaml(imu_map)}]


def sqlite_mutate(files: Files, rng: random.Random, seeds: list[Files]) -> Files:
    files = dict(files)
    roll = rng.random()
    if roll < 0.75:
        files["bag/rosbag2_test_0.db3"] = mutate_bytes(files["bag/rosbag2_test_0.db3"], rng, hot=range(0, 100, 4))
    elif roll < 0.92:
        files["bag/metadata.yaml"] = mutate_yaml_text(files["bag/metadata.yaml"], rng)
    else:
        files["map.yaml"] = mutate_yaml_text(files["map.yaml"], rng)
    return files


def sqlite_run(folder: Path, scratch: Path) -> str:
    return _inspect_and_convert(folder / "bag", folder / "map.yaml", scratch, "ros2")


_MAP_BAG: dict[str, Path] = {}


def map_seeds(work: Path) -> list[Files]:
    _MAP_BAG["bag"] = small_turtle_bag(work / "map-turtle.bag")
    variants = [
        TURTLE_MAP,
        {**TURTLE_MAP, "align": "interpolate", "episodes": {"split": "gap", "seconds": 0.3}, "env_id": None},
        {**TURTLE_MAP, "time": "log", "reward": {"topic": "/turtle1/pose", "field": "linear_velocity"},
         "action": [{"topic": "/turtle1/cmd_vel", "fields": ["linear.x"], "default": 0.0, "max_age": 0.5, "align": "hold"}]},
        {**TURTLE_MAP, "episodes": {"split": "topic", "topic": "/rosout"}},
    ]
    return [{"map.yaml": _yaml(variant)} for variant in variants]


def map_mutate(files: Files, rng: random.Random, seeds: list[Files]) -> Files:
    return {"map.yaml": mutate_yaml_text(files["map.yaml"], rng)}


def map_run(folder: Path, scratch: Path) -> str:
    from imitation.data.convert.maps import load_map

    load_map(folder / "map.yaml")
    return _convert(_MAP_BAG["bag"], scratch, source="ros1", map_path=folder / "map.yaml")


# -- stable-baselines3 zips: load_sb3_policy ---------------------------------------------------------


def sb3_seeds(work: Path) -> list[Files]:
    """A zip as SB3 2.x writes it (tests/sb3_zips.py) and, with ../shared/testdata, the real
    ones: a PPO CartPole agent and the zoo's."""
    import gymnasium as gym
    import numpy as np
    import torch

    sys.path.insert(0, str(REPO / "tests"))
    from sb3_zips import sb3_weights, space_entry

    buffer = io.BytesIO()
    torch.save(sb3_weights(4, 2, pi=[8], vf=[8]), buffer)
    data = {"observation_space": space_entry(gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)), "action_space": space_entry(gym.spaces.Discrete(2)),
            "policy_kwargs": {}, "use_sde": False}
    seeds = [{"model.zip": _zip({"data": json.dumps(data).encode(), "policy.pth": buffer.getvalue()})}]
    real = TESTDATA / "experts" / "sb3_ppo_cartpole" / "CartPole-v1.zip"
    if real.is_file():
        seeds.append({"model.zip": real.read_bytes()})
    return seeds


def _zip(members: dict[str, bytes]) -> bytes:
    import zipfile

    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, content in members.items():
            archive.writestr(name, content)
    return buffer.getvalue()


def sb3_mutate(files: Files, rng: random.Random, seeds: list[Files]) -> Files:
    """Edit one member (the data JSON node by node, policy.pth's bytes) and zip it again, or
    mutate the zip's own bytes (its headers' sizes and offsets)."""
    import zipfile

    data = files["model.zip"]
    if rng.random() < 0.3:
        return {"model.zip": mutate_bytes(data, rng, hot=[i for i in range(len(data) - 3) if data[i : i + 2] == b"PK"])}
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    name = rng.choice([n for n in ("data", "data", "policy.pth") if n in members] or list(members))
    members[name] = mutate_json_text(members[name], rng) if name == "data" else mutate_bytes(members[name], rng, hot=(0, 64))
    return {"model.zip": _zip(members)}


def sb3_run(folder: Path, scratch: Path) -> str:
    from imitation.experts.sb3 import load_sb3_policy

    policy = load_sb3_policy(folder / "model.zip")
    return "loaded:" + ("continuous" if policy.is_continuous else "discrete")


# -- whole commands: exit codes, one stderr line, nothing left behind --------------------------------

_CLI_BATCH = r"""
import contextlib, io, json, sys, traceback
import cli
results = []
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        try:
            code = cli.main(argv)
        except SystemExit as exit:
            code = exit.code if isinstance(exit.code, int) else 1
        except BaseException:
            traceback.print_exc()
            code = 1
    results.append([code, err.getvalue()])
print(json.dumps(results))
"""


def cli_run(folder: Path, scratch: Path) -> str:
    """`info`, `export --to foxglove` and `recover` on a mutated demo file, in a fresh process
    running the command line's own main: each must exit 0, or 1 with exactly one `error:` line
    and no traceback, and leave no partial or lock file behind."""
    import subprocess

    demo = folder / "demo.mcap"
    partial = scratch / "copy.mcap.partial"
    partial.write_bytes(demo.read_bytes())
    commands = [["info", str(demo)], ["export", str(demo), "--to", "foxglove", str(scratch / "steps.mcap"), "--quiet"], ["recover", str(partial)]]
    process = subprocess.run([sys.executable, "-c", _CLI_BATCH, json.dumps(commands)], capture_output=True, text=True, cwd=REPO, timeout=120)
    if process.returncode != 0:
        raise AssertionError(f"the command process died ({process.returncode}): {process.stderr[-500:]}")
    outcomes = []
    for argv, (code, stderr) in zip(commands, json.loads(process.stdout.splitlines()[-1])):
        lines = [line for line in stderr.splitlines() if line.strip() and not line.startswith("warning:")]
        if "Traceback" in stderr or code not in (0, 1) or (code == 1 and (len(lines) != 1 or not lines[0].startswith("error: "))):
            raise AssertionError(f"imitation {argv[0]}: exit {code}, stderr {stderr[-500:]!r}")
        if code == 1:
            NOTES.append(lines[0].removeprefix("error: "))
        outcomes.append(f"{argv[0]}:{code}")
    leftovers = sorted(p.name for p in scratch.iterdir() if p.name.endswith((".lock", ".recovering")) or p.name == "steps.mcap.partial")
    if leftovers:
        raise AssertionError(f"left behind: {leftovers}")
    if all(outcome.endswith(":1") for outcome in outcomes):
        raise ImitationError(NOTES.pop(0))  # every command refused the input: count it as refused
    return ",".join(outcomes)


def cli_mutate(files: Files, rng: random.Random, seeds: list[Files]) -> Files:
    return demo_mutate(files, rng, seeds)


def cli_seeds(work: Path) -> list[Files]:
    return [{"demo.mcap": (REPO / "datasets" / name).read_bytes()} for name in ("CartPole-v1.mcap", "Pendulum-v1.mcap")]


TARGETS = {
    target.name: target
    for target in (
        Target("demo", "MCAP demo reader + info + bulk loader (bundled datasets/*.mcap, a Dict-space file, image files: png, jpeg, progressive jpeg, raw, webp)", demo_seeds, demo_mutate, demo_run),
        Target("run", "run directories: load_policy and load_reward (config.json + model.safetensors)", run_seeds, run_mutate, run_run),
        Target("npz", "npz converter (SB GAIL and imitation layouts)", npz_seeds, npz_mutate, npz_run, needs_testdata=True),
        Target("lerobot", "LeRobot converter (v2.1 and v3.0: meta/*.json(l), parquet, an H.264 camera video)", lerobot_seeds, lerobot_mutate, lerobot_run, needs_testdata=True),
        Target("ros2", "ROS 2 MCAP bags: inspect + convert (files and rosbag2 folders, a camera bag: Image and CompressedImage, PNG and progressive JPEG)", ros2_seeds, ros2_mutate, ros2_run, needs_testdata=True),
        Target("ros1", "ROS 1 bag: inspect + convert", ros1_seeds, ros1_mutate, ros1_run, needs_testdata=True),
        Target("sqlite", "rosbag2 sqlite: inspect + convert (.db3 and metadata.yaml)", sqlite_seeds, sqlite_mutate, sqlite_run, needs_testdata=True),
        Target("map", "conversion-map YAML: load_map + convert with it", map_seeds, map_mutate, map_run, needs_testdata=True),
        Target("sb3", "stable-baselines3 zips: load_sb3_policy (data JSON, policy.pth, the zip's headers)", sb3_seeds, sb3_mutate, sb3_run),
        Target("cli", "whole commands (info, export --to foxglove, recover) on demo files, in a fresh process each", cli_seeds, cli_mutate, cli_run),
    )
}


# ------------------------------------------------------------------------------------------------
# The harness


class InputTimeout(BaseException):
    """One input ran past the limit (BaseException: no `except Exception` in the code under test swallows it)."""


@dataclass
class Failure:
    index: int
    error: str
    where: str
    saved: str


@dataclass
class Report:
    target: str
    inputs: int = 0
    outcomes: dict[str, int] = field(default_factory=dict)
    refused: int = 0
    failures: list[Failure] = field(default_factory=list)
    refusals: dict[str, int] = field(default_factory=dict)  # distinct refusal messages (input paths blanked), at most 5,000
    seconds: float = 0.0
    slowest: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        distinct = {}
        for failure in self.failures:
            distinct.setdefault((failure.error.split(":")[0], failure.where), failure)
        return {
            "target": self.target, "inputs": self.inputs, "refused_with_imitation_error": self.refused, "outcomes": self.outcomes,
            "failures": len(self.failures), "distinct_failures": [vars(f) for f in distinct.values()],
            "seconds": round(self.seconds, 1), "inputs_per_second": round(self.inputs / self.seconds, 1) if self.seconds else None,
            "slowest_input_seconds": round(self.slowest, 3),
        }


def _where(error: BaseException) -> str:
    """The innermost frame in the project's code (where the fix goes), else the innermost one."""
    frames = traceback.extract_tb(error.__traceback__)
    ours = [f for f in frames if str(REPO / "imitation") in f.filename or f.filename.endswith("cli.py")]
    frame = (ours or frames or [None])[-1]
    return f"{Path(frame.filename).relative_to(REPO) if str(REPO) in frame.filename else frame.filename}:{frame.lineno}" if frame else "?"


def _materialise(files: Files, case: Path, scratch: Path) -> None:
    for folder in (case, scratch):
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir()
    for relative, content in files.items():
        (case / relative).parent.mkdir(parents=True, exist_ok=True)
        (case / relative).write_bytes(content)


def _alarm(signum: int, frame: Any) -> None:
    raise InputTimeout()


def fuzz(name: str, *, count: int, seed: int = 0, time_limit: float = 30.0, failures_dir: Path | None = None, progress: bool = False) -> Report:
    """Feed `count` mutated inputs to target `name`; every failure's input is saved under `failures_dir`."""
    target = TARGETS[name]
    report = Report(name)
    work = Path(tempfile.mkdtemp(prefix=f"imitation-fuzz-{name}-"))
    failures_dir = failures_dir or Path(tempfile.mkdtemp(prefix=f"imitation-fuzz-failures-{name}-"))
    previous = signal.signal(signal.SIGALRM, _alarm) if time_limit else None
    started = time.perf_counter()
    try:
        with warnings.catch_warnings(), contextlib.redirect_stderr(io.StringIO()):
            warnings.simplefilter("ignore")
            seeds = target.seeds(work)
            for index, files in enumerate(seeds):  # the unmutated seeds must load, or the run means little
                _materialise(files, work / "case", work / "scratch")
                try:
                    target.run(work / "case", work / "scratch")
                except BaseException as error:
                    raise RuntimeError(f"{name}: seed {index} does not load: {type(error).__name__}: {error}") from error
            for k in range(count):
                rng = random.Random(f"{name}:{seed}:{k}")
                files = target.mutate(rng.choice(seeds), rng, seeds)
                case, scratch = work / "case", work / "scratch"
                _materialise(files, case, scratch)
                tick = time.perf_counter()
                NOTES.clear()
                try:
                    if time_limit:
                        signal.setitimer(signal.ITIMER_REAL, time_limit)
                    outcome = target.run(case, scratch)
                    report.outcomes[outcome] = report.outcomes.get(outcome, 0) + 1
                except ImitationError as error:
                    report.refused += 1
                    if not str(error).strip():
                        raise AssertionError("an ImitationError without a message") from error
                    message = str(error).replace(str(case), "<input>").replace(str(work), "<work>")
                    if message in report.refusals or len(report.refusals) < 5000:
                        report.refusals[message] = report.refusals.get(message, 0) + 1
                except (Exception, InputTimeout) as error:  # noqa: BLE001 - every other one is a finding
                    saved = failures_dir / f"{name}-seed{seed}-{k}"
                    shutil.rmtree(saved, ignore_errors=True)
                    shutil.copytree(case, saved)
                    text = "timeout" if isinstance(error, InputTimeout) else "".join(traceback.format_exception(error))
                    (saved / "traceback.txt").write_text(text)
                    report.failures.append(Failure(k, f"{type(error).__name__}: {str(error)[:300]}", _where(error), str(saved)))
                finally:
                    if time_limit:
                        signal.setitimer(signal.ITIMER_REAL, 0)
                for note in NOTES:
                    message = note.replace(str(case), "<input>").replace(str(work), "<work>")
                    if message in report.refusals or len(report.refusals) < 5000:
                        report.refusals[message] = report.refusals.get(message, 0) + 1
                report.slowest = max(report.slowest, time.perf_counter() - tick)
                report.inputs += 1
                if progress and (k + 1) % 500 == 0:
                    print(f"  {name}: {k + 1}/{count}, {len(report.failures)} failures, {time.perf_counter() - started:.0f} s", file=sys.__stderr__, flush=True)
    finally:
        if previous is not None:
            signal.signal(signal.SIGALRM, previous)
        shutil.rmtree(work, ignore_errors=True)
    report.seconds = time.perf_counter() - started
    return report


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="targets:\n" + "\n".join(f"  {name:8} {target.what}" for name, target in TARGETS.items()),
    )
    parser.add_argument("--targets", default=",".join(TARGETS), help=f"comma-separated, from {', '.join(TARGETS)} (default: all)")
    parser.add_argument("--count", type=int, default=10_000, help="mutated inputs per target (default: 10000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--time-limit", type=float, default=30.0, help="seconds one input may take before it counts as a hang")
    parser.add_argument("--memory-limit-gb", type=float, default=12.0, help="address-space limit, so a runaway allocation fails instead of swapping (0: none)")
    parser.add_argument("--failures", type=Path, help="where failing inputs are saved (default: a new temp folder)")
    parser.add_argument("--json", action="store_true", help="print one JSON object with the figures")
    parser.add_argument("--refusals", type=Path, help="write every distinct refusal message, by target, to this JSON file")
    args = parser.parse_args(argv)
    names = [name.strip() for name in args.targets.split(",") if name.strip()]
    unknown = [name for name in names if name not in TARGETS]
    if unknown:
        parser.error(f"unknown targets {unknown}")
    if args.memory_limit_gb:
        limit = int(args.memory_limit_gb * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    failures = args.failures or Path(tempfile.mkdtemp(prefix="imitation-fuzz-failures-"))
    reports = []
    refusals: dict[str, dict[str, int]] = {}
    for name in names:
        if TARGETS[name].needs_testdata and not TESTDATA.is_dir():
            print(f"{name}: skipped, {TESTDATA} not found", file=sys.stderr)
            continue
        report = fuzz(name, count=args.count, seed=args.seed, time_limit=args.time_limit, failures_dir=failures, progress=not args.json)
        reports.append(report.as_dict())
        refusals[name] = report.refusals
        if not args.json:
            figures = reports[-1]
            print(f"{name}: {figures['inputs']} inputs in {figures['seconds']} s ({figures['inputs_per_second']}/s), "
                  f"{figures['refused_with_imitation_error']} refused with ImitationError, outcomes {figures['outcomes']}, "
                  f"{figures['failures']} failures ({len(figures['distinct_failures'])} distinct)", flush=True)
            for failure in figures["distinct_failures"]:
                print(f"    {failure['where']}: {failure['error'][:200]}  [input {failure['saved']}]", flush=True)
    if args.refusals:
        args.refusals.write_text(json.dumps(refusals, indent=1))
    if args.json:
        print(json.dumps({"seed": args.seed, "count": args.count, "failures_dir": str(failures), "targets": reports}))
    return 1 if any(report["failures"] for report in reports) else 0


if __name__ == "__main__":
    sys.exit(main())

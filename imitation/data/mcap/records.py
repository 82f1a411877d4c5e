"""The raw MCAP records of a demo file: bounds-checked record iteration, chunk headers, chunk
decompression and checksums, and reading chunks on a thread pool. Any structural problem
raises `Damage`, which the reader reports or salvages around."""

from __future__ import annotations

import struct
import zlib
from collections import deque
from collections.abc import Buffer, Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from io import BytesIO
from typing import TYPE_CHECKING, Any

import lz4.frame
import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Schema

from imitation.limits import LIMITS

if TYPE_CHECKING:
    from imitation.data.mcap.source import ByteSource

# The opcodes of the MCAP records read here (https://mcap.dev/spec).
OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x02, 0x03, 0x04, 0x05, 0x06
OP_CHUNK_INDEX, OP_METADATA, OP_METADATA_INDEX, OP_DATA_END = 0x08, 0x0C, 0x0D, 0x0F
_RECORD_HEADER = struct.Struct("<BQ")
_MESSAGE_HEADER = struct.Struct("<HIQQ")


class Damage(Exception):
    """A structural problem found while reading; the reader makes it a DemoFileError or salvages around it."""


@dataclass(frozen=True)
class ChunkRef:
    """Where a Chunk record lies in the file, and the time range of its messages."""

    offset: int
    length: int
    start_time: int
    end_time: int
    uncompressed_size: int


def iter_records(buffer: bytes | memoryview, start: int, end: int) -> Iterator[tuple[int, memoryview]]:
    """(opcode, record body) for each record in buffer[start:end], bounds-checked."""
    for opcode, body, _ in iter_records_with_offsets(buffer, start, end):
        yield opcode, body


def iter_records_with_offsets(buffer: Buffer, start: int, end: int) -> Iterator[tuple[int, memoryview, int]]:
    """(opcode, record body, record offset) for each record in buffer[start:end], bounds-checked."""
    view = memoryview(buffer)
    offset = start
    while offset < end:
        if end - offset < 9:
            raise Damage(f"truncated record header at byte {offset}")
        opcode, length = _RECORD_HEADER.unpack_from(view, offset)
        body_start = offset + 9
        if length > end - body_start:
            raise Damage(f"truncated: record at byte {offset} needs {length} bytes, {end - body_start} remain")
        yield opcode, view[body_start : body_start + length], offset
        offset = body_start + length


@dataclass(frozen=True)
class ChunkHeader:
    """The header of a Chunk record, and its compressed payload."""

    compression: str
    uncompressed_size: int
    uncompressed_crc: int
    payload: memoryview  # the compressed records


def chunk_header(record: memoryview) -> ChunkHeader:
    """Parse one Chunk record (opcode and length included) down to its compressed payload."""
    if len(record) < 9 or record[0] != OP_CHUNK:
        raise Damage("chunk index points at a non-chunk record")
    body = record[9:]
    try:
        _, _, uncompressed_size, uncompressed_crc, compression_length = struct.unpack_from("<QQQII", body)
        position = 32
        compression = bytes(body[position : position + compression_length]).decode()
        position += compression_length
        (data_length,) = struct.unpack_from("<Q", body, position)
        position += 8
    except (struct.error, UnicodeDecodeError) as error:
        raise Damage(f"bad chunk header ({error})") from None
    payload = body[position : position + data_length]
    if len(payload) != data_length:
        raise Damage("chunk data is truncated")
    if compression not in ("zstd", "lz4", ""):
        raise Damage(f"unsupported chunk compression {compression!r}")
    # No writer makes chunks this large (ours: 1 MiB); a header claiming more is damaged, and is
    # refused before a buffer of that size is asked for.
    if uncompressed_size > LIMITS.chunk_bytes:
        raise Damage(
            f"the chunk claims {uncompressed_size} bytes uncompressed, more than the limit chunk_bytes={LIMITS.chunk_bytes}"
        )
    return ChunkHeader(compression, uncompressed_size, uncompressed_crc, payload)


def decode_chunk(record: memoryview, out: memoryview | None = None) -> memoryview | bytes:
    """The checked, decompressed content of one Chunk record (zstd, lz4 or none), decompressed
    into `out` when given (it must hold exactly the uncompressed size).

    Decompression and CRC-32 release the GIL, so chunks decode in parallel threads."""
    header = chunk_header(record)
    compressed, uncompressed_size = header.payload, header.uncompressed_size
    content: memoryview | bytes
    if header.compression == "zstd":
        try:
            if out is not None and len(out) == uncompressed_size:
                content = _zstd_decompress_into(compressed, out)
            else:
                content = zstandard.ZstdDecompressor().decompress(compressed, max_output_size=uncompressed_size)
        except zstandard.ZstdError as error:
            raise Damage(f"zstd cannot decompress it ({error})") from None
    elif header.compression == "lz4":
        try:
            content = lz4.frame.decompress(compressed)
        except RuntimeError as error:
            raise Damage(f"lz4 cannot decompress it ({error})") from None
    else:
        content = compressed  # a view of the record's own buffer: no copy
    if len(content) != uncompressed_size:
        raise Damage("decompressed size differs from the chunk header")
    if header.uncompressed_crc != 0 and zlib.crc32(content) != header.uncompressed_crc:
        raise Damage("checksum mismatch: the chunk's bytes were altered")
    return content


def _zstd_decompress_into(compressed: memoryview, out: memoryview) -> memoryview:
    reader = zstandard.ZstdDecompressor().stream_reader(compressed)
    filled = 0
    while filled < len(out):
        count = reader.readinto(out[filled:])
        if count == 0:
            raise Damage("zstd data ends before the chunk's uncompressed size")
        filled += count
    return out


class ChunkBuffers:
    """One large buffer for the raw records of many chunks and one for their decompressed
    content; each chunk gets its slices."""

    def __init__(self, chunks: Sequence[ChunkRef]) -> None:
        raw, content = sum(c.length for c in chunks), sum(c.uncompressed_size for c in chunks)
        try:
            self.raw = memoryview(np.empty(raw, dtype=np.uint8))
            self.content = memoryview(np.empty(content, dtype=np.uint8))
        except MemoryError:
            raise Damage(f"its chunks add up to {(raw + content) / 2**30:.1f} GiB, more than this machine can hold") from None
        self._slices: dict[int, tuple[memoryview, memoryview]] = {}
        raw_at = content_at = 0
        for c in chunks:
            self._slices[c.offset] = (
                self.raw[raw_at : raw_at + c.length],
                self.content[content_at : content_at + c.uncompressed_size],
            )
            raw_at += c.length
            content_at += c.uncompressed_size

    def __getitem__(self, chunk: ChunkRef) -> tuple[memoryview, memoryview]:
        return self._slices[chunk.offset]


def _read_chunk(source: ByteSource, chunk: ChunkRef, buffers: ChunkBuffers | None) -> memoryview | bytes:
    # pread into our own buffer, not mmap: the cost of faulting in a mapped file's pages varies
    # widely from run to run on a VM (bench/RESULTS.md).
    if buffers is None:
        record: memoryview | bytes = source.read(chunk.offset, chunk.length)
        out = None
    else:
        record, out = buffers[chunk]
        if source.readinto(record, chunk.offset) != chunk.length:
            raise Damage("chunk is truncated")
    if len(record) != chunk.length:
        raise Damage("chunk is truncated")
    return decode_chunk(memoryview(record), out)


def decode_chunks(
    source: ByteSource, chunks: Sequence[ChunkRef], buffers: ChunkBuffers | None
) -> Iterator[tuple[ChunkRef, Future]]:
    """Read and decode chunks on a small thread pool (reading, decompression and CRC-32 release
    the GIL), a bounded window ahead of the consumer, in order.

    A chunk that cannot be decoded raises Damage from its future's result()."""
    threads = min(len(chunks), source.parallel_reads, 8)
    window: deque[tuple[ChunkRef, Future]] = deque()
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for chunk in chunks:
            window.append((chunk, pool.submit(_read_chunk, source, chunk, buffers)))
            if len(window) > 2 * threads:
                yield window.popleft()
        while window:
            yield window.popleft()


def chunk_records(content: memoryview | bytes, on_channel: Callable[[Channel], Any]) -> Iterator[tuple[int, int, memoryview]]:
    """(channel id, log time, data) of each message in a decoded chunk; channels are registered."""
    view = memoryview(content)
    for opcode, inner in iter_records(view, 0, len(view)):
        if opcode == OP_MESSAGE:
            channel_id, _, log_time, _ = _MESSAGE_HEADER.unpack_from(inner)
            yield channel_id, log_time, inner[_MESSAGE_HEADER.size :]
        elif opcode == OP_CHANNEL:
            on_channel(Channel.read(ReadDataStream(BytesIO(inner))))
        elif opcode == OP_SCHEMA:
            Schema.read(ReadDataStream(BytesIO(inner)))

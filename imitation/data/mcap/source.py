"""Where a demo file's bytes come from: a local file, read with pread, or an object behind an
fsspec URL (http(s)://, s3://, gs://, memory://, ...), read by range requests, each bounded in
bytes and time (remote_reads.py). Every read is counted (bytes and reads), so tests and
benchmarks can tell what opening or loading fetched.

A source is opened per reading session and closed after it, as a file would be: a dataset of
thousands of files holds no descriptor between loads, and threads reading one file each use a
session of their own."""

from __future__ import annotations

import mmap
import os
import threading
from abc import ABC, abstractmethod
from collections.abc import Buffer
from pathlib import Path
from typing import Any, Self

from imitation.data.mcap.remote_reads import fetch_range, object_size
from imitation.errors import DemoFileError, ImitationError
from imitation.inputs import open_input_fd

# The first read that reaches an object's end fetches this much of its tail instead: footer,
# summary and episode index of a small dataset, in one request.
_TAIL_BYTES = 16 * 1024
# A read ending this close below the cached tail extends it rather than making a request of its own
# (the episode index lies right before the summary, behind a 13-byte DataEnd record).
_NEAR_TAIL = 4096
# How many chunks a remote source fetches at once: requests wait on the network, not the CPU.
_REMOTE_PARALLEL_READS = 8


def is_url(path: str | os.PathLike) -> bool:
    """Whether `path` names an object through fsspec (anything with a scheme) rather than a local file."""
    return "://" in os.fspath(path)


def refuse_url(path: str | os.PathLike) -> None:
    """Writers keep local paths: say so, rather than create a local folder named like the URL."""
    if is_url(path):
        raise ImitationError(f"{os.fspath(path)}: cannot write to a URL; write a local file, then upload it")


class ReadCounter:
    """The bytes read and the reads made through every session of one file (thread-safe)."""

    def __init__(self) -> None:
        self.bytes = 0
        self.requests = 0
        self._lock = threading.Lock()

    def add(self, count: int) -> None:
        with self._lock:
            self.bytes += count
            self.requests += 1


class ByteSource(ABC):
    """One reading session of a demo file's `size` bytes, by offset; a context manager."""

    size: int

    @property
    @abstractmethod
    def parallel_reads(self) -> int:
        """How many reads of this source are worth making at once."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    @abstractmethod
    def read(self, offset: int, length: int) -> bytes:
        """`length` bytes from `offset`, fewer where the file ends first."""

    @abstractmethod
    def readinto(self, buffer: memoryview, offset: int) -> int:
        """Fill `buffer` from `offset`; the count of bytes read (less where the file ends first)."""

    @abstractmethod
    def whole(self) -> Buffer:
        """Every byte of the file (the salvage scan reads it front to back)."""

    @abstractmethod
    def close(self) -> None:
        """End the session."""


class LocalSource(ByteSource):
    """A local file read with pread/preadv into the caller's buffers: no copy, one call a read."""

    def __init__(self, path: Path, counter: ReadCounter, size: int | None) -> None:
        self._counter = counter
        self._fd = open_input_fd(path)  # a FIFO or a device is refused, not waited on or read for ever
        self.size = size if size is not None else os.fstat(self._fd).st_size

    @property
    def parallel_reads(self) -> int:
        return os.cpu_count() or 1  # asked only when needed: on Linux it reads a file

    def read(self, offset: int, length: int) -> bytes:
        data = os.pread(self._fd, max(0, min(length, self.size - offset)), offset)
        self._counter.add(len(data))
        return data

    def readinto(self, buffer: memoryview, offset: int) -> int:
        count = os.preadv(self._fd, [buffer], offset)
        self._counter.add(count)
        return count

    def whole(self) -> Buffer:
        self._counter.add(self.size)
        return mmap.mmap(self._fd, 0, access=mmap.ACCESS_READ)

    def close(self) -> None:
        os.close(self._fd)


class RemoteSource(ByteSource):
    """An object behind an fsspec URL, read by range requests. The first read that reaches the
    object's end fetches its last `_TAIL_BYTES`, and reads just below that cached tail extend it,
    so opening a file usually costs three requests: the magic, the tail, the dataset metadata."""

    def __init__(self, url: str, counter: ReadCounter, size: int | None) -> None:
        self.name = url
        self._counter = counter
        self._fs, self._path = _filesystem(url)
        self.size = size if size is not None else self._object_size()
        # (offset, bytes) of the cached tail, replaced whole so that threads see it whole.
        self._tail: tuple[int, bytes] | None = None

    def _object_size(self) -> int:
        try:
            size = object_size(self._fs, self._path, self.name)
            reason = "the server does not say how large the object is"
        except DemoFileError:
            raise
        except Exception as error:
            size, reason = None, _reason(error)
        self._counter.add(0)  # a request (HEAD, for HTTP) that fetches no content
        if size is None:
            raise DemoFileError(f"{self.name}: cannot open: {reason}")
        return int(size)

    def read(self, offset: int, length: int) -> bytes:
        end = min(offset + length, self.size)
        if end <= offset:
            return b""
        tail = self._tail
        if tail is None and end == self.size:
            start = max(0, self.size - _TAIL_BYTES)
            tail = self._tail = (start, self._fetch(start, self.size))
        if tail is not None and offset < tail[0] <= end + _NEAR_TAIL:
            tail = self._tail = (offset, self._fetch(offset, tail[0]) + tail[1])
        if tail is not None and offset >= tail[0]:
            return tail[1][offset - tail[0] : end - tail[0]]
        return self._fetch(offset, end)

    @property
    def parallel_reads(self) -> int:
        return _REMOTE_PARALLEL_READS

    def readinto(self, buffer: memoryview, offset: int) -> int:
        data = self.read(offset, len(buffer))
        buffer[: len(data)] = data
        return len(data)

    def whole(self) -> Buffer:
        return self._fetch(0, self.size)

    def close(self) -> None:
        """Nothing to release: fsspec keeps its connections for the next session."""

    def _fetch(self, start: int, end: int) -> bytes:
        try:
            data = fetch_range(self._fs, self._path, self.name, start, end, self.size)
        except DemoFileError:
            raise
        except Exception as error:
            raise DemoFileError(f"{self.name}: cannot read: {_reason(error)}") from None
        self._counter.add(len(data))
        return data


def open_source(path: Path | str, counter: ReadCounter, size: int | None = None) -> ByteSource:
    """A reading session of `path` (a local path, or a URL as given); `size` when already known
    spares asking for it again. A file that cannot be opened is a DemoFileError naming it."""
    if isinstance(path, str) and is_url(path):
        return RemoteSource(path, counter, size)
    try:
        return LocalSource(Path(path), counter, size)
    except OSError as error:
        raise DemoFileError(f"{path}: cannot open: {error.strerror or error}") from error


def _filesystem(url: str) -> tuple[Any, str]:
    """fsspec's filesystem for `url` and the object's path in it."""
    import fsspec.core
    from fsspec.registry import known_implementations

    scheme = url.split("://", 1)[0]
    try:
        return fsspec.core.url_to_fs(url)
    except ImportError as error:
        missing = error.__cause__ if isinstance(error.__cause__, ModuleNotFoundError) else error
        implementation = known_implementations.get(scheme, {}).get("class", "")
        package = getattr(missing, "name", None) or implementation.split(".")[0] or "?"
        raise DemoFileError(
            f"{url}: reading {scheme}:// URLs needs the Python package {package} (pip install {package})"
        ) from None
    except ValueError as error:
        raise DemoFileError(f"{url}: cannot open: {_reason(error)}") from None


def _reason(error: Exception) -> str:
    """What went wrong, in a few words; fsspec's own exceptions are often generic."""
    status = getattr(error, "status", None)  # an HTTP error status (aiohttp's ClientResponseError)
    if isinstance(status, int):
        return "no such object" if status == 404 else f"the server answered {status} {getattr(error, 'message', '')}".strip()
    if isinstance(error, FileNotFoundError):
        # fsspec's HTTP filesystem reports any failure to learn the size as "not found": its cause says more.
        cause = error.__cause__
        return (
            _reason(cause) if isinstance(cause, Exception) and not isinstance(cause, FileNotFoundError) else "no such object"
        )
    if isinstance(error, OSError) and error.strerror:
        return error.strerror
    return f"{type(error).__name__}: {str(error)[:200]}"

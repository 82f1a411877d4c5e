"""Bounded requests to the object behind a demo URL: what a server sends is never trusted.

Over http(s), each answer is read only as far as the bytes asked for (a server that ignores
Range has what precedes the range skipped, not kept), and refused where it says or sends other
than what was asked, naming the server (`host:port`) and what it did. Every request is bounded
in time: LIMITS.remote_stall_seconds without a byte (to connect, to answer, between bytes; for
http(s)), LIMITS.remote_request_seconds from asking to the last byte, and all of a command's
requests together LIMITS.remote_total_seconds of wall time (any request in flight), counted from
`restart_command_clock()`. Other fsspec filesystems that talk to a server (s3, gs, ...) read
through their own clients: their requests are bounded in time, and an answer longer than asked
for is refused once read; in-process ones (memory://) are read as they are.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

from imitation.errors import DemoFileError
from imitation.limits import LIMITS, over_limit

# What an answer is read in: enough to keep a fast link busy, small beside any bound.
_READ_PIECE = 2**20
_DEFAULT_PORTS = {"http": 80, "https": 443}


class _CommandClock:
    """Seconds of wall time this command has had a remote request in flight (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._spent = 0.0
        self._in_flight = 0
        self._busy_since = 0.0

    def restart(self) -> None:
        with self._lock:
            self._spent = 0.0
            self._busy_since = time.monotonic()

    def spent(self) -> float:
        with self._lock:
            return self._spent + (time.monotonic() - self._busy_since if self._in_flight else 0.0)

    @contextlib.contextmanager
    def running(self) -> Iterator[None]:
        with self._lock:
            if self._in_flight == 0:
                self._busy_since = time.monotonic()
            self._in_flight += 1
        try:
            yield
        finally:
            with self._lock:
                self._in_flight -= 1
                if self._in_flight == 0:
                    self._spent += time.monotonic() - self._busy_since


_COMMAND_CLOCK = _CommandClock()


def restart_command_clock() -> None:
    """A command starts: its remote_total_seconds start afresh (one process may run many commands)."""
    _COMMAND_CLOCK.restart()


def server_of(url: str) -> str:
    """`host:port` of a URL, the port given or the scheme's default."""
    parts = urlsplit(url)
    port = parts.port or _DEFAULT_PORTS.get(parts.scheme)
    return f"{parts.hostname}:{port}" if port else str(parts.hostname)


@dataclass
class _Progress:
    """How far one request got, for the message when it is given up on."""

    asked: int
    received: int = 0


def is_http(fs: Any) -> bool:
    """Whether `fs` is fsspec's HTTP filesystem (aiohttp underneath)."""
    protocol = fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,)
    return "http" in protocol or "https" in protocol


def object_size(fs: Any, path: str, url: str) -> int | None:
    """The size of the object at `path` in fsspec filesystem `fs` (`url`, as the user gave it),
    None where the server does not say."""
    if is_http(fs):
        return _run(fs, url, _Progress(0), lambda: _http_size(fs, path))
    if getattr(fs, "async_impl", False):
        return _run(fs, url, _Progress(0), lambda: fs._size(path))
    return fs.size(path)


def fetch_range(fs: Any, path: str, url: str, start: int, end: int, size: int) -> bytes:
    """Bytes [start, end) of the `size`-byte object at `path` in `fs` (`url`, as the user gave
    it): exactly those, or a DemoFileError."""
    server = server_of(url)
    if end - start > LIMITS.remote_request_bytes:
        what = f"bytes one request to the server at {server} would bring (bytes {start}-{end - 1})"
        raise DemoFileError(f"{url}: {over_limit(what, end - start, 'remote_request_bytes')}")
    progress = _Progress(end - start)
    if is_http(fs):
        return _run(fs, url, progress, lambda: _http_range(fs, path, url, start, end, size, progress))
    if getattr(fs, "async_impl", False):
        data = _run(fs, url, progress, lambda: fs._cat_file(path, start=start, end=end))
    else:
        data = fs.cat_file(path, start=start, end=end)
    if len(data) == size > end - start:  # a store that ignores ranges sends it all
        data = data[start:end]
    if len(data) > end - start:
        raise misbehaved(url, server, f"sent {len(data)} bytes for a request of {end - start}")
    return data


def misbehaved(url: str, server: str, what: str) -> DemoFileError:
    """The one-line error for a server that answered other than it was asked."""
    return DemoFileError(f"{url}: the server at {server} {what}")


def _run[T](fs: Any, url: str, progress: _Progress, request: Callable[[], Awaitable[T]]) -> T:
    """`request()` on fsspec's event loop, within this request's and this command's time;
    `progress` tells how far it got."""
    import asyncio  # here, not at the top: a command that reads no URL does not pay its import

    import fsspec.asyn

    server = server_of(url)
    allowed = LIMITS.remote_total_seconds - _COMMAND_CLOCK.spent()
    seconds = min(LIMITS.remote_request_seconds, allowed)
    if seconds <= 0:
        raise _past_total(url, server)

    async def bounded() -> T:
        try:
            async with asyncio.timeout(seconds) as deadline:
                return await request()
        except TimeoutError:
            if not deadline.expired():  # aiohttp's stall timeout, not the deadline
                raise DemoFileError(
                    f"{url}: the server at {server} sent nothing for {LIMITS.remote_stall_seconds} s (limit "
                    "remote_stall_seconds; raise it with `imitation --limit remote_stall_seconds=N` if the server is only "
                    "slow)"
                ) from None
            if seconds < LIMITS.remote_request_seconds:
                raise _past_total(url, server) from None
            task = f"send {progress.asked} bytes, {progress.received} received" if progress.asked else "answer"
            raise DemoFileError(
                f"{url}: the server at {server} took more than {LIMITS.remote_request_seconds} s to {task} (limit "
                "remote_request_seconds; raise it with `imitation --limit remote_request_seconds=N` if the server is only "
                "slow)"
            ) from None

    with _COMMAND_CLOCK.running():
        return fsspec.asyn.sync(fs.loop, bounded)


def _past_total(url: str, server: str) -> DemoFileError:
    return DemoFileError(
        f"{url}: reading from the server at {server} went past this command's {LIMITS.remote_total_seconds} s for "
        "remote reading (limit remote_total_seconds; raise it with `imitation --limit remote_total_seconds=N` if the "
        "data is real)"
    )


def _request_options(fs: Any, headers: dict[str, str]) -> dict[str, Any]:
    """The filesystem's own request options (auth, proxies, headers), with ours: no encoding (a
    compressed answer would not be the bytes asked for, and could expand without bound), and
    aiohttp's stall timeout."""
    import aiohttp

    options = dict(fs.kwargs)
    options.pop("timeout", None)
    stall = LIMITS.remote_stall_seconds
    return options | {
        "headers": {**options.get("headers", {}), **headers, "Accept-Encoding": "identity"},
        "timeout": aiohttp.ClientTimeout(total=None, sock_connect=stall, sock_read=stall),
        "auto_decompress": False,
    }


def _encoded(response: Any) -> str | None:
    """The answer's content coding, where it has one (it would not be the object's bytes)."""
    encoding = response.headers.get("Content-Encoding", "identity").strip().lower()
    return None if encoding in ("", "identity") else encoding


async def _http_size(fs: Any, path: str) -> int | None:
    """The object's size from HEAD (or, from a server that refuses HEAD, a GET's headers, its body unread)."""
    session = await fs.set_session()
    for method in ("HEAD", "GET"):
        async with session.request(method, fs.encode_url(path), **_request_options(fs, {})) as response:
            if response.status == 404:
                raise FileNotFoundError(path)
            if method == "HEAD" and response.status >= 400:
                continue
            response.raise_for_status()
            total = response.headers.get("Content-Range", "").rpartition("/")[2]
            if response.content_length is not None and _encoded(response) is None:
                return int(response.content_length)
            if total.isdigit():
                return int(total)
    return None


async def _http_range(fs: Any, path: str, url: str, start: int, end: int, size: int, progress: _Progress) -> bytes:
    """Bytes [start, end) of the object at `path` (`url` in messages), read no further."""
    import aiohttp

    session = await fs.set_session()
    options = _request_options(fs, {"Range": f"bytes={start}-{end - 1}"})
    async with session.get(fs.encode_url(path), **options) as response:
        server = server_of(str(response.url))
        if response.status == 404:
            raise FileNotFoundError(path)
        response.raise_for_status()
        asked = f"bytes {start}-{end - 1}"
        length = response.content_length
        encoding = _encoded(response)
        if encoding is not None:
            raise misbehaved(url, server, f"answered {asked} encoded as {encoding[:40]!r}, not as the object's bytes")
        if response.status == 200:
            # A server that ignores Range sends the object from its start: skip to the range, keep it, hang up.
            if length is not None and length != size:
                raise misbehaved(
                    url, server, f"ignored the Range of {asked} and answered 200 with {length} bytes, not the object's {size}"
                )
            if end > LIMITS.remote_request_bytes:
                what = f"bytes the server at {server} sends to reach {asked} (it ignores Range: each answer starts at byte 0)"
                raise DemoFileError(f"{url}: {over_limit(what, end, 'remote_request_bytes')}")
        elif response.status == 206:
            shown = response.headers.get("Content-Range", "").removeprefix("bytes ").partition("/")[0]
            if shown and shown != f"{start}-{end - 1}":
                raise misbehaved(url, server, f"answered bytes {shown[:60]} to a request for {asked}")
            if length is not None and length != end - start:
                raise misbehaved(url, server, f"answered a request for {end - start} bytes with Content-Length {length}")
        else:
            raise misbehaved(url, server, f"answered {response.status} to a request for {asked}")
        data = b""
        with contextlib.suppress(aiohttp.ClientPayloadError):  # the connection closed early: told below
            if response.status == 200:
                await _read(response.content, _Progress(start), keep=False)
            data = await _read(response.content, progress, keep=True)
        if progress.received < progress.asked:
            raise misbehaved(
                url, server, f"ended its answer after {progress.received} of the {progress.asked} bytes asked for"
            )
        if response.status == 206 and length is None and await response.content.read(1):
            raise misbehaved(url, server, f"sent more than the {progress.asked} bytes asked for")
        if response.status == 200:
            response.close()  # hang up: the rest of the object is not wanted
    return data


async def _read(content: Any, progress: _Progress, *, keep: bool) -> bytes:
    """Up to `progress.asked` bytes of an answer's body (fewer where it ends first), kept or dropped."""
    pieces = []
    while progress.received < progress.asked:
        piece = await content.read(min(_READ_PIECE, progress.asked - progress.received))
        if not piece:
            break
        progress.received += len(piece)
        if keep:
            pieces.append(piece)
    return b"".join(pieces)

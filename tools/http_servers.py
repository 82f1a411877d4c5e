"""HTTP servers on 127.0.0.1 (a thread of the calling process, any free port) that serve demo
files, for tests, benchmarks and tools/hostile_inputs.py.

`serve(files)` answers as object stores do: HEAD with Content-Length, GET with
`Range: bytes=a-b` as 206 with Content-Range and Content-Length (without a Range, the whole
object as 200), and counts what it sends. `serve(files, HostileHandler)` also serves each file
under `/BEHAVIOUR/NAME`, answered the way one misbehaving server does (see `HostileHandler`).
`serve(files, NoRangeHandler)` is `python -m http.server`: it ignores Range and sends the whole
file, with Content-Length, every time.
"""

from __future__ import annotations

import functools
import itertools
import re
import sys
import threading
import time
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, SimpleHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

TEN_GB = 10 * 2**30


@dataclass
class Served:
    """What a server holds and sent: each GET's byte range [start, end), and every request."""

    files: dict[str, bytes]
    ranges: list[tuple[str, int, int]] = field(default_factory=list)
    requests: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)
    stopping: threading.Event = field(default_factory=threading.Event)

    @property
    def bytes(self) -> int:
        return sum(end - start for _, start, end in self.ranges)

    def reset(self) -> None:
        with self.lock:
            self.ranges.clear()
            self.requests = 0


class RangeHandler(BaseHTTPRequestHandler):
    """GET with or without `Range: bytes=a-b`, and HEAD with Content-Length (http.server's own
    handler knows no ranges)."""

    served: Served
    protocol_version = "HTTP/1.1"  # keep-alive, as object stores serve
    disable_nagle_algorithm = True  # headers and body go out in two writes: no 40 ms delayed-ACK stall
    send_length = True  # False: no Content-Length, the body ends when the connection does (HTTP/1.0's way)

    def do_HEAD(self) -> None:
        self.respond(body=False)

    def do_GET(self) -> None:
        self.respond(body=True)

    def respond(self, *, body: bool) -> None:
        with self.served.lock:
            self.served.requests += 1
        data = self.served.files.get(self.path)
        if data is None:
            self.send_error(404)
            return
        start, end, status = 0, len(data), 200
        asked = re.fullmatch(r"bytes=(\d+)-(\d*)", self.headers.get("Range", ""))
        if asked is not None:
            start, end, status = int(asked[1]), min(len(data), int(asked[2]) + 1 if asked[2] else len(data)), 206
        self.send_response(status)
        if self.send_length or not body:
            self.send_header("Content-Length", str(end - start))
        else:
            self.send_header("Connection", "close")
            self.close_connection = True
        self.send_header("Accept-Ranges", "bytes")
        if status == 206:
            self.send_header("Content-Range", f"bytes {start}-{end - 1}/{len(data)}")
        self.end_headers()
        if body:
            with self.served.lock:
                self.served.ranges.append((self.path, start, end))
            self.wfile.write(memoryview(data)[start:end])

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (http.server's name)
        pass


class NoRangeHandler(SimpleHTTPRequestHandler):
    """http.server's own handler, serving `served.files` instead of a folder: HEAD and GET with
    Content-Length, Range ignored (200 and the whole file)."""

    served: Served

    def send_head(self) -> Any:
        import io

        with self.served.lock:
            self.served.requests += 1
        data = self.served.files.get(self.path)
        if data is None:
            self.send_error(404)
            return None
        self.send_response(200)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        if self.command == "GET":
            with self.served.lock:
                self.served.ranges.append((self.path, 0, len(data)))
        return io.BytesIO(data)

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (http.server's name)
        pass


class HostileHandler(RangeHandler):
    """Serves each file honestly at its own path, and at `/BEHAVIOUR/NAME` as a misbehaving server:

    - `no-length`: 206 with the right Content-Range but no Content-Length, then the range and
      bytes without end;
    - `claims-10gb`: the object is 10 GB (HEAD), and every range is answered with
      `Content-Length: 10737418240` and that many bytes;
    - `garbage-10gb`: an honest server of a 10 GB object: the file's first bytes, then zeros;
    - `ignores-range`: a 3 GB object (the file, then zeros) sent whole with 200 to every GET;
    - `trickle`: honest headers, then one byte of the body every 2 s;
    - `silent`: takes the request, never answers;
    - `slow`: honest, each answer after 0.5 s;
    - `wrong-range`: every range answered with as many bytes from the object's start, and a
      Content-Range that says so;
    - `short`: half the range asked for, then the connection closed;
    - `gzip-bomb`: every range answered `Content-Encoding: gzip`, 0.5 MB that inflate to 512 MiB
      (`gzip_bomb()`, made on first use: seconds).

    Endless bodies end when the client goes away or the server stops."""

    def respond(self, *, body: bool) -> None:
        behaviour, _, rest = self.path[1:].partition("/")
        data = self.served.files.get("/" + rest)
        answer = getattr(self, "answer_" + behaviour.replace("-", "_"), None)
        if data is None or answer is None:
            super().respond(body=body)
            return
        with self.served.lock:
            self.served.requests += 1
        start, end = self.range_asked()
        try:
            answer(data, body, start, end)
        except (BrokenPipeError, ConnectionResetError):
            self.close_connection = True

    def range_asked(self) -> tuple[int, int | None]:
        """[start, end) of the request's `Range: bytes=a-b` (end None: to the end); (0, None) without one."""
        asked = re.fullmatch(r"bytes=(\d+)-(\d*)", self.headers.get("Range", ""))
        if asked is None:
            return 0, None
        return int(asked[1]), int(asked[2]) + 1 if asked[2] else None

    def headers_for(self, status: int, length: int | None, content_range: str | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Accept-Ranges", "bytes")
        self.send_header("ETag", '"5f3a-1c2b"')
        self.send_header("Last-Modified", "Mon, 07 Dec 2026 10:00:00 GMT")
        if length is not None:
            self.send_header("Content-Length", str(length))
        else:
            self.send_header("Connection", "close")  # the body ends when the connection does
            self.close_connection = True
        if content_range is not None:
            self.send_header("Content-Range", content_range)
        self.end_headers()

    def stream(self, pieces: Iterator[bytes]) -> None:
        for piece in pieces:
            if self.served.stopping.is_set():
                return
            self.wfile.write(piece)

    def answer_no_length(self, data: bytes, body: bool, start: int, end: int | None) -> None:
        stop = len(data) if end is None else min(end, len(data))
        if not body:
            self.headers_for(200, len(data))
            return
        self.headers_for(206, None, f"bytes {start}-{stop - 1}/{len(data)}")
        self.stream(itertools.chain([data[start:stop]], itertools.repeat(data[:65536])))

    def answer_claims_10gb(self, data: bytes, body: bool, start: int, end: int | None) -> None:
        if not body:
            self.headers_for(200, TEN_GB)
            return
        stop = TEN_GB if end is None else min(end, TEN_GB)
        self.headers_for(206, TEN_GB, f"bytes {start}-{stop - 1}/{TEN_GB}")
        self.stream(_object_bytes(data, start, start + TEN_GB))

    def answer_garbage_10gb(self, data: bytes, body: bool, start: int, end: int | None) -> None:
        stop = TEN_GB if end is None else min(end, TEN_GB)
        if not body:
            self.headers_for(200, TEN_GB)
            return
        self.headers_for(206, stop - start, f"bytes {start}-{stop - 1}/{TEN_GB}")
        self.stream(_object_bytes(data, start, stop))

    def answer_ignores_range(self, data: bytes, body: bool, start: int, end: int | None) -> None:
        size = 3 * 2**30
        self.headers_for(200, size)
        if body:
            self.stream(_object_bytes(data, 0, size))

    def answer_trickle(self, data: bytes, body: bool, start: int, end: int | None) -> None:
        stop = len(data) if end is None else min(end, len(data))
        if not body:
            self.headers_for(200, len(data))
            return
        self.headers_for(206, stop - start, f"bytes {start}-{stop - 1}/{len(data)}")
        for position in range(start, stop):
            self.wfile.write(data[position : position + 1])
            self.wfile.flush()
            if self.served.stopping.wait(2):
                return

    def answer_silent(self, data: bytes, body: bool, start: int, end: int | None) -> None:
        self.served.stopping.wait(600)
        self.close_connection = True

    def answer_slow(self, data: bytes, body: bool, start: int, end: int | None) -> None:
        time.sleep(0.5)
        stop = len(data) if end is None else min(end, len(data))
        self.headers_for(
            206 if body and end is not None else 200,
            stop - start,
            f"bytes {start}-{stop - 1}/{len(data)}" if body and end is not None else None,
        )
        if body:
            self.wfile.write(data[start:stop])

    def answer_wrong_range(self, data: bytes, body: bool, start: int, end: int | None) -> None:
        stop = len(data) if end is None else min(end, len(data))
        if not body:
            self.headers_for(200, len(data))
            return
        self.headers_for(206, stop - start, f"bytes 0-{stop - start - 1}/{len(data)}")
        self.wfile.write(data[: stop - start])

    def answer_short(self, data: bytes, body: bool, start: int, end: int | None) -> None:
        stop = len(data) if end is None else min(end, len(data))
        if not body:
            self.headers_for(200, len(data))
            return
        self.headers_for(206, stop - start, f"bytes {start}-{stop - 1}/{len(data)}")
        self.wfile.write(data[start : start + (stop - start) // 2])
        self.close_connection = True

    def answer_gzip_bomb(self, data: bytes, body: bool, start: int, end: int | None) -> None:
        if not body:
            self.headers_for(200, len(data))
            return
        bomb = gzip_bomb()
        stop = len(data) if end is None else min(end, len(data))
        self.send_response(206)
        self.send_header("Content-Encoding", "gzip")
        self.send_header("Content-Length", str(len(bomb)))
        self.send_header("Content-Range", f"bytes {start}-{stop - 1}/{len(data)}")
        self.end_headers()
        self.wfile.write(bomb)


@functools.cache
def gzip_bomb() -> bytes:
    """512 MiB of zeros, gzipped (about 0.5 MB)."""
    packer = zlib.compressobj(6, zlib.DEFLATED, 31)  # 31: the gzip container
    zeros = bytes(2**20)
    return b"".join([*(packer.compress(zeros) for _ in range(512)), packer.flush()])


def _object_bytes(data: bytes, start: int, stop: int) -> Iterator[bytes]:
    """Bytes [start, stop) of an object that is `data` followed by zeros, in pieces of 1 MiB."""
    zeros = bytes(2**20)
    position = start
    while position < stop:
        if position < len(data):
            piece = data[position : min(stop, len(data), position + 2**20)]
        else:
            piece = zeros[: min(stop - position, len(zeros))]
        yield piece
        position += len(piece)


class _QuietServer(ThreadingHTTPServer):
    """A client hanging up mid-answer is what bounded readers do: no traceback for it."""

    def handle_error(self, request: Any, client_address: Any) -> None:
        if not isinstance(sys.exc_info()[1], ConnectionError):
            super().handle_error(request, client_address)


@dataclass
class Server:
    """A running server: its base URL (`http://127.0.0.1:PORT`) and what it served."""

    url: str
    served: Served
    httpd: ThreadingHTTPServer

    def stop(self) -> None:
        self.served.stopping.set()
        self.httpd.shutdown()
        self.httpd.server_close()


def serve(files: dict[str, bytes], handler: type[BaseHTTPRequestHandler] = RangeHandler) -> Server:
    """A server of `files` (path → bytes) on 127.0.0.1 at any free port, answering with `handler`."""
    served = Served(dict(files))
    httpd = _QuietServer(("127.0.0.1", 0), type("Handler", (handler,), {"served": served}))
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    return Server(f"http://127.0.0.1:{httpd.server_address[1]}", served, httpd)

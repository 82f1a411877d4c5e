"""Demo files read from URLs through fsspec: over HTTP from a server on 127.0.0.1 that honours
range requests and counts what it serves, and from fsspec's in-memory filesystem. Opening reads
the summary only; an episode fetches its own chunks and nothing else; what is read equals the
local file's episodes; damage and missing packages are the same one-line errors as locally."""

from __future__ import annotations

import importlib.util
import io
import json
import re
import struct
import threading
from collections.abc import Iterator
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import fsspec
import gymnasium as gym
import numpy as np
import pytest
from helpers import assert_episodes_equal
from mcap.reader import make_reader

import cli
from imitation.data.dataset import DemoDataset
from imitation.data.loader import load_transitions
from imitation.data.mcap.format import DATASET_METADATA, EPISODES_METADATA
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.source import _TAIL_BYTES
from imitation.data.mcap.writer import DemoWriter, write_episodes
from imitation.data.types import Episode
from imitation.errors import DemoFileError, ImitationError
from imitation.limits import LIMITS

OBSERVATION_SPACE = gym.spaces.Box(-1.0, 1.0, (64,), np.float32)
ACTION_SPACE = gym.spaces.Box(-1.0, 1.0, (4,), np.float32)


@dataclass
class Served:
    """What the test server sent: each GET's byte range [start, end), and every request."""

    files: dict[str, bytes]
    ranges: list[tuple[str, int, int]] = field(default_factory=list)
    requests: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def bytes(self) -> int:
        return sum(end - start for _, start, end in self.ranges)

    def reset(self) -> None:
        with self.lock:
            self.ranges.clear()
            self.requests = 0


class _RangeHandler(BaseHTTPRequestHandler):
    """GET with or without `Range: bytes=a-b`, and HEAD with Content-Length (http.server's own
    handler knows no ranges)."""

    served: Served
    disable_nagle_algorithm = True

    def do_HEAD(self) -> None:
        self._respond(body=False)

    def do_GET(self) -> None:
        self._respond(body=True)

    def _respond(self, *, body: bool) -> None:
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
        self.send_header("Content-Length", str(end - start))
        self.send_header("Accept-Ranges", "bytes")
        if status == 206:
            self.send_header("Content-Range", f"bytes {start}-{end - 1}/{len(data)}")
        self.end_headers()
        if body:
            with self.served.lock:
                self.served.ranges.append((self.path, start, end))
            self.wfile.write(data[start:end])

    def log_message(self, format: str, *args: object) -> None:  # noqa: A002 (http.server's name)
        pass


@dataclass(frozen=True)
class Layout:
    """Where a demo file's parts lie, read with the mcap library."""

    size: int
    chunks: list[tuple[int, int]]  # (offset, length)
    dataset_metadata: tuple[int, int]
    episode_index: tuple[int, int]
    summary_start: int


def layout(data: bytes) -> Layout:
    summary = make_reader(io.BytesIO(data)).get_summary()
    assert summary is not None
    metadata = {m.name: (m.offset, m.length) for m in summary.metadata_indexes}
    (summary_start,) = struct.unpack_from("<Q", data, len(data) - 8 - 20)
    return Layout(
        len(data),
        sorted((c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes),
        metadata[DATASET_METADATA],
        metadata[EPISODES_METADATA],
        summary_start,
    )


def _episode(steps: int, seed: int) -> Episode:
    rng = np.random.default_rng(seed)
    return Episode(
        observations=rng.uniform(-1, 1, (steps + 1, 64)).astype(np.float32),
        actions=rng.uniform(-1, 1, (steps, 4)).astype(np.float32),
        rewards=rng.normal(size=steps),
        terminated=seed % 2 == 0,
        truncated=seed % 2 == 1,
    )


@pytest.fixture(scope="module")
def local(tmp_path_factory) -> Path:
    """A 3 MB demo file of 60 episodes of incompressible rows: chunks of 1 MiB, some holding
    several episodes, some episodes spread over two."""
    episodes = [_episode(150 + 10 * (k % 7), seed=k) for k in range(60)]
    return write_episodes(
        tmp_path_factory.mktemp("remote") / "demos.mcap",
        episodes,
        env_id="Test-v0",
        observation_space=OBSERVATION_SPACE,
        action_space=ACTION_SPACE,
        compression="none",
    )


@pytest.fixture(scope="module")
def server(local: Path) -> Iterator[tuple[str, Served]]:
    data = local.read_bytes()
    flipped = bytearray(data)
    flipped[layout(data).summary_start + 20] ^= 0x40
    served = Served({"/demos.mcap": data, "/cut.mcap": data[: len(data) // 2], "/flipped.mcap": bytes(flipped)})
    handler = type("Handler", (_RangeHandler,), {"served": served})
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}", served
    httpd.shutdown()
    httpd.server_close()


@pytest.fixture(scope="module")
def memory_url(local: Path) -> Iterator[str]:
    fs = fsspec.filesystem("memory")
    fs.pipe("/remote-demos/demos.mcap", local.read_bytes())
    yield "memory://remote-demos/demos.mcap"
    fs.rm("/remote-demos", recursive=True)


def _within_summary(found: Layout, start: int, end: int) -> bool:
    """Whether [start, end) is what opening needs: the magic, the dataset metadata, or the tail
    from the episode index on (footer, summary; the tail read may begin up to _TAIL_BYTES early)."""
    tail_start = min(found.episode_index[0], found.size - _TAIL_BYTES)
    dataset_start, dataset_length = found.dataset_metadata
    return (start, end) in ((0, 8), (dataset_start, dataset_start + dataset_length)) or start >= tail_start


def _opening_bound(found: Layout) -> int:
    return 8 + found.dataset_metadata[1] + (found.size - found.episode_index[0]) + _TAIL_BYTES


def _multi_chunk_episode(demo: DemoFile) -> int:
    return next(k for k, facts in enumerate(demo.episodes) if len(demo.chunks_of(facts)) > 1)


def test_opening_over_http_reads_only_the_summary(local: Path, server) -> None:
    base, served = server
    found = layout(local.read_bytes())
    served.reset()
    demo = DemoFile(f"{base}/demos.mcap")
    assert demo.path == f"{base}/demos.mcap" and len(demo) == 60 and demo.size == found.size
    assert all(_within_summary(found, start, end) for _, start, end in served.ranges), served.ranges
    assert served.bytes == demo.bytes_read <= _opening_bound(found) < found.size / 50
    assert served.requests == demo.requests <= 4  # the size (HEAD), the magic, the tail, the dataset metadata


def test_one_episode_over_http_fetches_only_its_chunks(local: Path, server) -> None:
    base, served = server
    remote, here = DemoFile(f"{base}/demos.mcap"), DemoFile(local)
    k = _multi_chunk_episode(remote)
    before = remote.bytes_read
    served.reset()
    assert_episodes_equal(remote[k], here[k])
    chunks = sorted((c.offset, c.offset + c.length) for c in remote.chunks_of(remote.episodes[k]))
    assert sorted((start, end) for _, start, end in served.ranges) == chunks
    assert remote.bytes_read - before == served.bytes == sum(end - start for start, end in chunks)


def test_every_episode_over_http_fetches_each_chunk_once(local: Path, server) -> None:
    base, served = server
    found = layout(local.read_bytes())
    remote = DemoFile(f"{base}/demos.mcap")
    here = DemoFile(local)
    for read in (lambda demo: demo.read_episodes(), lambda demo: list(demo)):
        served.reset()
        for got, expected in zip(read(remote), read(here), strict=True):
            assert_episodes_equal(got, expected)
        assert sorted((start, end - start) for _, start, end in served.ranges) == found.chunks
    dataset = DemoDataset([f"{base}/demos.mcap"])
    served.reset()
    fetched = load_transitions(dataset)  # the bulk loader reads chunks its own way
    assert sorted((start, end - start) for _, start, end in served.ranges) == found.chunks
    expected = load_transitions(local)
    for name in ("observations", "actions", "rewards", "terminated", "truncated", "episode_index"):
        np.testing.assert_array_equal(getattr(fetched, name), getattr(expected, name))


def _cli(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = cli.main(list(argv))
    return code, out.getvalue(), err.getvalue()


def test_info_over_http_prints_the_local_facts_from_the_summary(local: Path, server) -> None:
    base, served = server
    found = layout(local.read_bytes())
    served.reset()
    code, remote_json, _ = _cli("info", f"{base}/demos.mcap", "--json")
    assert code == 0 and served.bytes <= _opening_bound(found)
    assert all(_within_summary(found, start, end) for _, start, end in served.ranges)
    local_json = _cli("info", str(local), "--json")[1]
    assert json.loads(remote_json) == json.loads(local_json) | {"file": f"{base}/demos.mcap"}
    remote_text, local_text = _cli("info", f"{base}/demos.mcap")[1], _cli("info", str(local))[1]
    assert remote_text.replace(f"{base}/demos.mcap", str(local)) == local_text


def test_memory_filesystem_reads_the_summary_then_only_the_chunks(local: Path, memory_url: str) -> None:
    found = layout(local.read_bytes())
    remote, here = DemoFile(memory_url), DemoFile(local)
    assert remote.bytes_read <= _opening_bound(found) and remote.fingerprint == here.fingerprint
    k = _multi_chunk_episode(remote)
    opened = remote.bytes_read
    assert_episodes_equal(remote[k], here[k])
    assert remote.bytes_read - opened == sum(c.length for c in remote.chunks_of(remote.episodes[k]))
    for got, expected in zip(remote.read_episodes(), here.read_episodes(), strict=True):
        assert_episodes_equal(got, expected)


@pytest.mark.parametrize("name", ["cut.mcap", "flipped.mcap"])
def test_damage_over_http_is_the_local_one_line_error(tmp_path: Path, server, name: str) -> None:
    base, served = server
    copy = tmp_path / name
    copy.write_bytes(served.files[f"/{name}"])
    with pytest.raises(DemoFileError) as here:
        DemoFile(copy)
    with pytest.raises(DemoFileError) as remote:
        DemoFile(f"{base}/{name}")
    assert str(remote.value) == str(here.value).replace(str(copy), f"{base}/{name}") and "\n" not in str(remote.value)
    # `info` salvages: the whole object is read, through the same range requests.
    remote_json, local_json = _cli("info", f"{base}/{name}", "--json"), _cli("info", str(copy), "--json")
    assert remote_json[0] == local_json[0] == 1
    assert json.loads(remote_json[1]) == json.loads(local_json[1]) | {"file": f"{base}/{name}"}


def test_hostile_input_limits_hold_for_urls(local: Path, memory_url: str, monkeypatch) -> None:
    """A chunk declaring more bytes than the limit is refused from the summary, before any chunk is fetched."""
    monkeypatch.setattr(LIMITS, "chunk_bytes", 1000)
    with pytest.raises(DemoFileError) as here:
        DemoFile(local)
    with pytest.raises(DemoFileError) as remote:
        DemoFile(memory_url)
    assert "chunk_bytes=1000" in str(here.value)
    assert str(remote.value) == str(here.value).replace(str(local), memory_url)


def test_a_missing_object_is_one_line(server) -> None:
    base, served = server
    with pytest.raises(DemoFileError, match=re.escape(f"{base}/none.mcap: cannot open: no such object")):
        DemoFile(f"{base}/none.mcap")
    served.files["/gone.mcap"] = served.files["/demos.mcap"]
    demo = DemoFile(f"{base}/gone.mcap")
    del served.files["/gone.mcap"]
    with pytest.raises(DemoFileError, match=re.escape(f"{base}/gone.mcap: cannot read: no such object")):
        demo[0]


@pytest.mark.skipif(importlib.util.find_spec("s3fs") is not None, reason="s3fs is installed")
def test_s3_without_s3fs_names_the_package() -> None:
    code, out, err = _cli("info", "s3://bucket/demos.mcap")
    assert (code, out) == (1, "")
    assert err == "error: s3://bucket/demos.mcap: reading s3:// URLs needs the Python package s3fs (pip install s3fs)\n"


def test_writers_refuse_urls(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)  # where a URL taken for a path would leave an "s3:" folder
    with pytest.raises(ImitationError, match=r"^memory://out/demos.mcap: cannot write to a URL"):
        DemoWriter("memory://out/demos.mcap", env_id="Test-v0", observation_space=OBSERVATION_SPACE, action_space=ACTION_SPACE)
    for argv in (["record", "--env", "CartPole-v1", "--episodes", "1", "--out"], ["recover"]):
        code, _, err = _cli(*argv, "s3://bucket/demos.mcap")
        assert (code, err) == (1, "error: s3://bucket/demos.mcap: cannot write to a URL; write a local file, then upload it\n")
    assert not list(tmp_path.iterdir())


def test_train_bc_reads_demos_from_a_url(tmp_path: Path, server) -> None:
    base, served = server
    cartpole = Path(__file__).resolve().parents[2] / "datasets" / "CartPole-v1.mcap"
    served.files["/CartPole-v1.mcap"] = cartpole.read_bytes()
    url = f"{base}/CartPole-v1.mcap"
    code, out, err = _cli("train", "bc", "--demos", url, "--env", "CartPole-v1", "--epochs", "1", "--hidden", "8",
                          "--out", str(tmp_path / "bc"), "--json")
    assert code == 0, err
    config = json.loads((tmp_path / "bc" / "config.json").read_text())
    assert config["demos"] == [url] and config["demo_fingerprints"] == [DemoFile(cartpole).fingerprint]

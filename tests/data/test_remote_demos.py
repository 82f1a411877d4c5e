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
import sys
from collections.abc import Iterator
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path

import fsspec
import gymnasium as gym
import numpy as np
import pytest
from helpers import assert_episodes_equal
from mcap.reader import make_reader
from support import DATASETS, REPO

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

sys.path.insert(0, str(REPO / "tools"))
from http_servers import HostileHandler, NoRangeHandler, RangeHandler, Served, serve  # noqa: E402

OBSERVATION_SPACE = gym.spaces.Box(-1.0, 1.0, (64,), np.float32)
ACTION_SPACE = gym.spaces.Box(-1.0, 1.0, (4,), np.float32)


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
    running = serve({"/demos.mcap": data, "/cut.mcap": data[: len(data) // 2], "/flipped.mcap": bytes(flipped)})
    yield running.url, running.served
    running.stop()


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
    cartpole = DATASETS / "CartPole-v1.mcap"
    served.files["/CartPole-v1.mcap"] = cartpole.read_bytes()
    url = f"{base}/CartPole-v1.mcap"
    code, out, err = _cli("train", "bc", "--demos", url, "--env", "CartPole-v1", "--epochs", "1", "--hidden", "8",
                          "--out", str(tmp_path / "bc"), "--json")
    assert code == 0, err
    config = json.loads((tmp_path / "bc" / "config.json").read_text())
    assert config["demos"] == [url] and config["demo_fingerprints"] == [DemoFile(cartpole).fingerprint]


def test_a_server_that_ignores_range_still_serves_info_and_training(local: Path, tmp_path: Path) -> None:
    """`python -m http.server` sends the whole file, 200, to every range request: each read takes
    the file's start up to the end of its range and hangs up, and keeps only the range."""
    cartpole = DATASETS / "CartPole-v1.mcap"
    running = serve({"/demos.mcap": local.read_bytes(), "/CartPole-v1.mcap": cartpole.read_bytes()}, NoRangeHandler)
    try:
        url = f"{running.url}/demos.mcap"
        code, remote_json, err = _cli("info", url, "--json")
        assert code == 0, err
        assert json.loads(remote_json) == json.loads(_cli("info", str(local), "--json")[1]) | {"file": url}
        remote, here = DemoFile(url), DemoFile(local)
        opened = remote.bytes_read, here.bytes_read
        for got, expected in zip(remote.read_episodes(), here.read_episodes(), strict=True):
            assert_episodes_equal(got, expected)
        assert remote.bytes_read - opened[0] == here.bytes_read - opened[1]  # the chunks alone were kept
        code, _, err = _cli("train", "bc", "--demos", f"{running.url}/CartPole-v1.mcap", "--env", "CartPole-v1",
                            "--epochs", "1", "--hidden", "8", "--out", str(tmp_path / "bc"), "--json")
        assert code == 0, err
    finally:
        running.stop()


def test_a_server_without_content_length_still_serves(local: Path) -> None:
    """206 with Content-Range but no Content-Length, each body ending when the connection does
    (HTTP/1.0's way): read to its end, nothing refused."""
    handler = type("CloseDelimited", (RangeHandler,), {"protocol_version": "HTTP/1.0", "send_length": False})
    running = serve({"/demos.mcap": local.read_bytes()}, handler)
    try:
        remote, here = DemoFile(f"{running.url}/demos.mcap"), DemoFile(local)
        assert remote.fingerprint == here.fingerprint
        for got, expected in zip(remote.read_episodes(), here.read_episodes(), strict=True):
            assert_episodes_equal(got, expected)
    finally:
        running.stop()


@pytest.fixture(scope="module")
def hostile(local: Path) -> Iterator[str]:
    running = serve({"/demos.mcap": local.read_bytes()}, HostileHandler)
    yield running.url
    running.stop()


@pytest.mark.parametrize(
    ("behaviour", "wrong"),
    [
        ("wrong-range", r"answered bytes 0-\d+ to a request for bytes [1-9]\d*-\d+"),
        ("short", r"ended its answer after \d+ of the \d+ bytes asked for"),
        ("no-length", r"sent more than the 8 bytes asked for"),
        ("claims-10gb", r"answered a request for 8 bytes with Content-Length 10737418240"),
        ("gzip-bomb", r"answered bytes 0-7 encoded as 'gzip', not as the object's bytes"),
    ],
)
def test_a_misbehaving_server_is_named_with_what_it_did(hostile: str, behaviour: str, wrong: str) -> None:
    url = f"{hostile}/{behaviour}/demos.mcap"
    server = hostile.removeprefix("http://")
    with pytest.raises(DemoFileError, match=f"^{re.escape(url)}: the server at {re.escape(server)} {wrong}$"):
        DemoFile(url)

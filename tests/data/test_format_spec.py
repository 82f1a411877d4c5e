"""docs/FORMAT.md is enough to read our files: an independent reader, written from the spec alone.

The reading side below uses only the generic `mcap` library (`make_reader`, `iter_metadata`,
`iter_messages`), numpy, json, zlib and, for the salvage scan, struct, zstandard and lz4. Nothing from
`imitation.data.mcap` or `imitation.data.spaces` is imported for reading (lz4.frame decodes LZ4 chunks there): `DemoWriter` only
produces the files under test, and the expected values are the arrays and gymnasium spaces the
test itself built. Section numbers (§) refer to docs/FORMAT.md.
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import gymnasium as gym
import numpy as np
import pytest
import lz4.frame
import zstandard
from mcap.reader import make_reader

from imitation.data.mcap.writer import DemoWriter  # the writer under test; never used for reading
from imitation.data.types import Episode

# ------------------------------------------------------------------------------------------------
# The independent reader (docs/FORMAT.md)

SUPPORTED_VERSION = 1
MAGIC = b"\x89MCAP0\r\n"


class SpecError(Exception):
    pass


def spec_crc32(record: dict[str, str]) -> str:
    """§3.3: CRC-32 over key NUL value NUL for each key but crc32, keys sorted."""
    data = b"".join(k.encode() + b"\0" + record[k].encode() + b"\0" for k in sorted(record) if k != "crc32")
    return str(zlib.crc32(data))


def check_dataset(dataset: dict[str, str] | None) -> None:
    """§8.1 checks 2-5."""
    if dataset is None:
        raise SpecError("not an imitation demo file")
    if dataset.get("crc32") != spec_crc32(dataset):
        raise SpecError("dataset metadata is corrupt")
    if int(dataset["format_version"]) > SUPPORTED_VERSION:
        raise SpecError("newer format version")
    for key in ("env_id", "observation_space", "action_space"):
        if key not in dataset:
            raise SpecError(f"dataset metadata lacks {key}")


def leaves(space: dict[str, Any], path: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], np.dtype, tuple[int, ...]]]:
    """§4: (path, little-endian dtype, row shape) of each leaf of a space JSON object."""
    kind = space["type"]
    if kind == "Dict":
        for key, sub in space["spaces"].items():
            yield from leaves(sub, path + (key,))
    elif kind == "Box":
        yield path, np.dtype(space["dtype"]).newbyteorder("<"), tuple(space["shape"])
    elif kind == "Discrete":
        yield path, np.dtype("<i8"), ()
    elif kind == "MultiDiscrete":
        yield path, np.dtype(space.get("dtype", "int64")).newbyteorder("<"), np.shape(space["nvec"])
    elif kind == "MultiBinary":
        n = space["n"]
        yield path, np.dtype("i1"), tuple(n) if isinstance(n, list) else (n,)
    else:
        raise SpecError(f"unknown space type {kind}")


def box_bounds(value: Any, dtype: str, shape: list[int]) -> np.ndarray:
    """§4 Box bounds: scalars broadcast; "inf"/"-inf"/"nan" strings; cast to dtype."""

    def parse(item: Any) -> Any:
        if isinstance(item, list):
            return [parse(x) for x in item]
        return float(item) if isinstance(item, str) else item

    parsed = parse(value)
    if isinstance(parsed, list):
        return np.asarray(parsed, dtype=dtype).reshape(shape)
    return np.full(shape, parsed, dtype=dtype)


def topic(kind: str, path: tuple[str, ...]) -> str:
    return "/" + "/".join((kind, *path))


def row_layout(channel_metadata: dict[str, str]) -> tuple[np.dtype, tuple[int, ...]]:
    """§5: numpy type string and JSON row shape."""
    return np.dtype(channel_metadata["dtype"]), tuple(json.loads(channel_metadata["shape"]))


@dataclass
class ReadEpisode:
    marker: dict[str, Any]
    observations: dict[tuple[str, ...], np.ndarray]
    actions: dict[tuple[str, ...], np.ndarray]
    rewards: np.ndarray
    timestamps: np.ndarray | None
    infos: list[Any] | None
    log_times: list[int]  # every message of the episode, marker included
    block_rows: list[int]  # rows in each block message


class Assembler:
    """§6 / §8.3: collect blocks per topic in file order; a marker completes an episode."""

    def __init__(self, dataset: dict[str, str]):
        self.obs_leaves = list(leaves(json.loads(dataset["observation_space"])))
        self.act_leaves = list(leaves(json.loads(dataset["action_space"])))
        self._reset()

    def _reset(self) -> None:
        self.blocks: dict[str, list[bytes]] = {}
        self.log_times: list[int] = []
        self.block_rows: list[int] = []

    def add(self, topic_name: str, metadata: dict[str, str], log_time: int, data: bytes) -> ReadEpisode | None:
        self.log_times.append(log_time)
        if topic_name != "/episode":
            self.blocks.setdefault(topic_name, []).append(data)
            if "dtype" in metadata:
                dtype, shape = row_layout(metadata)
                row_bytes = dtype.itemsize * int(np.prod(shape))
                if row_bytes == 0 or len(data) % row_bytes:
                    raise SpecError(f"{topic_name}: block of {len(data)} bytes, rows of {row_bytes}")
                self.block_rows.append(len(data) // row_bytes)
            return None
        marker = json.loads(data)
        steps = marker["length"]

        def rows(name: str, dtype: np.dtype, shape: tuple[int, ...], count: int) -> np.ndarray:
            row_bytes = dtype.itemsize * int(np.prod(shape))
            if row_bytes == 0:  # §6.2: zero-size rows have no messages
                assert name not in self.blocks
                return np.zeros((count, *shape), dtype=dtype)
            raw = b"".join(self.blocks.get(name, []))
            if len(raw) != count * row_bytes:
                raise SpecError(f"{name}: {len(raw)} bytes, expected {count} rows of {row_bytes}")
            return np.frombuffer(raw, dtype=dtype).reshape((count, *shape))

        episode = ReadEpisode(
            marker=marker,
            observations={p: rows(topic("observation", p), d, s, steps + 1) for p, d, s in self.obs_leaves},
            actions={p: rows(topic("action", p), d, s, steps) for p, d, s in self.act_leaves},
            rewards=rows("/reward", np.dtype("<f8"), (), steps),
            timestamps=rows("/time", np.dtype("<i8"), (), steps + 1) if "/time" in self.blocks else None,
            infos=[i for part in self.blocks["/info"] for i in json.loads(part)] if "/info" in self.blocks else None,
            log_times=self.log_times,
            block_rows=self.block_rows,
        )
        self._reset()
        return episode


@dataclass
class SpecFile:
    profile: str
    dataset: dict[str, str]
    index: dict[str, str]
    episodes: list[ReadEpisode]
    channels: dict[str, dict[str, str]]  # topic -> channel metadata, from the summary


def read_spec_file(path: Path) -> SpecFile:
    """§8.2 + §8.3 with the generic mcap reader."""
    with open(path, "rb") as stream:
        if stream.read(8) != MAGIC:
            raise SpecError("not an MCAP file")
        stream.seek(0)
        reader = make_reader(stream, validate_crcs=True)  # §8.1.6: chunk CRCs
        profile = reader.get_header().profile
        metadata = {record.name: dict(record.metadata) for record in reader.iter_metadata()}
        dataset = metadata.get("imitation.dataset")
        check_dataset(dataset)
        index = metadata["imitation.episodes"]
        if index.get("crc32") != spec_crc32(index):
            raise SpecError("episode index is corrupt")
        channels = {c.topic: dict(c.metadata) for c in reader.get_summary().channels.values()}
        assembler = Assembler(dataset)
        episodes = []
        for _, channel, message in reader.iter_messages(log_time_order=False):
            done = assembler.add(channel.topic, dict(channel.metadata), message.log_time, message.data)
            if done is not None:
                episodes.append(done)
    return SpecFile(profile, dataset, index, episodes, channels)


def read_spec_episode(path: Path, facts: dict[str, Any], dataset: dict[str, str]) -> ReadEpisode:
    """§8.3 random access: only the messages in [t_start_ns, t_end_ns] (inclusive)."""
    with open(path, "rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        assembler = Assembler(dataset)
        found = []
        for _, channel, message in reader.iter_messages(
            starting_at=facts["t_start_ns"], ending_at=facts["t_end_ns"], log_time_order=False
        ):
            done = assembler.add(channel.topic, dict(channel.metadata), message.log_time, message.data)
            if done is not None:
                found.append(done)
    assert len(found) == 1 and found[0].marker["index"] == facts["index"]
    return found[0]


def _string(buf: bytes, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    return bytes(buf[pos + 4 : pos + 4 + n]).decode(), pos + 4 + n


def _string_map(buf: bytes, pos: int) -> dict[str, str]:
    (n,) = struct.unpack_from("<I", buf, pos)
    end, pos, out = pos + 4 + n, pos + 4, {}
    while pos < end:
        key, pos = _string(buf, pos)
        out[key], pos = _string(buf, pos)
    return out


def _channel(body: bytes) -> tuple[int, str, dict[str, str]]:
    (channel_id,) = struct.unpack_from("<H", body)
    name, pos = _string(body, 4)
    _, pos = _string(body, pos)  # message encoding
    return channel_id, name, _string_map(body, pos)


def salvage_spec_file(data: bytes) -> tuple[dict[str, str], list[ReadEpisode], str | None]:
    """§8.4: scan the data section record by record; an episode is complete iff its marker was read."""
    assert data[:8] == MAGIC
    dataset, channels, episodes, assembler, damage = None, {}, [], None, None
    pos = 8
    try:
        while True:
            if len(data) - pos < 9:
                damage = "truncated"
                break
            opcode, length = struct.unpack_from("<BQ", data, pos)
            body = data[pos + 9 : pos + 9 + length]
            if len(body) != length:
                damage = "truncated"
                break
            pos += 9 + length
            if opcode == 0x0C:  # Metadata
                name, p = _string(body, 0)
                if name == "imitation.dataset" and dataset is None:
                    dataset = _string_map(body, p)
                    check_dataset(dataset)  # fatal, not salvageable
                    assembler = Assembler(dataset)
            elif opcode == 0x04:
                channel_id, name, meta = _channel(body)
                channels.setdefault(channel_id, (name, meta))
            elif opcode == 0x06:  # Chunk
                if assembler is None:
                    raise SpecError("data before the dataset metadata")
                _, _, size, crc = struct.unpack_from("<QQQI", body)
                compression, p = _string(body, 28)
                (n,) = struct.unpack_from("<Q", body, p)
                raw = body[p + 8 : p + 8 + n]
                if compression == "zstd":
                    content = zstandard.ZstdDecompressor().decompress(raw, max_output_size=size)
                else:
                    content = lz4.frame.decompress(raw) if compression == "lz4" else raw
                if len(content) != size or (crc and zlib.crc32(content) != crc):
                    raise SpecError("bad chunk")
                q = 0
                while q < len(content):
                    inner_op, inner_len = struct.unpack_from("<BQ", content, q)
                    inner = content[q + 9 : q + 9 + inner_len]
                    q += 9 + inner_len
                    if inner_op == 0x04:
                        channel_id, name, meta = _channel(inner)
                        channels.setdefault(channel_id, (name, meta))
                    elif inner_op == 0x05:
                        channel_id, _, log_time, _ = struct.unpack_from("<HIQQ", inner)
                        name, meta = channels[channel_id]
                        done = assembler.add(name, meta, log_time, inner[22:])
                        if done is not None:
                            episodes.append(done)
            elif opcode in (0x0F, 0x02):  # DataEnd, Footer
                break
    except (SpecError, KeyError, struct.error, zstandard.ZstdError, RuntimeError) as error:  # RuntimeError: lz4's
        if dataset is None or isinstance(error, SpecError) and "dataset" in str(error):
            raise
        damage = str(error)
    if dataset is None:
        raise SpecError("no dataset metadata")
    return dataset, episodes, damage


# ------------------------------------------------------------------------------------------------
# The files under test


@dataclass
class Case:
    env_id: str
    observation_space: gym.Space
    action_space: gym.Space
    dt: float | None
    block_steps: int
    episodes: list[Episode]


def _leaves_of(tree: Any, path: tuple[str, ...] = ()) -> dict[tuple[str, ...], np.ndarray]:
    if isinstance(tree, dict):
        return {p: a for key, sub in tree.items() for p, a in _leaves_of(sub, path + (key,)).items()}
    return {path: tree}


def _box_case() -> Case:
    rng = np.random.default_rng(0)
    high = np.array([4.8, np.inf, 0.41887903, np.inf], dtype=np.float32)
    obs_space = gym.spaces.Box(-high, high, dtype=np.float32)
    act_space = gym.spaces.Discrete(2)

    def episode(steps: int, **kwargs: Any) -> Episode:
        return Episode(
            observations=rng.normal(size=(steps + 1, 4)).astype(np.float32),
            actions=rng.integers(0, 2, size=steps),
            rewards=rng.normal(size=steps),
            **kwargs,
        )

    episodes = [
        episode(5, terminated=True, metadata={"seed": 3}),  # blocks of 3, 3 (obs) / 3, 2
        episode(
            3,
            truncated=True,
            metadata={"seed": 4, "source": "human"},
            infos=[{"step": i, "x": [i, 0.5]} for i in range(3)],
            timestamps=10**9 + 7_000_000 * np.arange(4, dtype=np.int64),  # real times, no shift needed
        ),
        episode(0, truncated=True),  # a lone final observation
    ]
    return Case("CartPole-v1", obs_space, act_space, 0.02, 3, episodes)


def _dict_case() -> Case:
    rng = np.random.default_rng(1)
    obs_space = gym.spaces.Dict(
        {
            "pos": gym.spaces.Box(-1.0, 1.0, (2,), np.float64),
            "cam": gym.spaces.Box(0, 255, (2, 3), np.uint8),
            "grid": gym.spaces.MultiBinary([2, 2]),
            "inner": gym.spaces.Dict({"k": gym.spaces.Discrete(5, start=1), "md": gym.spaces.MultiDiscrete([3, 4])}),
            "none": gym.spaces.Box(0.0, 1.0, (0,), np.float32),
        }
    )
    act_space = gym.spaces.Box(np.array([-1.0, -2.0], np.float32), np.array([1.0, 2.0], np.float32), dtype=np.float32)

    def episode(steps: int, **kwargs: Any) -> Episode:
        n = steps + 1
        observations = {
            "pos": rng.uniform(-1, 1, size=(n, 2)),
            "cam": rng.integers(0, 256, size=(n, 2, 3), dtype=np.uint8),
            "grid": rng.integers(0, 2, size=(n, 2, 2), dtype=np.int8),
            "inner": {"k": rng.integers(1, 6, size=n), "md": rng.integers(0, 3, size=(n, 2))},
            "none": np.zeros((n, 0), np.float32),
        }
        return Episode(
            observations=observations,
            actions=rng.uniform(-1, 1, size=(steps, 2)).astype(np.float32),
            rewards=rng.normal(size=steps),
            **kwargs,
        )

    return Case("Reacher-dict-v0", obs_space, act_space, None, 2, [episode(4, terminated=True), episode(3, truncated=True)])


def _expected_leaves(space: gym.Space, path: tuple[str, ...] = ()) -> dict[tuple[str, ...], tuple[np.dtype, tuple[int, ...]]]:
    if isinstance(space, gym.spaces.Dict):
        return {p: v for key, sub in space.spaces.items() for p, v in _expected_leaves(sub, path + (key,)).items()}
    return {path: (np.dtype(space.dtype), tuple(space.shape))}


def _check_space_json(text: str, space: gym.Space) -> None:
    """The space JSON describes `space` as §4 says (types, dtypes, shapes, bounds)."""
    description = json.loads(text)
    if isinstance(space, gym.spaces.Dict):
        assert description["type"] == "Dict" and list(description["spaces"]) == list(space.spaces)
        for key, sub in space.spaces.items():
            _check_space_json(json.dumps(description["spaces"][key]), sub)
    elif isinstance(space, gym.spaces.Box):
        assert description["type"] == "Box" and np.dtype(description["dtype"]) == space.dtype
        assert tuple(description["shape"]) == space.shape
        for name in ("low", "high"):
            bounds = box_bounds(description[name], description["dtype"], description["shape"])
            assert bounds.dtype == space.dtype
            np.testing.assert_array_equal(bounds, getattr(space, name))
    elif isinstance(space, gym.spaces.Discrete):
        assert description == {"type": "Discrete", "n": int(space.n), "start": int(space.start)}
    elif isinstance(space, gym.spaces.MultiDiscrete):
        assert description["type"] == "MultiDiscrete" and np.dtype(description["dtype"]) == space.dtype
        np.testing.assert_array_equal(description["nvec"], space.nvec)
        np.testing.assert_array_equal(description["start"], space.start)
    elif isinstance(space, gym.spaces.MultiBinary):
        assert description["type"] == "MultiBinary" and np.array_equal(description["n"], space.n)
    else:
        raise AssertionError(type(space))


def _write(case: Case, path: Path, **options: Any) -> DemoWriter:
    return DemoWriter(
        path,
        env_id=case.env_id,
        finite_only=False,  # the cases' random bytes include NaN and inf
        observation_space=case.observation_space,
        action_space=case.action_space,
        dt=case.dt,
        source="test",
        metadata={"note": "spec"},
        block_steps=case.block_steps,
        **options,
    )


def _assert_episode_matches(read: ReadEpisode, original: Episode, index: int) -> None:
    assert read.marker["index"] == index
    assert read.marker["length"] == len(original)
    assert read.marker["terminated"] is bool(original.terminated)
    assert read.marker["truncated"] is bool(original.truncated)
    assert read.marker["return"] == pytest.approx(float(np.sum(original.rewards)), rel=1e-12, abs=1e-12)
    assert read.marker["metadata"] == original.metadata
    for name, got, want in (("observations", read.observations, original.observations), ("actions", read.actions, original.actions)):
        want_leaves = _leaves_of(want)
        assert set(got) == set(want_leaves), name
        for path, array in want_leaves.items():
            assert got[path].dtype == array.dtype, (name, path)
            assert got[path].shape == array.shape, (name, path)
            np.testing.assert_array_equal(got[path], array, err_msg=f"{name}{path}")
    assert read.rewards.dtype == np.float64
    np.testing.assert_array_equal(read.rewards, np.asarray(original.rewards, np.float64))
    if original.timestamps is None:
        assert read.timestamps is None
    else:
        np.testing.assert_array_equal(read.timestamps, original.timestamps)
    assert read.infos == (json.loads(json.dumps(original.infos)) if original.infos else None)


# ------------------------------------------------------------------------------------------------
# Tests


@pytest.mark.parametrize("make_case", [_box_case, _dict_case], ids=["box-discrete", "dict-box"])
def test_independent_reader_recovers_everything(tmp_path: Path, make_case: Any) -> None:
    case = make_case()
    path = tmp_path / "demo.mcap"
    with _write(case, path, image_codec=None) as writer:  # the spec reader reads format version 1: blocks only
        for episode in case.episodes:
            writer.write(episode)

    spec = read_spec_file(path)

    # §2 / §3.1: header and dataset metadata
    assert spec.profile == "imitation"
    dataset = spec.dataset
    assert dataset["format_version"] == "1"
    assert dataset["env_id"] == case.env_id
    assert dataset["source"] == "test"
    assert dataset["creator"].startswith("imitation-mcap ")
    assert json.loads(dataset["user_metadata"]) == {"note": "spec"}
    dt_ns = int(dataset["dt_ns"])
    assert dt_ns == (20_000_000 if case.dt == 0.02 else 1_000_000)
    assert dataset["crc32"] == spec_crc32(dataset) == str(zlib.crc32(b"".join(
        f"{k}\0{dataset[k]}\0".encode() for k in sorted(set(dataset) - {"crc32"})
    )))
    _check_space_json(dataset["observation_space"], case.observation_space)
    _check_space_json(dataset["action_space"], case.action_space)
    if isinstance(case.observation_space, gym.spaces.Box):  # §4 literally, incl. non-finite strings
        assert json.loads(dataset["observation_space"]) == {
            "type": "Box",
            "dtype": "float32",
            "shape": [4],
            "low": [-float(np.float32(4.8)), "-inf", -float(np.float32(0.41887903)), "-inf"],
            "high": [float(np.float32(4.8)), "inf", float(np.float32(0.41887903)), "inf"],
        }
        assert json.loads(dataset["action_space"]) == {"type": "Discrete", "n": 2, "start": 0}

    # §5: channels by topic, with numpy type strings and JSON shapes
    for kind, space in (("observation", case.observation_space), ("action", case.action_space)):
        for path_, (dtype, shape) in _expected_leaves(space).items():
            meta = spec.channels[topic(kind, path_)]
            assert meta["field"] == kind
            assert np.dtype(meta["dtype"]) == dtype and meta["dtype"][0] in "<|"
            assert json.loads(meta["shape"]) == list(shape)
    assert spec.channels["/reward"] == {"field": "reward", "dtype": "<f8", "shape": "[]"}
    assert spec.channels["/episode"] == {"field": "episode"}

    # §6: every array, flag, reward; §3.2: the index repeats the markers
    assert len(spec.episodes) == len(case.episodes)
    for k, (read, original) in enumerate(zip(spec.episodes, case.episodes)):
        _assert_episode_matches(read, original, k)
        assert max(read.block_rows, default=0) <= case.block_steps
    assert json.loads(spec.index["episodes"]) == [read.marker for read in spec.episodes]

    # §7: log times
    previous_end = None
    for read, original in zip(spec.episodes, case.episodes):
        start, end = read.marker["t_start_ns"], read.marker["t_end_ns"]
        assert all(start <= t <= end for t in read.log_times) and read.log_times[-1] == end
        assert read.log_times == sorted(read.log_times)
        if original.timestamps is None:
            assert start == (0 if previous_end is None else previous_end + dt_ns)
            assert end == start + len(original) * dt_ns
        else:
            assert (start, end) == (int(original.timestamps[0]), int(original.timestamps[-1]))
        previous_end = end

    # §8.3: random access by time range gives the same episode
    for facts, original in zip(json.loads(spec.index["episodes"]), case.episodes):
        _assert_episode_matches(read_spec_episode(path, facts, dataset), original, facts["index"])


def test_salvage_scan_of_a_killed_durable_writer(tmp_path: Path) -> None:
    """§8.4: a durable writer's `.partial` file holds every finished episode; a cut chunk loses one."""
    case = _box_case()
    path = tmp_path / "demo.mcap"
    writer = _write(case, path, durable=True)
    for episode in case.episodes[:2]:
        writer.write(episode)
    partial = tmp_path / "demo.mcap.partial"
    assert partial.exists() and not path.exists()
    snapshot = partial.read_bytes()  # what a killed process would leave behind
    writer.abort()

    dataset, episodes, damage = salvage_spec_file(snapshot)
    assert dataset["env_id"] == case.env_id and damage == "truncated"
    assert len(episodes) == 2
    for k, read in enumerate(episodes):
        _assert_episode_matches(read, case.episodes[k], k)

    # Cut the file inside the second episode's chunk: only the first survives.
    chunk_offsets, pos = [], 8
    while pos + 9 <= len(snapshot):
        opcode, length = struct.unpack_from("<BQ", snapshot, pos)
        if opcode == 0x06:
            chunk_offsets.append(pos)
        pos += 9 + length
    assert len(chunk_offsets) == 2  # durable: one chunk per (small) episode
    _, episodes, damage = salvage_spec_file(snapshot[: chunk_offsets[1] + 40])
    assert damage == "truncated" and len(episodes) == 1
    _assert_episode_matches(episodes[0], case.episodes[0], 0)

    # A flipped bit inside the second chunk's compressed data: CRC or the codec catches it.
    damaged = bytearray(snapshot)
    damaged[chunk_offsets[1] + 80] ^= 0x10
    _, episodes, damage = salvage_spec_file(bytes(damaged))
    assert damage is not None and len(episodes) == 1


def test_spec_rejects_newer_version_and_bad_crc() -> None:
    """§3.1 / §3.3: a reader refuses a newer version (with a valid CRC) and a CRC mismatch."""
    record = {"format_version": "2", "env_id": "X-v0", "observation_space": "{}", "action_space": "{}"}
    with pytest.raises(SpecError, match="newer"):
        check_dataset({**record, "crc32": spec_crc32(record)})
    record["format_version"] = "1"
    with pytest.raises(SpecError, match="corrupt"):
        check_dataset({**record, "crc32": "0"})
    with pytest.raises(SpecError, match="not an imitation"):
        check_dataset(None)

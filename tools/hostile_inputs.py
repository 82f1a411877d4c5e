"""Small hostile inputs through the command line: each is built here, given to the command a user
would run, and measured (exit code, the one line on stderr, wall and CPU time, peak RSS).

    python tools/hostile_inputs.py            # the table, as markdown (for bench/RESULTS.md)
    python tools/hostile_inputs.py --json     # one JSON object per case

tests/test_hostile_inputs.py runs the same cases and checks that each is refused in one line,
within 2 CPU seconds and 200 MB beyond what the same command costs on a trivially bad input (its
`baseline`: a command that imports torch costs about 2 s and 600-900 MB before it reads anything;
bench/RESULTS.md). CPU time, not wall time: the suite's other workers share the cores, and
waiting for one is no cost of the input.
"""

from __future__ import annotations

import argparse
import io
import json
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

REPO = Path(__file__).resolve().parent.parent
DATASETS = REPO / "datasets"
CARTPOLE = DATASETS / "CartPole-v1.mcap"


@dataclass(frozen=True)
class Case:
    name: str
    build: Callable[[Path], list[str]]  # folder → the command's arguments
    expect: str  # a fragment of the one-line error
    baseline: str  # the name of the case whose cost is the command's own
    testdata: bool = False  # needs ../shared/testdata (a real ROS 2 bag to convert)


@dataclass(frozen=True)
class Outcome:
    name: str
    command: str
    input_bytes: int
    returncode: int
    message: str
    seconds: float
    cpu_seconds: float
    peak_rss_mb: float


# Runs one command and reports its peak RSS and CPU time: the wrapper has that one child, so its
# RUSAGE_CHILDREN figures are the command's own.
_WRAPPER = (
    "import resource, subprocess, sys; "
    "code = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL).returncode; "
    "usage = resource.getrusage(resource.RUSAGE_CHILDREN); "
    "print(code, usage.ru_maxrss, usage.ru_utime + usage.ru_stime, file=sys.stdout)"
)


def run(args: list[str], timeout: float = 120) -> tuple[int, str, float, float, float]:
    """(exit code, stderr, wall seconds, CPU seconds, peak RSS in MB) of `imitation ARGS` in a fresh process."""
    started = time.perf_counter()
    result = subprocess.run([sys.executable, "-c", _WRAPPER, sys.executable, str(REPO / "cli.py"), *args], capture_output=True, text=True,
                            timeout=timeout, cwd=REPO)
    seconds = time.perf_counter() - started
    code, rss_kb, cpu = result.stdout.split()
    return int(code), result.stderr, seconds, float(cpu), int(rss_kb) / 1024


# -- the inputs -------------------------------------------------------------------------------


def _alias_bomb(levels: int = 8) -> str:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, levels + 1)]
    return "\n".join(lines + ["rate_hz: 10", f"observation: *a{levels}", "action: []"]) + "\n"


def _demo_with_space(folder: Path, name: str, observation_space: dict) -> Path:
    """A real demo file with its dataset metadata's observation space replaced (checksum kept valid)."""
    return _rewrite(folder / name, "imitation.dataset", lambda values: {**values, "observation_space": json.dumps(observation_space)})


def _demo_with_episodes(folder: Path, name: str, edit: Callable[[list], list]) -> Path:
    """A real demo file with its episode index edited (checksum kept valid)."""
    return _rewrite(folder / name, "imitation.episodes", lambda values: {"episodes": json.dumps(edit(json.loads(values["episodes"])))})


def _rewrite(path: Path, record_name: str, edit: Callable[[dict], dict]) -> Path:
    """The bundled CartPole demo file written again record by record, metadata `record_name` edited."""
    sys.path.insert(0, str(REPO))
    from mcap.records import Channel, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import Writer

    from imitation.data.mcap.format import metadata_crc

    records = list(StreamReader(io.BytesIO(CARTPOLE.read_bytes()), emit_chunks=False).records)
    out = io.BytesIO()
    writer = Writer(out)
    header = next(r for r in records if isinstance(r, Header))
    writer.start(profile=header.profile, library=header.library)
    seen: set = set()
    for record in records:
        if isinstance(record, Metadata) and record.name not in seen:
            seen.add(record.name)
            values = {k: v for k, v in record.metadata.items() if k != "crc32"}
            if record.name == record_name:
                values = edit(values)
            writer.add_metadata(record.name, {**values, "crc32": metadata_crc(values)})
        elif isinstance(record, Schema) and ("s", record.id) not in seen:
            seen.add(("s", record.id))
            writer.register_schema(record.name, record.encoding, record.data)
        elif isinstance(record, Channel) and ("c", record.id) not in seen:
            seen.add(("c", record.id))
            writer.register_channel(record.topic, record.message_encoding, record.schema_id, dict(record.metadata))
        elif isinstance(record, Message):
            writer.add_message(record.channel_id, log_time=record.log_time, data=record.data, publish_time=record.publish_time)
    writer.finish()
    path.write_bytes(out.getvalue())
    return path


def _box(shape: list[int]) -> dict:
    return {"type": "Box", "dtype": "float64", "shape": shape, "low": "-inf", "high": "inf"}


def _zeros_file(folder: Path) -> Path:
    """A demo file written by DemoWriter whose observations are all zeros: 98 MB of data in 7 KB."""
    sys.path.insert(0, str(REPO))
    import gymnasium as gym
    import numpy as np

    from imitation.data.mcap.writer import write_episodes
    from imitation.data.types import Episode

    space = gym.spaces.Box(-1, 1, (4096,), np.float32)
    episodes = [Episode(observations=np.zeros((2001, 4096), np.float32), actions=np.zeros(2000, np.int64), rewards=np.zeros(2000), truncated=True)
                for _ in range(3)]
    return write_episodes(folder / "zeros.mcap", episodes, env_id="CartPole-v1", observation_space=space, action_space=gym.spaces.Discrete(2),
                          chunk_size=2**26)


def _sb3_zip(folder: Path, name: str, data: dict | bytes, weights: bytes | None = None) -> Path:
    sys.path.insert(0, str(REPO / "tests"))
    import gymnasium as gym
    import numpy as np
    import torch
    from sb3_zips import space_entry, sb3_weights

    if weights is None:
        buffer = io.BytesIO()
        torch.save(sb3_weights(4, 2, pi=[8], vf=[8]), buffer)
        weights = buffer.getvalue()
    if isinstance(data, dict):
        fields = {"observation_space": space_entry(gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)), "action_space": space_entry(gym.spaces.Discrete(2)),
                  "policy_kwargs": {}, "use_sde": False}
        data = json.dumps(fields | data).encode()
    path = folder / name
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("data", data)
        archive.writestr("policy.pth", weights)
    return path


def _lying_zip(folder: Path, name: str, member: str, payload: bytes, claimed: int, *, compressed: bool = False) -> Path:
    """A zip whose headers claim `claimed` uncompressed (or, with `compressed`, compressed)
    bytes for `member`."""
    path = folder / name
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr(member, payload)
    data = bytearray(path.read_bytes())
    central, local = data.rindex(b"PK\x01\x02"), data.index(b"PK\x03\x04")
    struct.pack_into("<I", data, central + (20 if compressed else 24), claimed)  # the sizes in the central directory
    struct.pack_into("<I", data, local + (18 if compressed else 22), claimed)  # and in the local header
    path.write_bytes(bytes(data))
    return path


def _npy_bytes(shape: tuple[int, ...]) -> bytes:
    import numpy as np

    member = io.BytesIO()
    np.lib.format.write_array_header_1_0(member, {"descr": "<f4", "fortran_order": False, "shape": shape})
    return member.getvalue() + b"\0" * 64


def _rosbag2(folder: Path, text: str) -> Path:
    bag = folder / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text(text)
    return bag


def _map(folder: Path, name: str, text: str) -> Path:
    (folder / name).write_text(text)
    return folder / name


_OBS_ACT = "observation: [{topic: /a, fields: [x]}]\naction: [{topic: /b, fields: [y]}]\n"
_BAG = REPO.parent / "shared" / "testdata" / "ros2" / "replay_testing" / "cmd_vel_only.mcap"


HUGE_DISCRETE = {":type:": "<class 'gymnasium.spaces.discrete.Discrete'>", "n": "10000000000000", "_shape": []}


def _record_sb3(folder: Path, zip_path: Path) -> list[str]:
    return ["record", "--env", "CartPole-v1", "--expert", f"sb3:{zip_path}", "--out", str(folder / "o.mcap")]


def _convert_bag(map_path: Path, folder: Path) -> list[str]:
    return ["convert", str(_BAG), "--map", str(map_path), "--out", str(folder / "out.mcap")]


CASES = [
    Case("info baseline", lambda f: ["info", str(_map(f, "plain.mcap", "not mcap"))], "not an MCAP file", "info baseline"),
    Case("record sb3 baseline", lambda f: _record_sb3(f, _map(f, "plain.zip", "not a zip")), "cannot read as a stable-baselines3 zip",
         "record sb3 baseline"),
    Case("convert baseline", lambda f: ["convert", str(_map(f, "plain.npz", "not an npz")), "--out", str(f / "o.mcap")], "not a readable npz",
         "convert baseline"),
    Case("YAML alias bomb in --map", lambda f: _convert_bag(_map(f, "bomb.yaml", _alias_bomb()), f), "yaml_nodes", "convert baseline", testdata=True),
    Case("YAML alias bomb in rosbag2 metadata.yaml", lambda f: ["convert", str(_rosbag2(f, "rosbag2_bagfile_information:\n" + "".join(
        f"  {line}\n" for line in _alias_bomb().splitlines()))), "--inspect"], "yaml_nodes", "convert baseline"),
    Case("map with int and str keys", lambda f: _convert_bag(_map(f, "mixed.yaml", "rate_hz: 10\n3: x\n" + _OBS_ACT), f), "keys must be text",
         "convert baseline", testdata=True),
    Case("map with a 5000-digit rate_hz", lambda f: _convert_bag(_map(f, "digits.yaml", "rate_hz: 1" + "0" * 5000 + "\n" + _OBS_ACT), f),
         "an integer of 5001 digits", "convert baseline", testdata=True),
    Case("map with default 1e400 as an integer", lambda f: _convert_bag(_map(f, "huge.yaml", "rate_hz: 10\nobservation: [{topic: /a, fields: [x], default: [1"
                                                                                + "0" * 400 + "]}]\naction: [{topic: /b, fields: [y]}]\n"), f),
         "an integer of 401 digits", "convert baseline", testdata=True),
    Case("demo file declaring Box(2^26)", lambda f: ["info", str(_demo_with_space(f, "box.mcap", _box([2**26])))], "sample_elements", "info baseline"),
    Case("demo file with a Dict of 40 × Box(2^26)", lambda f: ["info", str(_demo_with_space(
        f, "dict.mcap", {"type": "Dict", "spaces": {f"k{i}": _box([2**26]) for i in range(40)}}))], "sample_elements", "info baseline"),
    Case("demo file of zeros (98 MB in 7 KB)", lambda f: ["info", str(_zeros_file(f))], "expansion_ratio", "info baseline"),
    Case("episode index claiming 10^15 steps", lambda f: ["info", str(_demo_with_episodes(f, "steps.mcap", lambda e: [{**e[0], "length": 10**15}, *e[1:]]))],
         "more than the file's chunks hold", "info baseline"),
    Case("episode index listing an episode twice", lambda f: ["info", str(_demo_with_episodes(
        f, "twice.mcap", lambda e: [*e[:2], {**e[1], "index": 2}, *[{**x, "index": k + 3} for k, x in enumerate(e[2:])]]))], "overlapping", "info baseline"),
    Case("SB3 zip declaring Discrete(1e13)", lambda f: _record_sb3(f, _sb3_zip(f, "discrete.zip", {"action_space": HUGE_DISCRETE})), "sample_elements",
         "record sb3 baseline"),
    Case("SB3 zip whose :type: is an int", lambda f: _record_sb3(f, _sb3_zip(f, "type.zip", {"observation_space": {":type:": 7}})),
         "no readable observation_space", "record sb3 baseline"),
    Case("SB3 zip with data nested 100,000 deep", lambda f: _record_sb3(f, _sb3_zip(f, "deep.zip", b"[" * 100_000 + b"]" * 100_000)), "nested too deep",
         "record sb3 baseline"),
    Case("SB3 zip whose header claims a 4 GB policy.pth", lambda f: _record_sb3(f, _lying_zip(f, "lying.zip", "policy.pth", b"x" * 1000, 2**32 - 1)),
         "expansion_ratio", "record sb3 baseline"),
    Case("npz claiming more compressed bytes than it has", lambda f: ["convert", str(_lying_zip(f, "short.npz", "obs.npy", _npy_bytes((4,)), 10**6,
                                                                                               compressed=True)), "--out", str(f / "o.mcap")],
         "is damaged (it claims more bytes than the archive has)", "convert baseline"),
    Case("npz whose zip header claims 4 GB", lambda f: ["convert", str(_lying_zip(f, "lying.npz", "obs.npy", _npy_bytes((10**9,)), 2**32 - 1)), "--out",
                                                        str(f / "o.mcap")], "expansion_ratio", "convert baseline"),
    Case("npz whose .npy header claims 74.5 GiB", lambda f: ["convert", str(_lying_zip(f, "claims.npz", "obs.npy", _npy_bytes((20 * 10**9,)), 1000)),
                                                             "--out", str(f / "o.mcap")], "promises more data", "convert baseline"),
]


# -- hostile servers: `info` of a URL, served by tools/http_servers.py on 127.0.0.1 -----------
# One server in this process for all cases, started by the first: the bundled CartPole demos at
# /demos.mcap, and at /BEHAVIOUR/demos.mcap as a misbehaving server answers (HostileHandler).
# Waiting on a server costs no CPU, so tests/test_hostile_inputs.py bounds these cases' wall time
# as well. The time bounds' defaults (30 s without a byte, 300 s a request) are for real servers
# over real networks: the trickling and the silent server are measured with them lowered to 1 s,
# as `imitation --limit` lets a user lower them.

_SERVER: list = []


def _served(path: str) -> str:
    """The URL of `path` on the hostile server, started on first use."""
    if not _SERVER:
        sys.path.insert(0, str(REPO / "tools"))
        from http_servers import HostileHandler, gzip_bomb, serve

        gzip_bomb()  # made once, before any command is timed
        _SERVER.append(serve({"/demos.mcap": CARTPOLE.read_bytes(), "/plain.mcap": b"not mcap"}, HostileHandler))
    return _SERVER[0].url + path


SERVER_CASES = [
    Case("info over HTTP baseline", lambda f: ["info", _served("/plain.mcap")], "not an MCAP file", "info over HTTP baseline"),
    Case("server streaming without end and without Content-Length", lambda f: ["info", _served("/no-length/demos.mcap")],
         "sent more than the 8 bytes asked for", "info over HTTP baseline"),
    Case("server answering 8 bytes with Content-Length 10 GB", lambda f: ["info", _served("/claims-10gb/demos.mcap")],
         "answered a request for 8 bytes with Content-Length 10737418240", "info over HTTP baseline"),
    Case("server of a 10 GB object, zeros behind the magic", lambda f: ["info", _served("/garbage-10gb/demos.mcap")],
         "10737418240 is more than the limit remote_request_bytes", "info over HTTP baseline"),
    Case("server answering gzip that inflates to 512 MiB", lambda f: ["info", _served("/gzip-bomb/demos.mcap")],
         "encoded as 'gzip'", "info over HTTP baseline"),
    Case("server ignoring Range on a 3 GB object (200, the whole body)",
         lambda f: ["info", _served("/ignores-range/demos.mcap")], "it ignores Range: each answer starts at byte 0", "info over HTTP baseline"),
    Case("server trickling a byte every 2 s",
         lambda f: ["--limit", "remote_request_seconds=1", "info", _served("/trickle/demos.mcap")],
         "took more than 1 s to send 8 bytes", "info over HTTP baseline"),
    Case("server that never answers", lambda f: ["--limit", "remote_stall_seconds=1", "info", _served("/silent/demos.mcap")],
         "sent nothing for 1 s", "info over HTTP baseline"),
    Case("server answering each request after 0.5 s",
         lambda f: ["--limit", "remote_total_seconds=1", "info", _served("/slow/demos.mcap")],
         "went past this command's 1 s for remote reading", "info over HTTP baseline"),
]
CASES += SERVER_CASES


# -- camera frames that decode to far more than their files hold ------------------------------
# Each file is written by the library a user's data comes from: DemoWriter (Pillow's PNG and
# JPEG encoders), rosbags' rosbag2 writer, lerobot's own dataset writer (its video through
# PyAV). A black 1080p frame is 6.2 MB decoded and 27 KB as a PNG; identical frames in one zstd
# chunk cost next to nothing more, so 40 of them (249 MB) fit in 11 KB.

_H, _W = 1080, 1920
_BUILT: dict = {}  # (builder, arguments) → a folder built once per process, copied for each case


def _black_frames_demo(folder: Path, name: str, steps: int, codec: str = "png") -> Path:
    """A demo file of `steps` steps whose observation is a black 1080p camera."""
    sys.path.insert(0, str(REPO))
    import gymnasium as gym
    import numpy as np

    from imitation.data.mcap.writer import write_episodes
    from imitation.data.types import Episode

    frames = np.broadcast_to(np.zeros((1, _H, _W, 3), np.uint8), (steps + 1, _H, _W, 3))
    episode = Episode(observations=frames, actions=np.zeros(steps, np.int64), rewards=np.zeros(steps), truncated=True)
    return write_episodes(folder / name, [episode], env_id="CartPole-v1", observation_space=gym.spaces.Box(0, 255, (_H, _W, 3), np.uint8),
                          action_space=gym.spaces.Discrete(2), image_codec=codec)


def _many_scans_jpeg(scans: int) -> bytes:
    """A black 1080p progressive JPEG from Pillow with its last scan (a refinement that changes
    nothing, 12 bytes) repeated until the picture has `scans` scans: libjpeg decodes each over the
    whole picture."""
    sys.path.insert(0, str(REPO))
    import numpy as np
    from PIL import Image

    from imitation.data.jpeg_scans import scan_count

    out = io.BytesIO()
    Image.fromarray(np.zeros((_H, _W, 3), np.uint8)).save(out, format="JPEG", progressive=True, quality=90)
    data = out.getvalue()
    last, end = data.rindex(b"\xff\xda"), data.rindex(b"\xff\xd9")
    jpeg = data[:end] + data[last:end] * (scans - scan_count(data)) + data[end:]
    assert scan_count(jpeg) == scans
    return jpeg


def _many_scans_demo(folder: Path, scans: int, steps: int) -> Path:
    """A JPEG demo file of a black 1080p camera whose every frame is `_many_scans_jpeg(scans)`
    (the messages re-written around it, each keeping its timestamp)."""
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from mcap.records import Channel, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader
    from mcap.writer import Writer

    source = _black_frames_demo(folder, "source.mcap", steps, codec="jpeg")
    jpeg = _many_scans_jpeg(scans)
    records = list(StreamReader(io.BytesIO(source.read_bytes()), emit_chunks=False).records)
    source.unlink()
    path, out = folder / "scans.mcap", io.BytesIO()
    writer = Writer(out)
    header = next(r for r in records if isinstance(r, Header))
    writer.start(profile=header.profile, library=header.library)
    schemas = {r.id: r.name for r in records if isinstance(r, Schema)}
    cameras = {r.id for r in records if isinstance(r, Channel) and schemas.get(r.schema_id) == "foxglove.CompressedImage"}
    seen: set = set()
    for record in records:
        if isinstance(record, Metadata) and record.name not in seen:
            seen.add(record.name)
            writer.add_metadata(record.name, dict(record.metadata))
        elif isinstance(record, Schema) and ("s", record.id) not in seen:
            seen.add(("s", record.id))
            writer.register_schema(record.name, record.encoding, record.data)
        elif isinstance(record, Channel) and ("c", record.id) not in seen:
            seen.add(("c", record.id))
            writer.register_channel(record.topic, record.message_encoding, record.schema_id, dict(record.metadata))
        elif isinstance(record, Message):
            data = record.data
            if record.channel_id in cameras:
                frame = CompressedImage.FromString(data)
                data = CompressedImage(timestamp=frame.timestamp, format="jpeg", data=jpeg).SerializeToString()
            writer.add_message(record.channel_id, log_time=record.log_time, data=data, publish_time=record.publish_time)
    writer.finish()
    path.write_bytes(out.getvalue())
    return path


def _camera_bag(folder: Path, frames: list[tuple[float, bytes, str]], commands: list[float]) -> Path:
    """A rosbag2 MCAP folder written by rosbags: sensor_msgs/CompressedImage messages on
    /camera/compressed ((seconds, bytes, format) each) and std_msgs/Float64 on /cmd at `commands`
    (seconds)."""
    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    start = 1_700_000_000 * 10**9
    bag = folder / "bag"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        camera = writer.add_connection("/camera/compressed", "sensor_msgs/msg/CompressedImage", typestore=store)
        command = writer.add_connection("/cmd", "std_msgs/msg/Float64", typestore=store)
        for seconds, data, encoding in frames:
            t = start + round(seconds * 1e9)
            header = types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9), frame_id="camera")
            message = types["sensor_msgs/msg/CompressedImage"](header=header, format=encoding, data=np.frombuffer(data, np.uint8))
            writer.write(camera, t, store.serialize_cdr(message, message.__msgtype__))
        for seconds in commands:
            t = start + round(seconds * 1e9)
            writer.write(command, t, store.serialize_cdr(types["std_msgs/msg/Float64"](data=1.0), "std_msgs/msg/Float64"))
    return bag


def _convert_camera_bag(folder: Path, frames: list[tuple[float, bytes, str]], commands: list[float], rate_hz: int) -> list[str]:
    bag = _camera_bag(folder, frames, commands)
    recording_map = _map(folder, "map.yaml", f"rate_hz: {rate_hz}\nobservation: [{{topic: /camera/compressed, image: front}}]\n"
                                             "action: [{topic: /cmd, fields: [data]}]\n")
    return ["convert", str(bag), "--map", str(recording_map), "--out", str(folder / "out.mcap")]


def _black_png() -> bytes:
    import numpy as np
    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(np.zeros((_H, _W, 3), np.uint8)).save(out, format="PNG", compress_level=9)
    return out.getvalue()


def _lerobot_still_video(folder: Path, frames: int) -> Path:
    """A LeRobot v3.0 dataset written by lerobot's own writer (its H.264 encoder through PyAV):
    one episode of `frames` frames of a black 1080p camera beside a one-number state and action.
    Built once per process (importing lerobot takes seconds), copied into `folder`."""
    key = ("lerobot", frames)
    if key not in _BUILT:
        import os

        import numpy as np

        os.environ["HF_HUB_OFFLINE"] = "1"
        sys.path.insert(0, str(REPO))
        from imitation.data.convert.lerobot import lerobot_quietly

        built = Path(tempfile.mkdtemp(prefix="imitation-hostile-lerobot-")) / "dataset"
        with lerobot_quietly():
            from lerobot.configs import RGBEncoderConfig
            from lerobot.datasets.lerobot_dataset import LeRobotDataset

            features = {"observation.images.front": {"dtype": "video", "shape": [_H, _W, 3], "names": ["height", "width", "channel"]},
                        "observation.state": {"dtype": "float32", "shape": [1], "names": None},
                        "action": {"dtype": "float32", "shape": [1], "names": None}}
            dataset = LeRobotDataset.create(repo_id="local/still", fps=30, features=features, root=built, use_videos=True, image_writer_threads=0,
                                            rgb_encoder=RGBEncoderConfig(vcodec="h264", pix_fmt="yuv420p"))
            black = np.zeros((_H, _W, 3), np.uint8)
            for _ in range(frames):
                dataset.add_frame({"observation.images.front": black, "observation.state": np.zeros(1, np.float32),
                                   "action": np.zeros(1, np.float32), "task": "stand still"})
            dataset.save_episode()
            dataset.finalize()
        _BUILT[key] = built
    shutil.copytree(_BUILT[key], folder / "dataset")
    return folder / "dataset"


def _train_bc(folder: Path, demos: Path) -> list[str]:
    return ["train", "bc", "--demos", str(demos), "--epochs", "1", "--out", str(folder / "run")]


def _export_foxglove(folder: Path, demos: Path) -> list[str]:
    return ["export", str(demos), "--to", "foxglove", str(folder / "steps.mcap")]


IMAGE_CASES = [
    Case("train bc baseline", lambda f: _train_bc(f, _map(f, "plain.mcap", "not mcap")), "not an MCAP file", "train bc baseline"),
    Case("export baseline", lambda f: _export_foxglove(f, _map(f, "plain.mcap", "not mcap")), "not an MCAP file", "export baseline"),
    Case("demo file of 40 black 1080p PNG frames (249 MB decoded)", lambda f: ["info", str(_black_frames_demo(f, "black.mcap", 39))],
         "image_expansion_ratio", "info baseline"),
    Case("the same demo file, trained on", lambda f: _train_bc(f, _black_frames_demo(f, "black.mcap", 39)), "image_expansion_ratio",
         "train bc baseline"),
    Case("the same demo file, exported to Foxglove", lambda f: _export_foxglove(f, _black_frames_demo(f, "black.mcap", 39)),
         "image_expansion_ratio", "export baseline"),
    Case("demo file of 1080p progressive JPEG frames of 600 scans", lambda f: ["info", str(_many_scans_demo(f, 600, 9))], "jpeg_scans",
         "info baseline"),
    Case("ROS 2 bag of 1080p progressive JPEG frames of 600 scans", lambda f: _convert_camera_bag(
        f, [(i / 10, _many_scans_jpeg(600), "jpeg") for i in range(10)], [i / 10 for i in range(10)], 10), "jpeg_scans", "convert baseline"),
    Case("ROS 2 bag of two black 1080p PNG frames held over 100 steps", lambda f: _convert_camera_bag(
        f, [(0.0, _black_png(), "png"), (0.5, _black_png(), "png")], [i / 20 for i in range(20)], 100), "image_expansion_ratio", "convert baseline"),
    Case("LeRobot dataset of a 40-frame black 1080p video", lambda f: ["convert", str(_lerobot_still_video(f, 40)), "--out", str(f / "o.mcap")],
         "image_expansion_ratio", "convert baseline"),
]
CASES += IMAGE_CASES

def measure(case: Case, folder: Path) -> Outcome:
    args = case.build(folder)
    size = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
    code, stderr, seconds, cpu, rss = run(args)
    lines = [line for line in stderr.splitlines() if line.strip() and not line.startswith("warning:")]
    message = (lines[-1] if lines else "").replace(f"{folder}/", "")
    return Outcome(case.name, "imitation " + " ".join(a if len(a) < 40 else "…/" + Path(a).name for a in args[:3]), size, code, message, seconds, cpu, rss)


def measure_all(cases: list[Case] = CASES) -> list[Outcome]:
    outcomes = []
    for case in cases:
        with tempfile.TemporaryDirectory(prefix="imitation-hostile-") as folder:
            outcomes.append(measure(case, Path(folder)))
    return outcomes


def table(outcomes: list[Outcome]) -> str:
    by_name = {o.name: o for o in outcomes}
    rows = ["| input | command | exit | message | time (CPU) | peak RSS | beyond the command's baseline (CPU) |", "|---|---|---|---|---|---|---|"]
    for case, outcome in zip(CASES, outcomes):
        base = by_name[case.baseline]
        extra = "—" if case.baseline == case.name else f"{outcome.cpu_seconds - base.cpu_seconds:+.2f} s, {outcome.peak_rss_mb - base.peak_rss_mb:+.0f} MB"
        message = outcome.message if len(outcome.message) <= 140 else outcome.message[:139] + "…"
        rows.append(f"| {case.name} ({outcome.input_bytes:,} B) | `{outcome.command}` | {outcome.returncode} | {message.replace('|', '/')} | "
                    f"{outcome.seconds:.2f} s ({outcome.cpu_seconds:.2f} s) | {outcome.peak_rss_mb:.0f} MB | {extra} |")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="one JSON object per case instead of the markdown table")
    args = parser.parse_args()
    outcomes = measure_all()
    if args.json:
        for outcome in outcomes:
            print(json.dumps(vars(outcome)))
    else:
        print(table(outcomes))


if __name__ == "__main__":
    main()

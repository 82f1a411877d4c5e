"""Benchmark: decode and load camera frames into torch uint8 batches of 256, ours vs LeRobot's video path.

Frames: the wrist camera of the SO-101 LeRobot v3.0 test recording (../shared/testdata/lerobot/so101_v30,
AV1 640x360, 1,782 frames in 6 episodes), decoded once with PyAV; --frames N keeps the first N
(episodes cut to fit). The same uint8 frames are written, once, and cached under --data-dir:

- ours: four MCAP demo files through DemoWriter, image_codec "jpeg" (quality 95, lossy),
  "png" (lossless), "raw" with zstd chunks and "raw" with lz4 chunks (both lossless; compression
  "lz4"), the source's episodes, a 1-dim zero action;
- LeRobot: a LeRobotDataset v3.0 through its own writer (create(use_videos=True), add_frame,
  save_episode, finalize) with its default video encoder (libsvtav1, lossy; LeRobot has no
  lossless video default), the same episodes and action.

After writing, our lossless files are checked to decode to the source frames exactly, and the
PSNR of the lossy ones (our JPEG, LeRobot's video) against them is measured.

Each timed run is a fresh Python process (this script with --measure), timed from just before the
dataset is opened until the last batch of 256 frames exists as a torch uint8 tensor, imports
excluded; runs are interleaved across methods and the median of --repeats is reported. With
--prefault-gib G each run first touches G GiB in a child process that exits (`prefault`), outside
the clock, for VMs that hand freed memory back to their host.

- ours: load_transitions(DemoDataset(file), next_observations=False) → transitions_to_torch →
  MinibatchLoader(batch_size=256, shuffle=True); a batch's observations are (256, H, W, C) uint8.
  The last observation of each episode (no transition) is not loaded, so ours delivers N − E frames.
- LeRobot: LeRobotDataset(video_backend="pyav", return_uint8=True), as lerobot-train opens it
  (torchcodec does not import here), through torch's DataLoader(batch_size=256, shuffle=True)
  with num_workers 2 and 0; a batch's image is (256, C, H, W) uint8. N frames.

Neither side converts layout or dtype further. frames/s = frames delivered / seconds.
Targets (issue): ours / LeRobot ≥ 3 for the lossy format (our JPEG) and ≥ 5 for the lossless
one (our PNG, and raw with either chunk compression), against LeRobot's faster DataLoader setting.
Hugging Face libraries run with HF_HUB_OFFLINE=1 and HF_HOME under --data-dir.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from load import hf_environment, ratio_line, run_json

BENCH = Path(__file__).resolve().parent
SOURCE = BENCH.parent.parent / "shared" / "testdata" / "lerobot" / "so101_v30"
CAMERA = "observation.images.wrist"
VIDEO = SOURCE / "videos" / CAMERA / "chunk-000" / "file-000.mp4"
BATCH = 256
FPS = 30  # the source's recording rate
JPEG_QUALITY = 95
LOSSY_TARGET = 3.0  # ours / LeRobot, frames per second
LOSSLESS_TARGET = 5.0
REPO_ID = "bench/so101-wrist"
TASK = "pick"
MIB = 1024 * 1024
# Our files: method key → (image codec, chunk compression).
OURS = {
    "ours-jpeg": ("jpeg", "zstd"),
    "ours-png": ("png", "zstd"),
    "ours-raw": ("raw", "zstd"),
    "ours-raw-lz4": ("raw", "lz4"),
}


@dataclass(frozen=True)
class Method:
    """One row of the table: what --measure runs, and where its bytes are."""

    key: str
    label: str
    stored: str  # file or directory under the data directory whose size is reported
    lossless: bool
    workers: int = 0  # LeRobot's DataLoader workers


METHODS = [
    Method("ours-jpeg", f"ours, jpeg q{JPEG_QUALITY} (lossy)", "ours-jpeg.mcap", lossless=False),
    Method("ours-png", "ours, png (lossless)", "ours-png.mcap", lossless=True),
    Method("ours-raw", "ours, raw + zstd chunks (lossless)", "ours-raw.mcap", lossless=True),
    Method("ours-raw-lz4", "ours, raw + lz4 chunks (lossless)", "ours-raw-lz4.mcap", lossless=True),
    Method("lerobot-w2", "LeRobot video (lossy), DataLoader num_workers=2", "lerobot/videos", lossless=False, workers=2),
    Method("lerobot-w0", "LeRobot video (lossy), DataLoader num_workers=0", "lerobot/videos", lossless=False, workers=0),
]


@dataclass
class Runs:
    """Every measured run of one method."""

    method: Method
    results: list[dict] = field(default_factory=list)

    @property
    def median(self) -> float:
        return statistics.median(r["seconds"] for r in self.results)

    @property
    def median_cpu(self) -> float:
        return statistics.median(r["cpu_seconds"] for r in self.results)

    @property
    def fps(self) -> float:
        return self.results[0]["frames"] / self.median

    @property
    def fps_cpu(self) -> float:
        return self.results[0]["frames"] / self.median_cpu


# ---------------------------------------------------------------------------- one timed run


def measure_ours(path: Path) -> tuple[int, tuple[int, ...]]:
    """Our public API: load every transition's observation, then shuffled batches of 256."""
    import torch

    from imitation.data.dataset import DemoDataset
    from imitation.data.loader import MinibatchLoader, load_transitions, transitions_to_torch

    data = transitions_to_torch(load_transitions(DemoDataset(path), next_observations=False), "cpu")
    frames, shape = 0, ()
    for batch in MinibatchLoader(data, batch_size=BATCH, shuffle=True, seed=0):
        images = batch.observations
        assert images.dtype == torch.uint8
        frames, shape = frames + len(images), tuple(images.shape[1:])
    return frames, shape


def measure_lerobot(root: Path, workers: int) -> tuple[int, tuple[int, ...]]:
    """LeRobot's training path: the dataset as lerobot-train opens it, through torch's DataLoader."""
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = LeRobotDataset(REPO_ID, root=root, video_backend="pyav", return_uint8=True)
    loader = torch.utils.data.DataLoader(
        dataset, batch_size=BATCH, shuffle=True, num_workers=workers, generator=torch.Generator().manual_seed(0)
    )
    frames, shape = 0, ()
    for batch in loader:
        images = batch[CAMERA]
        assert images.dtype == torch.uint8
        frames, shape = frames + len(images), tuple(images.shape[1:])
    return frames, shape


def prefault(gib: float) -> None:
    """Touch `gib` GiB in a forked child that then exits, so the memory the run is about to take
    is backed by the host again. A VM with free-page reporting (Firecracker's, here) hands freed
    guest memory back to its host, and touching it again is a host fault, many times slower than
    reusing memory (bench/RESULTS.md), so without this a run that holds more frames in memory pays
    for the host's memory rather than for decoding. Every run, ours and LeRobot's, gets the same."""
    if gib <= 0:
        return
    child = os.fork()
    if child == 0:
        np.ones(int(gib * 2**30), dtype=np.uint8)
        os._exit(0)
    os.waitpid(child, 0)


def children_cpu_seconds() -> float:
    """User and system CPU seconds of this process's waited-for children so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def measure(key: str, data: Path, prefault_gib: float) -> dict:
    """One run of `key` in this process; the JSON the parent reads."""
    import torch  # noqa: F401  (imported before the clock starts, like every library below)

    if key.startswith("lerobot"):
        import lerobot.datasets.lerobot_dataset  # noqa: F401
    else:  # with what the frame decoder imports on its first frame
        import foxglove_schemas_protobuf.CompressedImage_pb2  # noqa: F401
        import foxglove_schemas_protobuf.RawImage_pb2  # noqa: F401
        import PIL.Image  # noqa: F401

        import imitation.data.loader  # noqa: F401
    method = next(m for m in METHODS if m.key == key)
    prefault(prefault_gib)
    children_before = children_cpu_seconds()  # the prefault child's CPU is not the run's
    cpu_start = time.process_time()
    start = time.perf_counter()
    if key.startswith("lerobot"):
        frames, shape = measure_lerobot(data / "lerobot", method.workers)
    else:
        frames, shape = measure_ours(data / method.stored)
    seconds = time.perf_counter() - start
    children = children_cpu_seconds() - children_before  # DataLoader workers, joined by now
    return {
        "seconds": seconds,
        "cpu_seconds": time.process_time() - cpu_start + children,
        "frames": frames,
        "shape": list(shape),
        "max_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


# ---------------------------------------------------------------------------- data, once


def source_frames(limit: int) -> tuple[np.ndarray, list[int]]:
    """The first `limit` frames of the wrist camera (uint8, N x H x W x 3) and their episode lengths."""
    import av
    import pyarrow.parquet as pq

    frames: list[np.ndarray] = []
    with av.open(str(VIDEO)) as container:
        for frame in container.decode(container.streams.video[0]):
            frames.append(frame.to_ndarray(format="rgb24"))
            if len(frames) == limit:
                break
    lengths: list[int] = []
    for length in pq.read_table(SOURCE / "meta" / "episodes" / "chunk-000" / "file-000.parquet", columns=["length"])["length"]:
        lengths.append(min(length.as_py(), len(frames) - sum(lengths)))
    lengths = [n for n in lengths if n > 0]
    if lengths[-1] == 1 and len(lengths) > 1:  # an episode needs two observations (one transition)
        lengths[-2:] = [lengths[-2] + 1]
    return np.stack(frames), lengths


def write_ours(frames: np.ndarray, lengths: list[int], path: Path, codec: str, compression: str) -> float:
    """Our file through DemoWriter, one episode per source episode; returns seconds."""
    import gymnasium as gym

    from imitation.data.mcap.writer import DemoWriter
    from imitation.data.types import Episode

    start = time.perf_counter()
    observation_space = gym.spaces.Box(0, 255, frames.shape[1:], np.uint8)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    with DemoWriter(
        path,
        env_id="",
        observation_space=observation_space,
        action_space=action_space,
        dt=1 / FPS,
        image_codec=codec,
        jpeg_quality=JPEG_QUALITY,
        compression=compression,
    ) as writer:
        offset = 0
        for length in lengths:
            steps = length - 1
            writer.write(
                Episode(
                    observations=frames[offset : offset + length],
                    actions=np.zeros((steps, 1), np.float32),
                    rewards=np.zeros(steps),
                    truncated=True,
                )
            )
            offset += length
    return time.perf_counter() - start


def write_lerobot(frames: np.ndarray, lengths: list[int], root: Path) -> float:
    """A LeRobotDataset through its documented recording path, default video encoder; returns seconds."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    import datasets

    datasets.disable_progress_bars()
    features = {
        CAMERA: {"dtype": "video", "shape": frames.shape[1:], "names": ["height", "width", "channels"]},
        "action": {"dtype": "float32", "shape": (1,), "names": None},
    }
    start = time.perf_counter()
    dataset = LeRobotDataset.create(REPO_ID, FPS, features, root=root, use_videos=True, video_backend="pyav")
    offset = 0
    for length in lengths:
        for frame in frames[offset : offset + length]:
            dataset.add_frame({CAMERA: frame, "action": np.zeros(1, np.float32), "task": TASK})
        dataset.save_episode()
        offset += length
    dataset.finalize()
    return time.perf_counter() - start


def psnr(reference: np.ndarray, decoded: np.ndarray) -> float:
    """Peak signal-to-noise ratio over all frames, dB."""
    error = 0.0
    for a, b in zip(reference, decoded, strict=True):
        error += float(np.square(a.astype(np.float32) - b.astype(np.float32)).sum())
    return float(10 * np.log10(255.0**2 * reference.size / error)) if error else float("inf")


def check_ours(frames: np.ndarray, data: Path, keys: list[str]) -> dict[str, float]:
    """Our lossless files must give back the frames; PSNR of each against them, by method key."""
    from imitation.data.dataset import DemoDataset

    ours = {}
    for key in keys:
        episodes = DemoDataset(data / f"{key}.mcap").read_episodes()
        decoded = np.concatenate([episode.observations for episode in episodes])
        ours[key] = psnr(frames, decoded)
        if next(m for m in METHODS if m.key == key).lossless and not np.array_equal(frames, decoded):
            raise SystemExit(f"{key}.mcap does not decode to the source frames")
    return ours


def check_quality(frames: np.ndarray, lengths: list[int], data: Path) -> dict:
    """Our lossless files must give back the frames; PSNR of the lossy formats against them."""
    import av

    ours = check_ours(frames, data, list(OURS))
    videos = sorted((data / "lerobot" / "videos").rglob("*.mp4"))
    lerobot_frames = []
    for video in videos:
        with av.open(str(video)) as container:
            stream = container.streams.video[0]
            lerobot_frames += [frame.to_ndarray(format="rgb24") for frame in container.decode(stream)]
            codec = stream.codec_context.name
    if len(lerobot_frames) != len(frames):
        raise SystemExit(f"LeRobot's videos hold {len(lerobot_frames)} frames, not {len(frames)}")
    return {
        "psnr": {**ours, "lerobot": psnr(frames, np.stack(lerobot_frames))},
        "lerobot_decoder": codec,
        "lerobot_videos": len(videos),
    }


def tree_size(path: Path) -> int:
    """Bytes in a file, or in every file under a directory."""
    return path.stat().st_size if path.is_file() else sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def ensure_data(data: Path, limit: int, regenerate: bool) -> dict:
    """The cached data's manifest, writing every format first when missing (or asked to)."""
    manifest_path = data / "manifest.json"
    if regenerate and data.exists():
        shutil.rmtree(data)
    if manifest_path.exists():
        return add_missing(json.loads(manifest_path.read_text()), data, limit, manifest_path)
    if data.exists():  # a run killed half-way; LeRobot refuses an existing root
        shutil.rmtree(data)
    data.mkdir(parents=True)
    print(f"decoding {VIDEO} ...", flush=True)
    frames, lengths = source_frames(limit)
    seconds = {}
    for key, (codec, compression) in OURS.items():
        print(f"writing {key}.mcap ...", flush=True)
        seconds[key] = write_ours(frames, lengths, data / f"{key}.mcap", codec, compression)
    print("writing the LeRobotDataset (add_frame path, video encoding) ...", flush=True)
    seconds["lerobot"] = write_lerobot(frames, lengths, data / "lerobot")
    print("checking what each format decodes to ...", flush=True)
    info = json.loads((data / "lerobot" / "meta" / "info.json").read_text())
    manifest = {
        "frames": len(frames),
        "episodes": len(lengths),
        "shape": list(frames.shape[1:]),
        "write_seconds": seconds,
        "bytes": {m.stored: tree_size(data / m.stored) for m in METHODS} | {"lerobot": tree_size(data / "lerobot")},
        "lerobot_video_info": info["features"][CAMERA].get("info", {}),
        **check_quality(frames, lengths, data),
    }
    manifest_path.write_text(json.dumps(manifest, indent=2))
    return manifest


def add_missing(manifest: dict, data: Path, limit: int, manifest_path: Path) -> dict:
    """A cached data set from before a format was added to OURS: write and check just that file."""
    missing = [key for key in OURS if key not in manifest["write_seconds"]]
    if not missing:
        return manifest
    print(f"decoding {VIDEO} for {', '.join(missing)} ...", flush=True)
    frames, lengths = source_frames(limit)
    for key in missing:
        codec, compression = OURS[key]
        print(f"writing {key}.mcap ...", flush=True)
        manifest["write_seconds"][key] = write_ours(frames, lengths, data / f"{key}.mcap", codec, compression)
        manifest["bytes"][f"{key}.mcap"] = tree_size(data / f"{key}.mcap")
    manifest["psnr"] |= check_ours(frames, data, missing)
    manifest_path.write_text(json.dumps(manifest, indent=2))
    return manifest


def prepare(data: Path, limit: int, regenerate: bool) -> dict:
    """The manifest, with the data written if needed, every file in the page cache and LeRobot's HF
    datasets cache built, so no timed run pays for either. Runs in its own process, so that the
    frames it holds do not count in the timed runs' peak RSS (which a child inherits)."""
    manifest = ensure_data(data, limit, regenerate)
    for file in sorted(p for p in data.rglob("*") if p.is_file()):
        with open(file, "rb") as stream:
            while stream.read(MIB):
                pass
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    LeRobotDataset(REPO_ID, root=data / "lerobot", video_backend="pyav", return_uint8=True)
    return manifest


# ---------------------------------------------------------------------------- report


def report(all_runs: list[Runs], manifest: dict, load: tuple[float, float], prefault_gib: float) -> str:
    """The Markdown tables and target verdicts."""
    by_key = {runs.method.key: runs for runs in all_runs}
    lerobot = max((runs for runs in all_runs if runs.method.key.startswith("lerobot")), key=lambda runs: runs.fps)
    frames, sizes = manifest["frames"], manifest["bytes"]
    found = manifest["psnr"]  # by method key; manifests written before ours-raw-lz4 keyed ours by codec

    def quality_of(key: str) -> float:
        return found["lerobot"] if key.startswith("lerobot") else found.get(key, found.get(OURS[key][0]))

    height, width, channels = manifest["shape"]
    lines = [
        f"{frames:,} wrist-camera frames ({width}x{height}x{channels} uint8, {manifest['episodes']} episodes) "
        f"into torch uint8 batches of {BATCH}; fresh process per run, median of {len(all_runs[0].results)}; "
        f"os.cpu_count() = {os.cpu_count()}; 1-minute load average {load[0]:.1f} before the runs, {load[1]:.1f} after "
        "(above the core count, other processes take CPU: compare the CPU-time ratios); "
        + (f"{prefault_gib:g} GiB touched before each run (--prefault-gib)." if prefault_gib > 0 else "no --prefault-gib."),
        "",
        "| path | frames | median s | frames/s | × LeRobot | runs (s) | median CPU s | peak RSS MiB | KiB/frame | PSNR dB |",
        "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|",
    ]
    for runs in all_runs:
        method = runs.method
        label = method.label + (" ← LeRobot baseline (faster)" if runs is lerobot else "")
        quality = quality_of(method.key)
        lines.append(
            f"| {label} | {runs.results[0]['frames']:,} | {runs.median:.2f} | {runs.fps:,.0f} | "
            f"{runs.fps / lerobot.fps:.2f} | "
            f"{', '.join(format(r['seconds'], '.2f') for r in runs.results)} | {runs.median_cpu:.2f} | "
            f"{max(r['max_rss_mib'] for r in runs.results):,.0f} | {sizes[method.stored] / frames / 1024:.1f} | "
            f"{'exact' if quality == float('inf') else format(quality, '.1f')} |"
        )
    video = manifest["lerobot_video_info"]
    lines += ["", "Targets (frames/s, ours / LeRobot's faster setting; judged on wall time):", ""]
    for key, target, kind in (
        ("ours-jpeg", LOSSY_TARGET, "lossy"),
        ("ours-png", LOSSLESS_TARGET, "lossless"),
        ("ours-raw", LOSSLESS_TARGET, "lossless"),
        ("ours-raw-lz4", LOSSLESS_TARGET, "lossless"),
    ):
        mine = by_key[key]
        ratio = mine.fps / lerobot.fps
        lines.append(
            ratio_line(
                f"{kind}: {key} / {lerobot.method.key}",
                ratio,
                mine.fps_cpu / lerobot.fps_cpu,
                ratio >= target,
                f">= {target:g}",
            )
        )
    writes = manifest["write_seconds"]
    lines += [
        "",
        f"LeRobot's video: {video.get('video.codec')} {video.get('video.pix_fmt')} crf {video.get('video.crf')}, "
        f"GOP {video.get('video.g')}, preset {video.get('video.preset')} (LeRobot's default encoder; decoded by "
        f"{manifest['lerobot_decoder']} through PyAV), {manifest['lerobot_videos']} mp4 file(s); "
        "LeRobot has no lossless video default, "
        "so the lossless rows are compared with the same lossy video path.",
        "",
        "Write (once, single run) and size on disk:",
        "",
        "| format | write s | frames/s | MiB | KiB/frame |",
        "|---|---:|---:|---:|---:|",
    ]
    for key, stored in [*((key, f"{key}.mcap") for key in OURS), ("lerobot", "lerobot")]:
        lines.append(
            f"| {key}{' (whole dataset; its videos alone in the table above)' if key == 'lerobot' else ''} | "
            f"{writes[key]:.1f} | "
            f"{frames / writes[key]:,.0f} | {sizes[stored] / MIB:.1f} | {sizes[stored] / frames / 1024:.1f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=1782, help="first N frames of the camera (default 1782, all of them)")
    parser.add_argument(
        "--repeats", type=int, default=3, help="fresh-process runs per method; the median is reported (default 3)"
    )
    parser.add_argument(
        "--data-dir", type=Path, default=BENCH / "data", help="where data sets and the HF cache live (default bench/data)"
    )
    parser.add_argument("--regenerate", action="store_true", help="rewrite the data even if it is cached")
    parser.add_argument("--json", type=Path, help="also write every run's raw result here")
    parser.add_argument(
        "--prefault-gib",
        type=float,
        default=0.0,
        metavar="G",
        help="before each timed run, touch G GiB in a child process so that a VM which hands freed memory back to "
        "its host does not charge the run for getting it back (default 0: off)",
    )
    parser.add_argument("--measure", metavar="METHOD", choices=[m.key for m in METHODS], help=argparse.SUPPRESS)
    parser.add_argument("--prepare", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.frames < 2 or args.repeats < 1:
        parser.error("--frames must be at least 2 and --repeats positive")

    data_root = args.data_dir.resolve()
    data = data_root / f"pixels-so101-wrist-f{args.frames}"
    env = hf_environment(data_root)
    os.environ.update(env)  # before any Hugging Face library is imported here
    if args.measure:
        print(json.dumps(measure(args.measure, data, args.prefault_gib)))
        return
    if args.prepare:
        print(json.dumps(prepare(data, args.frames, args.regenerate)))
        return
    if not VIDEO.is_file():
        raise SystemExit(f"test data absent: {VIDEO} (the bench reads the SO-101 recording from ../shared/testdata)")

    started = time.perf_counter()
    common = [sys.executable, __file__, "--frames", str(args.frames), "--data-dir", str(data_root)]
    print("preparing the data (the first time: decode, write every format, check; a few minutes) ...", flush=True)
    manifest = run_json([*common, "--prepare", *(["--regenerate"] if args.regenerate else [])], env)
    load_before = os.getloadavg()[0]
    all_runs = [Runs(method) for method in METHODS]
    # Interleaved, so drift in machine load spreads over every method instead of hitting one.
    for repeat in range(args.repeats):
        for runs in all_runs:
            print(f"run {repeat + 1}/{args.repeats}: {runs.method.key} ...", end=" ", flush=True)
            measuring = [*common, "--measure", runs.method.key, "--prefault-gib", str(args.prefault_gib)]
            runs.results.append(run_json(measuring, env))
            print(f"{runs.results[-1]['seconds']:.2f} s", flush=True)
    print()
    print(report(all_runs, manifest, (load_before, os.getloadavg()[0]), args.prefault_gib))
    print(f"\nwhole benchmark: {time.perf_counter() - started:.0f} s wall (data generation included when it ran)")
    if args.json:
        args.json.write_text(json.dumps({"manifest": manifest, "runs": {r.method.key: r.results for r in all_runs}}, indent=2))


if __name__ == "__main__":
    main()

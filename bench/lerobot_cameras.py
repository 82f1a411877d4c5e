"""Issue 51: a LeRobot v2.1 set's two 224x224 cameras as demo files of each image codec.

Builds the set with lerobot's own writer (tests/lerobot_v21.py: AV1 videos, wall-clock stamps,
`timestamp` not declared), then, through the command line, converts it with each codec (and
resized), and times `imitation info` on each file and loading every frame. Prints a Markdown
table: file size against the videos' bytes, PSNR to PyAV's decode of the videos, times.

    .venv/bin/python bench/lerobot_cameras.py --episodes 25 --frames 60 --work /tmp/bench51
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(REPO), str(REPO / "tests")]

from lerobot_v21 import video_files, write_v21  # noqa: E402

from imitation.data.image_resize import resized  # noqa: E402
from imitation.data.mcap.reader import DemoFile  # noqa: E402

CASES = [  # (name, extra flags)
    ("png", ["--image-codec", "png"]),
    ("jpeg", ["--image-codec", "jpeg"]),
    ("jpeg q85", ["--image-codec", "jpeg", "--image-quality", "85"]),
    ("webp", ["--image-codec", "webp"]),
    ("webp q90", ["--image-codec", "webp", "--image-quality", "90"]),
    ("png 96x96", ["--image-codec", "png", "--image-size", "96x96"]),
    ("webp 96x96", ["--image-codec", "webp", "--image-size", "96x96"]),
]


def timed(argv: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, str(REPO / "cli.py"), *argv], check=True, capture_output=True, text=True)
    return time.perf_counter() - start


def pyav_frames(video: Path) -> np.ndarray:
    import av

    with av.open(str(video)) as container:
        return np.stack([frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)])


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float("inf") if mse == 0 else float(10 * np.log10(255.0**2 / mse))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=25)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--work", type=Path, required=True)
    args = parser.parse_args()
    shutil.rmtree(args.work, ignore_errors=True)
    args.work.mkdir(parents=True)
    testdata = REPO.parent / "shared" / "testdata"
    start = time.perf_counter()
    lengths = (args.frames,) * args.episodes
    root = write_v21(args.work / "set", testdata, lengths=lengths, jitter_s=0.006, declare_timestamp=False)
    print(f"lerobot wrote {args.episodes} episodes x {args.frames} frames x 2 cameras in {time.perf_counter() - start:.1f} s")
    videos = sum(video.stat().st_size for video in video_files(root))
    expected = {video.parent.name.removeprefix("observation.") + video.name: pyav_frames(video) for video in video_files(root)}
    print(f"videos: {videos / 1e6:.2f} MB\n")
    print("| codec | demo file | × videos | PSNR to PyAV's decode | convert | info | load every frame |")
    print("|---|---|---|---|---|---|---|")
    for name, flags in CASES:
        out = args.work / f"{name.replace(' ', '_')}.mcap"
        convert_s = timed(["convert", str(root), "--out", str(out), "--quiet", *flags])
        info_s = timed(["info", str(out)])
        start = time.perf_counter()
        episodes = list(DemoFile(out))
        load_s = time.perf_counter() - start
        size = tuple(episodes[0].observations["images.top"].shape[1:3])
        got, want = [], []
        for index, episode in enumerate(episodes):
            for camera in ("images.top", "images.wrist"):
                got.append(episode.observations[camera])
                frames = expected[f"{camera}episode_{index:06d}.mp4"]
                want.append(frames if size == (224, 224) else np.stack([resized(frame, size) for frame in frames]))
        quality = psnr(np.concatenate(got), np.concatenate(want))
        shown = "lossless" if quality == float("inf") else f"{quality:.1f} dB"
        print(
            f"| {name} | {out.stat().st_size / 1e6:.2f} MB | {out.stat().st_size / videos:.2f} | {shown} | "
            f"{convert_s:.1f} s | {info_s:.2f} s | {load_s:.2f} s |"
        )


if __name__ == "__main__":
    main()

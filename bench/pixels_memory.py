"""Benchmark: peak memory and learner idle time of BC streaming an image dataset larger than its budget.

Data: E synthetic CartPole-like episodes of S steps, 84×84 grayscale frames (a cart and a pole
drawn on a plain background, as a renderer would) beside a 4-dim state, Discrete(2) actions
that follow the pole's lean, written as PNG frames to one MCAP file by DemoWriter. The decoded
transitions (frames, state, action, reward, flags) are `--ratio` times the loader's memory cap.
The file is generated once (in a child process, so its memory is not counted) and cached under
--data-dir.

The measurement: BC (`BehaviouralCloning`, the default CNN, frame stack 4, random shift 4) for
one epoch over the training episodes and its streamed validation pass, with
`BCConfig.stream_memory` = the cap. The cap is enforced by the loader itself
(`imitation.data.stream`): a preallocated shuffle buffer of half the cap, and decoding admitted
only while the buffer plus decoded episodes waiting for it stay within the cap (at most one
episode over). Reported: the process's peak RSS (getrusage ru_maxrss, everything: Python, torch,
the CNN, its activations, the loader), the loader's own peak of decoded bytes held, the
fraction of the epoch the learner waited for a batch, and, beside the learner's rate, how fast
the loader alone delivers the training batches (one epoch drained, no training): the headroom a
faster learner (a GPU) would have before it waited. Targets (issue): peak RSS ≤ 1.5 GB and
idle < 10 %.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH.parent))
MB = 2**20
SIDE = 84
RSS_TARGET = 1.5e9  # bytes
IDLE_TARGET = 0.10


def episode_frames(seed: int, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames, states and actions of one synthetic episode: the cart drifts, the pole swings, the
    action pushes the way the pole leans."""
    import cv2

    rng = np.random.default_rng(seed)
    t = np.arange(steps + 1)
    x = 0.8 * np.sin(t / rng.uniform(20, 60) + rng.uniform(0, 6))
    theta = 0.2 * np.sin(t / rng.uniform(5, 15) + rng.uniform(0, 6))
    states = np.stack([x, np.gradient(x), theta, np.gradient(theta)], axis=1).astype(np.float32)
    frames = np.full((steps + 1, SIDE, SIDE, 1), 255, dtype=np.uint8)
    for i in range(steps + 1):
        cart = int(SIDE / 2 + x[i] * SIDE / 3)
        cv2.rectangle(frames[i], (cart - 8, 58), (cart + 8, 66), 0, -1)
        tip = (int(cart + 30 * math.sin(theta[i])), int(58 - 30 * math.cos(theta[i])))
        cv2.line(frames[i], (cart, 58), tip, 90, 3)
        cv2.line(frames[i], (0, 67), (SIDE - 1, 67), 40, 1)
    actions = (theta[:-1] > 0).astype(np.int64)
    return frames, states, actions


def generate(path: Path, episodes: int, steps: int) -> None:
    """Write the dataset (run in a child process: see the module docstring)."""
    import gymnasium as gym

    from imitation.data.mcap.writer import DemoWriter
    from imitation.data.types import Episode

    space = gym.spaces.Dict(
        {
            "pixels": gym.spaces.Box(0, 255, (SIDE, SIDE, 1), np.uint8),
            "state": gym.spaces.Box(-np.inf, np.inf, (4,), np.float32),
        }
    )
    started = time.perf_counter()
    partial = path.with_name(path.name + ".tmp")
    with DemoWriter(
        partial,
        env_id="SyntheticCartPolePixels-v0",
        observation_space=space,
        action_space=gym.spaces.Discrete(2),
        metadata={"pixels": {"size": [SIDE, SIDE], "grayscale": True}},
    ) as writer:
        for k in range(episodes):
            frames, states, actions = episode_frames(k, steps)
            writer.write(
                Episode(
                    observations={"pixels": frames, "state": states},
                    actions=actions,
                    rewards=np.ones(steps),
                    truncated=True,
                )
            )
    partial.rename(path)
    print(json.dumps({"write_seconds": time.perf_counter() - started, "file_bytes": path.stat().st_size}))


def measure(path: Path, cap: int, batch_size: int, frame_stack: int, threads: int, device: str) -> dict:
    """One epoch of streamed BC on `path` within `cap` bytes; the figures of the module docstring."""
    import torch

    from imitation.algorithms.bc import BCConfig, BehaviouralCloning, policy_options
    from imitation.data.dataset import DemoDataset
    from imitation.data.loader import split_episodes
    from imitation.data.stream import StreamingLoader
    from imitation.envs.pixels import stacked_space
    from imitation.policies import make_policy

    config = BCConfig(
        epochs=1,
        batch_size=batch_size,
        epoch_samples=0,
        frame_stack=frame_stack,
        stream_memory=cap,
        device=device,
        threads=threads,
        validation_fraction=0.1,
    )
    dataset = DemoDataset([path])
    train_ids, validation_ids = split_episodes(len(dataset), validation_fraction=config.validation_fraction, seed=0)
    options = {"batch_size": batch_size, "memory": cap, "frames": frame_stack, "image_keys": ["pixels"]}
    train = StreamingLoader(dataset, train_ids, seed=0, **options)
    validation = StreamingLoader(dataset, validation_ids, shuffle=False, **options)
    policy = make_policy(
        stacked_space(dataset.observation_space, frame_stack),
        dataset.action_space,
        **policy_options(config, train.transitions),
        frame_stack=frame_stack,
        observation_keys=["pixels"],
    )
    started = time.perf_counter()
    for _ in StreamingLoader(dataset, train_ids, seed=1, **options):
        pass  # the loader alone: how fast a learner could be fed
    loader_seconds = time.perf_counter() - started
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    learner = BehaviouralCloning(policy, train, validation, config)
    started = time.perf_counter()
    learner.step()
    epoch_seconds = time.perf_counter() - started
    row_bytes = train.row_bytes
    return {
        "train_transitions": train.transitions,
        "validation_transitions": validation.transitions,
        "decoded_dataset_bytes": dataset.num_transitions * (SIDE * SIDE + 4 * 4 + 8 + 8 + 2),
        "in_memory_stacked_bytes": dataset.num_transitions * row_bytes,
        "cap_bytes": cap,
        "loader_peak_bytes": max(train.peak_bytes, validation.peak_bytes),
        "rss_before_training_bytes": rss_before,
        "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
        "epoch_seconds": epoch_seconds,
        "waited_seconds": train.wait_seconds + validation.wait_seconds,
        "idle_fraction": (train.wait_seconds + validation.wait_seconds) / epoch_seconds,
        "batches": len(train),
        "loader_alone_transitions_per_second": train.transitions / loader_seconds,
        "learner_transitions_per_second": (train.transitions + validation.transitions) / epoch_seconds,
        "torch_threads": torch.get_num_threads(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cap-mb", type=int, default=128, help="the loader's memory cap (default: 128)")
    parser.add_argument("--ratio", type=float, default=4.0, help="decoded dataset size / cap (default: 4)")
    parser.add_argument("--steps", type=int, default=500, help="steps per episode (default: 500)")
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--frame-stack", type=int, default=4)
    parser.add_argument("--threads", type=int, default=1, help="torch threads of the learner (default: 1)")
    parser.add_argument("--device", default="cpu", help="where the network runs (default: cpu)")
    parser.add_argument("--data-dir", type=Path, default=Path("/tmp/imitation-bench-pixels"))
    parser.add_argument("--generate", type=Path, help=argparse.SUPPRESS)  # the child process's job
    parser.add_argument("--episodes", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.generate is not None:
        generate(args.generate, args.episodes, args.steps)
        return
    cap = args.cap_mb * MB
    transition_bytes = SIDE * SIDE + 4 * 4 + 8 + 8 + 2
    episodes = math.ceil(args.ratio * cap / (args.steps * transition_bytes))
    path = args.data_dir / f"pixels-{episodes}x{args.steps}.mcap"
    written = {}
    if not path.exists():
        args.data_dir.mkdir(parents=True, exist_ok=True)
        command = [sys.executable, __file__, "--generate", str(path), "--episodes", str(episodes), "--steps", str(args.steps)]
        written = json.loads(subprocess.run(command, check=True, capture_output=True, text=True).stdout.splitlines()[-1])
    result = measure(path, cap, args.batch_size, args.frame_stack, args.threads, args.device) | written
    result |= {"episodes": episodes, "file": str(path)}
    print(json.dumps(result, indent=1))
    rss, idle = result["peak_rss_bytes"], result["idle_fraction"]
    print(
        f"peak RSS {rss / 1e9:.2f} GB (target ≤ {RSS_TARGET / 1e9:.1f}: {'met' if rss <= RSS_TARGET else 'MISSED'}); "
        f"learner idle {idle:.1%} (target < {IDLE_TARGET:.0%}: {'met' if idle < IDLE_TARGET else 'MISSED'})"
    )


if __name__ == "__main__":
    main()

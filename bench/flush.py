"""Benchmark: what crash safety costs the demo writer, per write mode.

Writes the same synthetic rollouts (4-float observations, one discrete action) through
`DemoWriter` three ways: chunks of 1 MiB (the default), a chunk per episode handed to the OS
(`flush_episodes=True`, what `convert` does: kill -9 keeps every finished episode) and a chunk
per episode fsync'd (`durable=True`, what `record` does: a power cut keeps them too). Prints the
wall time, the file size and both as ratios to the default, for short and long episodes.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

from imitation.data.mcap.writer import DemoWriter
from imitation.data.types import Episode

MODES = {"1 MiB chunks": {}, "flush per episode": {"flush_episodes": True}, "fsync per episode": {"durable": True}}
OBSERVATIONS = gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)
ACTIONS = gym.spaces.Discrete(2)


def rollouts(episodes: int, length: int, seed: int) -> list[Episode]:
    rng = np.random.default_rng(seed)
    return [
        Episode(
            observations=rng.normal(size=(length + 1, 4)).astype(np.float32), actions=rng.integers(0, 2, length),
            rewards=rng.normal(size=length), terminated=False, truncated=True,
        )
        for _ in range(episodes)
    ]


def write(path: Path, episodes: list[Episode], options: dict) -> float:
    started = time.perf_counter()
    with DemoWriter(path, env_id="Bench-v0", observation_space=OBSERVATIONS, action_space=ACTIONS, dt=0.02, **options) as writer:
        for episode in episodes:
            writer.write(episode)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["30000x10", "200x500"], metavar="EPISODESxSTEPS", help="(default: 30000x10 200x500)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(f"{'episodes × steps':>17} | {'mode':>17} | {'seconds':>7} | {'MiB':>6} | time ratio | size ratio")
    with tempfile.TemporaryDirectory(prefix="bench-flush-") as folder:
        for case in args.cases:
            count, length = (int(part) for part in case.split("x"))
            episodes = rollouts(count, length, args.seed)
            baseline: tuple[float, int] | None = None
            for name, options in MODES.items():
                path = Path(folder) / f"{case}-{len(name)}.mcap"
                seconds, size = write(path, episodes, options), path.stat().st_size
                baseline = baseline or (seconds, size)
                print(f"{count:>8} × {length:<6} | {name:>17} | {seconds:7.2f} | {size / 2**20:6.2f} | {seconds / baseline[0]:9.2f}× | {size / baseline[1]:9.2f}×")


if __name__ == "__main__":
    main()

"""Acting one observation at a time: a SAC expert's step on one torch thread and on two, with the
other core idle and then busy (a spinning process beside it), the case `SingleObservationPolicy`
sets one thread for (imitation/policies.py).

Usage: python bench/single_observation_threads.py [--steps 300]
"""

from __future__ import annotations

import argparse
import multiprocessing
import time
from pathlib import Path

import torch

import imitation.envs  # noqa: F401  (registers the ids)
from imitation.envs.make import make_env
from imitation.experts.load import load_expert

ZIP = (
    Path(__file__).resolve().parents[2]
    / "shared"
    / "testdata"
    / "experts"
    / "zoo"
    / "sac_HalfCheetah-v3"
    / "HalfCheetah-v3.zip"
)


def spin() -> None:
    while True:
        pass


def milliseconds_per_step(expert, observation, steps: int, threads: int) -> float:
    torch.set_num_threads(threads)
    started = time.perf_counter()
    for _ in range(steps):
        expert(observation)
    return (time.perf_counter() - started) / steps * 1000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=300)
    args = parser.parse_args()
    env = make_env("imitation/HalfCheetahFixedHorizon-v0")
    observation, _ = env.reset(seed=0)
    expert = load_expert(f"sb3:{ZIP}", env, seed=0)
    milliseconds_per_step(expert, observation, args.steps, 2)  # warm-up: first calls allocate
    for load in ("idle", "busy"):
        spinner = multiprocessing.Process(target=spin, daemon=True) if load == "busy" else None
        if spinner is not None:
            spinner.start()
        one, two = (milliseconds_per_step(expert, observation, args.steps, n) for n in (1, 2))
        print(f"other core {load}: {one:.3f} ms a step on 1 thread, {two:.3f} ms on 2 ({two / one:.1f}x)", flush=True)
        if spinner is not None:
            spinner.terminate()


if __name__ == "__main__":
    main()

"""Benchmark: PPO's rollouts on Ray actors (`--workers N`) beside the single-process learner.

For each environment, a fixed-length PPO run (the env's preset, as `train ppo` runs it) in one
process, then on a local Ray with 1, 2 and 4 rollout workers. Ray is told it has as many CPUs as
there are workers (`ray.init(num_cpus=N)`), so 4 workers on a 2-core machine is a simulation:
the actors share the cores. Each run is a fresh process; Ray's start-up is excluded (the clock
starts when the learner is built), its actors' start-up is not: steps/s includes it.

Printed per run: env-steps/s, the efficiency per worker (steps/s of N workers divided by N times
the steps/s of one worker), and where the learner's time went: updates, waiting for the
slowest worker's collection, the actors' start-up (once, before the first rollout), and the cost
of going through Ray at every rollout:

- broadcast: putting π_k's weights in the object store and submitting the collections, plus
  the slowest worker's loading of them;
- gather: the wait beyond the slowest worker's collection (scheduling, serialising and fetching
  the segments), plus copying them into the learner's buffers.

Target (issue 23): broadcast + gather ≤ 20 % of the update time at 2 workers.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OVERHEAD_TARGET = 0.20
# Steps per run and settings over the env's preset: HalfCheetah's preset steps one env, which one
# worker cannot split, so it runs 4 copies of 512 steps (the preset's 2,048 per update).
ENVS: dict[str, tuple[int, dict[str, int]]] = {
    "CartPole-v1": (100_000, {}),
    "HalfCheetah-v5": (49_152, {"n_envs": 4, "n_steps": 512}),
}


def worker(env_id: str, workers: int) -> dict[str, float]:
    """One run in this process: `workers` 0 is the single-process learner."""
    sys.path.insert(0, str(ROOT))
    import torch

    from imitation.algorithms.ppo import PPO
    from imitation.algorithms.ray_rollouts import RayRollouts
    from imitation.jobs.loop import run
    from imitation.jobs.presets import ppo_config
    from imitation.ray_engine import ray_session

    torch.set_num_threads(1)
    steps, settings = ENVS[env_id]
    config = ppo_config(env_id, total_steps=steps, seed=0, device="cpu", **settings)
    with ray_session(num_cpus=max(workers, 1)):
        started = time.perf_counter()
        remote = RayRollouts(config.n_envs, workers) if workers else None
        learner = PPO(config, remote=remote)
        rows = run(learner)
        seconds = time.perf_counter() - started
        learner.close()
    result = {
        "steps_per_second": learner.global_step / seconds,
        "seconds": seconds,
        "update": learner.timers["update"],
        "return": rows[-1]["return"],
    }
    if remote is not None:
        spent = remote.seconds
        result |= {
            "broadcast": spent["broadcast"] + spent["worker_load"],
            "gather": max(0.0, spent["wait"] - spent["worker_collect"] - spent["worker_load"]) + spent["gather"],
            "collect": spent["worker_collect"],
            "start": spent["start"],
        }
    return result


def measure(env_id: str, workers: int) -> dict[str, float]:
    command = [sys.executable, __file__, "--worker", env_id, str(workers)]
    environment = {**os.environ, "OMP_NUM_THREADS": "1"}
    output = subprocess.run(command, capture_output=True, text=True, check=True, env=environment).stdout
    return json.loads(output.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--worker", nargs=2, metavar=("ENV", "WORKERS"), help=argparse.SUPPRESS)
    parser.add_argument("--envs", nargs="+", default=list(ENVS), choices=list(ENVS), help="environments (default: all)")
    args = parser.parse_args()
    if args.worker:
        env_id, workers = args.worker
        print(json.dumps(worker(env_id, int(workers))))
        return
    for env_id in args.envs:
        steps, settings = ENVS[env_id]
        print(f"\n{env_id}: {steps:,} steps, the preset's settings" + (f" but {settings}" if settings else ""))
        print(
            f"{'run':>10} {'steps/s':>8} {'eff/worker':>10} {'update s':>8} {'collect s':>9} {'bcast s':>7} {'gather s':>8} "
            f"{'start s':>7} {'(b+g)/upd':>9} {'return':>7}"
        )
        one = None
        for workers in (0, 1, 2, 4):
            result = measure(env_id, workers)
            name = "1 process" if workers == 0 else f"{workers} worker" + ("s" if workers > 1 else "")
            if workers == 1:
                one = result["steps_per_second"]
            efficiency = f"{result['steps_per_second'] / (workers * one):.2f}" if workers and one else "-"
            if workers:
                overhead = (result["broadcast"] + result["gather"]) / result["update"]
                flag = "" if workers != 2 else (" ✓" if overhead <= OVERHEAD_TARGET else " ✗")
                ray_part = (
                    f"{result['collect']:>9.1f} {result['broadcast']:>7.2f} {result['gather']:>8.2f} {result['start']:>7.2f} "
                    f"{overhead:>8.0%}{flag:2}"
                )
            else:
                ray_part = f"{'-':>9} {'-':>7} {'-':>8} {'-':>7} {'-':>9}"
            print(
                f"{name:>10} {result['steps_per_second']:>8.0f} {efficiency:>10} {result['update']:>8.1f} {ray_part} "
                f"{result['return']:>7.1f}",
                flush=True,
            )


if __name__ == "__main__":
    main()

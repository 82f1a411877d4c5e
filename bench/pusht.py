"""Benchmark: state-based PushT from the Diffusion Policy paper's 206 human demonstrations, through
the CLI as a user runs it, beside trivial closed-loop baselines.

`convert` the zarr replay buffer (../shared/testdata/manipulation/pusht) for `gym_pusht/PushT-v0`,
`train bc` each policy head named by --heads (the Gaussian actor-critic, the chunk head with a
receding horizon and with temporal ensembling, the diffusion head), then `eval policy` each on the
same --episodes episodes (seeds 10000 + i), reporting what the PushT literature reports: the mean
over episodes of the largest coverage of the goal the block reached, and the success rate (coverage
above 0.95). The baselines act in the same episodes: uniform random targets, and "hold" (the target
is the agent's own position: nothing moves, the block's first coverage stays). Prints a line per
policy and one JSON object (bench/RESULTS.md, "PushT").

    .venv/bin/python bench/pusht.py [--heads gaussian chunk diffusion] [--epochs N] [--seed S] [--threads T]
        [--patience P] [--train-flags="--observation-noise 0.1"] [--keep DIR --name=-SUFFIX]
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests"))
from support import TESTDATA  # noqa: E402

ZARR = TESTDATA / "manipulation" / "pusht" / "pusht_cchi_v7_replay.zarr"
ENV = "gym_pusht/PushT-v0"
EVAL_SEED = 10_000
# The heads' flags: the Diffusion Policy paper's windows (2 observations, 16 actions, 8 executed), the
# block's angle (state position 4) read as (cos, sin).
WINDOWS = ["--history", "2", "--chunk", "16", "--angles", "4"]
# The sequence heads train for --epochs on all but 5 % of the episodes, without weight decay or early
# stopping, as the Diffusion Policy code does; today's Gaussian BC at its defaults (early stopping on 20 %).
SEQUENCE = ["--hidden", "512,512,512", "--validation", "0.05", "--l2", "0"]
HEADS = {
    "gaussian": ["--policy", "actor-critic"],
    "chunk": ["--policy", "chunk", *WINDOWS, *SEQUENCE, "--execute", "8"],
    "chunk-ensemble": ["--policy", "chunk", *WINDOWS, *SEQUENCE, "--ensemble", "0.01"],
    "diffusion": ["--policy", "diffusion", *WINDOWS, *SEQUENCE, "--execute", "8", "--lr", "3e-4"],
}


def cli(*args: str, threads: int) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": str(threads)}
    return subprocess.run([sys.executable, str(REPO / "cli.py"), *args], check=True, env=env, capture_output=True, text=True)


def baseline(name: str, episodes: int) -> dict[str, float]:
    """Mean max coverage and success rate of a trivial policy in the evaluation episodes."""
    import gym_pusht  # noqa: F401  (registers the env)
    import gymnasium as gym

    env = gym.make(ENV)
    rng = np.random.default_rng(0)
    coverages, successes = [], []
    for i in range(episodes):
        observation, _ = env.reset(seed=EVAL_SEED + i)
        best, success, done = 0.0, False, False
        while not done:
            action = rng.uniform(0, 512, 2) if name == "random" else observation[:2]
            observation, _, terminated, truncated, info = env.step(np.asarray(action, dtype=np.float32))
            best, success, done = max(best, info["coverage"]), success or info["is_success"], terminated or truncated
        coverages.append(best)
        successes.append(success)
    return {"mean_max_coverage": float(np.mean(coverages)), "success_rate": float(np.mean(successes))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--heads", nargs="+", choices=sorted(HEADS), default=sorted(HEADS))
    parser.add_argument("--epochs", type=int, default=300)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--keep", type=Path, default=None, help="keep the demos and runs in this folder")
    parser.add_argument("--patience", type=int, default=None, help="the sequence heads' patience (default: --epochs)")
    parser.add_argument("--train-flags", default="", help="more `train bc` flags for every head, as one string")
    parser.add_argument("--name", default="", help="a suffix of the run folders' names (with --keep)")
    args = parser.parse_args()
    results: dict[str, dict[str, float]] = {}
    for name in ("random", "hold"):
        results[name] = baseline(name, args.episodes)
        print(
            f"{name}: mean max coverage {results[name]['mean_max_coverage']:.3f}, success {results[name]['success_rate']:.2f}"
        )
    with tempfile.TemporaryDirectory(prefix="bench-pusht-") as folder:
        work = args.keep or Path(folder)
        work.mkdir(parents=True, exist_ok=True)
        demos = work / "pusht.mcap"
        if not demos.exists():
            cli("convert", str(ZARR), "--env", ENV, "--out", str(demos), "--quiet", threads=args.threads)
        for head in args.heads:
            run = work / f"{head}-seed{args.seed}{args.name}"
            patience = str(args.patience or args.epochs)
            common = ["--epochs", str(args.epochs), *(["--patience", patience] if head != "gaussian" else [])]
            common += shlex.split(args.train_flags)
            started = time.perf_counter()
            cli("train", "bc", "--demos", str(demos), "--env", ENV, *HEADS[head], *common, "--seed", str(args.seed),
                "--threads", str(args.threads), "--out", str(run), "--quiet", threads=args.threads)  # fmt: skip
            train_seconds = time.perf_counter() - started
            started = time.perf_counter()
            evaluation = json.loads(
                cli(
                    "eval",
                    "policy",
                    str(run),
                    "--env",
                    ENV,
                    "--episodes",
                    str(args.episodes),
                    "--seed",
                    str(EVAL_SEED),
                    "--json",
                    threads=args.threads,
                ).stdout  # fmt: skip
            )
            eval_seconds = time.perf_counter() - started
            results[head] = {
                "mean_max_coverage": evaluation["mean_max_coverage"],
                "success_rate": evaluation["success_rate"],
                "train_minutes": train_seconds / 60,
                "seconds_per_action": eval_seconds / (evaluation["mean_length"] * args.episodes),  # env steps included
            }
            print(
                f"{head}: mean max coverage {evaluation['mean_max_coverage']:.3f}, success {evaluation['success_rate']:.2f}, "
                f"trained {train_seconds / 60:.1f} min, {results[head]['seconds_per_action'] * 1e3:.2f} ms per action"
            )
    print(
        json.dumps(
            {"epochs": args.epochs, "episodes": args.episodes, "seed": args.seed, "threads": args.threads,
             "train_flags": args.train_flags, "results": results}  # fmt: skip
        )
    )


if __name__ == "__main__":
    main()

"""Benchmark: where a fresh process's first BC training loses its time (bench/bc.py's "cold" row).

In a fresh process, one torch thread: the import of torch; building imitation's `FlatAdam` (what
BC and PPO use) and then `torch.optim.Adam`, each the first and the second time, and their first
and second steps; and, in another fresh process, with a fresh policy each, building
`BehaviouralCloning` on bench/bc.py's CartPole data the first and the second time. Medians of
--repeats fresh processes.

Usage: python bench/cold_start.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parent
DATA = BENCH.parent.parent / "shared" / "testdata" / "experts" / "expert_cartpole.npz"


def worker() -> dict[str, float]:
    import time

    started = time.perf_counter()
    import torch

    timings = {"import torch": time.perf_counter() - started}
    torch.set_num_threads(1)
    sys.path.insert(0, str(BENCH.parent))
    from imitation.flat_adam import FlatAdam

    for attempt in ("first", "second"):
        layer = torch.nn.Linear(4, 2)
        started = time.perf_counter()
        flat = FlatAdam(layer.parameters(), lr=1e-3)
        timings[f"{attempt} FlatAdam(...)"] = time.perf_counter() - started
        layer(torch.randn(8, 4)).sum().backward()
        started = time.perf_counter()
        flat.step()
        timings[f"{attempt} FlatAdam.step()"] = time.perf_counter() - started
    for attempt in ("first", "second"):
        layer = torch.nn.Linear(4, 2)
        started = time.perf_counter()
        optimiser = torch.optim.Adam(layer.parameters(), lr=1e-3)
        timings[f"{attempt} Adam(...)"] = time.perf_counter() - started
        layer(torch.randn(8, 4)).sum().backward()
        started = time.perf_counter()
        optimiser.step()
        timings[f"{attempt} Adam.step()"] = time.perf_counter() - started
    return timings


def bc_worker() -> dict[str, float]:
    import time

    import gymnasium as gym
    import torch

    sys.path.insert(0, str(BENCH.parent))
    sys.path.insert(0, str(BENCH))
    from bc import _our_transitions

    from imitation.algorithms.bc import BCConfig, BehaviouralCloning, policy_options
    from imitation.policies import make_policy

    torch.set_num_threads(1)
    train = _our_transitions(str(DATA))
    config = BCConfig(hidden_sizes=[32, 32], validation_fraction=0.0, epochs=5, patience=5, seed=0, device="cpu", threads=1)
    env = gym.make("CartPole-v1")
    timings = {}
    for attempt in ("first", "second"):
        policy = make_policy(env.observation_space, env.action_space, **policy_options(config))
        started = time.perf_counter()
        BehaviouralCloning(policy, train, None, config)
        timings[f"{attempt} BehaviouralCloning(...)"] = time.perf_counter() - started
    return timings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--worker", choices=["torch", "bc"], help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker() if args.worker == "torch" else bc_worker()))
        return
    runs: dict[str, list[float]] = {}
    for _ in range(args.repeats):
        for kind in ("torch", "bc"):
            done = subprocess.run([sys.executable, __file__, "--worker", kind], capture_output=True, text=True, check=True)
            for name, seconds in json.loads(done.stdout.strip().splitlines()[-1]).items():
                runs.setdefault(name, []).append(seconds)
    print(f"fresh processes, median of {args.repeats}:")
    for name, values in runs.items():
        print(f"  {name:32s} {statistics.median(values) * 1000:9.1f} ms   ({', '.join(f'{v * 1000:.1f}' for v in values)})")


if __name__ == "__main__":
    main()
